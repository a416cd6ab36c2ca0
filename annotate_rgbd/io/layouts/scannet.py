"""ScanNet's exported layout (what ScanNet's ``SensReader`` writes from a ``.sens`` file).

::

    scene0000_00/
        color/0.jpg 1.jpg ...        colour images (1296 x 968 in ScanNet v2)
        depth/0.png 1.png ...        16-bit depth, millimetres (640 x 480), 0 = no depth
        pose/0.txt 1.txt ...         4 x 4 camera-to-world matrices; all -inf where tracking failed
        intrinsic/intrinsic_color.txt  intrinsic_depth.txt  extrinsic_color.txt  extrinsic_depth.txt

Frames are numbers, not timestamps: ``color/i.jpg``, ``depth/i.png`` and ``pose/i.txt`` are one
frame (a frame skip when exporting leaves gaps: 0, 10, 20 ...). The depth camera is
``intrinsic_depth.txt`` (4 x 4, the pinhole matrix in its top-left corner) with a depth scale of
1000 (ScanNet's ``depthShift``); the colour camera is ``intrinsic_color.txt`` at the size of the
colour images. Each extrinsic maps its camera's frame to the rig's base frame, the colour
camera's: ScanNet's ``SensReader/src/sensorData.h`` says of ``m_extrinsic`` "the mapping to base
frame in a multi-view setup (typically it's depth to color; and the color extrinsic is the
identity)", and ScanNet's ``Converter/src/metaData.h`` stores the inverse of a scan's
``colorToDepthExtrinsics`` as the depth extrinsic and the identity as the colour one. So a depth
camera point reaches the colour camera's frame by ``inv(extrinsic_color) @ extrinsic_depth``
(``extrinsic_depth`` itself when the colour one is the identity). In the released ScanNet scans
both are the identity: ScanNet's ``Calibrate`` tool re-projected the depth into the colour
camera before release (depth intrinsics = colour intrinsics scaled to 640 x 480). A missing
extrinsic file is the identity.

Only ``depth/`` is required (``propose`` works on depth alone); the folder is recognised as
ScanNet's by ``depth/`` with any of ``color/``, ``pose/`` or ``intrinsic/``.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from annotate_rgbd.errors import InputError
from annotate_rgbd.io.images import read_image
from annotate_rgbd.io.rotations import rigid_problem
from .lists import check_inside, numbered_files, read_matrix
from .model import FRAME_NUMBERS, ColourCamera, LayoutCamera, Sequence

NAME = "ScanNet"
#: Raw depth units per metre: ScanNet's ``depthShift`` (millimetres).
DEPTH_SCALE = 1000.0
DEPTH_NAMES = r"(\d+)\.png"
COLOUR_NAMES = r"(\d+)\.(?:jpg|jpeg|png)"


def is_scannet(root: Path) -> bool:
    return (root / "depth").is_dir() and any((root / name).is_dir() for name in ("color", "pose", "intrinsic"))


def read_scannet(root: Path) -> Sequence:
    """Read a ScanNet export folder into the sequence model.

    Raises
    ------
    InputError
        A frame file of another name in ``depth/`` or ``color/``, an unreadable or malformed
        intrinsic or extrinsic matrix, a non-rigid extrinsic.
    """
    folders = tuple(name for name in ("color", "depth", "pose", "intrinsic") if (root / name).exists())
    check_inside(root, folders)
    depth = numbered_files(root / "depth", root, DEPTH_NAMES, "<frame number>.png, as ScanNet exports depth")
    rgb = None
    if (root / "color").is_dir():
        rgb = numbered_files(root / "color", root, COLOUR_NAMES, "<frame number>.jpg, as ScanNet exports colour")
        rgb = rgb if len(rgb) else None
    intrinsic = root / "intrinsic"
    camera = depth_camera(intrinsic / "intrinsic_depth.txt")
    notes = () if camera is not None else (
        f"{intrinsic / 'intrinsic_depth.txt'} not found: give the depth camera with --config "
        f"(ScanNet depth is in millimetres: depth_scale = {DEPTH_SCALE:g})",
    )
    colour = None
    if rgb is not None and (intrinsic / "intrinsic_color.txt").exists():
        colour = colour_camera(intrinsic, root / rgb.files[0])
    poses = root / "pose" if (root / "pose").is_dir() else None
    return Sequence(root, rgb, depth, NAME, FRAME_NUMBERS, camera, colour, poses, notes)


def pinhole(path: Path) -> tuple[float, float, float, float]:
    """``(fx, fy, cx, cy)`` of a 3 x 3 or 4 x 4 intrinsic matrix file.

    Raises
    ------
    InputError
        Unreadable or malformed, or a focal length of zero.
    """
    matrix = read_matrix(path, shapes=((3, 3), (4, 4)))
    fx, fy, cx, cy = matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2]
    if fx == 0 or fy == 0:
        raise InputError(path, f"not an intrinsic matrix: focal length fx {fx:g}, fy {fy:g}")
    return float(fx), float(fy), float(cx), float(cy)


def depth_camera(path: Path) -> LayoutCamera | None:
    """The depth camera of ``intrinsic_depth.txt`` with ScanNet's depth scale; None without the file."""
    if not path.exists():
        return None
    return LayoutCamera(*pinhole(path), depth_scale=DEPTH_SCALE, source=str(path))


def colour_camera(intrinsic: Path, first_image: Path) -> ColourCamera:
    """The colour camera: ``intrinsic_color.txt``, the size of the first colour image, and the
    depth-to-colour transform from the two extrinsic files.

    Raises
    ------
    InputError
        A malformed matrix, an extrinsic that is not a rigid transform, an unreadable image.
    """
    fx, fy, cx, cy = pinhole(intrinsic / "intrinsic_color.txt")
    height, width = read_image(first_image, cv2.IMREAD_GRAYSCALE).shape[:2]
    extrinsic = {}
    for name in ("extrinsic_color.txt", "extrinsic_depth.txt"):
        path = intrinsic / name
        extrinsic[name] = read_matrix(path) if path.exists() else np.eye(4)
        problem = rigid_problem(extrinsic[name])
        if problem is not None:
            raise InputError(path, f"not a rigid transform: {problem}")
    # Each extrinsic is camera -> base frame (the colour camera's): X_colour = inv(E_c) E_d X_depth.
    depth_to_colour = np.linalg.inv(extrinsic["extrinsic_color.txt"]) @ extrinsic["extrinsic_depth.txt"]
    return ColourCamera(fx, fy, cx, cy, int(width), int(height), depth_to_colour,
                        source=str(intrinsic / "intrinsic_color.txt"))

"""RGB-D sequences: the format-neutral model, reading any known layout, and pairing frames.

The layouts (TUM RGB-D, ICL-NUIM, ScanNet, 7-Scenes, depth-only folders) are each read in one
place (:mod:`annotate_rgbd.io.layouts`) into one model, re-exported here with the image readers
(:mod:`annotate_rgbd.io.images`) that every stage uses:

- :class:`Sequence`: the folder, its colour and depth :class:`FrameList` s, what the timestamps
  count (``clock``: seconds, or frame numbers in ScanNet and 7-Scenes), the layout's own depth
  camera (``camera``), colour camera (``colour_camera``, when colour is on another grid) and
  per-frame poses (``poses``);
- :func:`read_sequence`: the layout recognised by its files; a folder that fits none is one
  error line naming every layout known;
- :func:`associate`: each depth frame's nearest colour frame; :func:`camera_problem` and
  :func:`focal_problem`: intrinsics that do not fit the images.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from annotate_rgbd.errors import InputError
from .files import open_regular
from .inputs import open_input
from .images import (
    MAX_IMAGE_BYTES, MAX_IMAGE_PIXELS, NO_DEPTH_16, PNG_SIGNATURE, decode_image, png_size, read_bytes, read_depth,
    read_image, read_rgb,
)
from .layouts import scannet, seven_scenes, tum
from .layouts.lists import (
    IMAGE_SUFFIXES, MAX_FRAMES, MAX_LIST_BYTES, MAX_LIST_LINES, MAX_TIMESTAMP, check_depth_names, check_inside,
    parse_timestamp,
)
from .layouts.model import FRAME_NUMBERS, SECONDS, ColourCamera, FrameList, LayoutCamera, Sequence
from .layouts.tum import list_image_folder, read_associations, read_frame_list

__all__ = [
    "EXPECTED", "FRAME_NUMBERS", "IMAGE_SUFFIXES", "LAYOUTS", "MAX_FRAMES", "MAX_IMAGE_BYTES", "MAX_IMAGE_PIXELS",
    "MAX_LIST_BYTES", "MAX_LIST_LINES", "MAX_TIMESTAMP", "NO_DEPTH_16", "PNG_SIGNATURE", "SECONDS", "ColourCamera",
    "FrameList", "LayoutCamera", "Sequence", "associate", "camera_problem", "focal_problem", "intrinsics_problems", "check_depth_names", "check_inside",
    "decode_image", "list_image_folder", "open_input", "open_regular", "parse_timestamp", "png_size",
    "read_associations", "read_bytes", "read_depth", "read_frame_list", "read_image", "read_rgb", "read_sequence",
]


#: (test, reader) of each layout, in the order they are tried: the TUM lists first
#: (a TUM folder also has ``rgb/`` and ``depth/``), ScanNet before ``rgb/``-and-``depth/`` folders.
LAYOUTS = (
    (tum.is_tum_lists, tum.read_tum_lists),
    (tum.is_associations, tum.read_icl),
    (scannet.is_scannet, scannet.read_scannet),
    (tum.is_tum_folders, tum.read_tum_folders),
    (seven_scenes.is_seven_scenes, seven_scenes.read_seven_scenes),
    (tum.is_depth_list, tum.read_depth_list),
    (tum.is_depth_folder, tum.read_depth_folder),
)
#: What the one-line error names when no layout fits.
EXPECTED = (
    "TUM RGB-D (rgb.txt and depth.txt), ICL-NUIM (associations.txt), ScanNet (color/, depth/, pose/, "
    "intrinsic/), 7-Scenes (frame-000000.color.png, .depth.png, .pose.txt), rgb/ and depth/ folders, "
    "or for propose depth only (depth.txt or depth/)"
)


def read_sequence(root: str | Path, need_rgb: bool = True) -> Sequence:
    """Read the frame lists of a sequence folder in any known layout.

    Parameters
    ----------
    root : str or Path
        The sequence folder.
    need_rgb : bool
        Refuse a folder without colour images (``cvat2mask``: the polygons were drawn on them);
        ``propose`` works on depth alone.

    Returns
    -------
    Sequence

    Raises
    ------
    InputError
        The folder is missing or fits no layout (the layouts are named), a list or frame name is
        malformed, empty or too long, a timestamp is not finite or out of range, a symbolic link
        leads a file out of the folder, or (``need_rgb``) there are no colour images.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(root, "sequence folder not found")
    for fits, reader in LAYOUTS:
        if fits(root):
            sequence = reader(root)
            break
    else:
        raise InputError(root, f"not an RGB-D sequence: expected {EXPECTED}")
    if sequence.rgb is not None and len(sequence.rgb) == 0:
        raise InputError(root, "the sequence lists no RGB frames")
    if len(sequence.depth) == 0:
        raise InputError(root, "the sequence lists no depth frames")
    if sequence.rgb is None and need_rgb:
        raise InputError(
            root, f"{sequence.layout}: no colour images; cvat2mask needs the images the polygons were drawn on "
            "(propose works on depth alone)"
        )
    check_depth_names(sequence.depth, root / _depth_source(sequence))
    check_inside(root, (sequence.rgb.files if sequence.rgb is not None else ()) + sequence.depth.files)
    return sequence


def _depth_source(sequence: Sequence) -> str:
    """Where the depth frames are listed, for messages."""
    first = sequence.depth.files[0]
    if sequence.layout.startswith("TUM RGB-D") or sequence.layout.startswith("depth.txt"):
        return "depth.txt"
    if sequence.layout.startswith("ICL-NUIM"):
        return "associations.txt"
    return first.rpartition("/")[0]


def associate(depth_times: np.ndarray, rgb_times: np.ndarray, max_time_diff: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every depth frame, the RGB frame nearest in time.

    Unlike TUM's ``associate.py`` (greedy one-to-one pairing), an RGB frame may serve several
    depth frames: every depth frame gets the annotation of the image the labeller saw closest
    to it.

    Parameters
    ----------
    depth_times, rgb_times : ndarray of float64
        Timestamps in seconds, each strictly increasing.
    max_time_diff : float
        Largest accepted |t_depth - t_rgb| in seconds.

    Returns
    -------
    nearest : ndarray of int64, shape (N_depth,)
        Index of the nearest RGB frame.
    time_diff : ndarray of float64, shape (N_depth,)
        ``t_rgb - t_depth`` for that frame.
    matched : ndarray of bool, shape (N_depth,)
        Whether the nearest RGB frame is within ``max_time_diff``.
    """
    depth_times = np.asarray(depth_times, dtype=np.float64)
    rgb_times = np.asarray(rgb_times, dtype=np.float64)
    if len(rgb_times) == 1:
        nearest = np.zeros(len(depth_times), dtype=np.int64)
    else:
        after = np.clip(np.searchsorted(rgb_times, depth_times), 1, len(rgb_times) - 1)
        before = after - 1
        pick_after = np.abs(rgb_times[after] - depth_times) < np.abs(depth_times - rgb_times[before])
        nearest = np.where(pick_after, after, before).astype(np.int64)
    time_diff = rgb_times[nearest] - depth_times
    # A tiny tolerance: timestamps are printed with 6 decimals, so 0.02 must not read as 0.0200001.
    matched = np.abs(time_diff) <= max_time_diff + 1e-9
    return nearest, time_diff, matched


def camera_problem(cx: float, cy: float, width: int, height: int) -> str | None:
    """Why intrinsics with principal point ``(cx, cy)`` look wrong for ``width x height`` images.

    The principal point of a real RGB-D camera lies near the image centre; one outside the
    middle half of the image usually means intrinsics for another resolution (TUM's 640x480
    values on half-size images, or the other way round).

    Parameters
    ----------
    cx, cy : float
        Principal point in pixels.
    width, height : int
        Size of the depth images.

    Returns
    -------
    str or None
        A one-line warning, or ``None`` when the principal point is plausible.
    """
    if abs(cx - width / 2) <= width / 4 and abs(cy - height / 2) <= height / 4:
        return None
    where = "outside" if not (0 <= cx <= width and 0 <= cy <= height) else "far from the centre of"
    return (
        f"the camera's principal point ({cx:g}, {cy:g}) is {where} the {width}x{height} depth "
        "images: are the [camera] intrinsics for another resolution?"
    )


#: Horizontal fields of view of depth cameras, degrees: a Kinect v1 58, a Kinect v2 70, a
#: RealSense D435 87, an Azure Kinect's wide mode 120. Outside these bounds the focal length is
#: almost surely not in pixels of these images.
FIELD_OF_VIEW = (30.0, 150.0)


def focal_problem(fx: float, fy: float, width: int, height: int) -> str | None:
    """Why focal lengths ``fx``, ``fy`` (pixels) look wrong for ``width x height`` images: a
    horizontal field of view outside :data:`FIELD_OF_VIEW`, or pixels far from square.

    Parameters
    ----------
    fx, fy : float
        Focal lengths in pixels (a negative one flips its axis).
    width, height : int
        Size of the depth images.

    Returns
    -------
    str or None
        A one-line warning, or ``None`` when the focal lengths are plausible.
    """
    fov = math.degrees(2.0 * math.atan2(width / 2.0, abs(fx)))
    if not FIELD_OF_VIEW[0] <= fov <= FIELD_OF_VIEW[1]:
        return (f"the camera's fx = {fx:g} gives the {width}x{height} depth images a {fov:.0f} degree field of view "
                f"(depth cameras: {FIELD_OF_VIEW[0]:.0f}-{FIELD_OF_VIEW[1]:.0f}): are the [camera] intrinsics in pixels "
                "and for this resolution?")
    ratio = abs(fy) / abs(fx)
    if not 0.8 <= ratio <= 1.25:
        return (f"the camera's fy = {fy:g} is {ratio:.2f} times fx = {fx:g} (square pixels: about 1): "
                "are the [camera] intrinsics right?")
    return None


def intrinsics_problems(camera, depth_path: Path | str, width: int, height: int) -> list[str]:
    """:func:`camera_problem` and :func:`focal_problem` together: the warnings (zero to two
    lines, each ``"<depth_path>: <problem>"``) for a depth camera's intrinsics (a
    :class:`annotate_rgbd.geometry.camera.Camera`) on the ``width x height`` depth image at
    ``depth_path``."""
    found = (camera_problem(camera.cx, camera.cy, width, height), focal_problem(camera.fx, camera.fy, width, height))
    return [f"{depth_path}: {problem}" for problem in found if problem is not None]

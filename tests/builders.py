"""Builders that several test modules share: a tiny TUM-layout scene and CVAT exports for it,
the one-error-line check of the command line, and point clouds of a carton on a floor."""

from __future__ import annotations

import hashlib
from pathlib import Path

import cv2
import numpy as np

#: The tiny scene: 40 x 30 frames of one tilted plane, and a camera that fits it.
W, H = 40, 30
CAMERA = "[camera]\nfx = 40.0\nfy = 40.0\ncx = 19.5\ncy = 14.5\ndepth_scale = 5000.0\n"
XML_HEAD = '<?xml version="1.0" encoding="utf-8"?>\n'


def timestamp(i: int) -> str:
    """The tiny scene's timestamp of frame ``i`` (as written in its file names)."""
    return f"{100 + 0.1 * i:.6f}"


def depth_image(size=(W, H)) -> np.ndarray:
    """A plane tilted away from the camera, 2 to 2.3 m: every pixel valid."""
    rows, cols = np.mgrid[0 : size[1], 0 : size[0]]
    return (10000 + 30 * cols + 20 * rows).astype(np.uint16)


def make_sequence(root: Path, n: int = 3, varied_rgb: bool = False) -> None:
    """TUM layout: rgb/ and depth/ PNGs, rgb.txt and depth.txt with equal timestamps; the RGB
    frames are grey, or each a different grey with ``varied_rgb``."""
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    for i in range(n):
        cv2.imwrite(str(root / f"depth/{timestamp(i)}.png"), depth_image())
        cv2.imwrite(str(root / f"rgb/{timestamp(i)}.png"), np.full((H, W, 3), 90 + 40 * i if varied_rgb else 128, np.uint8))
    for kind in ("rgb", "depth"):
        lines = [f"{timestamp(i)} {kind}/{timestamp(i)}.png" for i in range(n)]
        (root / f"{kind}.txt").write_text(f"# {kind}\n# file: 'tiny'\n# timestamp filename\n" + "\n".join(lines) + "\n")


def video_export(path: Path, n: int, body: str, size=(W, H)) -> Path:
    """A "CVAT for video 1.1" task of frames 0 .. n - 1 whose tracks begin on line 3."""
    original = f"<original_size><width>{size[0]}</width><height>{size[1]}</height></original_size>"
    path.write_text(
        f"{XML_HEAD}<annotations><version>1.1</version><meta><task><start_frame>0</start_frame>"
        f"<stop_frame>{n - 1}</stop_frame><frame_filter></frame_filter>{original}</task></meta>\n"
        f"{body}\n</annotations>\n"
    )
    return path


def box(frame: int, outside: int = 0) -> str:
    """A keyframe box over most of the tiny scene."""
    return (
        f'<box frame="{frame}" keyframe="1" outside="{outside}" occluded="0" '
        'xtl="2" ytl="2" xbr="30" ybr="25" z_order="0"/>'
    )


def wall_track(n: int, track_id: int = 0) -> str:
    """One track of :func:`box` keyframes on frames 0 .. n - 1."""
    return f'<track id="{track_id}" label="wall" source="manual">{"".join(box(f) for f in range(n))}</track>'


def snapshot(root: Path, skip: Path) -> dict:
    """Every path under ``root`` (not under ``skip``) with its type, mode and content hash."""
    state = {}
    for path in sorted(root.rglob("*")):
        if path == skip or skip in path.parents:
            continue
        info = path.lstat()
        digest = hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() and not path.is_fifo() else ""
        state[path.relative_to(root).as_posix()] = (info.st_mode, info.st_size, info.st_mtime_ns, digest)
    return state


def error_line(result) -> str:
    """The one ``error:`` line of a failed run (with no traceback)."""
    errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "Traceback" not in result.stderr, result.stderr
    return errors[0]


def floor_under_carton(rng, floor_points=500, top_points=800, side_points=400):
    """Points of a floor 1.5 m below the camera, a carton top 0.3 m above it (more points than
    the floor) and the carton's side facing the camera (behind the top's plane, as the floor
    is): camera frame, y down, Kinect-like noise."""
    floor_y, top_y = 1.5, 1.2
    floor = np.column_stack([rng.uniform(-1, 1, floor_points), np.full(floor_points, floor_y),
                             rng.uniform(1.5, 3.0, floor_points)])
    top = np.column_stack([rng.uniform(-0.3, 0.3, top_points), np.full(top_points, top_y),
                           rng.uniform(2.0, 2.5, top_points)])
    side = np.column_stack([rng.uniform(-0.3, 0.3, side_points), rng.uniform(top_y, floor_y, side_points),
                            np.full(side_points, 2.0)])
    points = np.vstack([floor, top, side])
    sigma = 0.0012 + 0.0019 * (points[:, 2] - 0.4) ** 2
    points[:, 2] += rng.standard_normal(len(points)) * sigma
    return points, floor_y, top_y


def through(equation, y, z=2.25):
    """Whether a plane is the horizontal one at height ``y``: it passes within 1 cm of the
    point (0, y, z) and is level within a degree."""
    return abs(equation[:3] @ (0.0, y, z) + equation[3]) < 0.01 and abs(equation[1]) > np.cos(np.radians(1))

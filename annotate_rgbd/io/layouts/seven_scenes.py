"""Microsoft's 7-Scenes layout: one folder per sequence (``seq-01/`` ...) of numbered frame files.

::

    seq-01/
        frame-000000.color.png       colour image, 640 x 480 (.jpg accepted too)
        frame-000000.depth.png       16-bit depth, millimetres; 65535 = no depth
        frame-000000.pose.txt        4 x 4 camera-to-world matrix

Frames are numbers, not timestamps. The dataset states no calibration of its own: its
documentation gives the depth camera's default intrinsics (focal length 585 px, principal point
(320, 240), for 640 x 480 depth), used here with a depth scale of 1000; colour and depth are not
registered (the dataset says so), so polygons drawn on the colour images are applied to the
depth grid as they are. The value 65535 is read as no depth by
:func:`annotate_rgbd.io.images.read_depth`.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from .lists import MAX_FRAMES, numbered_files
from .model import FRAME_NUMBERS, LayoutCamera, Sequence

NAME = "7-Scenes"
DEPTH_NAMES = r"frame-(\d+)\.depth\.png"
COLOUR_NAMES = r"frame-(\d+)\.color\.(?:png|jpg|jpeg)"
POSE_NAMES = r"frame-(\d+)\.pose\.txt"
#: The depth camera 7-Scenes documents (the KinectFusion defaults it was recorded with).
CAMERA = LayoutCamera(fx=585.0, fy=585.0, cx=320.0, cy=240.0, depth_scale=1000.0,
                      source="7-Scenes' documented depth camera")


def is_seven_scenes(root: Path) -> bool:
    """Whether ``root`` holds a ``frame-<number>.depth.png`` (looks at most ``4 MAX_FRAMES`` entries)."""
    depth = re.compile(DEPTH_NAMES)
    with os.scandir(root) as scan:
        for count, entry in enumerate(scan):
            if depth.fullmatch(entry.name):
                return True
            if count > 4 * MAX_FRAMES:
                break
    return False


def read_seven_scenes(root: Path) -> Sequence:
    """Read a 7-Scenes sequence folder into the sequence model."""
    depth = numbered_files(root, root, DEPTH_NAMES, "frame-000000.depth.png")
    rgb = numbered_files(root, root, COLOUR_NAMES, "frame-000000.color.png")
    has_poses = len(numbered_files(root, root, POSE_NAMES, "frame-000000.pose.txt")) > 0
    return Sequence(root, rgb if len(rgb) else None, depth, NAME, FRAME_NUMBERS, CAMERA, None,
                    root if has_poses else None)

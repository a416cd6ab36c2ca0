"""Where annotated frames land in the RGB list, and how frames that do not are reported."""

from __future__ import annotations

import numpy as np
import pytest

from annotate_rgbd.annotation.frames import frame_ranges, rgb_indices
from annotate_rgbd.annotation.model import Annotation
from annotate_rgbd.errors import InputError
from annotate_rgbd.io.layouts.model import FrameList


def _rgb(n: int) -> FrameList:
    return FrameList(np.arange(n, dtype=np.float64) + 1.0, tuple(f"rgb/{i:03d}.png" for i in range(n)))


def test_frame_ranges_joins_consecutive_frames_and_counts_them():
    assert frame_ranges([5]) == "frame 5"
    assert frame_ranges([15, 11, 12, 13, 14, 219, 220]) == "frames 11-15, 219-220 (7 frames)"
    assert frame_ranges([1, 3, 5, 7]) == "frames 1, 3, 5, ... (4 frames)"


def test_an_export_of_another_task_gets_one_line_not_one_per_frame():
    # A video export of 221 frames over an 11-frame sequence: frames 11-220 are beyond it.
    annotation = Annotation("other.xml", "video", [], list(range(221)))
    mapping, missing = rgb_indices(annotation, _rgb(11))
    assert mapping == {i: i for i in range(11)}
    assert missing == ["frames 11-220 (210 frames): their RGB indices are beyond the 11 RGB frames"]
    mapping, missing = rgb_indices(annotation, _rgb(11), offset=-5)
    assert mapping == {i: i - 5 for i in range(5, 16)}
    assert missing == ["frames 0-4, 16-220 (210 frames): their RGB indices (frame - 5) are beyond the 11 RGB frames"]


def test_one_frame_beyond_the_sequence_is_named_with_its_index():
    annotation = Annotation("a.xml", "video", [], list(range(12)))
    assert rgb_indices(annotation, _rgb(11))[1] == ["frame 11: RGB index 11 is beyond the 11 RGB frames"]


def test_images_not_in_the_list_are_one_line_with_the_first_names():
    names = {0: "rgb/000.png", 1: "x1.png", 2: "x2.png", 3: "rgb/001.png", 4: "x3.png", 5: "x4.png"}
    annotation = Annotation("i.xml", "images", [], list(range(6)), image_names=names)
    mapping, missing = rgb_indices(annotation, _rgb(3))
    assert mapping == {0: 0, 3: 1}
    assert missing == ["frames 1-2, 4-5 (4 frames): their images ('x1.png', 'x2.png', 'x3.png', ...) "
                       "are not in the RGB list"]


def test_no_frame_in_the_sequence_is_fatal_and_says_why():
    annotation = Annotation("far.xml", "video", [], list(range(20, 30)))
    with pytest.raises(InputError, match=r"no annotated frame is in the sequence \(frames 20-29 \(10 frames\)"):
        rgb_indices(annotation, _rgb(11))

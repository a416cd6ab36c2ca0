"""How much the keyframes on either side of a frame agree about a carried plane there
(:func:`annotate_rgbd.propagate.carry.keyframe_agreement`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from annotate_rgbd.config.settings import Config
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.propagate.carry import keyframe_agreement
from annotate_rgbd.propagate.lift import LiftedKeyframe, TrackLift

CAMERA = Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, depth_scale=5000.0)
CONFIG = replace(Config(), camera=CAMERA)
SIZE = (320, 240)
Z = 2.0
PLANE = np.array([0.0, 0.0, 1.0, -Z])  # z = 2 in the world, which is the frame's camera
IDENTITY = (np.eye(3), np.zeros(3))


def _on_plane(u0: float, u1: float, v0: float, v1: float) -> np.ndarray:
    """The world rectangle the frame's camera sees as CVAT columns u0-u1 and rows v0-v1."""
    corners = np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]], dtype=np.float64) - 0.5
    x = (corners[:, 0] - CAMERA.cx) / CAMERA.fx * Z
    y = (corners[:, 1] - CAMERA.cy) / CAMERA.fy * Z
    return np.stack([x, y, np.full(4, Z)], axis=1)


def _lift(*keyframes: LiftedKeyframe) -> TrackLift:
    return TrackLift("a.xml", 1, 2, keyframes=list(keyframes))


def test_agreement_is_the_iou_of_the_two_outlines_where_both_keyframes_saw_the_plane():
    # Both keyframes drawn from the frame's own camera: the whole image was seen by both, and the
    # agreement is the rectangles' IoU, 80 x 120 over 240 x 120 px.
    before = LiftedKeyframe(0, _on_plane(40, 200, 40, 160), PLANE, 0, view=(*IDENTITY, SIZE))
    after = LiftedKeyframe(10, _on_plane(120, 280, 40, 160), PLANE, 0, view=(*IDENTITY, SIZE))
    assert keyframe_agreement(_lift(before, after), 5, CONFIG, IDENTITY, SIZE) == pytest.approx(1 / 3, abs=0.02)
    # The later keyframe's camera 96 px to the right (on the plane): it saw columns 96 and on
    # only, so what the earlier one outlined left of them is no disagreement: 80 of 184 columns.
    shifted = (np.eye(3), np.array([96 * Z / CAMERA.fx, 0.0, 0.0]))
    after = replace(after, view=(*shifted, SIZE))
    assert keyframe_agreement(_lift(before, after), 5, CONFIG, IDENTITY, SIZE) == pytest.approx(80 / 184, abs=0.02)
    # Without a view (the export did not state the image's size) the whole image counts.
    after = replace(after, view=None)
    assert keyframe_agreement(_lift(before, after), 5, CONFIG, IDENTITY, SIZE) == pytest.approx(1 / 3, abs=0.02)


def test_agreement_needs_a_keyframe_on_each_side_and_a_region_both_saw():
    same = _on_plane(40, 200, 40, 160)
    before = LiftedKeyframe(0, same, PLANE, 0, view=(*IDENTITY, SIZE))
    after = LiftedKeyframe(10, same, PLANE, 0, view=(*IDENTITY, SIZE))
    assert keyframe_agreement(_lift(before, after), 5, CONFIG, IDENTITY, SIZE) == 1.0
    assert keyframe_agreement(_lift(before, after), 12, CONFIG, IDENTITY, SIZE) is None  # past the last one
    assert keyframe_agreement(_lift(after), 5, CONFIG, IDENTITY, SIZE) is None  # none before
    # The frame's camera turned away from the plane: nothing of either outline in its image.
    away = (np.diag([-1.0, 1.0, -1.0]), np.zeros(3))
    assert keyframe_agreement(_lift(before, after), 5, CONFIG, away, SIZE) is None
    # The later keyframe saw none of what either outlines (its camera far to the side).
    aside = (np.eye(3), np.array([50.0, 0.0, 0.0]))
    assert keyframe_agreement(_lift(before, replace(after, view=(*aside, SIZE))), 5, CONFIG, IDENTITY, SIZE) is None

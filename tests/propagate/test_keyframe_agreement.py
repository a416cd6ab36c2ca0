"""How much the keyframes on either side of a frame agree about a carried plane there
(:func:`annotate_rgbd.propagate.carry.keyframe_agreement`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from annotate_rgbd.config.settings import Config
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.propagate.carry import PRIOR_SAMPLES, keyframe_agreement
from annotate_rgbd.propagate.lift import LiftedKeyframe, TrackLift

CAMERA = Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, depth_scale=5000.0)
CONFIG = replace(Config(), camera=CAMERA)
SIZE = (320, 240)
Z = 2.0
PLANE = np.array([0.0, 0.0, 1.0, -Z])  # z = 2 in the world, which is the frame's camera
IDENTITY = (np.eye(3), np.zeros(3))
ROWS = 15  # the rows compared (every 8th pixel, 8r + 4) whose CVAT centre lies in [40, 160]


def _on_plane(u0: float, u1: float, v0: float, v1: float) -> np.ndarray:
    """The world rectangle the frame's camera sees as CVAT columns u0-u1 and rows v0-v1."""
    corners = np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]], dtype=np.float64) - 0.5
    x = (corners[:, 0] - CAMERA.cx) / CAMERA.fx * Z
    y = (corners[:, 1] - CAMERA.cy) / CAMERA.fy * Z
    return np.stack([x, y, np.full(4, Z)], axis=1)


def _share(both: int, compared: int, rows: int = 1) -> float:
    """The agreement of ``both`` of ``compared`` columns over ``rows`` rows (the prior added)."""
    return (both * rows + PRIOR_SAMPLES) / (compared * rows + PRIOR_SAMPLES)


def _lift(*keyframes: LiftedKeyframe) -> TrackLift:
    return TrackLift("a.xml", 1, 2, keyframes=list(keyframes))


def _on_plane_at(z: float, u0: float, u1: float, v0: float, v1: float) -> np.ndarray:
    """:func:`_on_plane` on the plane at depth ``z``."""
    return _on_plane(u0, u1, v0, v1) * (z / Z)


def _plane_at(z: float) -> np.ndarray:
    return np.array([0.0, 0.0, 1.0, -z])


def _sampled(u0: float, u1: float) -> set[int]:
    """The columns compared (every 8th pixel, 8c + 4) whose CVAT centre lies in [u0, u1]."""
    return {c for c in range(SIZE[0] // 8) if u0 <= 8 * c + 4.5 <= u1}


def test_agreement_is_the_iou_of_the_two_outlines_where_both_keyframes_saw_the_plane():
    # Both keyframes drawn from the frame's own camera: the whole image was seen by both, and the
    # agreement is the rectangles' IoU on the columns compared (rows alike in both).
    first, second = _sampled(40, 200), _sampled(120, 280)
    before = LiftedKeyframe(0, _on_plane(40, 200, 40, 160), PLANE, 0, view=(*IDENTITY, SIZE))
    after = LiftedKeyframe(10, _on_plane(120, 280, 40, 160), PLANE, 0, view=(*IDENTITY, SIZE))
    assert len(first & second) / len(first | second) == pytest.approx(1 / 3)
    expected = _share(len(first & second), len(first | second), ROWS)
    assert keyframe_agreement(_lift(before, after), 5, CONFIG, IDENTITY, SIZE) == pytest.approx(expected)
    # The later keyframe's camera 100 px to the right (on the plane): it saw the columns from 100
    # on (the pixel whose centre lies on that edge too), so what the earlier one outlined left of
    # them is no disagreement.
    shifted = (np.eye(3), np.array([100 * Z / CAMERA.fx, 0.0, 0.0]))
    seen = {c for c in first | second if 8 * c + 4 >= 100}
    shifted_after = replace(after, view=(*shifted, SIZE))
    assert keyframe_agreement(_lift(before, shifted_after), 5, CONFIG, IDENTITY, SIZE) == pytest.approx(
        _share(len(first & second & seen), len(seen), ROWS))
    # Without a view (its size unknown) the whole image counts; the image's size then comes from
    # the other keyframe.
    blind = replace(after, view=None)
    assert keyframe_agreement(_lift(before, blind), 5, CONFIG, IDENTITY, SIZE) == pytest.approx(expected)
    assert keyframe_agreement(_lift(before, blind), 5, CONFIG, IDENTITY) == pytest.approx(expected)
    assert keyframe_agreement(_lift(replace(before, view=None), blind), 5, CONFIG, IDENTITY) is None


def test_outline_edges_are_taken_in_cvat_coordinates():
    # The column compared at pixel 100 has its CVAT centre at 100.5: an outline ending at 100.6
    # holds it, one ending at 99.8 does not (OpenCV's fill takes a pixel an edge reaches half of).
    rows = (36, 99.8)  # 8 rows compared
    wide = LiftedKeyframe(0, _on_plane(36, 100.6, *rows), PLANE, 0, view=(*IDENTITY, SIZE))
    short = LiftedKeyframe(10, _on_plane(36, 99.8, *rows), PLANE, 0, view=(*IDENTITY, SIZE))
    assert keyframe_agreement(_lift(wide, short), 5, CONFIG, IDENTITY, SIZE) == pytest.approx(_share(8, 9, rows=8))


def test_what_a_turned_keyframe_saw_is_found_on_the_nearer_keyframes_plane():
    # The later keyframe looked 20 degrees to the right: a column of the frame counts when its
    # point on the plane lies inside that keyframe's image (computed here ray by ray).
    angle = np.radians(20)
    turn = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    before = LiftedKeyframe(0, _on_plane(40, 200, 40, 160), PLANE, 0, view=(*IDENTITY, SIZE))
    after = LiftedKeyframe(10, _on_plane(120, 240, 40, 160), PLANE, 0, view=(turn, np.zeros(3), SIZE))

    def seen_by(rotation, translation, z) -> set[int]:
        found = set()
        for c in range(SIZE[0] // 8):
            point = np.array([(8 * c + 4 - CAMERA.cx) / CAMERA.fx, (8 * 7 + 4 - CAMERA.cy) / CAMERA.fy, 1.0]) * z
            own = rotation.T @ (point - translation)
            u = own[0] * CAMERA.fx / own[2] + CAMERA.cx + 0.5
            if own[2] > 0.05 and 0 <= u < SIZE[0]:
                found.add(c)
        return found

    first, second = _sampled(40, 200), _sampled(120, 240)
    seen = seen_by(turn, np.zeros(3), Z) & (first | second)
    assert 0 < len(seen) < len(first | second)
    assert keyframe_agreement(_lift(before, after), 5, CONFIG, IDENTITY, SIZE) == pytest.approx(
        _share(len(first & second & seen), len(seen), ROWS))
    # The keyframes on two parallel planes, 2 and 3 m away, the later one's camera moved 0.73 m
    # to the right: the points are on the nearer keyframe's plane, so the columns it saw are those
    # from 100 px on at 2 m (frame 2, nearer the first keyframe) and from 67 px on at 3 m (frame 8).
    move = np.array([100 * Z / CAMERA.fx, 0.0, 0.0])
    near = LiftedKeyframe(0, _on_plane_at(2.0, 40, 200, 40, 160), _plane_at(2.0), 0, view=(*IDENTITY, SIZE))
    far = LiftedKeyframe(10, _on_plane_at(3.0, 120, 280, 40, 160), _plane_at(3.0), 0, view=(np.eye(3), move, SIZE))
    first, second = _sampled(40, 200), _sampled(120, 280)
    for frame, z in ((2, 2.0), (8, 3.0)):
        seen = seen_by(np.eye(3), move, z) & (first | second)
        assert keyframe_agreement(_lift(near, far), frame, CONFIG, IDENTITY, SIZE) == pytest.approx(
            _share(len(first & second & seen), len(seen), ROWS)), frame
    assert len(seen_by(np.eye(3), move, 2.0)) != len(seen_by(np.eye(3), move, 3.0))


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


def test_where_the_keyframes_disagree_every_outline_goes_over_every_exclusion():
    # Keyframe 0 (nearer to frame 4) outlined columns 40-200 and left out 200-300 as touching
    # the plane; keyframe 10 outlined 120-280. Normally the nearer keyframe decides 200-280 (left
    # out); where the two disagree, what any of them outlined is the plane's and only 280-300,
    # which no outline holds, stays left out.
    from annotate_rgbd.propagate.carry import carried_layers
    from annotate_rgbd.segment.rasterize import paint_layers

    near = LiftedKeyframe(0, _on_plane(40, 200, 40, 160), PLANE, 0, excluded=(_on_plane(200, 300, 40, 160),),
                          view=(*IDENTITY, SIZE))
    far = LiftedKeyframe(10, _on_plane(120, 280, 40, 160), PLANE, 0, view=(*IDENTITY, SIZE))
    painted = {}
    for disagree in (False, True):
        layers, beyond = carried_layers(_lift(near, far), 4, CONFIG, IDENTITY, disagree)
        assert beyond == ()
        inside, excluded = paint_layers(layers, SIZE[1], SIZE[0])
        painted[disagree] = (inside.astype(np.int8) - excluded)[100]  # one row inside every rectangle
    assert (painted[False][50:199] == 1).all() and (painted[False][201:299] == -1).all()
    assert (painted[True][50:279] == 1).all() and (painted[True][281:299] == -1).all()
    assert (painted[True][:39] == 0).all() and (painted[True][301:] == 0).all()


def test_the_plan_carries_with_every_outline_only_where_the_keyframes_disagree():
    # The frame's shapes as the plan makes them (pipeline.plan._frame_shapes): keyframes 0 and 10
    # drawn, frame 4 carried. Outlines 40-200 and 120-280 (agreement about a third on what both saw)
    # disagree; 40-200 and 50-210 agree. Only the first pair is painted with every outline last.
    from types import SimpleNamespace

    from annotate_rgbd.annotation.model import Shape, Track
    from annotate_rgbd.pipeline.plan import _frame_shapes
    from annotate_rgbd.propagate import DISAGREE_BELOW
    from annotate_rgbd.propagate.carry import carried_layers

    excluded = (_on_plane(200, 300, 40, 160),)
    for far_columns, disagree in (((120, 280), True), ((50, 210), False)):
        near = LiftedKeyframe(0, _on_plane(40, 200, 40, 160), PLANE, 0, excluded=excluded, view=(*IDENTITY, SIZE))
        far = LiftedKeyframe(10, _on_plane(*far_columns, 40, 160), PLANE, 0, view=(*IDENTITY, SIZE))
        lift = _lift(near, far)
        square = Shape("polygon", np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]))
        track = Track(2, "plane", shapes={f: square for f in range(11)}, keyframes=frozenset({0, 10}))
        part = SimpleNamespace(name="a.xml", annotation=SimpleNamespace(tracks=[track], image_size={4: SIZE}))
        poses = SimpleNamespace(ok=np.ones(1, dtype=bool), rotations=np.eye(3)[None], translations=np.zeros((1, 3)))
        propagation = SimpleNamespace(lifts={("a.xml", 2): lift}, depth_poses=poses)
        _, propagated, _, carried, agreement = _frame_shapes(part, 4, {("a.xml", 2): 7}, propagation, CONFIG, 0)
        assert propagated == {7} and (agreement[7] < DISAGREE_BELOW) == disagree
        (_, plane, _, layers, _), = carried
        expected, _ = carried_layers(lift, 4, CONFIG, IDENTITY, disagree)
        other, _ = carried_layers(lift, 4, CONFIG, IDENTITY, not disagree)
        signs = [sign for sign, _ in layers]
        assert plane == 7 and signs == [sign for sign, _ in expected] != [sign for sign, _ in other]

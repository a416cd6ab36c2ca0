"""A carried plane's fit is judged by where its points lie, not by its angle (issue 26)."""

from __future__ import annotations

import numpy as np

from annotate_rgbd.config.masks import PropagateConfig
from annotate_rgbd.segment.ransac import ON_EXPECTED_SHARE, on_expected_plane

FLOOR = np.array([0.0, -1.0, 0.0, 1.2])  # y = 1.2 m below a level camera, normal towards it


def _patch(tilt_deg: float, height: float, n: int = 400, seed: int = 0) -> np.ndarray:
    """Points of a 0.4 m square patch of floor 1.5-1.9 m ahead, tilted about the x axis at its
    near edge, lifted by ``height``."""
    rng = np.random.default_rng(seed)
    x, z = rng.uniform(-0.2, 0.2, n), rng.uniform(1.5, 1.9, n)
    y = 1.2 - height - np.tan(np.radians(tilt_deg)) * (z - 1.5)
    return np.column_stack([x, y, z])


def test_a_tilted_view_of_the_same_floor_is_where_expected():
    # A Kinect's depth distortion tilts one view's floor by ~6 degrees: over 0.4 m, 4.2 cm at most.
    points = _patch(6.0, 0.0)
    distance = np.abs(points @ FLOOR[:3] + FLOOR[3])
    assert distance.max() > 0.03  # the tilt is real
    assert on_expected_plane(points, FLOOR, PropagateConfig())


def test_another_surface_is_not():
    # A box top 8 cm above the floor, and a wall standing on it.
    assert not on_expected_plane(_patch(0.0, 0.08), FLOOR, PropagateConfig())
    rng = np.random.default_rng(1)
    wall = np.column_stack([rng.uniform(-0.2, 0.2, 300), rng.uniform(0.6, 1.2, 300), np.full(300, 1.7)])
    assert not on_expected_plane(wall, FLOOR, PropagateConfig())
    assert not on_expected_plane(np.zeros((0, 3)), FLOOR, PropagateConfig())


def test_the_share_and_the_offset_decide():
    near, far = _patch(0.0, 0.0, 100), _patch(0.0, 0.2, 100)
    k = int(np.ceil(ON_EXPECTED_SHARE * 100))
    assert on_expected_plane(np.vstack([near[:k], far[: 100 - k]]), FLOOR, PropagateConfig())
    assert not on_expected_plane(np.vstack([near[: k - 2], far[: 102 - k]]), FLOOR, PropagateConfig())
    # 4 cm above the floor: within the default 5 cm, not within 3 cm.
    lifted = _patch(0.0, 0.04)
    assert on_expected_plane(lifted, FLOOR, PropagateConfig())
    assert not on_expected_plane(lifted, FLOOR, PropagateConfig(same_surface_offset=0.03))

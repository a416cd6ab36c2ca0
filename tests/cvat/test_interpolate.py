"""CVAT's keyframe interpolation (annotate_rgbd.interpolate)."""

from __future__ import annotations

import numpy as np
import pytest

from annotate_rgbd.cvat.interpolate import (
    interpolate_angle,
    interpolate_box,
    interpolate_polygon,
    interpolate_polygon_series,
    match_outlines,
)

SQUARE = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
# The same square with an extra vertex in the middle of its top edge.
SQUARE_WITH_MIDPOINT = np.array([[0.0, 0.0], [5.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])


def irregular_polygon(seed: int, n: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    angles = np.sort(rng.uniform(0, 2 * np.pi, n))
    radii = rng.uniform(5, 50, n)
    return np.c_[100 + radii * np.cos(angles), 80 + radii * np.sin(angles)]


def test_box_is_linear():
    b0 = np.array([[0.0, 0.0], [10.0, 10.0]])
    b1 = np.array([[10.0, 20.0], [30.0, 50.0]])
    np.testing.assert_array_equal(interpolate_box(b0, b1, 0.25), [[2.5, 5.0], [15.0, 20.0]])
    np.testing.assert_array_equal(interpolate_box(b0, b1, 0.0), b0)
    np.testing.assert_array_equal(interpolate_box(b0, b1, 1.0), b1)


@pytest.mark.parametrize(
    ("a0", "a1", "t", "expected"),
    [(0, 90, 0.5, 45), (350, 10, 0.5, 0), (10, 350, 0.5, 0), (10, 350, 0.25, 5), (0, 0, 0.7, 0)],
)
def test_rotation_turns_along_the_shorter_arc(a0, a1, t, expected):
    assert interpolate_angle(a0, a1, t) == pytest.approx(expected)


@pytest.mark.parametrize("t", [0.0, 1.0])
def test_polygon_at_the_keyframes_is_the_keyframe(t):
    p0 = irregular_polygon(1, 12)
    p1 = 1.5 * (p0 - p0.mean(axis=0)) + [30.0, -12.0]  # scaled and moved, same arc lengths
    expected = p0 if t == 0.0 else p1
    np.testing.assert_allclose(interpolate_polygon(p0, p1, t), expected, atol=1e-9)


@pytest.mark.parametrize("t", [0.1, 0.3, 0.5, 0.9])
def test_translated_polygon_moves_linearly(t):
    p0 = irregular_polygon(2, 9)
    shift = np.array([12.0, -7.5])
    np.testing.assert_allclose(interpolate_polygon(p0, p0 + shift, t), p0 + t * shift, atol=1e-9)


def test_vertex_count_changes_like_cvat():
    # The square's first corner is matched with both the corner and the new midpoint; the
    # pair is kept while the two are at least base_length / (2 N) = 5 / 4 apart ...
    half_way = interpolate_polygon(SQUARE, SQUARE_WITH_MIDPOINT, 0.5)
    np.testing.assert_allclose(half_way, [[0, 0], [2.5, 0], [10, 0], [10, 10], [0, 10]])
    # ... and collapses into its midpoint when closer.
    early = interpolate_polygon(SQUARE, SQUARE_WITH_MIDPOINT, 0.1)
    np.testing.assert_allclose(early, [[0.25, 0], [10, 0], [10, 10], [0, 10]])


def test_series_equals_single_interpolations():
    p0 = irregular_polygon(3, 7)
    p1 = irregular_polygon(4, 15)
    ts = [0.2, 0.5, 0.8]
    for t, outline in zip(ts, interpolate_polygon_series(p0, p1, ts)):
        np.testing.assert_array_equal(outline, interpolate_polygon(p0, p1, t))
        assert outline.ndim == 2 and outline.shape[1] == 2
        assert np.all(np.isfinite(outline))


def test_every_vertex_is_matched():
    for left_count, right_count in [(6, 17), (17, 6)]:
        left = irregular_polygon(5, left_count)
        right = irregular_polygon(6, right_count)
        matching = match_outlines(np.vstack([left, left[:1]]), np.vstack([right, right[:1]]))
        assert len(matching) == left_count + 1
        assert all(len(matched) >= 1 for matched in matching)
        # Every right vertex, the closing one included, is matched to some left vertex.
        assert {j for matched in matching for j in matched} == set(range(right_count + 1))

"""RANSAC through all its iterations, scored in blocks (segment.ransac.every_hypothesis), against
a plain loop over the same hypotheses."""

import numpy as np
import pytest

from annotate_rgbd.segment.ransac import HYPOTHESES_PER_BLOCK, every_hypothesis


def _two_surfaces(rng, near=400, far=600, gap=0.02, noise=0.003):
    """A table top 2 m away (``far`` points) and papers ``gap`` in front of it (``near`` points)."""
    far_points = np.c_[rng.uniform(-1, 1, (far, 2)), 2.0 + rng.normal(0, noise, far)]
    near_points = np.c_[rng.uniform(-1, 1, (near, 2)), 2.0 - gap + rng.normal(0, noise, near)]
    return rng.permutation(np.r_[far_points, near_points])


def _loop_reference(sample, threshold, iterations, seed):
    """One hypothesis at a time: its plane from the 3 points' cross product, its inliers counted
    point by point (strictly within the threshold); the first best one wins, re-fitted by SVD
    to its inliers."""
    corners = np.random.default_rng(seed).integers(0, len(sample), (iterations, 3))
    best, best_count = None, -1
    for a, b, c in corners:
        normal = np.cross(sample[b] - sample[a], sample[c] - sample[a])
        if not np.linalg.norm(normal) > 0:
            continue
        normal = normal / np.linalg.norm(normal)
        offset = -float(sample[a] @ normal)
        count = sum(abs(float(p @ normal) + offset) < threshold for p in sample)
        if count > best_count:
            best, best_count = (normal, offset), count
    normal, offset = best
    inliers = sample[np.abs(sample @ normal + offset) < threshold]
    centre = inliers.mean(axis=0)
    normal = np.linalg.svd(inliers - centre)[2][2]
    plane = np.append(normal, -normal @ centre)
    return (-plane if plane[3] < 0 else plane), best_count


@pytest.mark.parametrize("iterations", [1, HYPOTHESES_PER_BLOCK - 1, 2 * HYPOTHESES_PER_BLOCK + 37])
def test_the_plane_and_its_count_are_the_plain_loop_s(iterations):
    rng = np.random.default_rng(iterations)
    sample = _two_surfaces(rng, near=120, far=180)
    threshold = 0.004
    equation, count = every_hypothesis(sample, threshold, iterations, seed=7)
    expected, expected_count = _loop_reference(sample, threshold, iterations, seed=7)
    assert count == expected_count
    assert np.allclose(equation, expected, atol=1e-9)
    assert equation[3] >= 0 and np.linalg.norm(equation[:3]) == pytest.approx(1.0)


def test_it_finds_the_surface_with_more_points():
    rng = np.random.default_rng(3)
    sample = _two_surfaces(rng, near=400, far=600)
    equation, count = every_hypothesis(sample, 0.004, 1000, seed=0)
    assert abs(equation[2]) == pytest.approx(1.0, abs=1e-3)
    assert equation[3] == pytest.approx(2.0, abs=0.003)  # the table, not the papers at 1.98 m
    assert 500 <= count <= 600
    # Another seed draws other hypotheses and finds the same surface.
    other, _ = every_hypothesis(sample, 0.004, 1000, seed=1)
    assert other[3] == pytest.approx(2.0, abs=0.003)
    # The same seed gives the same plane.
    again, again_count = every_hypothesis(sample, 0.004, 1000, seed=0)
    assert np.array_equal(again, equation) and again_count == count
    # Whatever the seed, the table wins with about as many points.
    for seed in range(2, 12):
        plane, found = every_hypothesis(sample, 0.004, 1000, seed=seed)
        assert plane[3] == pytest.approx(2.0, abs=0.003) and abs(found - count) <= 0.05 * count


def test_degenerate_samples_hold_no_points():
    same = np.tile([[0.1, 0.2, 1.5]], (10, 1))
    equation, count = every_hypothesis(same, 0.01, 50, seed=0)
    assert count == 0 and np.array_equal(equation, np.zeros(4))
    on_a_line = np.c_[np.linspace(0, 1, 20), np.zeros(20), np.full(20, 2.0)]
    assert every_hypothesis(on_a_line, 0.01, 50, seed=0)[1] == 0

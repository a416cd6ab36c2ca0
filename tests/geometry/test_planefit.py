"""Weighted plane fit and noise-aware re-fit, against independent computations (SVD, counts)."""

from __future__ import annotations

import numpy as np
import pytest

from annotate_rgbd.geometry.noise import SENSOR_MODELS, ConstantNoise, NoiseSettings, inlier_band
from annotate_rgbd.geometry.planes import (
    Moments, Refit, fit_planes, mean_squared_distance, merge_pairs, moments_from_sums, point_plane_distance, pool_groups,
    refit_plane, residual_ms, weighted_plane_fit,
)

KINECT = SENSOR_MODELS["kinect_v1"]
K, FLOOR, CAP = 3.0, 0.002, 0.10


def svd_plane(points: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Independent weighted total least squares: SVD of the sqrt-weighted, centred points."""
    w = np.ones(len(points)) if weights is None else weights
    centroid = np.average(points, axis=0, weights=w)
    _, _, vt = np.linalg.svd(np.sqrt(w)[:, None] * (points - centroid), full_matrices=False)
    normal = vt[-1]
    d = -normal @ centroid
    return np.append(normal, d) * (1 if d > 0 else -1)


def angle_deg(n1: np.ndarray, n2: np.ndarray) -> float:
    return float(np.degrees(np.arccos(min(1.0, abs(n1[:3] @ n2[:3])))))


def tilted_plane(rng, n_points, z_range=(1.0, 4.0), model=KINECT):
    """Points of a plane seen obliquely (depth from z_range), with noise sigma(z) along the normal."""
    normal = np.array([0.0, -0.6, -0.8])  # unit; a floor-like plane, tilted towards the camera
    xs = rng.uniform(-1.0, 1.0, n_points)
    zs = rng.uniform(*z_range, n_points)
    d = 1.2  # plane: -0.6 y - 0.8 z + d = 0  ->  y = (d - 0.8 z) / 0.6
    points = np.stack([xs, (d - 0.8 * zs) / 0.6, zs], axis=1)
    offsets = model.sigma(points[:, 2]) * rng.standard_normal(n_points)
    points += offsets[:, None] * normal
    truth = np.append(normal, d)  # d > 0: oriented towards the camera
    return points, truth


def test_uniform_weights_match_svd_fit():
    rng = np.random.default_rng(0)
    points, _ = tilted_plane(rng, 500)
    fitted = weighted_plane_fit(points)
    expected = svd_plane(points)
    assert np.linalg.norm(fitted[:3]) == pytest.approx(1.0)
    assert fitted == pytest.approx(expected, abs=1e-9)


def test_weights_match_weighted_svd_fit():
    rng = np.random.default_rng(1)
    points = rng.normal(size=(300, 3)) * [1.0, 0.5, 0.05] + [0.2, -0.1, 2.0]
    weights = rng.uniform(0.1, 10.0, 300)
    assert weighted_plane_fit(points, weights) == pytest.approx(svd_plane(points, weights), abs=1e-9)


def test_integer_weight_equals_repeating_the_point():
    rng = np.random.default_rng(2)
    points = rng.normal(size=(40, 3)) * [1.0, 1.0, 0.1] + [0, 0, 1.5]
    weights = rng.integers(1, 4, 40)
    repeated = np.repeat(points, weights, axis=0)
    assert weighted_plane_fit(points, weights.astype(float)) == pytest.approx(weighted_plane_fit(repeated), abs=1e-12)


def test_zero_weight_ignores_the_point():
    rng = np.random.default_rng(3)
    points = rng.normal(size=(50, 3)) * [1.0, 1.0, 0.01] + [0, 0, 2.0]
    outlier = np.array([[0.0, 0.0, 10.0]])
    weights = np.append(np.ones(50), 0.0)
    fitted = weighted_plane_fit(np.vstack([points, outlier]), weights)
    assert fitted == pytest.approx(weighted_plane_fit(points), abs=1e-12)


def test_plane_is_oriented_towards_the_camera():
    # z = 2 plane: the normal must point to the origin, (0, 0, -1) with d = 2.
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 5), np.linspace(-1, 1, 5)), -1).reshape(-1, 2)
    points = np.column_stack([grid, np.full(len(grid), 2.0)])
    assert weighted_plane_fit(points) == pytest.approx([0, 0, -1, 2.0], abs=1e-12)
    assert weighted_plane_fit(points + [0, 0, -4.0]) == pytest.approx([0, 0, 1, 2.0], abs=1e-12)  # z = -2


@pytest.mark.parametrize(
    "points, weights, message",
    [
        (np.zeros((2, 3)), None, "at least 3"),
        (np.array([[0, 0, 1], [1, 1, 2], [2, 2, 3], [3, 3, 4.0]]), None, "one line"),
        (np.array([[0, 0, 1], [1, 0, 1], [0, 1, np.nan]]), None, "finite"),
        (np.eye(3) + 1, np.array([1.0, -1.0, 1.0]), ">= 0"),
        (np.eye(3) + 1, np.array([1.0, 0.0, 1.0]), "at least 3"),
        (np.zeros((4, 2)), None, "shape"),
    ],
)
def test_bad_input_raises(points, weights, message):
    with pytest.raises(ValueError, match=message):
        weighted_plane_fit(points, weights)


def test_point_plane_distance_by_hand():
    normal = np.array([2.0, -1.0, 2.0]) / 3.0
    equation = np.append(normal, 1.5)
    foot = -1.5 * normal  # a point of the plane
    offsets = np.array([0.0, 0.01, -0.03, 2.0])
    points = foot + offsets[:, None] * normal + np.array([1.0, 2.0, 0.0])  # (1, 2, 0) lies in it
    assert point_plane_distance(points, equation) == pytest.approx(np.abs(offsets), abs=1e-12)
    assert np.isnan(point_plane_distance(np.array([[np.nan, 0, 1]]), equation)[0])


def three_point_plane(points, rng, trials=50):
    """What RANSAC returns: of planes through 3 random points, the one with most inliers."""
    band = inlier_band(points[:, 2], KINECT, K, FLOOR, CAP)
    best, best_count = None, -1
    for _ in range(trials):
        a, b, c = points[rng.choice(len(points), 3, replace=False)]
        normal = np.cross(b - a, c - a)
        normal /= np.linalg.norm(normal)
        d = -normal @ a
        plane = np.append(normal, d) * (1 if d > 0 else -1)
        count = np.count_nonzero(np.abs(points @ plane[:3] + plane[3]) <= band)
        if count > best_count:
            best, best_count = plane, count
    return best


def test_refit_recovers_the_normal_better_than_a_three_point_plane():
    worse = 0
    for seed in range(20):
        rng = np.random.default_rng(seed)
        points, truth = tilted_plane(rng, 20_000)
        start = three_point_plane(points, rng)
        fit = refit_plane(points, start, NoiseSettings(KINECT, K, FLOOR, CAP))
        assert angle_deg(fit.equation, truth) < 0.03
        worse += angle_deg(fit.equation, truth) >= angle_deg(start, truth)
    assert worse == 0


def test_weighting_by_noise_beats_an_unweighted_fit():
    # Noise grows 10x from 1 to 4 m: weighting by 1 / sigma^2 must give a better normal than
    # plain least squares on the same inliers, on average over many planes.
    weighted_errors, plain_errors = [], []
    for seed in range(30):
        rng = np.random.default_rng(100 + seed)
        points, truth = tilted_plane(rng, 3000)
        fit = refit_plane(points, truth, NoiseSettings(KINECT, K, FLOOR, CAP))
        weighted_errors.append(angle_deg(fit.equation, truth))
        plain_errors.append(angle_deg(svd_plane(points[fit.inliers]), truth))
    assert np.mean(weighted_errors) < 0.7 * np.mean(plain_errors)


def test_rms_in_sigma_units_is_about_one_for_noise_of_that_sigma():
    rng = np.random.default_rng(7)
    points, truth = tilted_plane(rng, 50_000)
    fit = refit_plane(points, truth, NoiseSettings(KINECT, K, FLOOR, CAP))
    # Gaussian noise cut at 3 sigma has RMS 0.986 sigma.
    assert fit.rms_sigma == pytest.approx(0.986, abs=0.02)
    # twice the noise -> twice the RMS in units of the model's sigma (band 6 of those: 3 true sigma)
    doubled, _ = tilted_plane(np.random.default_rng(7), 50_000, model=type(KINECT)(2 * KINECT.a, 2 * KINECT.b, KINECT.c))
    assert refit_plane(doubled, truth, NoiseSettings(KINECT, 6.0, FLOOR, 1.0)).rms_sigma == pytest.approx(2 * 0.986, rel=0.02)


def test_counts_band_and_inliers_against_an_independent_count():
    rng = np.random.default_rng(11)
    points, truth = tilted_plane(rng, 30_000)
    clutter = points[:3000] + truth[:3] * 0.05  # 5 cm in front of the plane
    points = np.vstack([points, clutter])
    start = three_point_plane(points[:30_000], rng)
    fit = refit_plane(points, start, NoiseSettings(KINECT, K, FLOOR, CAP))
    band = np.clip(K * (0.0012 + 0.0019 * (points[:, 2] - 0.4) ** 2), FLOOR, CAP)
    distance_start = np.abs(points @ start[:3] + start[3])
    assert fit.inliers_before == np.count_nonzero(distance_start <= band)
    distance_final = np.abs(points @ fit.equation[:3] + fit.equation[3])
    expected = distance_final <= band
    assert np.array_equal(fit.inliers, expected)
    assert fit.inliers_after == np.count_nonzero(expected)
    median = np.median(points[expected, 2])
    assert fit.band_at_median == pytest.approx(np.clip(K * (0.0012 + 0.0019 * (median - 0.4) ** 2), FLOOR, CAP))
    rms = np.sqrt(np.mean((distance_final[expected] / (band[expected] / K)) ** 2))
    assert fit.rms_sigma == pytest.approx(rms, rel=1e-9)
    # clutter 5 cm off the plane is out where the band plus the clutter's own noise stay
    # well below 5 cm (z < 2 m: band 1.8 cm, sigma 6 mm)
    near = clutter[:, 2] < 2.0
    assert not fit.inliers[30_000:][near].any()


def test_constant_model_refit_is_plain_least_squares_on_the_inliers():
    rng = np.random.default_rng(5)
    points, truth = tilted_plane(rng, 5000, model=ConstantNoise(0.003))
    start = three_point_plane(points, rng)
    model = ConstantNoise(0.004)
    fit = refit_plane(points, start, NoiseSettings(model, K, FLOOR, CAP), iterations=1, fit_points=0)
    inliers = np.abs(points @ start[:3] + start[3]) <= K * 0.004
    assert fit.equation == pytest.approx(svd_plane(points[inliers]), abs=1e-9)


def test_iterations_zero_keeps_the_plane_and_counts_its_inliers():
    rng = np.random.default_rng(6)
    points, truth = tilted_plane(rng, 2000)
    start = three_point_plane(points, rng)
    fit = refit_plane(points, start, NoiseSettings(KINECT, K, FLOOR, CAP), iterations=0)
    assert np.array_equal(fit.equation, start)
    assert fit.inliers_before == fit.inliers_after == np.count_nonzero(fit.inliers)


def test_nan_points_are_never_inliers_and_change_nothing_else():
    rng = np.random.default_rng(8)
    points, truth = tilted_plane(rng, 4000)
    with_nan = points.copy()
    with_nan[::7, 2] = np.nan
    with_nan[3::7] = np.nan
    keep = np.isfinite(with_nan).all(axis=1)
    fit = refit_plane(with_nan, truth, NoiseSettings(KINECT, K, FLOOR, CAP), fit_points=0)
    alone = refit_plane(points[keep], truth, NoiseSettings(KINECT, K, FLOOR, CAP), fit_points=0)
    assert not fit.inliers[~keep].any()
    assert np.array_equal(fit.inliers[keep], alone.inliers)
    assert fit.equation == pytest.approx(alone.equation, abs=1e-12)
    assert np.isfinite(fit.rms_sigma)


def test_subsampled_fit_agrees_with_the_full_fit():
    rng = np.random.default_rng(9)
    points, truth = tilted_plane(rng, 100_000)
    sampled = refit_plane(points, truth, NoiseSettings(KINECT, K, FLOOR, CAP), fit_points=10_000)
    full = refit_plane(points, truth, NoiseSettings(KINECT, K, FLOOR, CAP), fit_points=0)
    assert angle_deg(sampled.equation, full.equation) < 0.02
    assert abs(sampled.inliers_after - full.inliers_after) < 0.001 * len(points)


def test_no_inliers_gives_nan_figures():
    rng = np.random.default_rng(10)
    points, truth = tilted_plane(rng, 100)
    far = truth.copy()
    far[3] += 1.0  # a plane 1 m away from every point
    fit = refit_plane(points, far, NoiseSettings(KINECT, K, FLOOR, CAP))
    assert isinstance(fit, Refit)
    assert fit.inliers_before == fit.inliers_after == 0
    assert np.isnan(fit.rms_sigma) and np.isnan(fit.band_at_median)
    assert np.array_equal(fit.equation, far)


def test_band_at_median_uses_the_noise_model():
    rng = np.random.default_rng(12)
    points, truth = tilted_plane(rng, 10_000, z_range=(2.0, 2.0001))
    fit = refit_plane(points, truth, NoiseSettings(KINECT, K, FLOOR, CAP))
    assert fit.band_at_median == pytest.approx(float(inlier_band(2.0, KINECT, K, FLOOR, CAP)), rel=1e-3)


# --- planes of point sets from their moments ----------------------------------------------------


def point_sets(rng, sizes):
    """Noisy patches of differently tilted planes, 1-4 m from the camera."""
    sets = []
    for size in sizes:
        points, _ = tilted_plane(rng, size)
        angle = rng.uniform(-0.5, 0.5)  # radians, about the camera's y axis
        turn = np.array([[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0], [-np.sin(angle), 0.0, np.cos(angle)]])
        sets.append(points @ turn.T + rng.normal(0, 0.003, points.shape))
    return sets


def moments_of(sets) -> Moments:
    """Count, centroid and centred scatter computed here, point by point."""
    means = [s.mean(axis=0) for s in sets]
    return Moments(np.array([len(s) for s in sets], dtype=np.float64), np.array(means),
                   np.array([(s - m).T @ (s - m) for s, m in zip(sets, means)]))


def svd_plane_and_residual(points):
    """The orthogonal least-squares plane by SVD, d >= 0, and the mean squared residual."""
    centre = points.mean(axis=0)
    _, singular, vt = np.linalg.svd(points - centre, full_matrices=False)
    plane = np.append(vt[-1], -vt[-1] @ centre)
    return (-plane if plane[3] < 0 else plane), singular[-1] ** 2 / len(points)


def test_fit_planes_from_moments_match_an_svd_of_the_points():
    rng = np.random.default_rng(20)
    sets = point_sets(rng, [50, 400, 3000])
    moments = moments_of(sets)
    planes, eigenvalues = fit_planes(moments.mean, moments.scatter)
    mse = residual_ms(moments.count, eigenvalues)
    for k, points in enumerate(sets):
        plane, residual = svd_plane_and_residual(points)
        np.testing.assert_allclose(planes[k], plane, atol=1e-9)
        assert mse[k] == pytest.approx(residual, rel=1e-6)
        assert mean_squared_distance(planes, moments)[k] == pytest.approx(np.mean(point_plane_distance(points, plane) ** 2), rel=1e-6)
    # Any plane: the mean squared distance of the points, from the moments alone.
    other = np.array([[0.0, 0.6, -0.8, 2.0]] * len(sets))
    for k, points in enumerate(sets):
        assert mean_squared_distance(other, moments)[k] == pytest.approx(np.mean(point_plane_distance(points, other[k]) ** 2))


def test_moments_pool_without_their_points():
    rng = np.random.default_rng(21)
    sets = point_sets(rng, [30, 200, 700, 90])
    moments = moments_of(sets)
    # Raw sums -> moments.
    from_sums = moments_from_sums(moments.count, np.array([s.sum(axis=0) for s in sets]), np.array([s.T @ s for s in sets]))
    np.testing.assert_allclose(from_sums.mean, moments.mean, atol=1e-12)
    np.testing.assert_allclose(from_sums.scatter, moments.scatter, atol=1e-8)
    # Pairs and groups -> the moments of the union of their points.
    joined = merge_pairs(moments, np.array([0, 1]), np.array([2, 3]))
    union = moments_of([np.concatenate([sets[0], sets[2]]), np.concatenate([sets[1], sets[3]])])
    for got, want in ((joined, union), (pool_groups(moments, np.array([5, 7, 5, 7]), np.array([5, 7])), union)):
        np.testing.assert_array_equal(got.count, want.count)
        np.testing.assert_allclose(got.mean, want.mean, atol=1e-12)
        np.testing.assert_allclose(got.scatter, want.scatter, rtol=1e-9, atol=1e-12)
    assert moments.take([1, 3]).count.tolist() == [200.0, 90.0]
    # No groups (a frame without a plane): no sets, of the right shapes.
    empty = pool_groups(moments.take([]), np.zeros(0, dtype=int), np.zeros(0, dtype=int))
    assert (empty.count.shape, empty.mean.shape, empty.scatter.shape) == ((0,), (0, 3), (0, 3, 3))

"""Surfaces inside the inlier band but off the plane (a whiteboard on a wall, seen from afar):
refinement finds them by the sign their pixels' residuals share over an area."""

import cv2
import numpy as np
import pytest

from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.config.settings import RansacConfig, RefineConfig
from annotate_rgbd.geometry.noise import SENSOR_MODELS, NoiseSettings
from annotate_rgbd.segment.refine import _score_statistics, inlier_density, refine_planes, window_scores

KINECT = NoiseSettings(SENSOR_MODELS["kinect_v1"])
CAMERA = Camera(fx=150.0, fy=150.0, cx=79.5, cy=59.5, depth_scale=5000.0)
SHAPE = (120, 160)


def kinect_sigma(z):
    return 0.0012 + 0.0019 * (z - 0.4) ** 2


def wall_with_board(z0, board_sigmas, rng, share=0.3, noise=None):
    """A wall facing the camera at ``z0`` m, tilted 20 degrees about the vertical axis, with a
    board ``board_sigmas`` noise deviations proud of it over ``share`` of the image.

    Returns depth (float32, metres), the board's pixels, and the wall's true plane (a, b, c, d)."""
    tilt = np.radians(20)
    normal = np.array([np.sin(tilt), 0.0, -np.cos(tilt)])
    d = z0 * np.cos(tilt)
    rows, cols = np.mgrid[: SHAPE[0], : SHAPE[1]]
    rays = np.stack([(cols - CAMERA.cx) / CAMERA.fx, (rows - CAMERA.cy) / CAMERA.fy, np.ones(SHAPE)], -1)
    depth = -d / (rays @ normal)
    board = np.zeros(SHAPE, bool)
    side = int(np.sqrt(share) * SHAPE[0])
    board[20:20 + side, 30:30 + int(side * SHAPE[1] / SHAPE[0])] = True
    sigma = kinect_sigma(depth)
    depth[board] -= board_sigmas * sigma[board] / np.cos(tilt)  # h along the normal: more along the ray
    depth += (rng.standard_normal(SHAPE) if noise is None else noise) * sigma
    return depth.astype(np.float32), board, np.array([*normal, d])


def refine_wall(depth, noise=KINECT):
    """The whole image drawn as one plane, refined."""
    return refine_planes(np.ones(SHAPE, np.uint8), depth, np.array([1]), CAMERA, RansacConfig(), noise)


def interior(board):
    """The board without its rim (windows there are half on the wall)."""
    return cv2.erode(board.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)


def test_a_board_within_the_band_is_dropped_and_the_wall_is_kept_and_fitted_to_itself():
    rng = np.random.default_rng(1)
    # 1.3 sigma proud at 2.5 m (sigma 9.6 mm: a 1.25 cm whiteboard), over 30 % of the wall:
    # each pixel of it is inside the 3 sigma band.
    depth, board, wall = wall_with_board(2.5, 1.3, rng)
    refined, fits = refine_wall(depth)
    assert refined[interior(board)].mean() < 0.005 and refined[board].mean() < 0.06  # its rim: windows half on the wall
    assert refined[~board].mean() > 0.985
    # The plane is the wall's, not one leaning towards the board (offset within 0.1 sigma).
    equation = fits[1].equation
    assert np.degrees(np.arccos(min(1.0, abs(equation[:3] @ wall[:3])))) < 0.3
    assert abs(equation[3] * np.sign(equation[:3] @ wall[:3]) - wall[3]) < 0.1 * kinect_sigma(2.5)
    # Without the test (as before it), the board stays in and the plane leans towards it.
    plain, plain_fits = refine_planes(np.ones(SHAPE, np.uint8), depth, np.array([1]), CAMERA, RansacConfig(), KINECT,
                                      refine=RefineConfig(coherence_window=0))
    assert plain[board].mean() > 0.8
    assert abs(plain_fits[1].equation[3] - wall[3]) > 0.2 * kinect_sigma(2.5)


def test_correlated_sensor_noise_does_not_punch_holes_in_a_plane():
    # Real sensors' noise is correlated over a few pixels (stereo matching windows): window
    # means then vary more than for independent noise. Each plane's own spread absorbs that.
    rng = np.random.default_rng(2)
    smooth = cv2.GaussianBlur(rng.standard_normal(SHAPE).astype(np.float32), (0, 0), 1.5)
    smooth /= smooth.std()
    depth, board, _ = wall_with_board(2.0, 0.0, rng, noise=smooth)
    refined, _ = refine_wall(depth)
    assert refined.mean() > 0.98


def test_a_fixed_band_is_left_as_it_is():
    rng = np.random.default_rng(3)
    depth, board, _ = wall_with_board(2.5, 1.3, rng)
    refined, _ = refine_wall(depth, NoiseSettings.fixed(0.05))
    assert refined.all()  # every pixel within 5 cm: a fixed band means what it says


def test_window_scores_are_window_sums_over_the_root_of_their_count():
    rng = np.random.default_rng(4)
    residual = rng.standard_normal((200, 250)).astype(np.float32)
    on_plane = rng.random((200, 250)) < 0.9
    score, usable = window_scores(residual, on_plane, 7)
    for row, col in ((0, 0), (20, 25), (199, 249), (5, 244)):
        window = (slice(max(row - 3, 0), row + 4), slice(max(col - 3, 0), col + 4))
        values = residual[window][on_plane[window]]
        assert score[row, col] == pytest.approx(values.sum() / np.sqrt(values.size), rel=1e-4)
        assert usable[row, col] == (on_plane[row, col] and values.size >= RefineConfig().min_window_inliers)
    # Independent noise: about standard normal.
    assert 0.9 < score[usable].std() < 1.1


def test_score_statistics_follow_the_dominant_surface():
    rng = np.random.default_rng(5)
    labels = np.ones((100, 100), np.int32)
    labels[:, 80:] = 2
    score = rng.standard_normal((100, 100)).astype(np.float32) * 2 + 1
    score[:40, :60] = 9 + rng.standard_normal((40, 60))  # 30 % of plane 1 on another surface
    usable = np.ones((100, 100), bool)
    centre, spread = _score_statistics(score, usable, labels, 3, step=1)
    # Independent: the shortest interval holding half of plane 1's wall scores.
    assert centre[1] == pytest.approx(1.0, abs=0.25) and spread[1] == pytest.approx(2.0, rel=0.15)
    assert centre[2] == pytest.approx(np.median(score[:, 80:]), abs=0.3)
    # A spread below that of independent noise is taken as 1.
    _, narrow = _score_statistics(score * 0.1, usable, labels, 3, step=1)
    assert narrow[2] == 1.0


def test_a_surface_just_beyond_the_band_leaves_no_scattered_pixels():
    # 3.3 sigma proud: the noise puts about a third of its pixels inside the 3 sigma band, scattered.
    rng = np.random.default_rng(6)
    depth, board, _ = wall_with_board(2.5, 3.3, rng)
    refined, _ = refine_wall(depth)
    assert refined[interior(board)].mean() < 0.005 and refined[board].mean() < 0.05
    # The wall loses a rim along the board (windows half on it), nothing elsewhere.
    near = cv2.dilate(board.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    assert refined[~near].mean() > 0.995 and refined[~board].mean() > 0.975


def test_inlier_density_is_the_share_of_inliers_among_labelled_pixels_of_the_window():
    rng = np.random.default_rng(7)
    labelled = rng.random((30, 40)) < 0.8
    on_plane = labelled & (rng.random((30, 40)) < 0.5)
    density = inlier_density(on_plane, labelled)
    for row, col in ((0, 0), (15, 20), (29, 39)):
        window = (slice(max(row - 3, 0), row + 4), slice(max(col - 3, 0), col + 4))
        assert density[row, col] == pytest.approx(on_plane[window].sum() / labelled[window].sum(), rel=1e-5)
    # On a straight occluder's edge 4 of the window's 7 columns are the plane's; in a corner 16 of 49.
    edge = np.zeros((21, 21), bool)
    edge[:, :11] = True
    assert inlier_density(edge, np.ones((21, 21), bool))[10, 10] == pytest.approx(4 / 7)
    assert inlier_density(edge, np.ones((21, 21), bool))[10, 8] == pytest.approx(6 / 7)
    corner = np.zeros((21, 21), bool)
    corner[:11, :11] = True
    assert inlier_density(corner, np.ones((21, 21), bool))[10, 10] == pytest.approx(16 / 49)
    assert 16 / 49 > RefineConfig().min_inlier_density  # corners are kept


def test_a_constant_noise_model_gets_the_window_test_too():
    from annotate_rgbd.geometry.noise import ConstantNoise

    rng = np.random.default_rng(8)
    sigma = kinect_sigma(2.5)
    depth, board, _ = wall_with_board(2.5, 1.3, rng)
    constant = NoiseSettings(ConstantNoise(sigma))
    refined, _ = refine_wall(depth, constant)
    # (The wall's true noise varies over its 2.2-2.9 m; the model's is that of 2.5 m.)
    assert refined[interior(board)].mean() < 0.02 and refined[~board].mean() > 0.98

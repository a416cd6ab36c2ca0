"""Growing refined planes to their true edges, on rendered scenes with known geometry."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.segment.grow import grow_planes
from annotate_rgbd.geometry.noise import SENSOR_MODELS, ConstantNoise, NoiseSettings

KINECT = SENSOR_MODELS["kinect_v1"]
K, FLOOR, CAP = 3.0, 0.002, 0.10
H, W = 120, 160
#: A TUM-like camera scaled to 160x120, and an ICL-NUIM-like one with its negative fy.
CAMERAS = {
    "tum": Camera(fx=131.0, fy=131.0, cx=79.5, cy=59.5, depth_scale=5000.0),
    "icl": Camera(fx=120.3, fy=-120.0, cx=79.5, cy=59.5, depth_scale=5000.0),
}
WALL = np.array([0.0, 0.0, -1.0, 3.0])  # z = 3 m, behind everything


def unit(a, b, c, d):
    n = np.array([a, b, c], dtype=float)
    scale = np.linalg.norm(n)
    return np.append(n / scale, d / scale)


TILTED = unit(0.2, -0.3, -0.93, 1.4)  # about 1.5 m away, facing the camera obliquely


def rays(camera):
    """Ray (x/z, y/z) of every pixel, from the pinhole formula (independent of camera.py)."""
    rows, cols = np.mgrid[0:H, 0:W].astype(float)
    return (cols - camera.cx) / camera.fx, (rows - camera.cy) / camera.fy


def plane_depth(camera, equation):
    x_n, y_n = rays(camera)
    a, b, c, d = equation
    return -d / (a * x_n + b * y_n + c)


def distance_to(camera, depth, equation):
    x_n, y_n = rays(camera)
    a, b, c, d = equation
    return np.abs(depth * (a * x_n + b * y_n + c) + d)


def box(r0, r1, c0, c1):
    mask = np.zeros((H, W), dtype=bool)
    mask[r0:r1, c0:c1] = True
    return mask


def noisy(depth, rng):
    return (depth + KINECT.sigma(depth) * rng.standard_normal(depth.shape)).astype(np.float32)


def refine(drawn, depth, camera, equations, model=KINECT):
    """Refinement as the lead will wire it: drawn pixels within the band of their plane."""
    refined = np.zeros_like(drawn)
    for plane_id, equation in equations.items():
        band = np.clip(K * model.sigma(depth), FLOOR, CAP)
        with np.errstate(invalid="ignore"):
            keep = (drawn == plane_id) & (distance_to(camera, depth, equation) <= band)
        refined[keep] = plane_id
    return refined


def scene(camera, seed=0):
    """A tilted plane whose true outline is rows 30-90, cols 40-120, before a wall; drawn 3 px inside."""
    rng = np.random.default_rng(seed)
    truth = box(30, 90, 40, 120)
    depth = np.where(truth, plane_depth(camera, TILTED), plane_depth(camera, WALL))
    depth = noisy(depth, rng)
    drawn = box(33, 87, 43, 117).astype(np.uint8)
    return truth, depth, drawn


def grow(refined, drawn, depth, camera, equations, grow_pixels, model=KINECT):
    return grow_planes(refined, drawn, depth, equations, camera, NoiseSettings(model, K, FLOOR, CAP), grow_pixels)


@pytest.mark.parametrize("name", ["tum", "icl"])
def test_recovers_the_true_border_from_a_polygon_drawn_3px_inside(name):
    camera = CAMERAS[name]
    truth, depth, drawn = scene(camera)
    refined = refine(drawn, depth, camera, {1: TILTED})
    labels, grown = grow(refined, drawn, depth, camera, {1: TILTED}, grow_pixels=4)
    mine = labels == 1
    assert not (mine & ~truth).any()  # the wall, 1.5 m behind, is never taken
    rows, cols = np.nonzero(mine)
    # the border within 1 px on every side (the true one is rows 30-89, cols 40-119)
    assert abs(rows.min() - 30) <= 1 and abs(rows.max() - 89) <= 1
    assert abs(cols.min() - 40) <= 1 and abs(cols.max() - 119) <= 1
    # and the ring between the drawn shape and the true border is filled, but for the few
    # pixels that 3-sigma noise puts outside the band
    ring = truth & (drawn == 0)
    assert np.count_nonzero(mine & ring) >= 0.99 * np.count_nonzero(ring)
    assert grown == {1: np.count_nonzero(labels != refined)}
    before = np.count_nonzero(refined == 1) / np.count_nonzero(truth)
    assert before < 0.9 and np.count_nonzero(mine) / np.count_nonzero(truth) > 0.99


def test_does_not_take_clutter_in_front_of_the_plane():
    camera = CAMERAS["tum"]
    truth, depth, drawn = scene(camera, seed=1)
    clutter = box(25, 45, 100, 130)  # straddles the plane's top right corner
    depth[clutter] = (plane_depth(camera, TILTED)[clutter] - 0.05).astype(np.float32)  # 5 cm in front
    refined = refine(drawn, depth, camera, {1: TILTED})
    labels, grown = grow(refined, drawn, depth, camera, {1: TILTED}, grow_pixels=4)
    assert not (labels[clutter] == 1).any()
    # it still grows elsewhere: the left border is reached
    assert (labels[40:80, 40] == 1).mean() > 0.9
    assert grown[1] > 0


def test_never_takes_pixels_without_valid_depth():
    camera = CAMERAS["tum"]
    truth, depth, drawn = scene(camera, seed=2)
    holes = box(30, 33, 50, 90) | box(60, 70, 117, 120)  # in the ring, on the plane
    depth[holes] = np.nan
    refined = refine(drawn, depth, camera, {1: TILTED})
    labels, _ = grow(refined, drawn, depth, camera, {1: TILTED}, grow_pixels=4)
    assert not labels[holes].any()
    assert (labels[30:33, 91:110] == 1).mean() > 0.95  # the rest of that side is taken


def test_never_takes_another_planes_drawn_shape_or_inliers():
    camera = CAMERAS["tum"]
    truth, depth, drawn = scene(camera, seed=3)
    # Plane 2 lies in plane 1's plane, to its right (a second panel of the same wall): its
    # drawn shape starts right at plane 1's true border. It is not refined (filtered out,
    # say), so it does not grow, and plane 1 must still leave its shape alone.
    depth[:, 120:150] = noisy(plane_depth(camera, TILTED)[:, 120:150], np.random.default_rng(4))
    drawn[33:87, 120:150] = 2
    # Plane 3's inliers (not drawn, e.g. from another pass) in plane 1's ring, bottom left.
    refined = refine(drawn, depth, camera, {1: TILTED})
    refined[87:90, 40:50] = 3
    labels, grown = grow(refined, drawn, depth, camera, {1: TILTED}, grow_pixels=4)
    assert not (labels[drawn == 2] == 1).any()
    assert (labels[87:90, 40:50] == 3).all()
    assert (labels[40:80, 117:120] == 1).mean() > 0.95  # the free columns between them are taken


def test_two_planes_wanting_a_pixel_it_goes_to_the_nearer_in_3d():
    camera = CAMERAS["tum"]
    # Two planes meeting at a crease near column 80; a constant band wide enough that both
    # accept every pixel between their drawn shapes.
    left, right = unit(0.3, 0.0, -1.0, 1.5), unit(-0.3, 0.05, -1.0, 1.5)
    depth = np.minimum(plane_depth(camera, left), plane_depth(camera, right)).astype(np.float32)
    drawn = np.zeros((H, W), dtype=np.uint16)
    drawn[20:100, 30:76] = 1
    drawn[20:100, 84:130] = 2
    model = ConstantNoise(0.05)
    equations = {2: right, 1: left}  # order must not matter
    refined = drawn.copy()
    labels, grown = grow(refined, drawn, depth, camera, equations, grow_pixels=8, model=model)
    gap = box(20, 100, 76, 84)
    d1, d2 = distance_to(camera, depth, left), distance_to(camera, depth, right)
    expected = np.where(d1 <= d2, 1, 2)
    assert np.array_equal(labels[gap], expected[gap])
    assert 0 < np.count_nonzero(labels[gap] == 1) < gap.sum()  # both planes win some
    assert grown[1] + grown[2] == np.count_nonzero(labels != refined)


def test_a_tie_goes_to_the_lower_plane_id():
    camera = CAMERAS["tum"]
    depth = plane_depth(camera, TILTED).astype(np.float32)  # no noise: both planes are the same
    drawn = np.zeros((H, W), dtype=np.int32)
    drawn[20:100, 20:70] = 7
    drawn[20:100, 74:140] = 5
    equations = {7: TILTED, 5: TILTED.copy()}
    labels, grown = grow(drawn.copy(), drawn, depth, camera, equations, grow_pixels=4)
    assert (labels[20:100, 70:74] == 5).all()
    assert labels.dtype == np.int32


def test_grows_exactly_grow_pixels_euclidean():
    camera = CAMERAS["icl"]
    depth = plane_depth(camera, TILTED).astype(np.float32)  # the plane fills the image
    drawn = np.zeros((H, W), dtype=np.uint8)
    drawn[50:70, 60:90] = 4
    drawn[40, 110] = 4  # a single drawn pixel grows into a disk
    for grow_pixels in (1, 3, 5):
        labels, grown = grow(drawn.copy(), drawn, depth, camera, {4: TILTED}, grow_pixels)
        expected = ndimage.distance_transform_edt(drawn == 0) <= grow_pixels
        assert np.array_equal(labels == 4, expected)
        assert grown[4] == np.count_nonzero(expected) - np.count_nonzero(drawn)


def test_grow_pixels_zero_returns_the_input():
    camera = CAMERAS["tum"]
    truth, depth, drawn = scene(camera)
    refined = refine(drawn, depth, camera, {1: TILTED})
    labels, grown = grow(refined, drawn, depth, camera, {1: TILTED}, grow_pixels=0)
    assert np.array_equal(labels, refined) and labels.dtype == refined.dtype
    assert grown == {1: 0}


@pytest.mark.parametrize("dtype, plane_id", [(np.uint8, 200), (np.uint16, 1000), (np.int32, 70000)])
def test_label_types_are_kept(dtype, plane_id):
    camera = CAMERAS["tum"]
    depth = plane_depth(camera, TILTED).astype(np.float32)
    drawn = np.zeros((H, W), dtype=dtype)
    drawn[50:70, 60:90] = plane_id
    labels, grown = grow(drawn.copy(), drawn, depth, camera, {plane_id: TILTED}, 2)
    assert labels.dtype == dtype
    assert set(np.unique(labels)) == {0, plane_id}
    assert grown[plane_id] == np.count_nonzero(labels) - np.count_nonzero(drawn) > 0


def test_a_plane_with_no_drawn_pixels_grows_nothing():
    camera = CAMERAS["tum"]
    truth, depth, drawn = scene(camera)
    refined = refine(drawn, depth, camera, {1: TILTED})
    labels, grown = grow(refined, drawn, depth, camera, {1: TILTED, 9: TILTED}, 3)
    assert grown[9] == 0 and not (labels == 9).any()
    assert grown[1] > 0


def test_zero_depth_is_invalid_too():
    # Raw depth 0 converted without NaN would back-project to the camera centre; with a band
    # wider than the plane's distance to the camera such pixels would pass the band test.
    camera = CAMERAS["tum"]
    depth = plane_depth(camera, TILTED).astype(np.float32)
    drawn = np.zeros((H, W), dtype=np.uint8)
    drawn[50:70, 60:90] = 1
    depth[45:50, 60:90] = 0.0
    labels, grown = grow_planes(drawn.copy(), drawn, depth, {1: TILTED}, camera, NoiseSettings(ConstantNoise(0.6), K, FLOOR, 2.0), 5)
    assert not labels[45:50, 60:90].any()
    assert (labels[70:75, 60:90] == 1).all()


def test_a_plane_does_not_grow_into_what_was_excluded_for_it():
    camera = CAMERAS["tum"]
    truth, depth, drawn = scene(camera)
    refined = refine(drawn, depth, camera, {1: TILTED})
    left = box(0, H, 0, 43)  # what a keyframe left out of plane 1: left of the drawn shape
    noise = NoiseSettings(KINECT, K, FLOOR, CAP)
    free, _ = grow_planes(refined, drawn, depth, {1: TILTED}, camera, noise, 4)
    kept, grown = grow_planes(refined, drawn, depth, {1: TILTED}, camera, noise, 4, {1: left})
    assert (free[left] == 1).sum() > 100  # without the exclusion it grows into cols 40-42
    assert not (kept[left] == 1).any()
    np.testing.assert_array_equal(kept[~left], free[~left])  # everywhere else as before
    assert grown[1] == int(((kept == 1) & (drawn == 0)).sum())
    # What was excluded for another plane does not hold this one back.
    other, _ = grow_planes(refined, drawn, depth, {1: TILTED}, camera, noise, 4, {2: left})
    np.testing.assert_array_equal(other, free)


def test_a_pixel_excluded_for_one_plane_can_still_go_to_its_neighbour():
    # Two coplanar planes side by side, drawn with a 6-px gap between them: the gap lies within
    # grow_pixels of both. What was excluded for plane 1 goes to plane 2, which may take it.
    camera = CAMERAS["tum"]
    rng = np.random.default_rng(3)
    depth = noisy(plane_depth(camera, TILTED), rng)
    drawn = np.zeros((H, W), dtype=np.uint8)
    drawn[30:90, 20:77] = 1
    drawn[30:90, 83:140] = 2
    equations = {1: TILTED, 2: TILTED}
    refined = refine(drawn, depth, camera, equations)
    gap = box(30, 90, 77, 83)
    noise = NoiseSettings(KINECT, K, FLOOR, CAP)
    free, _ = grow_planes(refined, drawn, depth, equations, camera, noise, 4)
    assert (free[gap] == 1).sum() > 100 and (free[gap] == 2).sum() > 100  # the lower id wins ties
    kept, _ = grow_planes(refined, drawn, depth, equations, camera, noise, 4, {1: gap})
    assert not (kept[gap] == 1).any()
    # Plane 2 takes what plane 1 may not, as far as its own 4 px reach (cols 79-82; 77-78 stay free).
    reach = box(30, 90, 79, 83)
    assert (kept[reach] == 2).sum() >= reach.sum() - 3 and (kept[reach] == 2).sum() > (free[reach] == 2).sum()
    assert not kept[box(30, 90, 77, 79)].any()

"""Each proposed plane's extent and numbers (annotate_rgbd.propose.extent and .measures),
against direct computations over every pixel."""

from __future__ import annotations

import numpy as np
import pytest

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.config.masks import RansacConfig
from annotate_rgbd.geometry.camera import Camera, ray_grid
from annotate_rgbd.geometry.noise import NoiseSettings, noise_scale
from annotate_rgbd.propose.measures import label_counts, polygon_fit, surface_areas
from annotate_rgbd.propose.extent import SCALE_POINTS, plane_scales
from annotate_rgbd.segment.rasterize import fill_window, shape_mask

CAMERA = Camera(fx=525.0, fy=525.0, cx=319.5, cy=239.5, depth_scale=5000.0)
NOISE = NoiseSettings()


def noisy_planes(seed: int, shape=(120, 160)):
    """A floor and two walls seen by a noisy sensor, blotches of other labels on them: the
    points of every pixel (float32, as propose builds them), the labels 1..K and the planes."""
    rng = np.random.default_rng(seed)
    height, width = shape
    ray_x, ray_y = (r.astype(np.float32) for r in ray_grid(CAMERA, height, width))
    planes = np.array([[0.0, 0.0, -1.0, 2.0], [0.6, 0.0, -0.8, 1.5], [0.0, -0.8, -0.6, 1.2]])
    facing = planes[:, 0, None, None] * ray_x[None, None, :] + planes[:, 1, None, None] * ray_y[None, :, None] + planes[:, 2, None, None]
    labels = np.zeros(shape, np.uint8)
    labels[:, : width // 2] = 1
    labels[:, width // 2 :] = 2
    labels[2 * height // 3 :, :] = 3
    labels[rng.random(shape) < 0.05] = 0
    labels[rng.random(shape) < 0.02] = 4  # a label without a plane of its own: ignored
    which = np.clip(labels.astype(np.intp) - 1, 0, 2)
    depth = (-planes[which, 3] / np.take_along_axis(facing, which[None], 0)[0]).astype(np.float32)
    depth *= 1 + rng.normal(0, 0.004, shape).astype(np.float32)
    depth[labels == 0] = np.nan
    points = np.stack(np.broadcast_arrays(ray_x[None, :] * depth, ray_y[:, None] * depth, depth), axis=-1)
    return labels, points, planes


@pytest.mark.parametrize("seed", range(3))
def test_plane_scales_are_the_noise_scales_of_every_nth_pixel(seed):
    # Every n-th pixel of each label in raster order (n: the label's pixels // SCALE_POINTS),
    # its noise scale found twice (the second within the widened band).
    labels, points, planes = noisy_planes(seed, shape=(240, 320) if seed == 2 else (120, 160))
    ransac = RansacConfig()
    scales = plane_scales(labels, points, planes, NOISE, ransac)
    cloud = points.reshape(-1, 3)
    for k in range(len(planes)):
        members = np.flatnonzero(labels.ravel() == k + 1)
        members = members[:: max(len(members) // SCALE_POINTS, 1)]
        found = noise_scale(cloud[members], planes[k], NOISE)
        expected = 1.0
        if found >= ransac.min_noise_scale:
            expected = min(found, ransac.max_noise_scale)
            again = noise_scale(cloud[members], planes[k], NOISE.scaled(expected))
            if again >= 1.02:
                expected = min(expected * again, ransac.max_noise_scale)
        assert scales[k] == expected
    assert (scales > 1).any()


def test_surface_areas_sum_every_pixel_of_each_outline():
    # Against the formula at each pixel of the window (np.nonzero, raster order: the same sum),
    # and a plane facing the camera: d**2 / (fx fy) per pixel.
    rng = np.random.default_rng(3)
    windows = [(5, 7, rng.random((40, 60)) < 0.7), (0, 0, np.ones((30, 20), bool)), (2, 3, np.zeros((4, 4), bool))]
    normal = np.array([0.3, -0.2, -1.0]) / np.linalg.norm([0.3, -0.2, -1.0])
    planes = np.array([[*normal, 1.7], [0.0, 0.0, -1.0, 2.0], [0.0, 0.0, -1.0, 1.0]])
    areas = surface_areas(windows, planes, CAMERA)
    top, left, window = windows[0]
    rows, cols = np.nonzero(window)
    a, b, c, d = planes[0]
    facing = np.abs(a * (cols + left - CAMERA.cx) / CAMERA.fx + b * (rows + top - CAMERA.cy) / CAMERA.fy + c)
    assert areas[0] == pytest.approx(d * d / (CAMERA.fx * CAMERA.fy) * np.sum(np.maximum(facing, 0.1) ** -3.0), rel=1e-12)
    assert areas[1] == pytest.approx(600 * 4.0 / (CAMERA.fx * CAMERA.fy), rel=1e-3)  # near the centre: r nearly (0, 0, 1)
    assert areas[2] == 0


def test_polygon_fit_counts_the_filled_pixels_of_each_plane():
    labels, _, _ = noisy_planes(4)
    height, width = labels.shape
    polygons = [np.array([[3.2, 4.0], [70.5, 2.0], [75.0, 90.25], [10.0, 100.0]]),
                np.array([[60.0, 10.0], [150.0, 12.5], [158.0, 70.0], [90.0, 85.0]]),
                np.array([[0.0, 70.0], [160.0, 70.0], [160.0, 120.0], [0.0, 120.0]])]
    unlimited = [None, np.array([[60.0, 10.0], [150.0, 12.5], [158.0, 70.0], [120.0, 60.0], [90.0, 85.0]]), None]
    pixels, iou, cost = polygon_fit(labels, polygons, unlimited)
    filled = [fill_window(p, height, width) for p in polygons]
    assert np.array_equal(polygon_fit(labels, polygons, unlimited, filled)[2], cost, equal_nan=True)

    def full(window):
        top, left, inside = window
        image = np.zeros(labels.shape, bool)
        image[top : top + inside.shape[0], left : left + inside.shape[1]] = inside
        return image

    for k, polygon in enumerate(polygons):
        plane = labels == k + 1
        drawn = full(shape_mask(Shape("polygon", polygon), height, width))
        assert pixels[k] == np.count_nonzero(drawn)
        assert iou[k] == np.count_nonzero(drawn & plane) / np.count_nonzero(drawn | plane)
    unlimited_iou = [np.count_nonzero(full(fill_window(p, height, width)) & (labels == 2)) /
                     np.count_nonzero(full(fill_window(p, height, width)) | (labels == 2)) for p in (unlimited[1], polygons[1])]
    assert cost[1] == unlimited_iou[0] - unlimited_iou[1] and np.isnan(cost[[0, 2]]).all()


@pytest.mark.parametrize("n", [0, 3, 70])
def test_label_counts_are_the_pixels_of_each_label(n):
    labels = np.random.default_rng(n).integers(0, n + 3, size=(50, 60)).astype(np.uint16)
    assert label_counts(labels, n).tolist() == [int(np.sum(labels == k)) for k in range(1, n + 1)]


def test_a_planes_pixels_in_its_outline_are_taken_within_a_band_wider_behind_it():
    from annotate_rgbd.geometry.noise import ConstantNoise
    from annotate_rgbd.propose.extent import assign_in_outlines

    # A wall 2 m away facing the camera (normal towards it); band 3 x 5 mm = 15 mm. Columns hold
    # points 1 cm in front, 2 cm in front, 1 cm behind and 2 cm behind the wall; the last column
    # lies outside the outline.
    z = np.array([[1.99, 1.98, 2.01, 2.02, 2.0]] * 3)
    points = np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=-1)
    wall = np.array([[0.0, 0.0, -1.0, 2.0]])
    window = np.ones((3, 5), dtype=bool)
    window[:, 4] = False
    noise = NoiseSettings(ConstantNoise(0.005))
    labels = {behind: assign_in_outlines(points, wall, [(0, 0, window)], np.ones(1), noise, behind)[0]
              for behind in (1.0, 1.5)}
    assert labels[1.0].tolist() == [1, 0, 1, 0, 0]
    assert labels[1.5].tolist() == [1, 0, 1, 1, 0]  # 2 cm behind: inside 22.5 mm; 2 cm in front: not
    # Twice the noise (the plane's scale): the 2 cm in front is inside too (30 mm).
    assert assign_in_outlines(points, wall, [(0, 0, window)], np.full(1, 2.0), noise, 1.5)[0].tolist() == [1, 1, 1, 1, 0]

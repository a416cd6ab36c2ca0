"""Each proposed plane's extent and numbers (annotate_rgbd.propose.extent, the helpers of
annotate_rgbd.propose.detect_job), against direct computations over every pixel."""

from __future__ import annotations

import numpy as np
import pytest

from annotate_rgbd.config.masks import RansacConfig
from annotate_rgbd.geometry.camera import Camera, ray_grid
from annotate_rgbd.geometry.noise import NoiseSettings, noise_scale
from annotate_rgbd.propose.extent import SCALE_POINTS, plane_scales

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

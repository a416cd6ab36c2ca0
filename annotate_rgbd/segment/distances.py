"""A pixel's signed distance to its plane, and the band within which it lies on the plane."""

from __future__ import annotations

import numpy as np

from annotate_rgbd.geometry.camera import Camera, ray_grid
from annotate_rgbd.geometry.noise import ConstantNoise, NoiseSettings


def signed_distances(
    depth_m: np.ndarray, a: np.ndarray | float, b: np.ndarray | float, c: np.ndarray | float, d: np.ndarray | float,
    camera: Camera,
) -> np.ndarray:
    """Every pixel's signed distance (m) to the plane ``a x + b y + c z + d = 0`` (unit normal;
    one plane, or one per pixel as images): ``z (a x_n + b y_n + c) + d`` with ``x_n = (col -
    cx) / fx``, ``y_n = (row - cy) / fy`` the pixel's ray at ``z = 1``. float32 is ample: depth
    has 0.2 mm steps, and bands are millimetres or more. NaN where the depth is."""
    ray_x, ray_y = ray_grid(camera, *depth_m.shape, np.float32)
    with np.errstate(invalid="ignore"):
        return plane_distance(depth_m, ray_x[None, :], ray_y[:, None], a, b, c, d)


def plane_distance(
    z: np.ndarray, x: np.ndarray, y: np.ndarray, a: np.ndarray | float, b: np.ndarray | float,
    c: np.ndarray | float, d: np.ndarray | float,
) -> np.ndarray:
    """The signed distance (m) of the point at depth ``z`` on the ray ``(x, y, 1)`` to the plane
    ``a x + b y + c z + d = 0`` (unit normal): ``z (a x + b y + c) + d``, for any broadcastable
    shapes. One formula, in one order of operations, for :func:`signed_distances` and for callers
    that gather pixels first (:func:`annotate_rgbd.segment.grow.grow_connected`): float32 gives
    the same numbers either way."""
    return z * (a * x + b * y + c) + d


def band_image(depth_m: np.ndarray, noise: NoiseSettings) -> np.ndarray | float:
    """The inlier band at every pixel's depth (float32; NaN where the depth is), or one number
    when the band does not depend on depth (a fixed ``distance_threshold``)."""
    if noise.floor >= noise.cap:
        return float(noise.floor)
    model = noise.model
    if isinstance(model, ConstantNoise):
        return float(np.clip(noise.k * model.value, noise.floor, noise.cap))
    # k (a + b (z - c)^2), clipped: a few passes of float32 arithmetic over the image.
    z = depth_m - np.float32(model.c)
    band = z * z
    band *= np.float32(noise.k * model.b)
    band += np.float32(noise.k * model.a)
    return np.clip(band, np.float32(noise.floor), np.float32(noise.cap), out=band)


def behind_factor(noise: NoiseSettings, behind_band: float) -> float:
    """How many times wider the inlier band is behind a plane than in front of it:
    ``refine.behind_band`` with a noise model, 1 with a fixed band (``distance_threshold``: the
    same distance on both sides, as given)."""
    return float(behind_band) if noise.floor < noise.cap else 1.0

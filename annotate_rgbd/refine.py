"""Depth refinement: keep only the pixels that lie on each plane (Open3D RANSAC)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import open3d as o3d

from .camera import Camera, backproject
from .config import RansacConfig
from .noise import ConstantNoise, NoiseSettings
from .planefit import refit_plane

#: Least-squares re-fits of a RANSAC plane to its inliers (the second settles the inlier set).
REFITS = 2
#: RANSAC's distance threshold, as a share of the inlier band (k = 3 sigma: 1.5 sigma). With
#: the full band a plane tilted between two surfaces a few sigma apart (a whiteboard on a wall,
#: books on a table) can gather more points than either surface's own plane; within 1.5 sigma
#: the dominant surface wins. Measured on benchmarks/bench_refine.py: the wall behind a
#: whiteboard went from mean IoU 0.86 to 0.94 (0.34 of the band gave the same).
RANSAC_SHARE = 0.5
#: Real sensors are noisier than their published axial noise: depth distortion (TUM fr1),
#: stereo ripples (RealSense), lateral noise on tilted planes. Each plane's own residuals tell
#: by how much: the noise is scaled by ``1.4826 median(|d| / sigma(z))`` of its fit's inliers
#: (the MAD estimate of a standard deviation, robust to the clutter in the band), never below 1
#: and at most this much. On TUM fr1_rpy and the RealSense office frames the planes' residuals
#: are about 1.5 sigma of the published models; on renders with exactly the model's noise the
#: factor stays about 1.
MAX_NOISE_SCALE = 2.5
#: A plane's noise is scaled only when its residuals say it is this much larger than the model:
#: below, the difference is within the spread of the estimate (a median of about a thousand
#: grid points varies by a few per cent).
MIN_NOISE_SCALE = 1.15


@dataclass(frozen=True)
class PlaneFit:
    """The result of fitting one plane.

    Parameters
    ----------
    equation : ndarray of float64, shape (4,)
        ``(a, b, c, d)`` with ``a x + b y + c z + d = 0`` in the camera frame (metres), unit
        normal, oriented towards the camera (``d > 0``).
    inliers : ndarray of bool, shape (N,)
        For each input point, whether it lies within the inlier band of the plane at its depth.
    band : float
        The inlier band (m) at the median depth of the inliers.
    rms_sigma : float
        Root mean square distance of the inliers to the plane, in units of the noise the band
        stands for (``band / k``); about 1 when the noise model fits the sensor. NaN without
        inliers.
    inliers_ransac, inliers_refit : int
        Inliers among the input points of RANSAC's plane and of the re-fitted plane.
    noise_scale : float
        How much noisier than the model the plane's points are (:data:`MAX_NOISE_SCALE`);
        the band, the re-fit's weights and the inlier test use the scaled noise.
    """

    equation: np.ndarray
    inliers: np.ndarray
    band: float = float("nan")
    rms_sigma: float = float("nan")
    inliers_ransac: int = 0
    inliers_refit: int = 0
    noise_scale: float = 1.0


def fit_plane(points: np.ndarray, config: RansacConfig, noise: NoiseSettings) -> PlaneFit:
    """Find a plane among 3-D points with Open3D's RANSAC, then re-fit it to its inliers.

    RANSAC searches for the plane among at most ``config.max_points`` of the points, taken
    evenly through the input (for a plane's pixels in row-major order: a regular grid over the
    plane), with half the inlier band of the noise model at the points' median depth as its one
    distance threshold (:data:`RANSAC_SHARE`). A 3-point RANSAC plane is noisier than the data, so the plane is then
    re-fitted by least squares to its inliers, each weighted by ``1 / sigma(z)^2``
    (:func:`annotate_rgbd.planefit.refit_plane`: every point tested against the band at its own
    depth). Open3D runs single-threaded with its generator seeded before every call: its
    multi-threaded RANSAC gives different planes from run to run, and frames are parallelised
    across processes instead.

    Parameters
    ----------
    points : ndarray of float64, shape (N, 3)
        N >= 3 points in metres.
    config : RansacConfig
    noise : NoiseSettings
        The inlier band (:meth:`annotate_rgbd.config.Config.noise_settings`).

    Returns
    -------
    PlaneFit
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    sample = points
    if config.max_points and len(points) > config.max_points:
        sample = points[:: -(-len(points) // config.max_points)]
        if len(sample) < 3:  # a stride over very few points (max_points = 3) can leave two
            sample = points[: max(config.max_points, 3)]
    threshold = RANSAC_SHARE * float(noise.band(np.median(sample[:, 2])))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(sample))
    threads = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(1)
    try:
        o3d.utility.random.seed(config.seed)
        model, _ = cloud.segment_plane(distance_threshold=threshold, ransac_n=3, num_iterations=config.num_iterations)
    finally:
        o3d.utility.set_max_threads(threads)
    equation = np.asarray(model, dtype=np.float64)
    equation = equation / np.linalg.norm(equation[:3])
    if equation[3] < 0:
        equation = -equation
    refit = refit_plane(points, equation, noise.model, noise.k, noise.floor, noise.cap, iterations=REFITS, fit_points=0)
    rms_sigma, before, scale = refit.rms_sigma, refit.inliers_before, 1.0
    for _ in range(2):  # the first estimate sees a band truncated at the model's k sigma
        found = noise_scale(points, refit.equation, noise.scaled(scale))
        if found < (MIN_NOISE_SCALE if scale == 1.0 else 1.02):
            break
        scale = min(scale * found, MAX_NOISE_SCALE)
        scaled = noise.scaled(scale)
        refit = refit_plane(points, refit.equation, scaled.model, scaled.k, scaled.floor, scaled.cap, iterations=1,
                            fit_points=0)
    equation = refit.equation / np.linalg.norm(refit.equation[:3])
    if equation[3] < 0:
        equation = -equation
    return PlaneFit(equation, refit.inliers, refit.band_at_median, rms_sigma, before, refit.inliers_after, scale)


def noise_scale(points: np.ndarray, equation: np.ndarray, noise: NoiseSettings) -> float:
    """How much noisier than ``noise`` a plane's points are: ``1.4826 median(|d| / sigma(z))``
    over the points within its band (``d`` the distance to the plane, ``z`` the depth), at
    least 1; 1 for a fixed band or fewer than 10 points.

    Parameters
    ----------
    points : ndarray of float64, shape (N, 3)
    equation : ndarray, shape (4,)
    noise : NoiseSettings

    Returns
    -------
    float
    """
    if noise.floor >= noise.cap:
        return 1.0  # a fixed band: nothing to adapt
    z = points[:, 2]
    sigma = noise.model.sigma(z)
    distance = np.abs(np.einsum("ij,j->i", points, equation[:3]) + equation[3])
    with np.errstate(invalid="ignore"):
        inside = distance <= np.clip(noise.k * sigma, noise.floor, noise.cap)
    if np.count_nonzero(inside) < 10:
        return 1.0
    return max(1.0, 1.4826 * float(np.median(distance[inside] / np.maximum(sigma[inside], 1e-9))))


def refine_planes(
    labels: np.ndarray,
    depth_m: np.ndarray,
    plane_ids: np.ndarray,
    camera: Camera,
    config: RansacConfig,
    noise: NoiseSettings,
    valid_pixels: np.ndarray | None = None,
) -> tuple[np.ndarray, dict[int, PlaneFit]]:
    """Keep, for each plane, only its pixels with valid depth that lie on its fitted plane.

    Each plane is fitted (:func:`fit_plane`) to its valid pixels on a regular grid (every
    pixel, or every s-th row and column so that at most ``config.max_points`` remain); whether
    a pixel is an inlier is then decided for every pixel of every plane at once: its distance
    to its own plane within the band ``noise.band(z)`` at its own depth.

    Parameters
    ----------
    labels : ndarray of non-negative int, shape (H, W)
        The rasterised polygons (plane ids, 0 = none).
    depth_m : ndarray of float32, shape (H, W)
        Depth in metres, NaN where invalid.
    plane_ids : ndarray of int
        The planes to refine; every other label becomes 0.
    camera : Camera
    config : RansacConfig
    noise : NoiseSettings
        The inlier band.
    valid_pixels : ndarray of int, optional
        Number of valid-depth pixels of each plane of ``plane_ids`` (as counted by
        :func:`annotate_rgbd.filters.plane_statistics`); counted here when not given.

    Returns
    -------
    refined : ndarray, shape (H, W), of the type of ``labels``
        Plane ids on inlier pixels, 0 everywhere else (off-plane and invalid-depth pixels too).
    fits : dict of int to PlaneFit
        The fit of each refined plane id (its ``inliers`` are those of the grid points).
    """
    valid = np.isfinite(depth_m)
    on_valid = np.where(valid, labels, 0)  # plane ids where the depth is valid
    n_labels = int(labels.max(initial=0)) + 1
    plane_ids = np.asarray(plane_ids)
    if valid_pixels is None:
        valid_pixels = np.bincount(on_valid.ravel(), minlength=n_labels)[plane_ids]
    table = np.zeros((n_labels, 4), dtype=np.float32)  # (a, b, c, d) per label; 0 = no plane
    scales = np.ones(n_labels, dtype=np.float32)  # each plane's noise scale
    fits = {}
    for plane_id, count in zip(plane_ids.tolist(), np.asarray(valid_pixels).tolist()):
        rows, cols = grid_pixels(on_valid, plane_id, count, config.max_points)
        if rows.size < 3:
            continue
        fit = fit_plane(backproject(cols, rows, depth_m[rows, cols], camera), config, noise)
        fits[plane_id] = fit
        table[plane_id] = fit.equation
        scales[plane_id] = fit.noise_scale
    # Distance of every pixel to its own label's plane: |z (a x_n + b y_n + c) + d| with
    # x_n = (col - cx) / fx, y_n = (row - cy) / fy the pixel's ray at z = 1.
    # float32 is ample here: depth has 0.2 mm steps, and the band is millimetres or more.
    a, b, c, d = (_lookup(table[:, k], on_valid) for k in range(4))
    x_n = ((np.arange(labels.shape[1], dtype=np.float32) - np.float32(camera.cx)) / np.float32(camera.fx))[None, :]
    y_n = ((np.arange(labels.shape[0], dtype=np.float32) - np.float32(camera.cy)) / np.float32(camera.fy))[:, None]
    with np.errstate(invalid="ignore"):
        distance = np.abs(depth_m * (a * x_n + b * y_n + c) + d)
        fitted = np.zeros(n_labels, dtype=np.float32)
        fitted[list(fits)] = 1
        band = band_image(depth_m, noise)
        if not isinstance(band, float) and (scales != 1).any():  # widened where a plane's noise is larger
            band = np.clip(band * _lookup(scales, on_valid), np.float32(noise.floor), np.float32(noise.cap))
        on_plane = (distance < band) & (_lookup(fitted, on_valid) > 0)
    return np.where(on_plane, labels, 0).astype(labels.dtype), fits


def grid_pixels(labels: np.ndarray, plane_id: int, count: int, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """A plane's pixels on a regular grid: every s-th row and column, so that at most about
    ``max_points`` of its ``count`` pixels remain (all of them when ``max_points`` is 0 or the
    grid would leave fewer than 3).

    Returns
    -------
    rows, cols : ndarray of int
        In row-major order.
    """
    step = max(1, int(np.ceil(np.sqrt(count / max_points)))) if max_points else 1
    rows, cols = np.nonzero(labels[::step, ::step] == plane_id)
    if rows.size < 3 and step > 1:
        return np.nonzero(labels == plane_id)
    return rows * step, cols * step


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


def _lookup(table: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """``table[labels]`` for a float32 table (OpenCV's table look-up for 8-bit labels)."""
    if labels.dtype == np.uint8:
        padded = np.zeros(256, dtype=np.float32)
        padded[: len(table)] = table
        return cv2.LUT(labels, padded)
    return np.take(table, labels)

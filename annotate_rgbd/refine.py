"""Depth refinement: keep only the pixels that lie on each plane (Open3D RANSAC)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import open3d as o3d

from .camera import Camera, backproject
from .config import RansacConfig


@dataclass(frozen=True)
class PlaneFit:
    """The result of fitting one plane.

    Parameters
    ----------
    equation : ndarray of float64, shape (4,)
        ``(a, b, c, d)`` with ``a x + b y + c z + d = 0`` in the camera frame (metres), unit
        normal, oriented towards the camera (``d > 0``).
    inliers : ndarray of bool, shape (N,)
        For each input point, whether it lies within the distance threshold.
    """

    equation: np.ndarray
    inliers: np.ndarray


def fit_plane(points: np.ndarray, config: RansacConfig) -> PlaneFit:
    """Fit a plane to 3-D points with Open3D's RANSAC.

    RANSAC searches for the plane among at most ``config.max_points`` of the points, taken
    evenly through the input (for a plane's pixels in row-major order: a regular grid over the
    plane); whether a point is an inlier is then decided for every point, with the same rule as
    Open3D (distance to the plane below the threshold). Open3D runs single-threaded with its
    generator seeded before every call: its multi-threaded RANSAC gives different planes from
    run to run, and frames are parallelised across processes instead.

    Parameters
    ----------
    points : ndarray of float64, shape (N, 3)
        N >= 3 points in metres.
    config : RansacConfig

    Returns
    -------
    PlaneFit
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    sample = points
    if config.max_points and len(points) > config.max_points:
        sample = points[:: -(-len(points) // config.max_points)]
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(sample))
    threads = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(1)
    try:
        o3d.utility.random.seed(config.seed)
        model, _ = cloud.segment_plane(
            distance_threshold=config.distance_threshold, ransac_n=3, num_iterations=config.num_iterations
        )
    finally:
        o3d.utility.set_max_threads(threads)
    equation = np.asarray(model, dtype=np.float64)
    equation = equation / np.linalg.norm(equation[:3])
    if equation[3] < 0:
        equation = -equation
    inliers = np.abs(points @ equation[:3] + equation[3]) < config.distance_threshold
    return PlaneFit(equation=equation, inliers=inliers)


def refine_planes(
    labels: np.ndarray,
    depth_m: np.ndarray,
    plane_ids: np.ndarray,
    camera: Camera,
    config: RansacConfig,
    valid_pixels: np.ndarray | None = None,
) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """Keep, for each plane, only its pixels with valid depth that lie on the plane RANSAC finds.

    Each plane is fitted to its valid pixels on a regular grid (every pixel, or every s-th row
    and column so that at most ``config.max_points`` remain); whether a pixel is an inlier is
    then decided for every pixel of every plane at once, with the distance to its own plane.

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
    valid_pixels : ndarray of int, optional
        Number of valid-depth pixels of each plane of ``plane_ids`` (as counted by
        :func:`annotate_rgbd.filters.plane_statistics`); counted here when not given.

    Returns
    -------
    refined : ndarray, shape (H, W), of the type of ``labels``
        Plane ids on inlier pixels, 0 everywhere else (off-plane and invalid-depth pixels too).
    equations : dict of int to ndarray
        The plane of each refined plane id, as in :class:`PlaneFit`.
    """
    valid = np.isfinite(depth_m)
    on_valid = np.where(valid, labels, 0)  # plane ids where the depth is valid
    n_labels = int(labels.max(initial=0)) + 1
    plane_ids = np.asarray(plane_ids)
    if valid_pixels is None:
        valid_pixels = np.bincount(on_valid.ravel(), minlength=n_labels)[plane_ids]
    table = np.zeros((n_labels, 4), dtype=np.float32)  # (a, b, c, d) per label; 0 = no plane
    equations = {}
    for plane_id, count in zip(plane_ids.tolist(), np.asarray(valid_pixels).tolist()):
        step = 1
        if config.max_points:
            step = max(1, int(np.ceil(np.sqrt(count / config.max_points))))
        rows, cols = np.nonzero(on_valid[::step, ::step] == plane_id)
        if rows.size < 3 and step > 1:
            rows, cols = np.nonzero(on_valid == plane_id)
            step = 1
        if rows.size < 3:
            continue
        rows, cols = rows * step, cols * step
        fit = fit_plane(backproject(cols, rows, depth_m[rows, cols], camera), config)
        equations[plane_id] = fit.equation
        table[plane_id] = fit.equation
    # Distance of every pixel to its own label's plane: |z (a x_n + b y_n + c) + d| with
    # x_n = (col - cx) / fx, y_n = (row - cy) / fy the pixel's ray at z = 1.
    # float32 is ample here: depth has 0.2 mm steps, and the threshold is millimetres or more.
    a, b, c, d = (_lookup(table[:, k], on_valid) for k in range(4))
    x_n = ((np.arange(labels.shape[1], dtype=np.float32) - np.float32(camera.cx)) / np.float32(camera.fx))[None, :]
    y_n = ((np.arange(labels.shape[0], dtype=np.float32) - np.float32(camera.cy)) / np.float32(camera.fy))[:, None]
    with np.errstate(invalid="ignore"):
        distance = np.abs(depth_m * (a * x_n + b * y_n + c) + d)
    fitted = np.zeros(n_labels, dtype=np.float32)
    fitted[list(equations)] = 1
    on_plane = (distance < config.distance_threshold) & (_lookup(fitted, on_valid) > 0)
    return np.where(on_plane, labels, 0).astype(labels.dtype), equations


def _lookup(table: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """``table[labels]`` for a float32 table (OpenCV's table look-up for 8-bit labels)."""
    if labels.dtype == np.uint8:
        padded = np.zeros(256, dtype=np.float32)
        padded[: len(table)] = table
        return cv2.LUT(labels, padded)
    return np.take(table, labels)

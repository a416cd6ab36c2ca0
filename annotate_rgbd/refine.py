"""Depth refinement: keep only the pixels that lie on each plane (Open3D RANSAC)."""

from __future__ import annotations

from dataclasses import dataclass

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
    labels: np.ndarray, depth_m: np.ndarray, plane_ids: np.ndarray, camera: Camera, config: RansacConfig
) -> tuple[np.ndarray, dict[int, PlaneFit]]:
    """Keep, for each plane, only its pixels with valid depth that RANSAC finds on the plane.

    Parameters
    ----------
    labels : ndarray of int32, shape (H, W)
        The rasterised polygons (plane ids, 0 = none).
    depth_m : ndarray of float32, shape (H, W)
        Depth in metres, NaN where invalid.
    plane_ids : ndarray of int
        The planes to refine; every other label becomes 0.
    camera : Camera
    config : RansacConfig

    Returns
    -------
    refined : ndarray of int32, shape (H, W)
        Plane ids on inlier pixels, 0 everywhere else (off-plane and invalid-depth pixels too).
    fits : dict of int to PlaneFit
        The fit of each plane; its ``inliers`` follow the order of the plane's valid pixels in
        row-major order.
    """
    refined = np.zeros_like(labels)
    keep = np.isin(labels, plane_ids) & np.isfinite(depth_m)
    rows, cols = np.nonzero(keep)
    ids = labels[rows, cols]
    # Group the pixels by plane once (stable, so each plane's pixels stay in row-major order)
    # and back-project only those pixels, not the whole image.
    order = np.argsort(ids, kind="stable")
    rows, cols, ids = rows[order], cols[order], ids[order]
    points = backproject(cols, rows, depth_m[rows, cols], camera)
    starts = np.searchsorted(ids, plane_ids, side="left")
    ends = np.searchsorted(ids, plane_ids, side="right")
    fits = {}
    for plane_id, start, end in zip(plane_ids.tolist(), starts, ends):
        if end - start < 3:
            continue
        fit = fit_plane(points[start:end], config)
        fits[plane_id] = fit
        refined[rows[start:end][fit.inliers], cols[start:end][fit.inliers]] = plane_id
    return refined, fits

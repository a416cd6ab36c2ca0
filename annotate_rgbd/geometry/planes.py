"""Least-squares plane fitting weighted by depth noise, and the re-fit of a RANSAC plane.

RANSAC (refine.py) returns the plane through 3 sampled points: its normal is as noisy as those
3 points. Re-fitting the plane to all its inliers by least squares, each point weighted by
``1 / sigma(z)^2`` (near, less noisy points count more), gives the maximum-likelihood plane under
Gaussian noise of standard deviation ``sigma(z)`` along the normal.

Planes are ``(a, b, c, d)`` with ``a x + b y + c z + d = 0`` in the camera frame (metres), a unit
normal ``(a, b, c)``, oriented towards the camera at the origin (``d > 0``), as in refine.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .noise import NoiseModel, inlier_band


def weighted_plane_fit(points: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """The plane minimising the weighted sum of squared point-to-plane distances.

    Weighted PCA: the plane passes through the weighted centroid, and its normal is the
    eigenvector of the smallest eigenvalue of the weighted covariance of the points.

    Parameters
    ----------
    points : ndarray of float, shape (N, 3)
        Finite points in metres, N >= 3, not all on one line.
    weights : ndarray of float, shape (N,), optional
        Finite, non-negative weights, at least 3 of them positive (e.g. ``1 / sigma(z)^2``).
        ``None``: all 1.

    Returns
    -------
    ndarray of float64, shape (4,)
        ``(a, b, c, d)``, unit normal, ``d >= 0`` (``d > 0`` unless the plane passes through
        the origin).

    Raises
    ------
    ValueError
        Wrong shapes, non-finite values, negative weights, fewer than 3 weighted points, or
        points on one line (no unique plane).
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {points.shape}")
    w = np.ones(len(points)) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (len(points),):
        raise ValueError(f"weights must have shape ({len(points)},), got {w.shape}")
    if not (np.isfinite(points).all() and np.isfinite(w).all()):
        raise ValueError("points and weights must be finite")
    if (w < 0).any():
        raise ValueError("weights must be >= 0")
    if np.count_nonzero(w) < 3:
        raise ValueError(f"a plane needs at least 3 points of positive weight, got {np.count_nonzero(w)}")
    return _fit(np.ascontiguousarray(points.T), w)


def _fit(coords: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """:func:`weighted_plane_fit` on coordinates stored as rows ``(x, y, z)``, shape (3, N).

    The weighted covariance is assembled from products of contiguous coordinate rows (several
    times faster than products of an (N, 3) array on 300k points), about a rough centre so that
    no precision is lost to large coordinates.
    """
    origin = coords.mean(axis=1)  # any point near the data will do
    centred = coords - origin[:, None]
    weighted = centred * weights
    total = weights.sum()
    mean = weighted.sum(axis=1) / total
    second = np.empty((3, 3))
    for i in range(3):
        for j in range(i, 3):
            # einsum, not ``@``: a BLAS dot on 300k elements starts OpenBLAS threads, which
            # on a busy machine made it 100x slower (5-12 ms instead of 0.05-0.13 ms).
            second[i, j] = second[j, i] = np.einsum("n,n->", weighted[i], centred[j]) / total
    covariance = second - np.outer(mean, mean)
    eigenvalues, eigenvectors = np.linalg.eigh(covariance)  # ascending
    # Collinear points: two eigenvalues vanish and the normal is any direction around the line.
    if eigenvalues[1] <= 1e-12 * max(eigenvalues[2], np.finfo(float).tiny):
        raise ValueError("the points lie on one line: no unique plane")
    normal = eigenvectors[:, 0]
    equation = np.append(normal, -normal @ (origin + mean))
    return -equation if equation[3] < 0 else equation


def _distance(coords: np.ndarray, equation: np.ndarray) -> np.ndarray:
    """:func:`point_plane_distance` for coordinates stored as rows, shape (3, N)."""
    # einsum rather than ``@`` (no BLAS threads, see _fit); in place: one array, not four.
    distance = np.einsum("i,in->n", equation[:3], coords)
    distance += equation[3]
    return np.abs(distance, out=distance)


def point_plane_distance(points: np.ndarray, equation: np.ndarray) -> np.ndarray:
    """Unsigned distance of each point to a plane.

    Parameters
    ----------
    points : ndarray of float, shape (N, 3)
        Metres; rows with NaN give NaN.
    equation : ndarray of float, shape (4,)
        ``(a, b, c, d)`` with a unit normal.

    Returns
    -------
    ndarray of float64, shape (N,)
        Metres.
    """
    points = np.asarray(points, dtype=np.float64)
    equation = np.asarray(equation, dtype=np.float64)
    return np.abs(points @ equation[:3] + equation[3])


@dataclass(frozen=True)
class Refit:
    """The result of :func:`refit_plane`.

    Parameters
    ----------
    equation : ndarray of float64, shape (4,)
        The re-fitted plane ``(a, b, c, d)`` (the input plane when no re-fit was possible).
    inliers : ndarray of bool, shape (N,)
        Whether each input point lies within the band of ``equation`` at its own depth.
    inliers_before : int
        Number of inliers of the input plane.
    inliers_after : int
        Number of inliers of the re-fitted plane (``inliers.sum()``).
    rms_sigma : float
        Root mean square of the final inliers' distances to the plane, each divided by the
        noise the band stands for at its depth (``band / k``: ``sigma(z)`` where the band is not
        clipped by floor or cap). About 1 when the noise model is right (0.986 for Gaussian noise
        cut at k = 3); NaN without inliers.
    band_at_median : float
        The band (metres) at the median depth of the final inliers; NaN without inliers.
    """

    equation: np.ndarray
    inliers: np.ndarray
    inliers_before: int
    inliers_after: int
    rms_sigma: float
    band_at_median: float


def refit_plane(
    points: np.ndarray,
    equation: np.ndarray,
    model: NoiseModel,
    k: float,
    floor: float,
    cap: float,
    iterations: int = 2,
    fit_points: int = 20_000,
) -> Refit:
    """Re-fit a plane to its inliers by least squares weighted with ``1 / sigma(z)^2``.

    Each iteration takes the points within the band ``clip(k sigma(z), floor, cap)`` of the
    current plane (``z`` the point's own depth) and fits the plane to them with
    :func:`weighted_plane_fit`, each weighted by ``1 / (band / k)^2`` (``1 / sigma(z)^2`` where
    the band is not clipped); two iterations settle a plane that RANSAC found within a few
    tenths of the band. An iteration with fewer than 3 inliers stops the re-fit. The fits use
    every s-th point only, so that at most ``fit_points`` remain (the standard error of the
    normal falls as one over the square root of the number of points: 20,000 points already
    make it ~80 times smaller than that of a 3-point plane, and cost a fraction of a
    millisecond); the inliers are then decided for every point.

    The noise ``sigma(z)`` of these models is along the viewing ray; the distance to the plane
    is perpendicular to it, at most ``|ray| <= 1.26`` times the depth error for a 640x480,
    f = 525 px camera and smaller for planes seen obliquely, so the band is mostly on the
    generous side for tilted planes (where lateral pixel noise also adds depth error).

    Parameters
    ----------
    points : ndarray of float, shape (N, 3)
        The plane's points in metres, camera frame (z = depth); rows with NaN are never inliers.
    equation : ndarray of float, shape (4,)
        The starting plane (e.g. RANSAC's), unit normal.
    model : ConstantNoise or QuadraticNoise
    k, floor, cap : float
        The band, as in :func:`annotate_rgbd.geometry.noise.inlier_band`.
    iterations : int
        Number of re-fits (0: only count the inliers of ``equation``).
    fit_points : int
        Largest number of points a fit uses; 0: all.

    Returns
    -------
    Refit
    """
    coords = np.ascontiguousarray(np.asarray(points, dtype=np.float64).T)  # rows x, y, z
    equation = np.asarray(equation, dtype=np.float64)
    band = inlier_band(coords[2], model, k, floor, cap)  # NaN where z is NaN: never an inlier
    with np.errstate(invalid="ignore"):
        distance = _distance(coords, equation)
        inliers = distance <= band
    before = int(np.count_nonzero(inliers))
    if iterations > 0 and before >= 3:
        step = -(-coords.shape[1] // fit_points) if fit_points else 1
        sample, sample_band = coords[:, ::step], band[::step]
        finite = np.isfinite(sample).all(axis=0)
        sample, sample_band = np.ascontiguousarray(sample[:, finite]), sample_band[finite]
        weights = (k / sample_band) ** 2  # floor / k > 0 keeps them finite
        sample_inliers = _distance(sample, equation) <= sample_band
        for _ in range(iterations):
            if np.count_nonzero(sample_inliers) < 3:
                break
            try:  # outliers get weight 0 rather than being copied out
                equation = _fit(sample, np.where(sample_inliers, weights, 0.0))
            except ValueError:  # collinear inliers: keep the plane we have
                break
            sample_inliers = _distance(sample, equation) <= sample_band
        with np.errstate(invalid="ignore"):
            distance = _distance(coords, equation)
            inliers = distance <= band
    after = int(np.count_nonzero(inliers))
    rms = band_median = float("nan")
    if after:
        # distance / (band / k), summed over the inliers without copying them out
        ratio = np.divide(distance, band, out=np.zeros_like(distance), where=inliers)
        rms = k * float(np.sqrt(np.einsum("n,n->", ratio, ratio) / after))
        band_median = float(inlier_band(np.median(coords[2, inliers]), model, k, floor, cap))
    return Refit(equation, inliers, before, after, rms, band_median)

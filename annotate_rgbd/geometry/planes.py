"""Planes from points: least-squares fits, the moments they are fitted from, and the re-fit of
a RANSAC plane weighted by depth noise.

Every plane fit of the package is an eigen-decomposition done here (:func:`fit_planes`): the
plane of a point set passes through its centroid, and its normal is the eigenvector of the
smallest eigenvalue of the points' scatter about the centroid. What differs between callers is
how the centroid and the scatter are gathered:

- :func:`weighted_plane_fit`: from the points themselves, each with a weight (refinement's re-fit,
  weighted by ``1 / sigma(z)^2``);
- :class:`Moments`: from the count, centroid and centred scatter of ``K`` point sets (cells and
  segments of the plane detector, merged proposals), which sets can be pooled without their
  points (:func:`moments_from_sums`, :func:`merge_pairs`, :func:`pool_groups`).

RANSAC (:mod:`annotate_rgbd.segment.ransac`) returns the plane through 3 sampled points: its
normal is as noisy as those 3 points. Re-fitting the plane to all its inliers by least squares,
each point weighted by ``1 / sigma(z)^2`` (near, less noisy points count more), gives the
maximum-likelihood plane under Gaussian noise of standard deviation ``sigma(z)`` along the normal
(:func:`refit_plane`).

Planes are ``(a, b, c, d)`` with ``a x + b y + c z + d = 0`` in the camera frame (metres), a unit
normal ``(a, b, c)``, oriented towards the camera at the origin (``d >= 0``). Moving planes between
camera and world frames and comparing them is :mod:`annotate_rgbd.geometry.lift`'s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .noise import NoiseSettings
from .statistics import median


@dataclass(frozen=True)
class Moments:
    """Point count, centroid and centred scatter of ``K`` point sets: all a least-squares plane needs.

    Attributes
    ----------
    count : ndarray of float64, shape (K,)
        Number of points.
    mean : ndarray of float64, shape (K, 3)
        Centroid, metres.
    scatter : ndarray of float64, shape (K, 3, 3)
        Sum of the outer products of the points about their centroid, m^2.
    """

    count: np.ndarray
    mean: np.ndarray
    scatter: np.ndarray

    def take(self, index) -> Moments:
        """The sets ``index`` (an index or a boolean mask along ``K``)."""
        return Moments(self.count[index], self.mean[index], self.scatter[index])


def fit_planes(mean: np.ndarray, scatter: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares (orthogonal) planes of point sets from their centroids and scatter matrices.

    Parameters
    ----------
    mean : ndarray of float64, shape (K, 3)
        Centroids, metres (NaN for an empty set gives a NaN offset).
    scatter : ndarray of float64, shape (K, 3, 3)
        Scatter (or covariance: any positive multiple) about the centroids.

    Returns
    -------
    planes : ndarray of float64, shape (K, 4)
        ``(a, b, c, d)`` through the centroid, unit normal oriented towards the camera (``d >= 0``).
    eigenvalues : ndarray of float64, shape (K, 3)
        Of ``scatter``, ascending: the first is the sum of squared distances to the plane (for a
        scatter), the second measures the sets' extent across their narrower in-plane direction.
    """
    eigenvalues, eigenvectors = np.linalg.eigh(scatter)  # ascending
    normal = eigenvectors[:, :, 0]
    offset = -np.einsum("ij,ij->i", normal, mean)
    flip = np.where(offset < 0, -1.0, 1.0)  # NaN < 0 is False: an empty set's normal stays as it is
    planes = np.concatenate([normal * flip[:, None], (offset * flip)[:, None]], axis=1)
    return planes, eigenvalues


def residual_ms(count: np.ndarray, eigenvalues: np.ndarray) -> np.ndarray:
    """Mean squared distance of each set's points to its least-squares plane, m^2: the smallest
    eigenvalue of its scatter (:func:`fit_planes`) over its number of points.

    Parameters
    ----------
    count : ndarray, shape (K,)
    eigenvalues : ndarray of float64, shape (K, 3)
        Of the sets' scatter matrices, ascending.

    Returns
    -------
    ndarray of float64, shape (K,)
    """
    return np.maximum(eigenvalues[:, 0], 0) / np.maximum(count, 1)


def moments_from_sums(count: np.ndarray, first: np.ndarray, second: np.ndarray) -> Moments:
    """:class:`Moments` from raw sums over the points (which add up when sets are joined).

    Parameters
    ----------
    count : ndarray of float64, shape (K,)
        Number of points; a set of 0 points gets centroid 0 and scatter ``second``.
    first : ndarray of float64, shape (K, 3)
        Sum of the points.
    second : ndarray of float64, shape (K, 3, 3)
        Sum of the outer products of the points (about the camera centre).

    Returns
    -------
    Moments
        ``count`` as given.
    """
    divisor = np.maximum(count, 1)
    mean = first / divisor[:, None]
    scatter = second - divisor[:, None, None] * mean[:, :, None] * mean[:, None, :]
    return Moments(count, mean, scatter)


def mean_squared_distance(planes: np.ndarray, moments: Moments) -> np.ndarray:
    """Mean squared distance of the points of set ``k`` to plane ``k``, from the set's moments:
    ``n^T S n / N + (n . m + d)^2`` (``S`` the scatter about the centroid ``m``, unit normal ``n``).

    Parameters
    ----------
    planes : ndarray of float64, shape (K, 4)
    moments : Moments
        ``K`` sets.

    Returns
    -------
    ndarray of float64, shape (K,)
        m^2.
    """
    normal = planes[:, :3]
    spread = np.einsum("ki,kij,kj->k", normal, moments.scatter, normal) / np.maximum(moments.count, 1)
    return spread + (np.einsum("ki,ki->k", moments.mean, normal) + planes[:, 3]) ** 2


def merge_pairs(moments: Moments, a: np.ndarray, b: np.ndarray) -> Moments:
    """The moments of the unions of sets ``a[p]`` and ``b[p]`` (parallel-axis theorem).

    Parameters
    ----------
    moments : Moments
    a, b : ndarray of int, shape (P,)
        Indices of the sets to join, pairwise.

    Returns
    -------
    Moments
        ``P`` sets.
    """
    count, mean, scatter = moments.count, moments.mean, moments.scatter
    joint = count[a] + count[b]
    centre = (count[a, None] * mean[a] + count[b, None] * mean[b]) / joint[:, None]
    delta = mean[a] - mean[b]
    spread = scatter[a] + scatter[b] + (count[a] * count[b] / joint)[:, None, None] * delta[:, :, None] * delta[:, None, :]
    return Moments(joint, centre, spread)


def pool_groups(moments: Moments, group: np.ndarray, heads: np.ndarray) -> Moments:
    """The moments of groups of sets, each about its own centroid.

    Parameters
    ----------
    moments : Moments
        ``K`` sets.
    group : ndarray of int, shape (K,)
        The group of each set.
    heads : ndarray of int, shape (G,)
        The groups to pool, in the order wanted.

    Returns
    -------
    Moments
        ``G`` sets.
    """
    if len(heads) == 0:  # nothing to pool (a frame without a plane)
        return Moments(moments.count[:0].copy(), moments.mean[:0].copy(), moments.scatter[:0].copy())
    count = np.array([moments.count[group == h].sum() for h in heads])
    mean = np.array([(moments.count[group == h, None] * moments.mean[group == h]).sum(0) for h in heads]) / count[:, None]
    scatter = np.array([
        sum(moments.scatter[k] + moments.count[k] * np.outer(moments.mean[k] - mean[g], moments.mean[k] - mean[g])
            for k in np.flatnonzero(group == h))
        for g, h in enumerate(heads)
    ])
    return Moments(count, mean, scatter)


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
    centroid = origin + mean
    planes, eigenvalues = fit_planes(centroid[None], covariance[None])
    # Collinear points: two eigenvalues vanish and the normal is any direction around the line.
    if eigenvalues[0, 1] <= 1e-12 * max(eigenvalues[0, 2], np.finfo(float).tiny):
        raise ValueError("the points lie on one line: no unique plane")
    # The offset of a single plane by ``@`` (a BLAS dot, whose last bit can differ from the
    # batched einsum's): re-fitted planes stay bit for bit what they were.
    normal = planes[0, :3]
    equation = np.append(normal, -normal @ centroid)
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
    noise: NoiseSettings,
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
    noise : NoiseSettings
        The noise model and the band built from it (``noise.band(z)``).
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
    k = noise.k
    band = noise.band(coords[2])  # NaN where z is NaN: never an inlier
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
        band_median = float(noise.band(median(coords[2, inliers])))
    return Refit(equation, inliers, before, after, rms, band_median)

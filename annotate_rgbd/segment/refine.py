"""Depth refinement: keep only the pixels that lie on each plane (each found by
:func:`annotate_rgbd.segment.ransac.fit_plane`)."""

from __future__ import annotations

from dataclasses import replace
from typing import Collection, Mapping

import cv2
import numpy as np

from annotate_rgbd.geometry.camera import Camera, backproject
from annotate_rgbd.config.settings import PropagateConfig, RansacConfig, RefineConfig
from annotate_rgbd.geometry.noise import NoiseSettings
from annotate_rgbd.geometry.planes import weighted_plane_fit
from .bend import plane_bends
from .distances import band_image, behind_factor, signed_distances
from .filters import NO_PLANE, NOT_WHERE_EXPECTED
from .ransac import PlaneFit, fit_plane, on_expected_plane
from .rims import near_surfaces_in_front


def refine_planes(
    labels: np.ndarray,
    depth_m: np.ndarray,
    plane_ids: np.ndarray,
    camera: Camera,
    config: RansacConfig,
    noise: NoiseSettings,
    valid_pixels: np.ndarray | None = None,
    rim_pixels: int = 0,
    propagated: Collection[int] = (),
    expected: Mapping[int, np.ndarray] | None = None,
    refine: RefineConfig = RefineConfig(),
    propagate: PropagateConfig = PropagateConfig(),
    unfit: dict[int, str] | None = None,
) -> tuple[np.ndarray, dict[int, PlaneFit]]:
    """Keep, for each plane, only its pixels with valid depth that lie on its fitted plane.

    Each plane is fitted (:func:`fit_plane`) to its valid pixels on a regular grid (every
    pixel, or every s-th row and column so that at most ``config.max_points`` remain); whether
    a pixel is an inlier is then decided for every pixel of every plane at once: its distance
    to its own plane within the band ``noise.band(z)`` at its own depth (with a noise model, not
    a fixed band, ``refine.behind_band`` times that behind the plane: nothing seen stands just
    behind the surface that hides it). With a noise model, surfaces inside the band but off the
    plane are then found by the window test
    (:func:`window_scores`): each plane is re-fitted to the windows around its dominant surface,
    and inliers whose window score lies beyond ``refine.coherence_limit`` spreads, or whose
    window holds under ``refine.min_inlier_density`` inliers, are dropped. Last, inliers within
    ``rim_pixels`` of a surface in front of their plane inside its shape are dropped
    (:func:`annotate_rgbd.segment.rims.near_surfaces_in_front`).

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
        :func:`annotate_rgbd.segment.filters.plane_statistics`); counted here when not given.
    rim_pixels : int
        Drop inliers this close (px) to a surface in front of their plane; 0: none.
    propagated : collection of int
        Planes whose shapes no labeller drew on this frame (carried here by camera poses): their
        fits look behind RANSAC's plane (:func:`annotate_rgbd.segment.ransac.fit_plane`) only for the
        plane ``expected`` says.
    expected : mapping of int to ndarray, shape (4,), optional
        Where camera poses put each of those planes in this frame.
    refine : RefineConfig
        The window test's tunables (``rim_pixels`` is the parameter above).
    propagate : PropagateConfig
        The same-surface tolerances for ``expected``. A carried plane's fit that is another
        surface than the expected one (:func:`annotate_rgbd.segment.ransac.on_expected_plane`: the
        shape landed on something else, its outline carried past the plane's end) is fitted again
        to the points near the expected plane; when those are too few or another surface too, the
        plane has no fit and keeps no pixel.
    unfit : dict, optional
        Filled with the reason of each plane of ``plane_ids`` that has no fit (so keeps no pixel):
        ``no_plane`` when its valid pixels span no plane (:func:`spans_a_plane`, or all of their
        points on one line in space), ``not_where_expected`` for a carried plane that is not
        where the poses put it.

    Returns
    -------
    refined : ndarray, shape (H, W), of the type of ``labels``
        Plane ids on inlier pixels, 0 everywhere else (off-plane and invalid-depth pixels too).
    fits : dict of int to PlaneFit
        The fit of each refined plane id (its ``inliers`` are those of the grid points); the
        planes of ``unfit`` have none.
    """
    valid = np.isfinite(depth_m)
    on_valid = labels * valid  # plane ids where the depth is valid
    n_labels = int(labels.max(initial=0)) + 1
    plane_ids = np.asarray(plane_ids)
    if valid_pixels is None:
        valid_pixels = np.bincount(on_valid.ravel(), minlength=n_labels)[plane_ids]
    table = np.zeros((n_labels, 4), dtype=np.float32)  # (a, b, c, d) per label; 0 = no plane
    scales = np.ones(n_labels, dtype=np.float32)  # each plane's noise scale
    fits = {}
    unfit = {} if unfit is None else unfit
    for plane_id, count in zip(plane_ids.tolist(), np.asarray(valid_pixels).tolist()):
        rows, cols = grid_pixels(on_valid, plane_id, count, config.max_points)
        if not spans_a_plane(rows, cols):
            unfit[plane_id] = NO_PLANE
            continue
        points = backproject(cols, rows, depth_m[rows, cols], camera)
        where = (expected or {}).get(plane_id) if plane_id in propagated else None
        fit = fit_plane(points, config, noise, look_behind=plane_id not in propagated, expected=where,
                        propagate=propagate)
        if not fit.inliers.any():
            unfit[plane_id] = NO_PLANE  # its points lie on one line in space: nothing of it is kept
            continue
        if where is not None and not on_expected_plane(points[fit.inliers], where, propagate):
            fit = _fit_near(points, where, config, noise, refine, propagate)
            if fit is None:
                unfit[plane_id] = NOT_WHERE_EXPECTED  # nothing of it is kept
                continue
        fits[plane_id] = fit
        table[plane_id] = fit.equation
        scales[plane_id] = fit.noise_scale
    band = band_image(depth_m, noise)
    behind = behind_factor(noise, refine.behind_band)
    if not isinstance(band, float) and (scales != 1).any():  # widened where a plane's noise is larger
        band = np.clip(band * label_lookup(scales, on_valid), np.float32(noise.floor), np.float32(noise.cap))
    # The window test needs the noise, which a fixed band (distance_threshold) does not give.
    coherence = noise.floor < noise.cap and refine.coherence_window > 0
    if coherence and isinstance(band, float):  # a constant noise model
        band = np.where(np.isfinite(depth_m), np.float32(band), np.float32(np.nan))
    if coherence:
        # Surfaces within the band but off the plane (a whiteboard on a wall) pull the
        # least-squares plane towards them, and so does an inlier test that cannot tell them
        # apart: re-fit each plane to the windows around its dominant surface (the middle of the
        # densest half of its window scores) until it settles, each time closer to that surface.
        # On every other row and column (a quarter of the work; the windows cover the same area).
        small = (slice(None, None, 2), slice(None, None, 2))
        labels_s, depth_s, band_s = on_valid[small], depth_m[small], band[small]
        camera_s = replace(camera, fx=camera.fx / 2, fy=camera.fy / 2, cx=camera.cx / 2, cy=camera.cy / 2)
        window = refine.coherence_window // 2 + 1
        on_plane_s, residual_s = _inlier_test(table, labels_s, depth_s, camera_s, band_s, noise.k, behind)
        for _ in range(refine.core_refits):
            score, usable = window_scores(residual_s, on_plane_s, window, refine.min_window_inliers)
            centre, _ = _score_statistics(score, usable, labels_s, n_labels)
            core = usable & (np.abs(score - label_lookup(centre, labels_s)) <= refine.core_score)
            before = table.copy()
            _refit_to(core, labels_s, depth_s, band_s, noise.k, camera_s, config.max_points, fits, table)
            if np.abs(table - before).max(initial=0.0) < SETTLED:
                break
            on_plane_s, residual_s = _inlier_test(table, labels_s, depth_s, camera_s, band_s, noise.k, behind)
    signed = _plane_distances(table, on_valid, depth_m, camera)
    on_plane, residual = _band_test(signed, table, on_valid, band, noise.k, behind)
    if coherence and refine.bend_rounds:
        # The sensor's disparity error bows a real plane by millimetres: test against the
        # plane's bent surface (:mod:`annotate_rgbd.segment.bend`); the window test follows it.
        fitted = np.flatnonzero(table[:, :3].any(axis=1))
        signed -= plane_bends(signed, on_plane, on_valid, fitted, depth_m, band, camera, refine.bend_rounds,
                              refine.bend_cell)
        on_plane, residual = _band_test(signed, table, on_valid, band, noise.k, behind)
    if coherence:
        score, usable = window_scores(residual, on_plane, refine.coherence_window, refine.min_window_inliers)
        centre, spread = _score_statistics(score, usable, on_valid, n_labels, step=4)
        limit = refine.coherence_limit * label_lookup(spread, on_valid)
        on_plane &= ~(usable & (np.abs(score - label_lookup(centre, on_valid)) > limit))
        on_plane &= inlier_density(on_plane, on_valid > 0, refine.coherence_window) >= refine.min_inlier_density
    if rim_pixels:
        with np.errstate(invalid="ignore"):
            in_front = (on_valid > 0) & ~on_plane & (residual > 0)
        on_plane &= ~near_surfaces_in_front(in_front, on_valid, rim_pixels)
    return labels * on_plane, fits


def _fit_near(
    points: np.ndarray, expected: np.ndarray, config: RansacConfig, noise: NoiseSettings, refine: RefineConfig,
    propagate: PropagateConfig,
) -> PlaneFit | None:
    """The plane among the points that lie near the ``expected`` one (within
    ``propagate.same_surface_offset``); None when too few points lie there or the fit holds none
    of them (every point it is fitted to lies near the expected plane, so it is that surface)."""
    signed = points @ np.asarray(expected[:3], dtype=np.float64) + float(expected[3])
    near = points[np.abs(signed) <= propagate.same_surface_offset]
    if len(near) < max(3, refine.min_window_inliers):
        return None
    fit = fit_plane(near, config, noise, look_behind=False, expected=expected, propagate=propagate)
    if not np.any(fit.inliers):
        return None
    # Inliers among all the points, as the caller's fits hold them.
    band = noise.scaled(fit.noise_scale).band(points[:, 2])
    inliers = np.abs(points @ fit.equation[:3] + fit.equation[3]) <= band
    return replace(fit, inliers=inliers)


#: The core re-fits (``refine.core_refits``) stop once no plane's normal or offset moved by this
#: (unit normal components; metres), a small fraction of any band.
SETTLED = 5e-4
#: Window scores are clipped to +-this for the statistics (far beyond any limit used).
SCORE_CLIP = 1000.0


def _refit_to(
    core: np.ndarray, labels: np.ndarray, depth_m: np.ndarray, band: np.ndarray, k: float, camera: Camera,
    max_points: int, fits: dict, table: np.ndarray,
) -> None:
    """Re-fit every plane of ``fits`` to its ``core`` pixels (weighted by 1 / sigma^2, on a grid of
    at most about ``max_points``); updates ``fits`` and ``table`` in place."""
    core_labels = labels * core
    counts = np.bincount(core_labels.ravel(), minlength=len(table))
    for plane_id, fit in list(fits.items()):
        rows, cols = grid_pixels(core_labels, plane_id, int(counts[plane_id]), max_points)
        if rows.size < 3:
            continue
        sigma = (band[rows, cols] / np.float32(k)).astype(np.float64)
        try:
            equation = weighted_plane_fit(backproject(cols, rows, depth_m[rows, cols], camera), 1.0 / np.square(sigma))
        except ValueError:  # the core on one line
            continue
        fits[plane_id] = replace(fit, equation=equation)
        table[plane_id] = equation


def inlier_density(
    on_plane: np.ndarray, labelled: np.ndarray, window: int = RefineConfig.coherence_window
) -> np.ndarray:
    """The share of inliers among the labelled pixels with depth of each pixel's window.

    Parameters
    ----------
    on_plane : ndarray of bool, shape (H, W)
        Pixels within their plane's band.
    labelled : ndarray of bool, shape (H, W)
        Pixels in a plane's shape with valid depth.
    window : int
        Side of the square window (px).

    Returns
    -------
    ndarray of float32, shape (H, W)
        About 1 on a plane (0.99 for a 3 sigma band), 0.57 on its straight edge against an
        occluder, and low over a surface just beyond the band, whose noise puts only scattered
        pixels inside it.
    """
    size = (window, window)
    inliers = cv2.boxFilter(on_plane.view(np.uint8), cv2.CV_32F, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
    total = cv2.boxFilter(labelled.view(np.uint8), cv2.CV_32F, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
    with np.errstate(invalid="ignore", divide="ignore"):
        return inliers / total


def window_scores(
    residual: np.ndarray, on_plane: np.ndarray, window: int = RefineConfig.coherence_window,
    min_inliers: int = RefineConfig.min_window_inliers,
) -> tuple[np.ndarray, np.ndarray]:
    """The mean residual of each pixel's window, scaled to a standard normal on a true plane.

    Parameters
    ----------
    residual : ndarray of float32, shape (H, W)
        Each pixel's signed distance to its plane in units of its noise (NaN without depth).
    on_plane : ndarray of bool, shape (H, W)
        The pixels within their plane's inlier band (the only ones averaged).
    window : int
        Side of the square window (px).
    min_inliers : int
        Fewest inliers in a window for its score to count.

    Returns
    -------
    score : ndarray of float32, shape (H, W)
        The sum of the window's inlier residuals over the square root of their number: about
        N(0, 1) where the noise is independent and the window lies on its plane, far from 0
        over a surface that stands off the plane (its residuals share a sign).
    usable : ndarray of bool, shape (H, W)
        Inlier pixels whose window holds at least ``min_inliers`` inliers.
    """
    mask = on_plane.view(np.uint8)
    values = cv2.copyTo(residual, mask)  # a new image: 0 off the mask
    size = (window, window)
    total = cv2.boxFilter(values, -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
    count = cv2.boxFilter(mask, cv2.CV_32F, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
    with np.errstate(invalid="ignore", divide="ignore"):
        score = total / np.sqrt(count)
    return score, on_plane & (count >= min_inliers)


def _score_statistics(
    score: np.ndarray, usable: np.ndarray, labels: np.ndarray, n_labels: int, step: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """Each plane's centre and spread of window scores: the middle of the shortest interval that
    holds half of them (robust to a surface in the band that covers almost half the plane's
    pixels, which pulls a median or a mean), and the smaller of the spreads on either side of it
    (the median distance to the centre over 0.6745, a standard deviation for a normal
    distribution; the other surface widens one side only); at least 1 (real sensors' noise is
    correlated between neighbouring pixels, which widens the spread). On every ``step``-th row
    and column."""
    centre = np.zeros(n_labels, dtype=np.float32)
    spread = np.ones(n_labels, dtype=np.float32)
    grid = (slice(None, None, step), slice(None, None, step))
    sample = usable[grid]
    ids = labels[grid][sample]
    # One sort orders the samples by plane, then by score (scores clipped far beyond any limit).
    values = np.sort(ids * np.float64(4 * SCORE_CLIP) + np.clip(score[grid][sample], -SCORE_CLIP, SCORE_CLIP))
    ids = np.floor((values + SCORE_CLIP) / (4 * SCORE_CLIP)).astype(np.int64)
    values -= ids * np.float64(4 * SCORE_CLIP)
    starts = np.searchsorted(ids, np.arange(n_labels + 1))
    for plane_id in range(1, n_labels):
        v = values[starts[plane_id]:starts[plane_id + 1]]
        if v.size < 10:
            continue
        half = v.size // 2
        widths = v[half:] - v[: v.size - half]
        first = int(np.argmin(widths))
        middle = (v[first] + v[first + half]) / 2
        # The spread on each side of the centre (the median distance of a normal's half is
        # 0.6745 sigma): another surface lies on one side, the smaller one is the plane's.
        split = int(np.searchsorted(v, middle))
        sides = [middle - _sorted_median(v[:split]), _sorted_median(v[split:]) - middle] if 2 <= split <= v.size - 2 else [np.inf]
        centre[plane_id] = middle
        spread[plane_id] = max(1.0, min(sides) / 0.6745) if np.isfinite(min(sides)) else max(1.0, widths[first] / 2 / 0.6745)
    return centre, spread


def _sorted_median(v: np.ndarray) -> float:
    """``np.median`` of an array already in ascending order (the same number, without a partition)."""
    return (v[(v.size - 1) // 2] + v[v.size // 2]) / 2


def _inlier_test(
    table: np.ndarray, labels: np.ndarray, depth_m: np.ndarray, camera: Camera, band: np.ndarray | float, k: float,
    behind: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels within their plane's band (``behind`` times wider behind the plane:
    ``refine.behind_band``), and every pixel's signed distance to its plane in noise units
    (``k`` times distance over band); ``table`` holds each label's plane, zeros for a label
    without one."""
    return _band_test(_plane_distances(table, labels, depth_m, camera), table, labels, band, k, behind)


def _plane_distances(table: np.ndarray, labels: np.ndarray, depth_m: np.ndarray, camera: Camera) -> np.ndarray:
    """Every pixel's signed distance (m) to its own label's plane of ``table``."""
    return signed_distances(depth_m, *(label_lookup(table[:, i], labels) for i in range(4)), camera)


def _band_test(
    signed: np.ndarray, table: np.ndarray, labels: np.ndarray, band: np.ndarray | float, k: float, behind: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_inlier_test` from the pixels' signed distances (m) to their surfaces (positive on
    the camera's side)."""
    fitted = table[:, :3].any(axis=1).astype(np.float32)  # a plane has a unit normal
    with np.errstate(invalid="ignore"):
        on_plane = (signed < band) & (signed > band * np.float32(-behind)) & (label_lookup(fitted, labels) > 0)
        residual = signed * (np.float32(k) / band)
    return on_plane, residual


def grid_pixels(labels: np.ndarray, plane_id: int, count: int, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """A plane's pixels on a regular grid: every s-th row and column, so that at most about
    ``max_points`` of its ``count`` pixels remain (all of them when ``max_points`` is 0 or the
    grid would leave pixels that span no plane, :func:`spans_a_plane`).

    Returns
    -------
    rows, cols : ndarray of int
        In row-major order.
    """
    step = max(1, int(np.ceil(np.sqrt(count / max_points)))) if max_points else 1
    rows, cols = np.nonzero(labels[::step, ::step] == plane_id)
    if step > 1 and not spans_a_plane(rows, cols):  # a thin plane the grid cut to a line
        return np.nonzero(labels == plane_id)
    return rows * step, cols * step


def spans_a_plane(rows: np.ndarray, cols: np.ndarray) -> bool:
    """Whether a plane's pixels can tell its plane: at least 3 of them, on more than one row and
    more than one column.

    The points of pixels on one image row (or column) lie in one plane through the camera
    centre, whatever surface they are on: a fit to them finds that plane, with a sensor's noise
    as with exact depth.
    """
    return rows.size >= 3 and rows.min() != rows.max() and cols.min() != cols.max()


def label_lookup(table: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """``table[labels]``: each pixel's entry of a per-label table (OpenCV's table look-up for 8-bit
    labels, several times faster than numpy's indexing).

    Parameters
    ----------
    table : ndarray, shape (N,)
        One value per label, N > the largest label.
    labels : ndarray of non-negative int, shape (H, W)

    Returns
    -------
    ndarray, shape (H, W), of the type of ``table``
    """
    if labels.dtype == np.uint8:
        padded = np.zeros(256, dtype=table.dtype)
        padded[: len(table)] = table
        return cv2.LUT(labels, padded)
    return np.take(table, labels)

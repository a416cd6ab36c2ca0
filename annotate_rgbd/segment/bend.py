"""A plane's depth bend: the smooth departure of a real sensor's depth from a flat surface.

Structured-light and stereo sensors measure disparity, and their disparity carries a
low-frequency error over the image (Kinect v1: Smisek, Jancosek & Pajdla 2011; Herrera, Kannala
& Heikkila 2012, who model it as a per-pixel disparity offset). In depth that error grows with
``z^2``, so a flat desk one metre away comes out bowed by several millimetres towards the
image's borders: a single plane's inlier band then cuts its far corners off. On TUM
freiburg1_rpy's dense labelling the desk lost 9 % of its pixels to this.

Each plane's signed distances ``d`` (m) to its fitted plane are modelled as

    d(x, y, z) = z^2 (c0 + c1 x + c2 y + c3 x^2 + c4 x y + c5 y^2)

with ``x = (col - cx) / fx``, ``y = (row - cy) / fy`` the pixel's ray: a quadratic disparity
error over the image. The coefficients are fitted to the median distance of the plane's inliers
in square cells of the image (robust to the pixels' noise), with cells off the fit (an object a
little proud of the plane inside its band, a sphere touching it) trimmed by their median
absolute deviation and never used: a bend follows the whole plane, not a part of it. The
correction is clipped to the range of the cells it was fitted to (no extrapolation), and kept
only where it explains most of the cells' spread (:data:`SIGNIFICANT`).
"""

from __future__ import annotations

import cv2
import numpy as np

from annotate_rgbd.geometry.camera import Camera, ray_grid
from annotate_rgbd.geometry.statistics import median

#: Cells whose median lies farther than this many (normal-scaled) median absolute deviations
#: from the bend are left out of its fit: far in the tail for the cells of one smooth surface.
TRIM = 3.0
#: Fewest cells a bend is fitted to: twice its six coefficients, with room for trimmed cells.
MIN_CELLS = 12
#: Smallest share of a cell's pixels that are the plane's inliers for the cell to count.
MIN_CELL_SHARE = 0.5
#: Rounds of trimming per fit (a trimmed set that stops changing ends them sooner).
TRIM_ROUNDS = 4
#: A bend is kept only when it shrinks the spread (median absolute deviation) of the cells it
#: was fitted to below this share of their spread about a flat plane: a sensor's bow does
#: (TUM fr1_rpy's desk), a flat plane's noise or an object inside the band at one end of it
#: does not, and bending towards such an object would take it in. 0.7 is the loosest of 0.6,
#: 0.7, 0.8, 0.9 that keeps a whiteboard over a third of a wall out (tests/segment/test_coherence.py).
SIGNIFICANT = 0.7


def bend_terms(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """The six terms of the bend model at rays ``(x, y)`` and depths ``z``.

    Parameters
    ----------
    x, y, z : ndarray of float, shape (N,)
        Ray coordinates at ``z = 1`` and depth (m).

    Returns
    -------
    ndarray of float64, shape (N, 6)
        ``z^2 (1, x, y, x^2, x y, y^2)``.
    """
    x, y, z = (np.asarray(v, dtype=np.float64) for v in (x, y, z))
    return np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=1) * (z * z)[:, None]


def bend_at(coefficients: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """The bend (m) at rays ``(x, y)`` and depths ``z`` of any broadcastable shapes (float32):
    :func:`bend_terms` times ``coefficients``, without building the terms."""
    c = np.asarray(coefficients, dtype=np.float32)
    return (c[0] + c[1] * x + c[2] * y + c[3] * x * x + c[4] * x * y + c[5] * y * y) * z * z


def fit_bend(x: np.ndarray, y: np.ndarray, z: np.ndarray, distance: np.ndarray, band: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Fit the bend to cells' median distances, trimming cells off it.

    The first trim is against the cells' own median (a flat plane); then the bend is fitted by
    least squares weighted by ``1 / band`` and the cells within :data:`TRIM` median absolute
    deviations of it are kept, until that set stops changing.

    Parameters
    ----------
    x, y, z : ndarray of float, shape (N,)
        Each cell's ray at its centre and depth there (m).
    distance : ndarray of float, shape (N,)
        Each cell's median signed distance to the plane (m).
    band : ndarray of float, shape (N,)
        The inlier band at each cell (m): the cells' weights.

    Returns
    -------
    (coefficients, kept) or None
        ``coefficients`` (6,) of :func:`bend_terms`; ``kept`` (N,) bool, the cells fitted. None
        with fewer than :data:`MIN_CELLS` cells, or when the bend explains too little of the
        cells' spread (:data:`SIGNIFICANT`).
    """
    distance = np.asarray(distance, dtype=np.float64)
    if distance.size < MIN_CELLS:
        return None
    deviation = np.abs(distance - median(distance))
    kept = deviation <= TRIM * 1.4826 * median(deviation) + 1e-5
    terms = bend_terms(x, y, z)
    weight = 1.0 / np.asarray(band, dtype=np.float64)
    coefficients = None
    for _ in range(TRIM_ROUNDS):
        if kept.sum() < MIN_CELLS:
            return None
        coefficients = np.linalg.lstsq(terms[kept] * weight[kept, None], distance[kept] * weight[kept], rcond=None)[0]
        residual = distance - terms @ coefficients
        now = np.abs(residual) <= TRIM * 1.4826 * median(np.abs(residual[kept])) + 1e-5
        if (now == kept).all():
            break
        kept = now
    flat = median(np.abs(distance[kept] - median(distance[kept])))
    if median(np.abs(residual[kept])) > SIGNIFICANT * flat:
        return None
    return coefficients, kept


def cell_medians(
    inliers: np.ndarray, distance: np.ndarray, cell: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The median of ``distance`` over the inliers of each ``cell`` x ``cell`` cell holding at
    least :data:`MIN_CELL_SHARE` inliers (the last partial row and column of cells left out).

    Parameters
    ----------
    inliers : ndarray of bool, shape (H, W)
    distance : ndarray of float32, shape (H, W)
    cell : int
        Cell side (px).

    Returns
    -------
    rows, cols : ndarray of int
        The counted cells' centre pixels.
    medians : ndarray of float
        Their median distances.
    """
    hc, wc = inliers.shape[0] // cell, inliers.shape[1] // cell
    cut = (slice(0, hc * cell), slice(0, wc * cell))
    counts = inliers[cut].reshape(hc, cell, wc, cell).sum(axis=(1, 3), dtype=np.int32)  # inliers per cell
    counted = counts >= MIN_CELL_SHARE * cell * cell
    if not counted.any():
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, np.zeros(0)
    values = np.where(inliers, distance, np.float32(np.nan))[cut]
    values = values.reshape(hc, cell, wc, cell).transpose(0, 2, 1, 3)[counted].reshape(-1, cell * cell)
    # np.nanmedian row by row, from one sort (NaN sorts last): the middle of each row's values
    # (an inlier's distance is finite, so a row holds its cell's inlier count of them).
    values.sort(axis=1)
    count = counts[counted]
    low = np.take_along_axis(values, ((count - 1) // 2)[:, None], axis=1)[:, 0]
    high = np.take_along_axis(values, (count // 2)[:, None], axis=1)[:, 0]
    medians = (low.astype(np.float64) + high) / 2
    rows, cols = np.nonzero(counted)
    return rows * cell + cell // 2, cols * cell + cell // 2, medians


def plane_bends(
    signed: np.ndarray, on_plane: np.ndarray, labels: np.ndarray, plane_ids: np.ndarray, depth_m: np.ndarray,
    band: np.ndarray, camera: Camera, rounds: int, cell: int,
) -> np.ndarray:
    """Each plane's bend at each of its pixels (m; 0 where no bend was fitted).

    Each plane is fitted on its own bounding box: the bend to its inlier cells (:func:`fit_bend`),
    then again to the cells of the inliers of its bent surface (pixels the flat band cut off
    join), ``rounds`` times at most.

    Parameters
    ----------
    signed : ndarray of float32, shape (H, W)
        Every pixel's signed distance to its own plane (m; NaN without depth).
    on_plane : ndarray of bool, shape (H, W)
        The flat inlier test.
    labels : ndarray of int, shape (H, W)
        Plane ids (0 = none).
    plane_ids : ndarray of int
        The planes to bend (those with a fit).
    depth_m : ndarray of float32, shape (H, W)
    band : ndarray of float32, shape (H, W)
        The inlier band at every pixel (m).
    camera : Camera
    rounds : int
        Fits per plane (0: none).
    cell : int
        Cell side (px).

    Returns
    -------
    ndarray of float32, shape (H, W)
    """
    bends = np.zeros(labels.shape, dtype=np.float32)
    if rounds <= 0:
        return bends
    ray_x, ray_y = ray_grid(camera, *labels.shape, np.float32)
    # Each plane's box by one comparison per plane: for a frame's few planes a fifth of the time
    # scipy's find_objects takes over every label.
    for plane_id in np.asarray(plane_ids).tolist():
        own = labels == plane_id
        left, top, width, height = cv2.boundingRect(own.view(np.uint8))
        if width == 0:
            continue
        box = (slice(top, top + height), slice(left, left + width))
        mine = own[box]
        inliers = on_plane[box] & mine
        distance, depth, band_box = signed[box], depth_m[box], band[box]
        x, y = ray_x[box[1]][None, :], ray_y[box[0]][:, None]
        bend = None
        for _ in range(rounds):
            rows, cols, medians = cell_medians(inliers, distance, cell)
            z, b = depth[rows, cols], band_box[rows, cols]
            usable = np.isfinite(medians) & np.isfinite(z) & np.isfinite(b)
            found = fit_bend(x[0, cols][usable], y[rows, 0][usable], z[usable], medians[usable], b[usable])
            if found is None:
                break
            coefficients, kept = found
            low, high = medians[usable][kept].min(), medians[usable][kept].max()
            bend = np.clip(bend_at(coefficients, x, y, depth), np.float32(low), np.float32(high))
            with np.errstate(invalid="ignore"):
                inliers = mine & (np.abs(distance - bend) < band_box)
        if bend is not None:
            bends[box][mine] = bend[mine]
    return bends

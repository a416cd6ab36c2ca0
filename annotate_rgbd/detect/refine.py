"""Pixel-level refinement of cell segments, and the final planes fitted on their pixels."""

from __future__ import annotations

import cv2
import numpy as np

from .cells import CloudCells


def assign_pixels(cells: CloudCells, region: np.ndarray, planes: np.ndarray, band_k: float, behind: float = 1.0) -> np.ndarray:
    """Give each pixel near a segment to the segment whose plane it lies on.

    A segment may claim the valid pixels of its own cells and of the cells next to them
    (8-neighbours: boundary and non-planar cells); a pixel goes to the nearest plane, in 3-D
    distance, among those that claim it and hold it within ``band_k * sigma(z)`` in front of the
    plane and ``behind`` times that behind it (planes' normals face the camera).

    Parameters
    ----------
    cells : CloudCells
    region : ndarray of int, shape (C,)
        Segment of each cell, 0 for none, segments 1..K.
    planes : ndarray, shape (K, 4)
        Plane of each segment (unit normal).
    band_k : float
    behind : float
        The band behind a plane, as a multiple of the band in front (>= 1).

    Returns
    -------
    ndarray of uint8 (K < 256) or int32, shape (H, W)
        Segment of each pixel, 0 for none.
    """
    height, width = cells.depth.shape
    rows, cols = cells.grid
    cell_px = cells.cell_px
    # Pixel rows (columns) of each cell row (column): the last one also covers the margin.
    cell_rows = np.full(rows, cell_px)
    cell_rows[-1] += height - rows * cell_px
    cell_cols = np.full(cols, cell_px)
    cell_cols[-1] += width - cols * cell_px
    # A pixel is taken when it lies nearer than ``best``: first the band itself (just above it,
    # so that a pixel on the band's edge is in; NaN where the depth is invalid: never taken),
    # then the nearest plane's distance so far.
    front = _just_above(np.float32(band_k) * cells.sigma)
    best = front if behind == 1 else _just_above(np.float32(band_k * behind) * cells.sigma)
    labels = np.zeros((height, width), dtype=np.uint8 if planes.shape[0] < 256 else np.int32)
    grid = region.reshape(rows, cols)
    ring = np.ones((3, 3), dtype=np.uint8)
    for k, (cell_window, window) in enumerate(claim_windows(cells, region), start=1):
        if window is None:
            continue
        # The segment's cells and their 8-neighbours, inside the segment's window grown by one cell.
        (top, bottom), (left, right) = cell_window
        (r0, r1), (c0, c1) = window
        near = cv2.dilate((grid[top:bottom, left:right] == k).view(np.uint8), ring, borderType=cv2.BORDER_CONSTANT,
                          borderValue=0) > 0
        claim = np.repeat(np.repeat(near, cell_rows[top:bottom], axis=0), cell_cols[left:right], axis=1)
        a, b, c, d = planes[k - 1].astype(np.float32)
        # Point = z * (ray_x, ray_y, 1), so the signed distance is z * (n . ray) + d.
        facing = a * cells.ray_x[c0:c1] + (b * cells.ray_y[r0:r1, None] + c)
        dist = cells.depth[r0:r1, c0:c1] * facing
        dist += d
        if behind != 1:
            with np.errstate(invalid="ignore"):
                claim &= dist < front[r0:r1, c0:c1]
        np.abs(dist, out=dist)
        with np.errstate(invalid="ignore"):
            claim &= dist < best[r0:r1, c0:c1]
        np.copyto(labels[r0:r1, c0:c1], k, where=claim)
        np.copyto(best[r0:r1, c0:c1], dist, where=claim)
    return labels


def _just_above(values: np.ndarray) -> np.ndarray:
    """``np.nextafter(values, inf)`` of float32 values: the next float32 up, by the bit pattern
    (one more) where the values are positive and finite, several times faster."""
    values = np.asarray(values, dtype=np.float32)
    above = (values.view(np.int32) + np.int32(1)).view(np.float32)
    odd = ~(values > 0) | (values == np.inf)  # zero, negative, infinite, NaN: numpy's own
    if odd.any():
        above[odd] = np.nextafter(values[odd], np.float32(np.inf))
    return above


def claim_windows(cells: CloudCells, region: np.ndarray) -> list:
    """Where each segment may claim pixels (:func:`assign_pixels`): its cells' bounding box
    grown by one cell.

    Parameters
    ----------
    cells : CloudCells
    region : ndarray of int, shape (C,)
        Segment of each cell, 0 for none, segments 1..K.

    Returns
    -------
    list of (cells, pixels) or (None, None)
        Per segment: ``((top, bottom), (left, right))`` in cells and the same in pixels (stop
        exclusive); ``(None, None)`` for a segment without cells.
    """
    height, width = cells.depth.shape
    rows, cols = cells.grid
    cell_px = cells.cell_px
    windows = []
    for window in _boxes(region.reshape(rows, cols)):
        if window is None:
            windows.append((None, None))
            continue
        top, left = max(window[0].start - 1, 0), max(window[1].start - 1, 0)
        bottom, right = min(window[0].stop + 1, rows), min(window[1].stop + 1, cols)
        pixels = (top * cell_px, _stop(bottom, rows, cell_px, height)), (left * cell_px, _stop(right, cols, cell_px, width))
        windows.append((((top, bottom), (left, right)), pixels))
    return windows


def _boxes(labels: np.ndarray, n: int | None = None) -> list:
    """The bounding box of each label 1..n, as ``scipy.ndimage.find_objects`` gives them (for the
    small cell grid; :func:`annotate_rgbd.cvat.pieces.label_boxes` is faster on images).

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Labels >= 0 (0: none).
    n : int, optional
        Largest label (default: the image's largest).

    Returns
    -------
    list of (slice, slice) or None
        ``(rows, cols)`` of label ``k`` at position ``k - 1``; None for a label not present.
    """
    labels = np.asarray(labels)
    n = int(labels.max(initial=0)) if n is None else int(n)
    rows, cols = np.nonzero((labels > 0) & (labels <= n))
    found = labels[rows, cols].astype(np.intp)
    low = np.full((2, n + 1), np.iinfo(np.intp).max)
    high = np.full((2, n + 1), -1)
    for axis, at in enumerate((rows, cols)):
        np.minimum.at(low[axis], found, at)
        np.maximum.at(high[axis], found, at)
    return [None if high[0, k] < 0 else (slice(int(low[0, k]), int(high[0, k]) + 1), slice(int(low[1, k]), int(high[1, k]) + 1))
            for k in range(1, n + 1)]


def _stop(stop_cell: int, n_cells: int, cell_px: int, size: int) -> int:
    """End pixel (exclusive) of cells up to ``stop_cell``; the last cell also covers the margin."""
    return size if stop_cell == n_cells else stop_cell * cell_px


def pixel_moments(
    cells: CloudCells, labels: np.ndarray, n: int, windows: list | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Count, centroid and centred scatter matrix of the points of each label.

    Parameters
    ----------
    cells : CloudCells
        The point cloud.
    labels : ndarray of int, shape (H, W)
        0 for none, else 1..n; labelled pixels must have valid depth.
    n : int
    windows : list, optional
        Where each label's pixels lie, as :func:`claim_windows` gives them for the segments
        that :func:`assign_pixels` labelled (default: the labels' bounding boxes, found here).

    Returns
    -------
    count : ndarray of int64, shape (n,)
    mean : ndarray of float64, shape (n, 3)
    centred : ndarray of float64, shape (n, 3, 3)
        Zero where a label has no pixel.
    """
    count = np.zeros(n, dtype=np.int64)
    mean = np.zeros((n, 3))
    centred = np.zeros((n, 3, 3))
    if windows is None:
        boxes = _boxes(labels, n)
    else:
        boxes = [None if w is None else (slice(*w[0]), slice(*w[1])) for _, w in windows]
    for k, window in enumerate(boxes):
        if window is None:
            continue
        inside = labels[window] == k + 1
        count[k] = np.count_nonzero(inside)
        if count[k] == 0:
            continue
        z = np.where(inside, cells.depth[window], 0).astype(np.float64)
        # With x = z * ray_x[col] and y = z * ray_y[row], every moment is a sum of
        # z**p * ray_y**i * ray_x**j: two small matrix products give them all.
        ray_x, ray_y = cells.ray_x[window[1]].astype(np.float64), cells.ray_y[window[0]].astype(np.float64)
        across = np.stack([np.ones_like(ray_x), ray_x, ray_x**2], axis=1)
        down = np.stack([np.ones_like(ray_y), ray_y, ray_y**2], axis=1)
        first = down.T @ (z @ across)  # first[i, j] = sum z * ray_y**i * ray_x**j
        second = down.T @ ((z * z) @ across)
        mean[k] = np.array([first[0, 1], first[1, 0], first[0, 0]]) / count[k]
        raw = np.array(
            [
                [second[0, 2], second[1, 1], second[0, 1]],
                [second[1, 1], second[2, 0], second[1, 0]],
                [second[0, 1], second[1, 0], second[0, 0]],
            ]
        )
        centred[k] = raw - count[k] * np.outer(mean[k], mean[k])
    return count, mean, centred


def order_labels(labels: np.ndarray, count: np.ndarray, min_area: int) -> np.ndarray:
    """New number of each label: by area descending, ties by first pixel in raster order.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
    count : ndarray, shape (n,)
        Pixels of labels 1..n.
    min_area : int
        Labels with fewer pixels get 0.

    Returns
    -------
    ndarray of int64, shape (n + 1,)
        Lookup table from old to new label (entry 0 is 0).
    """
    n = count.size
    first = np.zeros(n, dtype=np.int64)
    keep = np.flatnonzero(count >= max(min_area, 1))
    _, multiplicity = np.unique(count[keep], return_counts=True)
    if np.any(multiplicity > 1):  # the first pixel only matters for ties: find it just for those
        tied = keep[np.isin(count[keep], np.unique(count[keep])[multiplicity > 1])]
        flat = labels.ravel()
        for k in tied:
            first[k] = int(np.argmax(flat == k + 1))
    order = keep[np.lexsort((first[keep], -count[keep]))]
    table = np.zeros(n + 1, dtype=np.int64)
    table[order + 1] = np.arange(1, order.size + 1)
    return table


def relabel(labels: np.ndarray, table: np.ndarray, dtype) -> np.ndarray:
    """``table[labels]`` as ``dtype``; by OpenCV's lookup table where both fit in 8 bits (several
    times faster than numpy's indexing).

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
    table : ndarray of int, shape (N,)
        ``N > labels.max()``.
    dtype : numpy dtype

    Returns
    -------
    ndarray of ``dtype``, shape (H, W)
    """
    table = np.asarray(table)
    if labels.dtype == np.uint8 and np.dtype(dtype) == np.uint8 and len(table) <= 256:
        lut = np.zeros(256, dtype=np.uint8)
        lut[: len(table)] = table
        return cv2.LUT(labels, lut)
    return table.astype(dtype)[labels]

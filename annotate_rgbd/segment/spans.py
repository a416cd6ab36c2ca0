"""The pixels of polygons as spans of rows: the scanline fill under every drawn and carried shape.

A pixel belongs to a polygon when its centre lies inside it (even-odd rule); in CVAT coordinates
the centre of pixel ``(col, row)`` is ``(col + 0.5, row + 0.5)``, and a centre exactly on an
outline belongs to the polygon on the outline's top and left sides only (half-open spans).
:func:`polygon_spans` finds the spans of many polygons at once; :func:`fill_spans` turns one
polygon's spans into a boolean window of the image.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np


@dataclass(frozen=True)
class PolygonSpans:
    """The inside spans of several polygons (:func:`polygon_spans`).

    Parameters
    ----------
    top, bottom : ndarray of int64, shape (P,)
        First and last image row of each polygon's window (``bottom < top``: the polygon lies
        outside the image).
    start : ndarray of int64, shape (P + 1,)
        Polygon ``p``'s spans are ``start[p]`` to ``start[p + 1]`` of the arrays below.
    row : ndarray of int64, shape (S,)
        Image row of each span.
    first, stop : ndarray of int32, shape (S,)
        Columns ``first`` to ``stop - 1`` are inside (``first < stop``); the spans of one
        polygon's row are disjoint and in ascending order.
    """

    top: np.ndarray
    bottom: np.ndarray
    start: np.ndarray
    row: np.ndarray
    first: np.ndarray
    stop: np.ndarray


def polygon_spans(polygons: Sequence[np.ndarray], height: int, width: int) -> PolygonSpans:
    """The pixels of several polygons as spans of rows: the pixels whose centres are inside.

    Scanline fill, vectorised over the edges of all the polygons at once: each edge crosses the
    pixel-centre lines of the rows it spans (half-open in y), at one x each; sorted by polygon,
    row and x, pairs of crossings bound the inside spans. The work grows with the crossings
    (about twice the rows for a convex outline), not with rows times vertices, and a few dozen
    array operations serve all the polygons (the layers carried to a frame are a hundred).

    Parameters
    ----------
    polygons : sequence of ndarray, shape (N, 2)
        Vertices (x, y) in CVAT coordinates (pixel ``(col, row)`` has its centre at
        ``(col + 0.5, row + 0.5)``).
    height, width : int
        Image size.

    Returns
    -------
    PolygonSpans
    """
    count = len(polygons)
    sizes = np.array([len(p) for p in polygons], dtype=np.int64)
    vertices = (np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in polygons])
                if count else np.zeros((0, 2)))
    first_vertex = np.cumsum(sizes) - sizes
    top = np.zeros(count, dtype=np.int64)
    bottom = np.full(count, -1, dtype=np.int64)
    used = sizes > 0
    x0, y0 = vertices[:, 0], vertices[:, 1]
    if used.any():
        low = np.minimum.reduceat(y0, first_vertex[used])
        high = np.maximum.reduceat(y0, first_vertex[used])
        top[used] = np.maximum(np.floor(low - 0.5), 0)
        bottom[used] = np.minimum(np.ceil(high - 0.5), height - 1)
    # Each edge's end: the next vertex, the first one after the last.
    following = np.arange(1, len(vertices) + 1)
    following[first_vertex[used] + sizes[used] - 1] = first_vertex[used]
    x1, y1 = x0[following], y0[following]
    polygon = np.repeat(np.arange(count), sizes)
    edge_top, edge_bottom = top[polygon], bottom[polygon]
    # An edge counts for the rows whose centre r + 0.5 lies in [min(y0, y1), max(y0, y1)): r from
    # ceil(min - 0.5) to ceil(max - 0.5) - 1 (none for a horizontal edge), within its window.
    first_row = np.clip(np.ceil(np.minimum(y0, y1) - 0.5), edge_top, edge_bottom + 1).astype(np.int64)
    stop_row = np.clip(np.ceil(np.maximum(y0, y1) - 0.5), edge_top, edge_bottom + 1).astype(np.int64)
    spanned = np.where(edge_bottom >= edge_top, stop_row - first_row, 0)
    edges = np.flatnonzero(spanned > 0)
    counts = spanned[edges]
    edge = np.repeat(edges, counts)
    offsets = np.cumsum(counts) - counts
    rows = first_row[edge] + (np.arange(edge.size) - np.repeat(offsets, counts))
    centre_y = rows + 0.5
    xs = x0[edge] + (centre_y - y0[edge]) * (x1[edge] - x0[edge]) / (y1[edge] - y0[edge])
    owner = polygon[edge]
    key, xs, row_start = _sorted_crossings(owner * (height + 1) + rows, xs)
    owner, rows = np.divmod(key, height + 1)
    # Pairs within a polygon's row: crossings 0-1, 2-3, ... (a row's last crossing without a
    # partner, on a degenerate outline, bounds nothing).
    start = np.flatnonzero(((np.arange(key.size) - row_start) % 2 == 0)[:-1] & (key[1:] == key[:-1]))
    # Pixels with centre c + 0.5 in [start, end): c from ceil(start - 0.5) to ceil(end - 0.5) - 1.
    first = np.ceil(xs[start] - 0.5).clip(0, width).astype(np.int32)
    stop = np.ceil(xs[start + 1] - 0.5).clip(0, width).astype(np.int32)
    filled = stop > first
    owner = owner[start][filled]
    return PolygonSpans(top, bottom, np.searchsorted(owner, np.arange(count + 1)), rows[start][filled],
                        first[filled], stop[filled])


def _sorted_crossings(key: np.ndarray, xs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Crossings sorted by polygon and row (``key``), then x: what a sort on the two keys gives,
    faster.

    Within one key only the x values need ordering: one stable sort on the key (edges give runs
    of ascending or descending rows, which it merges), then the x values of the keys with the
    same number of crossings sorted together, as the rows of one array.

    Parameters
    ----------
    key : ndarray of int64, shape (C,)
        Each crossing's polygon and row (``polygon * (height + 1) + row``).
    xs : ndarray of float64, shape (C,)
        Its x.

    Returns
    -------
    key, xs : ndarray, shape (C,)
        Sorted.
    row_start : ndarray of int64, shape (C,)
        For each crossing, where its key's crossings begin.
    """
    if not np.isfinite(xs).all():  # NaN sorts last: leave it to the general sort
        order = np.lexsort((xs, key))
        key, xs = key[order], xs[order]
        return key, xs, np.searchsorted(key, key, side="left")
    order = np.argsort(key, kind="stable")
    key, xs = key[order], xs[order]
    starts = np.ones(key.size, dtype=bool)
    np.not_equal(key[1:], key[:-1], out=starts[1:])
    group = np.flatnonzero(starts)
    size = np.diff(group, append=key.size)
    for count in (np.flatnonzero(np.bincount(size)[2:]) + 2).tolist():  # a few: 2 on most rows, 4, 6, ...
        members = group[size == count][:, None] + np.arange(count)
        xs[members] = np.sort(xs[members], axis=1)
    return key, xs, np.repeat(group, size)


def fill_spans(spans: PolygonSpans, index: int) -> tuple[int, int, np.ndarray]:
    """One polygon of :func:`polygon_spans` as a boolean window of the image.

    Returns
    -------
    top, left : int
        Position of the window in the image: its rows are the polygon's rows, its columns those
        its spans reach.
    inside : ndarray of bool, shape (rows, cols)
        Empty (0, 0) when no pixel centre lies inside.
    """
    a, b = int(spans.start[index]), int(spans.start[index + 1])
    if b == a:
        return 0, 0, np.zeros((0, 0), dtype=bool)
    top = int(spans.top[index])
    span_rows, first, stop = spans.row[a:b] - top, spans.first[a:b], spans.stop[a:b]
    left, right = int(first.min()), int(stop.max())
    # +1 where a span starts, -1 where it stops (a row's spans are disjoint: no two starts nor two
    # stops share a pixel), summed along each row: inside where the sum is positive. The row sums
    # are differences of OpenCV's integral image (exact: small integers in float32).
    steps = np.zeros((int(spans.bottom[index]) - top + 1, right - left + 1), dtype=np.float32)
    steps[span_rows, first - left] += 1
    steps[span_rows, stop - left] -= 1
    total = cv2.integral(steps, sdepth=cv2.CV_32F)
    inside = (total[1:, 1:-1] - total[:-1, 1:-1]) > 0.5
    return top, left, inside

"""CVAT's track interpolation between two keyframes, as pure numpy functions.

Exports fetched through the CVAT API hold keyframes only; the frames in between must be filled
the way CVAT fills them when it exports a file (``TrackManager.get_interpolated_shapes`` in
``cvat/apps/dataset_manager/annotation.py``):

- boxes: the corners move linearly with ``t = (f - f0) / (f1 - f0)``; a box rotation turns along
  the shorter arc;
- polygons: both outlines are closed (first vertex repeated) and parametrised by normalised arc
  length; every vertex is matched to the vertex at the nearest arc-length position on the other
  outline (left to right, then the right vertices nobody chose, right to left); matched pairs move
  linearly; then runs of interpolated vertices closer than ``base_length / (2 N)`` are thinned.
  The vertex count can therefore change between frames.

CVAT's interpolation has no rule for masks (CVAT draws masks as shapes, not tracks): the reader
repeats the previous keyframe's mask, as CVAT does after a track's last keyframe.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def interpolate_box(b0: np.ndarray, b1: np.ndarray, t: float) -> np.ndarray:
    """Interpolate an axis-aligned box linearly, as CVAT does.

    Parameters
    ----------
    b0, b1 : ndarray, shape (2, 2)
        ``[[xtl, ytl], [xbr, ybr]]`` on the keyframes before and after.
    t : float
        Position between the keyframes, ``(f - f0) / (f1 - f0)`` in [0, 1].

    Returns
    -------
    ndarray of float64, shape (2, 2)
        The box at ``t``.
    """
    b0 = np.asarray(b0, dtype=np.float64)
    b1 = np.asarray(b1, dtype=np.float64)
    return b0 + (b1 - b0) * t


def interpolate_angle(a0: float, a1: float, t: float) -> float:
    """Interpolate a box rotation in degrees along the shorter arc, as CVAT does.

    Parameters
    ----------
    a0, a1 : float
        Rotations (degrees, clockwise in image coordinates) on the keyframes.
    t : float
        Position between the keyframes in [0, 1].

    Returns
    -------
    float
        The rotation at ``t``, in [0, 360).
    """
    difference = ((a1 - a0 + 180.0) % 360.0) - 180.0
    return (a0 + difference * t + 360.0) % 360.0


def interpolate_polygon(p0: np.ndarray, p1: np.ndarray, t: float) -> np.ndarray:
    """Interpolate a polygon between two keyframe outlines with CVAT's algorithm.

    Parameters
    ----------
    p0, p1 : ndarray, shape (N, 2) and (M, 2)
        The outlines on the keyframes before and after (vertices not repeated at the end).
        N and M may differ.
    t : float
        Position between the keyframes in [0, 1].

    Returns
    -------
    ndarray of float64, shape (K, 2)
        The outline at ``t``; K may differ from N and M (CVAT thins close vertices).
    """
    return interpolate_polygon_series(p0, p1, [t])[0]


def interpolate_polygon_series(
    p0: np.ndarray, p1: np.ndarray, ts: Sequence[float]
) -> list[np.ndarray]:
    """Interpolate a polygon at several positions, matching the outlines only once.

    Parameters
    ----------
    p0, p1 : ndarray, shape (N, 2) and (M, 2)
        The outlines on the keyframes before and after (vertices not repeated at the end).
    ts : sequence of float
        Positions between the keyframes in [0, 1].

    Returns
    -------
    list of ndarray of float64, shape (K, 2)
        One outline per position in ``ts``.
    """
    left = _close(p0)
    right = _close(p1)
    matching = match_outlines(left, right)
    # One interpolated vertex per matched (left, right) pair, in left order.
    pair_left = np.repeat(np.arange(len(left)), [len(m) for m in matching])
    pair_right = np.concatenate(matching)
    start = left[pair_left]
    motion = right[pair_right] - start
    blocks = _merge_single_vertices(_thinning_segments(left, right, matching))
    ts = np.asarray(ts, dtype=np.float64).reshape(-1)
    keep, collapse, run_first, run_last = _thin_all(start, motion, ts, blocks)
    outlines = []
    for index, t in enumerate(ts):
        points = start + motion * t
        # A run whose ends came closer than its threshold becomes their midpoint.
        first, last = run_first[collapse[index]], run_last[collapse[index]]
        points[first] = (points[first] + points[last]) / 2
        outlines.append(points[keep[index]][:-1])  # drop the closing vertex again
    return outlines


def match_outlines(left: np.ndarray, right: np.ndarray) -> list[list[int]]:
    """Match the vertices of two open curves by normalised arc length, as CVAT does.

    Every left vertex gets the right vertex nearest in arc-length position (first one on a
    tie); each right vertex nobody chose is then added to its nearest left vertex.

    Parameters
    ----------
    left, right : ndarray, shape (N, 2) and (M, 2)
        The curves (for a polygon: closed, first vertex repeated at the end).

    Returns
    -------
    list of list of int
        For each left vertex, the sorted indices of the right vertices matched to it (at least
        one each).
    """
    left_offsets = _arc_length_offsets(left)
    right_offsets = _arc_length_offsets(right)
    nearest_right = _nearest(right_offsets, left_offsets)
    chosen = np.zeros(len(right), dtype=bool)
    chosen[nearest_right] = True
    unchosen = np.flatnonzero(~chosen)
    # (left, right) pairs sorted by left vertex, then right vertex.
    pair_left = np.concatenate([np.arange(len(left)), _nearest(left_offsets, right_offsets[unchosen])])
    pair_right = np.concatenate([nearest_right, unchosen])
    order = np.lexsort((pair_right, pair_left))
    bounds = np.searchsorted(pair_left[order], np.arange(len(left) + 1)).tolist()
    matched = pair_right[order].tolist()
    return [matched[first:last] for first, last in zip(bounds, bounds[1:])]


def _nearest(sorted_offsets: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """For each of ``offsets``, the index of the nearest of ``sorted_offsets`` (ascending).

    Of equally near ones the first is taken, as ``argmin`` over all distances would; a sorted
    search finds it among the two neighbours of the position, in n log m.
    """
    above = np.minimum(np.searchsorted(sorted_offsets, offsets, side="left"), len(sorted_offsets) - 1)
    below = np.maximum(above - 1, 0)
    # The first of a run of equal offsets below (zero-length edges repeat an offset).
    below = np.searchsorted(sorted_offsets, sorted_offsets[below], side="left")
    take_below = np.abs(offsets - sorted_offsets[below]) <= np.abs(offsets - sorted_offsets[above])
    return np.where(take_below & (below < above), below, above)


def _close(polygon: np.ndarray) -> np.ndarray:
    polygon = np.asarray(polygon, dtype=np.float64).reshape(-1, 2)
    return np.vstack([polygon, polygon[:1]])


def _curve_length(points: np.ndarray) -> float:
    return float(np.sum(np.hypot(*np.diff(points, axis=0).T)))


def _arc_length_offsets(points: np.ndarray) -> np.ndarray:
    cumulative = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    return cumulative / cumulative[-1]


def _thinning_segments(
    left: np.ndarray, right: np.ndarray, matching: list[list[int]]
) -> list[tuple[int, int, float | None]]:
    """Split the interpolated vertices into the runs CVAT thins independently.

    A run is either consecutive left vertices that all matched the same single right vertex
    (its base length is measured on the left curve) or the several right vertices matched to
    one left vertex (base length on the right curve).

    Returns
    -------
    list of (first, last, threshold)
        Indices into the interpolated vertices (inclusive) and the distance under which
        vertices are dropped, ``base_length / (2 N)``; ``threshold`` is ``None`` for a single
        vertex kept as it is.
    """
    first_pair = np.concatenate([[0], np.cumsum([len(m) for m in matching])])
    segments: list[tuple[int, int, float | None]] = []

    def left_run(start: int, stop: int) -> None:
        first, last = first_pair[start], first_pair[stop]
        if first == last:
            segments.append((first, last, None))
        else:
            base = _curve_length(left[start : stop + 1])
            segments.append((first, last, base / (2 * (stop - start + 1))))

    opened = None  # start of the current run of left vertices sharing one right vertex
    for i, matched in enumerate(matching):
        if len(matched) == 1:
            if opened is None:
                opened = i
            elif matched[0] != matching[opened][0]:
                left_run(opened, i - 1)
                opened = i
        else:
            if opened is not None:
                left_run(opened, i - 1)
                opened = None
            start, stop = matched[0], matched[-1]
            base = _curve_length(right[start : stop + 1])
            first = first_pair[i]
            segments.append((first, first + len(matched) - 1, base / (2 * (stop - start + 1))))
    if opened is not None:
        left_run(opened, len(matching) - 1)
    return segments


def _merge_single_vertices(
    segments: list[tuple[int, int, float | None]],
) -> list[tuple[int, int, float | None]]:
    """Join neighbouring single-vertex segments into one block kept as it is (``None``)."""
    blocks: list[tuple[int, int, float | None]] = []
    for first, last, threshold in segments:
        if threshold is None and blocks and blocks[-1][2] is None:
            blocks[-1] = (blocks[-1][0], last, None)
        else:
            blocks.append((first, last, threshold))
    return blocks


def _thin_all(
    start: np.ndarray, motion: np.ndarray, ts: np.ndarray, blocks: list[tuple[int, int, float | None]]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Thin the interpolated vertices of every block as CVAT does, at all positions at once.

    A block with threshold ``None`` is kept as it is. Otherwise the run's ends are kept, each
    inner vertex only if it is at least ``threshold`` from the last one kept, and a run whose
    ends are closer than ``threshold`` with nothing kept between collapses into their midpoint.
    The test runs vertex by vertex (it depends on the last vertex kept) but for every position
    in ``ts`` at once, so its Python steps grow with the vertices, not vertices x frames.

    Returns
    -------
    keep : ndarray of bool, shape (T, P)
        Which interpolated vertices are kept at each position.
    collapse : ndarray of bool, shape (T, R)
        Which of the R thinned runs collapse into their midpoint at each position (the
        midpoint takes the place of the run's first vertex; its last one is not kept).
    run_first, run_last : ndarray of int, shape (R,)
        The first and last vertex of each thinned run.
    """
    keep = np.ones((len(ts), len(start)), dtype=bool)
    at = ts[:, None]
    runs = [(first, last, threshold) for first, last, threshold in blocks if threshold is not None]
    collapse = np.zeros((len(ts), len(runs)), dtype=bool)
    for run, (first, last, threshold) in enumerate(runs):
        kept = np.full(len(ts), first)
        for i in range(first + 1, last):
            far = np.hypot(*((start[i] + motion[i] * at) - (start[kept] + motion[kept] * at)).T) >= threshold
            keep[:, i] = far
            kept[far] = i
        ends = (start[last] + motion[last] * at) - (start[first] + motion[first] * at)
        collapse[:, run] = (kept == first) & (np.hypot(*ends.T) < threshold)
        keep[collapse[:, run], last] = False
    run_first = np.array([first for first, _, _ in runs], dtype=np.int64)
    run_last = np.array([last for _, last, _ in runs], dtype=np.int64)
    return keep, collapse, run_first, run_last

"""Whether a shape's geometry is usable: coordinates, area, self-crossings, mask and box sizes.

Pure functions over numpy arrays; each returns the reason a shape is skipped, or None.
"""

from __future__ import annotations

import numpy as np

from .format import MAX_COORDINATE, MAX_MASK_PIXELS, MAX_POLYGON_VERTICES

#: Edge pairs :func:`crosses_itself` tests at most (a few seconds); an ordinary outline needs a
#: few per vertex, so only edges crowded into a tiny area (thousands on one spot) reach it.
MAX_CANDIDATE_PAIRS = 50_000_000

#: Edge pairs tested at once (bounds the memory of the test to some 200 MB).
_PAIR_CHUNK = 1 << 21


def polygon_problem(points: np.ndarray) -> str | None:
    if len(points) < 3:
        return "polygon with fewer than 3 points"
    if len(points) > MAX_POLYGON_VERTICES:
        return f"polygon with more than {MAX_POLYGON_VERTICES} vertices"
    problem = _coordinate_problem(points)
    if problem is not None:
        return problem
    # Zero area: every triangle of the fan from the first vertex is flat, so the polygon covers
    # nothing. (Its signed area is no test: the lobes of a figure of eight cancel out.)
    d = points[1:] - points[0]
    if np.abs(d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]).sum() < 1e-9:
        return "polygon with zero area"
    return None


def crosses_itself(points: np.ndarray) -> bool:
    """Whether two edges of the closed polygon properly cross (not merely touch).

    Edges i and j cross when the ends of each lie strictly on opposite sides of the other;
    neighbouring edges share a vertex, which lies on neither side, so they never count.

    Only edges that come close are tested: each edge is cut into pieces no longer than a
    typical edge, each piece goes into the cell of a square grid that holds its midpoint, and
    the edges of pieces in one cell or in neighbouring cells are tested (two pieces that meet
    have midpoints less than a cell apart). For an ordinary outline that is a few pairs per
    vertex: the work grows as n log n, in bounded memory. A polygon whose edges crowd so
    densely that more than :data:`MAX_CANDIDATE_PAIRS` pairs would need a test is reported as
    not crossing (the answer only feeds a note; the shape is filled as drawn either way).
    """
    start = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(start) < 4 or not np.isfinite(start).all():
        return False
    end = np.roll(start, -1, axis=0)
    along = end - start
    length = np.hypot(along[:, 0], along[:, 1])
    edges = np.flatnonzero(length > 0)  # a zero-length edge lies on no side of anything
    if len(edges) < 4:
        return False  # three edges form a triangle: no two can cross
    # Pieces no longer than the median edge (nor shorter than a third of the mean, so that
    # there are at most three pieces per edge).
    piece = max(float(np.median(length[edges])), float(length[edges].sum()) / (2 * len(edges)))
    midpoints, edge_of_piece = _edge_pieces(start, along, length, edges, piece)
    order, starts, counts, first, second = _neighbour_cells(midpoints, piece * 1.125)
    weights = counts[first] * counts[second]
    ends = np.cumsum(weights)
    total = int(ends[-1])
    if total > MAX_CANDIDATE_PAIRS:
        return False
    edge_by_cell = edge_of_piece[order]
    # The candidate pairs, numbered cell pair by cell pair, are made and tested in chunks.
    for low in range(0, total, _PAIR_CHUNK):
        index = np.arange(low, min(low + _PAIR_CHUNK, total), dtype=np.int64)
        pair = np.searchsorted(ends, index, side="right")
        offset = index - (ends[pair] - weights[pair])
        size = counts[second[pair]]
        a = starts[first[pair]] + offset // size
        b = starts[second[pair]] + offset % size
        keep = a < b  # each pair once (a neighbouring cell comes later in the order)
        i, j = edge_by_cell[a[keep]], edge_by_cell[b[keep]]
        if (_straddles(start, end, along, i, j) & _straddles(start, end, along, j, i)).any():
            return True
    return False


def _edge_pieces(
    start: np.ndarray, along: np.ndarray, length: np.ndarray, edges: np.ndarray, piece: float
) -> tuple[np.ndarray, np.ndarray]:
    """Midpoints of ``edges`` cut into equal pieces no longer than ``piece``, and their edge."""
    count = np.ceil(length[edges] / piece).astype(np.int64)
    edge_of_piece = np.repeat(edges, count)
    position = np.arange(len(edge_of_piece)) - np.repeat(np.cumsum(count) - count, count)
    fraction = (position + 0.5) / np.repeat(count, count)
    return start[edge_of_piece] + along[edge_of_piece] * fraction[:, None], edge_of_piece


def _neighbour_cells(midpoints: np.ndarray, size: float):
    """Sort points into square cells of side ``size``; pair up the cells that touch.

    Returns
    -------
    order : ndarray of int
        The points sorted by cell.
    starts, counts : ndarray of int
        Each occupied cell's first position in ``order`` and its number of points.
    first, second : ndarray of int
        Pairs of occupied cells (indices into ``starts``) that are one cell or neighbours,
        each unordered pair once.
    """
    low = midpoints.min(axis=0)
    extent = float((midpoints.max(axis=0) - low).max())
    size = max(size, extent / (1 << 30))  # at most 2**30 cells a side: keys fit in int64
    cell = np.floor((midpoints - low) / size).astype(np.int64) + 1
    rows = int(cell[:, 1].max()) + 2
    key = cell[:, 0] * rows + cell[:, 1]
    order = np.argsort(key, kind="stable")
    occupied, starts, counts = np.unique(key[order], return_index=True, return_counts=True)
    first, second = [], []
    for dx, dy in ((0, 0), (1, -1), (1, 0), (1, 1), (0, 1)):
        wanted = occupied + dx * rows + dy
        at = np.minimum(np.searchsorted(occupied, wanted), len(occupied) - 1)
        found = np.flatnonzero(occupied[at] == wanted)
        first.append(found)
        second.append(at[found])
    return order, starts, counts, np.concatenate(first), np.concatenate(second)


def _straddles(
    start: np.ndarray, end: np.ndarray, along: np.ndarray, i: np.ndarray, j: np.ndarray
) -> np.ndarray:
    """The ends of edges ``j`` lie strictly on opposite sides of the lines of edges ``i``."""
    def side(points: np.ndarray) -> np.ndarray:
        dx = points[:, 0] - start[i, 0]
        dy = points[:, 1] - start[i, 1]
        return along[i, 0] * dy - along[i, 1] * dx

    return side(start[j]) * side(end[j]) < 0


def _coordinate_problem(points: np.ndarray) -> str | None:
    largest = np.abs(points).max()
    if not np.isfinite(largest):
        return "non-finite coordinates"
    if largest > MAX_COORDINATE:
        return f"coordinates beyond {MAX_COORDINATE:.0f} pixels"
    return None


def mask_problem(
    runs: np.ndarray, width: int, height: int, image_size: tuple[int, int] | None
) -> str | None:
    if width < 1 or height < 1 or np.any(runs < 0) or runs.sum() != width * height:
        return "mask RLE runs do not add up to width x height"
    if image_size is not None and (width > image_size[0] or height > image_size[1]):
        return "mask larger than the image"
    if image_size is None and width * height > MAX_MASK_PIXELS:
        return f"mask larger than {MAX_MASK_PIXELS} pixels"
    return None


def box_problem(corners: np.ndarray, rotation: float) -> str | None:
    problem = _coordinate_problem(corners)
    if problem is not None:
        return problem
    if not np.isfinite(rotation):
        return "non-finite coordinates"
    (xtl, ytl), (xbr, ybr) = corners
    if xbr <= xtl or ybr <= ytl:
        return "box with xbr <= xtl or ybr <= ytl"
    return None

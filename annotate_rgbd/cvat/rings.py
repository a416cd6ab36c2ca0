"""Simple polygons from traced outlines: simplification that keeps a ring simple, under a
vertex budget, and the test for edges that meet.

A labeller corrects a proposed polygon by dragging its vertices: it should have few of them,
and no two of its edges should cross or touch (a crossing polygon fills by the even-odd rule,
which leaves holes where its lobes overlap, and CVAT and most tools call it invalid).

:func:`simplify_ring` is Douglas-Peucker (Douglas & Peucker 1973) at the tolerance; where the
polygon has more vertices than the budget, its vertices are taken best-first (the chain of it
that lies farthest from the edge replacing it is split first) until the budget. Simplification
may make edges of a simple outline cross (two sides of a narrow neck each cut their corner);
every edge that meets another is then split again at its chain's farthest vertex of the traced
outline, which walks the polygon back towards that outline (simple) until no two edges meet.
:func:`meeting_edges` finds those pairs: candidate pairs whose boxes overlap along x (a sort
and sweep), then an exact orientation test (exact on the quarter-pixel coordinates traced
outlines have).
"""

from __future__ import annotations

import heapq
import math

import cv2
import numpy as np

#: Candidate edge pairs tested at once by :func:`meeting_edges` (bounds its memory).
_PAIR_CHUNK = 1 << 20
#: When the splits that keep a polygon simple took it past its vertex budget, :func:`simplify_ring`
#: simplifies again within this share of the budget (and so on, down to a triangle).
_BUDGET_STEP = 0.8
#: How close, in the ring's units (pixels), the bisection of a budget's tolerance comes to the
#: smallest (a tenth of a pixel: the tolerances of the steps around it keep nearly the same vertices).
_TOLERANCE_STEP = 0.1


def sorted_unique(*arrays) -> np.ndarray:
    """The sorted distinct values of integer arrays: ``np.unique`` of one, ``np.union1d`` of
    several, by sorting (numpy's own hash first, several times slower on the few hundred or
    thousand values of a ring).

    Parameters
    ----------
    *arrays : array_like of int
        Any shapes (flattened).

    Returns
    -------
    ndarray of int, shape (N,)
        Ascending, each value once; the dtype of the arrays joined.
    """
    values = np.sort(np.concatenate([np.asarray(a).ravel() for a in arrays]))
    if len(values) < 2:
        return values
    keep = np.empty(len(values), dtype=bool)
    keep[0] = True
    np.not_equal(values[1:], values[:-1], out=keep[1:])
    return values[keep]


def simplify_ring(ring: np.ndarray, tolerance: float, max_vertices: int = 0) -> np.ndarray:
    """The vertices of a closed outline to keep so that the polygon through them stays within
    ``tolerance`` of the outline, has at most ``max_vertices`` vertices and is simple.

    Parameters
    ----------
    ring : ndarray of float, shape (N, 2)
        A simple closed outline (not repeating its first vertex), e.g. a traced contour.
    tolerance : float
        Largest distance of the outline from the polygon's edges, in the ring's units; the
        budget may stop the simplification before the tolerance is reached.
    max_vertices : int
        Vertex budget, >= 3; 0: none. The polygon keeps more vertices only when fewer cannot
        keep it simple (rare: a narrow neck on a small budget).

    Returns
    -------
    ndarray of intp, shape (V,)
        Ascending indices into ``ring``, V >= 3 (all of them when N <= 3).
    """
    return ring_simplifications(ring, tolerance, [max_vertices])[0]


def ring_simplifications(ring: np.ndarray, tolerance: float, budgets, anchors=()) -> list[np.ndarray]:
    """:func:`simplify_ring` for several vertex budgets at once.

    The polygon at the tolerance is Douglas-Peucker's (``cv2.approxPolyDP`` on the ring, whose
    vertices lie on a quarter-pixel grid); under a budget below its vertex count, the tolerance
    is raised (bisection) to the smallest that keeps within the budget.

    Parameters
    ----------
    ring : ndarray of float, shape (N, 2)
    tolerance : float
    budgets : sequence of int
        Vertex budgets, each 0 (none) or >= 3.
    anchors : sequence of int
        Indices of vertices every polygon keeps; the chains between them are simplified one by
        one (a polygon keeps more vertices than its budget when the anchors alone exceed it).

    Returns
    -------
    list of ndarray of intp
        The kept indices for each budget.
    """
    ring = np.asarray(ring, dtype=np.float64)
    if any(b and b < 3 for b in budgets):
        raise ValueError(f"vertex budgets must be 0 or at least 3, got {list(budgets)}")
    if len(ring) <= 3:
        return [np.arange(len(ring)) for _ in budgets]
    simplify = _Simplifier(ring, sorted_unique(np.asarray(anchors, dtype=np.intp)))
    free = simplify(tolerance)
    results: list[np.ndarray] = []
    simple_free = _repair(ring, free)
    for max_vertices in budgets:
        keep, budget = simple_free, max_vertices
        while max_vertices and len(keep) > max_vertices and budget >= 3:
            keep = _repair(ring, simplify.within(tolerance, budget))
            budget = int(budget * _BUDGET_STEP)  # fewer next time, when the repair took it past the budget
        results.append(keep)
    return results


class _Simplifier:
    """Douglas-Peucker on one ring at any tolerance: ``cv2.approxPolyDP`` on the ring scaled to
    integers where its coordinates lie on a quarter grid and its vertices are distinct, else
    :func:`_best_first`."""

    def __init__(self, ring: np.ndarray, anchors: np.ndarray):
        self.ring = ring
        self.anchors = anchors
        scaled = ring * 4.0
        self.points = None
        if np.array_equal(scaled, np.round(scaled)) and np.abs(scaled).max() < 2**30:
            points = scaled.astype(np.int64)
            keys = (points[:, 0] << 32) + points[:, 1]
            order = np.argsort(keys, kind="stable")
            sorted_keys = keys[order]
            if not (sorted_keys[1:] == sorted_keys[:-1]).any():  # distinct vertices
                self.points = points.astype(np.int32).reshape(-1, 1, 2)
                self.order, self.sorted_keys, self.keys = order, sorted_keys, keys
                self.chains = self._chains() if len(anchors) >= 2 else []

    def _chains(self) -> list[np.ndarray]:
        """The chains from anchor to anchor (the last one round the end), each with its end
        vertex, that have vertices between their ends: a chain without any keeps its two
        ends, both anchors, at every tolerance."""
        rolled = np.roll(self.points, -int(self.anchors[0]), axis=0)
        bounds = np.append(self.anchors - self.anchors[0], len(rolled)).tolist()
        return [np.concatenate([rolled[a:b], rolled[b % len(rolled)][None]])
                for a, b in zip(bounds[:-1], bounds[1:]) if b - a >= 2]

    def __call__(self, tolerance: float) -> np.ndarray:
        """Ascending indices of the vertices kept at ``tolerance`` (at least 3), the anchors among them."""
        if self.points is not None:
            if len(self.anchors) < 2:
                found = cv2.approxPolyDP(self.points, 4.0 * tolerance, closed=True).reshape(-1, 2)
            elif self.chains:  # each chain from anchor to anchor on its own
                found = np.concatenate([cv2.approxPolyDP(chain, 4.0 * tolerance, closed=False).reshape(-1, 2)
                                        for chain in self.chains])
            else:
                found = np.zeros((0, 2), dtype=np.int32)
            keys = (found[:, 0].astype(np.int64) << 32) + found[:, 1]
            kept = sorted_unique(self.order[np.searchsorted(self.sorted_keys, keys)], self.anchors)
            if len(kept) >= 3:
                return kept
        return sorted_unique(np.asarray(_best_first(self.ring, tolerance, 0), dtype=np.intp), self.anchors).astype(np.intp)

    def count(self, tolerance: float) -> int:
        """``len(self(tolerance))``, without finding which vertices those are."""
        if self.points is not None:
            if len(self.anchors) < 2:
                found = cv2.approxPolyDP(self.points, 4.0 * tolerance, closed=True).reshape(-1, 2)
                keys = (found[:, 0].astype(np.int64) << 32) + found[:, 1]
                size = len(sorted_unique(keys, self.keys[self.anchors]))
            else:  # each chain keeps its two ends (anchors) and vertices between them, all distinct
                size = len(self.anchors) + sum(len(cv2.approxPolyDP(chain, 4.0 * tolerance, closed=False)) - 2
                                               for chain in self.chains)
            if size >= 3:
                return size
        return len(self(tolerance))

    def within(self, tolerance: float, budget: int) -> np.ndarray:
        """The vertices kept at the smallest tolerance (at least ``tolerance``, found by bisection
        to :data:`_TOLERANCE_STEP`) that leaves at most ``budget`` of them."""
        if self.points is None:
            return sorted_unique(np.asarray(_best_first(self.ring, tolerance, budget), dtype=np.intp), self.anchors).astype(np.intp)
        extent = float(np.ptp(self.ring, axis=0).max())
        low, high = tolerance, max(tolerance, 0.25)
        size = self.count(high)
        while size > budget and high <= extent:  # past the extent: the anchors and a triangle
            low, high = high, 2.0 * high
            size = self.count(high)
        if size > budget:
            return self(high)
        step = _TOLERANCE_STEP
        while high - low > step:
            middle = 0.5 * (low + high)
            if self.count(middle) <= budget:
                high = middle
            else:
                low = middle
        return self(high)


def meeting_edges(points: np.ndarray) -> np.ndarray:
    """Pairs of edges of a closed polygon that meet where they should not: non-neighbouring
    edges with a point in common (crossing, touching or overlapping), and neighbouring edges
    that overlap (a spike that turns back on itself, or a repeated vertex).

    Parameters
    ----------
    points : ndarray of float, shape (V, 2)
        The polygon, not repeating its first vertex; edge ``i`` runs from vertex ``i`` to
        vertex ``i + 1`` (the last back to the first).

    Returns
    -------
    ndarray of intp, shape (P, 2)
        ``(i, j)`` with ``i < j``, each pair once; empty for a simple polygon.
    """
    start = np.asarray(points, dtype=np.float64)
    m = len(start)
    if m < 3:
        return np.zeros((0, 2), dtype=np.intp)
    end = np.concatenate([start[1:], start[:1]])  # each edge's end: the next vertex
    found = [_folded_neighbours(start, end)]
    low_x, high_x = np.minimum(start[:, 0], end[:, 0]), np.maximum(start[:, 0], end[:, 0])
    low_y, high_y = np.minimum(start[:, 1], end[:, 1]), np.maximum(start[:, 1], end[:, 1])
    order = np.argsort(low_x, kind="stable")
    sorted_low = low_x[order]
    # Edge order[p] meets only edges order[q], q > p, that start (along x) before it ends.
    stop = np.searchsorted(sorted_low, high_x[order], side="right")
    counts = np.maximum(stop - np.arange(m) - 1, 0)
    ends = np.cumsum(counts)
    total = int(ends[-1])
    for low in range(0, total, _PAIR_CHUNK):
        index = np.arange(low, min(low + _PAIR_CHUNK, total), dtype=np.int64)
        p = np.searchsorted(ends, index, side="right")
        q = p + 1 + (index - (ends[p] - counts[p]))
        a, b = order[p], order[q]
        i, j = np.minimum(a, b), np.maximum(a, b)
        near = (low_y[i] <= high_y[j]) & (low_y[j] <= high_y[i])
        near &= (j - i != 1) & ~((i == 0) & (j == m - 1))  # neighbours share a vertex: tested apart
        i, j = i[near], j[near]
        hit = _segments_meet(start[i], end[i], start[j], end[j])
        found.append(np.stack([i[hit], j[hit]], axis=1))
    pairs = np.concatenate(found).astype(np.intp)
    if len(pairs) == 0:
        return pairs
    key = sorted_unique(pairs[:, 0] * m + pairs[:, 1])  # sorted by (i, j), each pair once
    return np.stack([key // m, key % m], axis=1)


def _folded_neighbours(start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Neighbouring edges ``i`` and ``i + 1`` that overlap: the middle vertex turns straight back
    (collinear, pointing back), or an edge has no length."""
    m = len(start)
    a = end - start
    b = np.concatenate([a[1:], a[:1]])
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    dot = a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]
    empty = (a[:, 0] == 0) & (a[:, 1] == 0)
    bad = ((cross == 0) & (dot < 0)) | empty | np.concatenate([empty[1:], empty[:1]])
    i = np.flatnonzero(bad)
    j = (i + 1) % m
    return np.stack([np.minimum(i, j), np.maximum(i, j)], axis=1)


def _orient(o: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Sign of the turn o -> p -> q (+1 left, -1 right, 0 collinear), per row."""
    return np.sign((p[:, 0] - o[:, 0]) * (q[:, 1] - o[:, 1]) - (p[:, 1] - o[:, 1]) * (q[:, 0] - o[:, 0]))


def _within(o: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Whether q lies in the box of segment o-p (for q collinear with it: on the segment)."""
    return ((np.minimum(o[:, 0], p[:, 0]) <= q[:, 0]) & (q[:, 0] <= np.maximum(o[:, 0], p[:, 0]))
            & (np.minimum(o[:, 1], p[:, 1]) <= q[:, 1]) & (q[:, 1] <= np.maximum(o[:, 1], p[:, 1])))


def _segments_meet(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Whether closed segments p1-q1 and p2-q2 share a point, per row."""
    o1, o2 = _orient(p1, q1, p2), _orient(p1, q1, q2)
    o3, o4 = _orient(p2, q2, p1), _orient(p2, q2, q1)
    meet = (o1 * o2 < 0) & (o3 * o4 < 0)
    meet |= (o1 == 0) & _within(p1, q1, p2)
    meet |= (o2 == 0) & _within(p1, q1, q2)
    meet |= (o3 == 0) & _within(p2, q2, p1)
    meet |= (o4 == 0) & _within(p2, q2, q1)
    return meet


def _farthest(ring: np.ndarray, first: int, last: int) -> tuple[float, int]:
    """The vertex of the chain strictly between ``first`` and ``last`` (indices into the ring
    closed by repeating its first vertex) farthest from the segment joining them, and its
    distance; ``(-1, -1)`` for a chain without inner vertices."""
    if last - first < 2:
        return -1.0, -1
    ax, ay = ring[first].tolist()
    bx, by = ring[last % len(ring)].tolist()
    inner = ring[first + 1 : last]
    px, py = inner[:, 0] - ax, inner[:, 1] - ay
    dx, dy = bx - ax, by - ay
    length2 = dx * dx + dy * dy
    if length2 == 0.0:
        squared = px * px + py * py
    else:
        t = np.minimum(np.maximum((px * dx + py * dy) / length2, 0.0), 1.0)
        ex, ey = px - t * dx, py - t * dy
        squared = ex * ex + ey * ey
    k = int(squared.argmax())
    return math.sqrt(float(squared[k])), first + 1 + k


def _best_first(ring: np.ndarray, tolerance: float, budget: int) -> list[int]:
    """Douglas-Peucker splits, farthest chain first, until within ``tolerance`` or ``budget``
    vertices (0: none), at least 3; the ring is closed at index ``len(ring)`` (= vertex 0)."""
    n = len(ring)
    gap = ring - ring[0]
    far = int(np.argmax(gap[:, 0] ** 2 + gap[:, 1] ** 2))
    keep = [0, far]
    heap: list[tuple[float, int, int, int]] = []
    for first, last in ((0, far), (far, n)):
        distance, split = _farthest(ring, first, last)
        if split >= 0:
            heapq.heappush(heap, (-distance, first, last, split))
    while heap:
        distance = -heap[0][0]
        if len(keep) >= 3 and (distance <= tolerance or (budget and len(keep) >= budget)):
            break
        _, first, last, split = heapq.heappop(heap)
        keep.append(split)
        for a, b in ((first, split), (split, last)):
            d, k = _farthest(ring, a, b)
            if k >= 0:
                heapq.heappush(heap, (-d, a, b, k))
    return sorted(keep)


def _repair(ring: np.ndarray, keep: list[int]) -> np.ndarray:
    """Split the edges that meet another at their chain's farthest vertex until none does (the
    traced ring itself is simple, so this ends at the latest with the whole ring)."""
    n = len(ring)
    keep = np.sort(np.asarray(keep, dtype=np.int64)).tolist()
    shift = keep[0]  # chains run from kept vertex to kept vertex: start the ring at one
    ring = np.roll(ring, -shift, axis=0)
    keep = [k - shift for k in keep]
    while True:
        pairs = meeting_edges(ring[keep])
        if len(pairs) == 0:
            break
        closed = keep + [n]
        farthest = {edge: _farthest(ring, closed[edge], closed[edge + 1]) for edge in sorted_unique(pairs).tolist()}
        added = set()
        for i, j in pairs.tolist():  # of two edges that meet, the one farther from its chain
            distance, split = max(farthest[i], farthest[j])
            if split >= 0:
                added.add(split % n)
        if not added:
            break  # edges of the traced ring itself meet: nothing left to split
        keep = sorted(set(keep) | added)
    return np.sort((np.asarray(keep, dtype=np.intp) + shift) % n)

"""Label masks -> CVAT polygons: the outlines of each label, and the order to draw them in.

What ``propose`` writes for its detections and ``export-cvat`` for a finished run's masks, so
that ``cvat2mask`` reads them back to nearly the same masks:

- :func:`plane_outlines`: the outer outline of each label's largest piece;
- :func:`outline_planes` (and :func:`piece_outlines`, its polygons alone): one polygon per label
  that covers all its pieces (CVAT tracks hold one shape per frame);
- :func:`draw_order`: the ``z_order`` that puts the plane whose pixels fill an overlap on top.

Every polygon is simple (no two edges cross or touch: :mod:`annotate_rgbd.cvat.rings`), within
a tolerance of the traced outline and, where asked, within a vertex budget: what a labeller can
correct by dragging a few vertices.

CVAT (and :mod:`annotate_rgbd.segment.rasterize`) puts the centre of pixel ``(col, row)`` at
``(col + 0.5, row + 0.5)`` and fills a polygon with the pixels whose centres it contains. An
outline traced through the centres of a region's border pixels would leave out half of the
border (its right and bottom pixels fall on the outline, which the half-open rule excludes).
So the region is traced on a grid twice as fine: there the border runs through points a quarter
of a pixel inside the region's edge, which puts every border pixel's centre a quarter of a
pixel inside the outline and every outside centre a quarter of a pixel outside it.

Before tracing, a region is made one piece whose pixels meet along edges: the pieces of a plane
(a floor on both sides of a table) are joined by one-pixel-wide corridors, each piece to the
nearest one already joined (Prim's minimum spanning tree over the pieces' border pixels), and
two pixels that touch only at a corner get one of the two pixels beside them. Traced outlines of
such regions never touch themselves; the corridors and corner pixels are the few pixels the
polygon covers beyond the mask (besides holes, which it fills).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .pieces import join_pieces, label_boxes
from .rings import ring_simplifications, sorted_unique

#: Pieces of a plane's mask smaller than this are left out of its polygon (speckle, not area).
MIN_PIECE_PX = 20
#: Under a vertex budget ``V`` a polygon joins at most ``V // VERTICES_PER_PIECE`` pieces (the
#: largest), fewer while the corridors' ends take more than a third of the budget: each corridor
#: keeps its four ends (more where it crosses a piece), and a piece needs vertices of its own. On
#: TUM fr1_rpy a desk of twelve pieces, its corridors with 80 ends, kept IoU 0.20 with its pixels
#: under a budget of 100; of the largest five pieces (32 ends) 0.91. At most 4 pieces instead
#: cost the 30 rendered room frames 0.018 of cvat2mask's precision at IoU 0.8.
VERTICES_PER_PIECE = 8


@dataclass(frozen=True)
class Outline:
    """The polygon of one label.

    Attributes
    ----------
    points : ndarray of float64, shape (V, 2)
        ``(x, y)`` vertices in CVAT pixel coordinates, V >= 3, a simple polygon.
    unlimited : ndarray of float64, shape (U, 2), optional
        The polygon at the tolerance alone, where the vertex budget stopped the simplification
        earlier (U > V); None where it did not.
    """

    points: np.ndarray
    unlimited: np.ndarray | None = None


def plane_outlines(labels: np.ndarray, tolerance_px: float = 1.5, max_vertices: int = 0) -> dict[int, np.ndarray]:
    """The outer outline of each label, simplified, in CVAT pixel coordinates.

    Each label gets one polygon: the outer boundary of its largest connected piece
    (8-connected; by pixels, ties to the first found in raster order), holes filled.
    Smaller pieces are left out: a proposal is one polygon per plane, and the labeller
    corrects it.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        0 = no plane, else plane labels.
    tolerance_px : float
        Largest distance of the simplified outline from the traced one, in pixels.
    max_vertices : int
        Vertex budget of each polygon (0: none; see :func:`annotate_rgbd.cvat.rings.simplify_ring`).

    Returns
    -------
    dict of int to ndarray of float64, shape (V, 2)
        ``(x, y)`` vertices per label present, V >= 3, in ascending label order; simple polygons.
    """
    labels = _check_labels(labels, tolerance_px)
    return {k: o.points for k, o in _outlines(labels, tolerance_px, max_vertices, None).items()}


def outline_planes(labels: np.ndarray, tolerance_px: float, max_vertices: int = 0,
                   min_piece: int = MIN_PIECE_PX) -> dict[int, Outline]:
    """One simple polygon per label that covers all its pieces, not only the largest.

    The pieces (8-connected) of at least ``min_piece`` pixels (the largest one when none is
    that large) are joined by corridors and traced as one region (see the module docstring);
    its outline is simplified within ``tolerance_px`` and ``max_vertices``.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        0 = none, else 1..K.
    tolerance_px : float
        Largest distance of the polygon from the traced outline, pixels.
    max_vertices : int
        Vertex budget of each polygon (0: none).
    min_piece : int
        Smallest piece, pixels.

    Returns
    -------
    dict of int to Outline
        Per label present, in ascending label order.
    """
    labels = _check_labels(labels, tolerance_px)
    return _outlines(labels, tolerance_px, max_vertices, min_piece)


def piece_outlines(labels: np.ndarray, tolerance_px: float, min_piece: int = MIN_PIECE_PX,
                   max_vertices: int = 0) -> dict[int, np.ndarray]:
    """The polygons of :func:`outline_planes` alone.

    Returns
    -------
    dict of int to ndarray of float64, shape (V, 2)
    """
    return {k: o.points for k, o in outline_planes(labels, tolerance_px, max_vertices, min_piece).items()}


def _check_labels(labels: np.ndarray, tolerance_px: float) -> np.ndarray:
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise ValueError(f"label image must be 2-D, got shape {labels.shape}")
    if tolerance_px < 0:
        raise ValueError(f"tolerance_px must be >= 0, got {tolerance_px}")
    if labels.size and labels.min() < 0:
        raise ValueError("labels must be >= 0")
    return labels if labels.dtype.kind in "iu" else labels.astype(np.int64)


def _outlines(labels: np.ndarray, tolerance_px: float, max_vertices: int, min_piece: int | None) -> dict[int, Outline]:
    """Per label: its region (the largest piece when ``min_piece`` is None, else every piece of
    at least ``min_piece`` pixels joined), traced and simplified."""
    outlines: dict[int, Outline] = {}
    for label, window in enumerate(label_boxes(labels), start=1):
        if window is None:
            continue
        mask = labels[window] == label
        # Under a budget, every corridor keeps its ends: so many pieces at most, fewer while
        # the corridors' ends (a corridor across a piece has more) take over a third of it.
        most = max(1, max_vertices // VERTICES_PER_PIECE) if max_vertices else 0
        while True:
            region, corridors = join_pieces(mask, min_piece, most)
            contours = trace_pieces(region)
            contour = contours[0] if len(contours) == 1 else max(contours, key=cv2.contourArea)
            anchors = corridor_ends(contour, corridors)
            if not max_vertices or most == 1 or 3 * len(anchors) <= max_vertices:
                break
            # Fewer pieces, in proportion to the ends too many (at least one fewer).
            most = max(1, min(most - 1, int(most * max_vertices / (3 * len(anchors)))))
        ring = to_image(contour, window[1].start, window[0].start)
        outlines[label] = simple_outline(ring, tolerance_px, max_vertices, anchors)
    return outlines


def corridor_ends(contour: np.ndarray, corridors: np.ndarray) -> np.ndarray:
    """The vertices of a traced outline (:func:`trace_pieces`) where it passes between a
    corridor and a piece: the ends of each of the corridor's sides, which a simplified polygon
    keeps so that the corridor stays a thin strip instead of collapsing onto itself.

    Parameters
    ----------
    contour : ndarray of int32, shape (V, 1, 2)
    corridors : ndarray of bool, shape (H, W)
        Of :func:`annotate_rgbd.cvat.pieces.join_pieces`, on the traced mask's grid.

    Returns
    -------
    ndarray of intp
        Ascending indices into the contour: both vertices of every edge between a corridor
        pixel and another.
    """
    if not corridors.any():
        return np.zeros(0, dtype=np.intp)
    fine = contour.reshape(-1, 2)
    inside = corridors[fine[:, 1] // 2 - 1, fine[:, 0] // 2 - 1]
    change = np.flatnonzero(inside != np.roll(inside, 1))  # edge (i - 1, i) crosses a corridor's end
    return sorted_unique(change, (change - 1) % len(fine))


def trace_pieces(mask: np.ndarray) -> list[np.ndarray]:
    """The outer borders of the 8-connected pieces of a mask, traced on the grid twice as fine.

    Pieces inside a hole of another piece are not traced (the other's outline covers them).

    Parameters
    ----------
    mask : ndarray of bool, shape (H, W)

    Returns
    -------
    list of ndarray of int32, shape (V, 1, 2)
        ``cv2.findContours`` contours on the fine grid of the mask padded by one pixel (fine
        pixel ``(x, y)`` lies in mask pixel ``(x // 2 - 1, y // 2 - 1)``), each starting at its
        piece's first pixel in raster order.
    """
    # One pixel of margin so that outlines along the window's edge close properly.
    padded = cv2.copyMakeBorder(np.ascontiguousarray(mask).view(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    fine = cv2.resize(padded, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
    contours, _ = cv2.findContours(fine, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return list(contours)


def to_image(contour: np.ndarray, left: int, top: int) -> np.ndarray:
    """A contour of :func:`trace_pieces` in CVAT coordinates of the whole image.

    Parameters
    ----------
    contour : ndarray of int32, shape (V, 1, 2)
    left, top : int
        Position of the traced mask in the image.

    Returns
    -------
    ndarray of float64, shape (V, 2)
        Quarter-pixel coordinates (exact in binary floating point).
    """
    # Fine pixel j has its centre at (j + 0.5) / 2 in coarse CVAT coordinates; undo the
    # margin and place the window.
    return (contour.reshape(-1, 2).astype(np.float64) + 0.5) / 2.0 - 1.0 + (left, top)


def simple_outline(ring: np.ndarray, tolerance_px: float, max_vertices: int = 0, anchors=()) -> Outline:
    """A traced outline as a simple polygon within ``tolerance_px`` and ``max_vertices``
    (:func:`annotate_rgbd.cvat.rings.ring_simplifications`), and the polygon at the tolerance
    alone when the budget stopped it earlier.

    Parameters
    ----------
    ring : ndarray of float64, shape (N, 2)
        A simple traced outline (:func:`to_image`).
    tolerance_px : float
    max_vertices : int
    anchors : sequence of int
        Vertices of the ring every polygon keeps (:func:`corridor_ends`).

    Returns
    -------
    Outline
    """
    # The straight runs of the trace carry no shape: only their ends (and the anchors) can be vertices.
    anchors = np.asarray(anchors, dtype=np.intp)
    turns = sorted_unique(_corners(ring), anchors) if len(anchors) else _corners(ring)
    corners = ring[turns]
    kept = np.searchsorted(turns, anchors)
    if not max_vertices:
        return Outline(corners[ring_simplifications(corners, tolerance_px, [0], kept)[0]])
    free, limited = (corners[k] for k in ring_simplifications(corners, tolerance_px, [0, max_vertices], kept))
    # Where the budget never stopped the splits, it gives the same polygon.
    return Outline(limited, free if len(free) > len(limited) else None)


def _corners(ring: np.ndarray) -> np.ndarray:
    """Indices of the vertices of a closed ring where it turns (all of them when it never does)."""
    before = ring - np.concatenate([ring[-1:], ring[:-1]])
    after = np.concatenate([before[1:], before[:1]])
    turn = before[:, 0] * after[:, 1] - before[:, 1] * after[:, 0] != 0
    turn |= before[:, 0] * after[:, 0] + before[:, 1] * after[:, 1] <= 0  # turning back (a one-pixel spike) is a corner too
    found = np.flatnonzero(turn)
    return found if len(found) >= 3 else np.arange(len(ring))


def polygon_coverage(labels: np.ndarray, windows: list) -> np.ndarray:
    """How many pixels of each plane lie inside each plane's polygon.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Planes 1..K, 0 for none.
    windows : list of (int, int, ndarray of bool)
        The filled polygon of plane ``k`` at position ``k - 1`` as ``(top, left, window)``
        (:func:`annotate_rgbd.segment.rasterize.fill_window`).

    Returns
    -------
    ndarray of int64, shape (K, K)
        ``[p, q]``: pixels of plane ``q + 1`` inside the polygon of plane ``p + 1``.
    """
    k = len(windows)
    inside = np.zeros((k, k + 1), dtype=np.int64)
    for p, (top, left, window) in enumerate(windows):
        rows, cols = window.shape
        covered = labels[top : top + rows, left : left + cols][window]
        inside[p] = np.bincount(covered.astype(np.intp), minlength=k + 1)[: k + 1]
    return inside[:, 1:]


def draw_order(labels: np.ndarray, windows: list, distance: np.ndarray, coverage: np.ndarray | None = None) -> np.ndarray:
    """``z_order`` of the polygons so that, where two overlap, the plane whose pixels fill the
    overlap is drawn on top: the nearer one where one plane occludes the other, the inner one
    where a polygon's filled holes hold another plane (a picture on a wall).

    Plane ``q`` goes above ``p`` when more of ``q``'s pixels lie inside ``p``'s polygon than of
    ``p``'s inside ``q``'s. The order is a topological sort of these relations, picking the
    farthest plane (``distance``) first among those free to go next, and the farthest of all
    when the relations form a cycle.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Planes 1..K.
    windows : list of (int, int, ndarray of bool)
        Pixels of the polygon of plane ``k`` at position ``k - 1``, as
        :func:`annotate_rgbd.segment.rasterize.shape_mask` (or the faster
        :func:`~annotate_rgbd.segment.rasterize.fill_window`) gives them: ``(top, left, window)``.
    distance : ndarray of float, shape (K,)
        Mean camera distance of each plane (NaN: farthest).
    coverage : ndarray of int, shape (K, K), optional
        :func:`polygon_coverage` of ``labels`` and ``windows``, when already computed.

    Returns
    -------
    ndarray of int64, shape (K,)
        0 (bottom) .. K - 1 (top).
    """
    counts = polygon_coverage(labels, windows) if coverage is None else np.asarray(coverage)
    k = len(counts)
    below = counts.T > counts  # below[q, p]: q must be drawn above p
    farthest = np.nan_to_num(np.asarray(distance, dtype=np.float64), nan=np.inf)
    z = np.zeros(k, dtype=np.int64)
    placed = np.zeros(k, dtype=bool)
    for level in range(k):
        ready = ~placed & ~(below & ~placed[None, :]).any(axis=1)
        pool = np.flatnonzero(ready if ready.any() else ~placed)
        pick = pool[np.lexsort((pool, -farthest[pool]))[0]]
        z[pick] = level
        placed[pick] = True
    return z

"""Label masks -> CVAT polygons: the outlines of each label, and the order to draw them in.

What ``propose`` writes for its detections and ``export-cvat`` for a finished run's masks, so
that ``cvat2mask`` reads them back to nearly the same masks:

- :func:`plane_outlines`: the outer outline of each label's largest piece;
- :func:`piece_outlines`: one polygon per label that covers all its pieces (CVAT tracks hold
  one shape per frame), bridged into one outline;
- :func:`draw_order`: the ``z_order`` that puts the plane whose pixels fill an overlap on top.

CVAT (and :mod:`annotate_rgbd.segment.rasterize`) puts the centre of pixel ``(col, row)`` at
``(col + 0.5, row + 0.5)`` and fills a polygon with the pixels whose centres it contains. An
outline traced through the centres of a region's border pixels would leave out half of the
border (its right and bottom pixels fall on the outline, which the half-open rule excludes).
So the region is traced on a grid twice as fine: there the border runs through points a quarter
of a pixel inside the region's edge, which puts every border pixel's centre a quarter of a
pixel inside the outline and every outside centre a quarter of a pixel outside it.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

#: Pieces of a plane's mask smaller than this are left out of its polygon (speckle, not area).
MIN_PIECE_PX = 20


def plane_outlines(labels: np.ndarray, tolerance_px: float = 1.5) -> dict[int, np.ndarray]:
    """The outer outline of each label, simplified, in CVAT pixel coordinates.

    Each label gets one polygon: the outer boundary of its largest connected piece
    (8-connected; by area enclosed, ties to the first found in raster order), holes filled.
    Smaller pieces are left out: a proposal is one polygon per plane, and the labeller
    corrects it. Simplification is Douglas-Peucker (``cv2.approxPolyDP``).

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        0 = no plane, else plane labels.
    tolerance_px : float
        Largest distance of the simplified outline from the traced one, in pixels.

    Returns
    -------
    dict of int to ndarray of float64, shape (V, 2)
        ``(x, y)`` vertices per label present, V >= 3, in ascending label order. A piece too
        small to simplify to 3 vertices keeps its traced outline.
    """
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise ValueError(f"label image must be 2-D, got shape {labels.shape}")
    if tolerance_px < 0:
        raise ValueError(f"tolerance_px must be >= 0, got {tolerance_px}")
    if labels.size and labels.min() < 0:
        raise ValueError("labels must be >= 0")
    if labels.dtype.kind not in "iu":
        labels = labels.astype(np.int64)
    outlines: dict[int, np.ndarray] = {}
    for label, window in enumerate(ndimage.find_objects(labels), start=1):
        if window is None:
            continue
        contours = trace_pieces(labels[window] == label)
        if contours:
            largest = contours[int(np.argmax([cv2.contourArea(c) for c in contours]))]
            outlines[label] = simplify(largest, tolerance_px, window[1].start, window[0].start)
    return outlines


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


def simplify(contour: np.ndarray, tolerance_px: float, left: int, top: int) -> np.ndarray:
    """A contour of :func:`trace_pieces` as a simplified CVAT polygon of the whole image.

    Parameters
    ----------
    contour : ndarray of int32, shape (V, 1, 2)
    tolerance_px : float
        Douglas-Peucker tolerance (``cv2.approxPolyDP``), pixels; a contour too small to
        simplify to 3 vertices is kept as traced.
    left, top : int
        Position of the traced mask in the image.

    Returns
    -------
    ndarray of float64, shape (V, 2)
    """
    simple = cv2.approxPolyDP(contour, 2.0 * tolerance_px, closed=True)
    if len(simple) < 3:
        simple = contour
    # Fine pixel j has its centre at (j + 0.5) / 2 in coarse CVAT coordinates; undo the
    # margin and place the window.
    xy = (simple.reshape(-1, 2).astype(np.float64) + 0.5) / 2.0 - 1.0
    xy += (left, top)
    return xy


def piece_outlines(labels: np.ndarray, tolerance_px: float, min_piece: int = MIN_PIECE_PX) -> dict[int, np.ndarray]:
    """One polygon per label that covers all its pieces, not only the largest.

    Each 8-connected piece of at least ``min_piece`` pixels is outlined as
    :func:`plane_outlines` outlines the largest; the pieces are then
    chained into one polygon by zero-width bridges, each walked there and back, which enclose
    no pixel centre under the even-odd rule CVAT and :mod:`annotate_rgbd.segment.rasterize` fill with.
    Pieces inside a hole of another piece are left to that piece's outline, which covers them.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        0 = none, else 1..K.
    tolerance_px : float
    min_piece : int

    Returns
    -------
    dict of int to ndarray of float64, shape (V, 2)
    """
    labels = np.asarray(labels)
    outlines: dict[int, np.ndarray] = {}
    for label, window in enumerate(ndimage.find_objects(labels), start=1):
        if window is None:
            continue
        mask = labels[window] == label
        contours = trace_pieces(mask)
        top, left = window[0].start, window[1].start
        if len(contours) == 1:
            outlines[label] = simplify(contours[0], tolerance_px, left, top)
            continue
        lengths = np.fromiter((len(c) for c in contours), dtype=np.int64, count=len(contours))
        kept = _large_pieces(mask, contours, lengths, min_piece)
        if len(kept) <= 1:  # the largest piece (as plane_outlines draws it)
            outlines[label] = simplify(contours[_largest(contours, lengths)], tolerance_px, left, top)
        else:
            outlines[label] = bridge([simplify(contours[i], tolerance_px, left, top) for i in kept])
    return outlines


def _largest(contours: list, lengths: np.ndarray) -> int:
    """Index of the contour of largest area (the first of equals), as ``argmax`` of
    ``cv2.contourArea`` over all of them, measuring only those long enough to enclose more:
    a closed path of ``L`` steps of at most sqrt(2) encloses at most ``L**2 / (2 pi)``."""
    bound = lengths.astype(np.float64) ** 2 / 6.0
    best, best_area = -1, -1.0
    for i in np.argsort(-lengths, kind="stable").tolist():
        if bound[i] < best_area:
            break
        area = cv2.contourArea(contours[i])
        if area > best_area or (area == best_area and i < best):
            best, best_area = i, area
    return best


def _large_pieces(mask: np.ndarray, contours: list, lengths: np.ndarray, min_piece: int) -> list[int]:
    """Indices of the contours (:func:`trace_pieces`) of pieces of
    at least ``min_piece`` pixels, largest first (ties: first pixel in raster order)."""
    # A closed path of L fine steps spans at most L / 2 fine pixels, so at most (L / 2 + 1) / 2
    # + 1 mask pixels, along each axis: most pieces (speckle) are too short to be measured.
    span = (lengths / 2 + 1) / 2 + 1
    candidates = np.flatnonzero(span * span >= min_piece)
    if len(candidates) <= 1:
        return []
    boxes = np.array([cv2.boundingRect(contours[i]) for i in candidates])  # fine x, y, width, height
    cells = ((boxes[:, :2] + boxes[:, 2:] - 1) // 2 - boxes[:, :2] // 2 + 1).prod(axis=1)
    candidates, boxes = candidates[cells >= min_piece], boxes[cells >= min_piece]
    if len(candidates) <= 1:
        return []  # at most one piece has room for min_piece pixels
    _, pieces = cv2.connectedComponents(mask.view(np.uint8), connectivity=8, ltype=cv2.CV_32S)
    starts = np.array([contours[i][0, 0] for i in candidates]) // 2 - 1  # (x, y) of each piece's first pixel
    sizes = np.zeros(len(candidates), dtype=np.int64)
    for n, ((x, y), (bx, by, bw, bh)) in enumerate(zip(starts.tolist(), boxes.tolist())):
        rows = slice(max(by // 2 - 1, 0), (by + bh - 1) // 2)  # the piece's box in mask pixels
        cols = slice(max(bx // 2 - 1, 0), (bx + bw - 1) // 2)
        sizes[n] = np.count_nonzero(pieces[rows, cols] == pieces[y, x])
    order = np.lexsort((starts[:, 0], starts[:, 1], -sizes))
    return [int(candidates[i]) for i in order if sizes[i] >= min_piece]


def bridge(polygons: list[np.ndarray]) -> np.ndarray:
    """Chain polygons into one: from the first vertex of the first, out to the nearest vertex of
    each next one, around it, and back the same way (each bridge is walked twice).

    A polygon that lies inside the chain so far (a piece on an island in another's hole, which
    that outline already covers) is left out: under the even-odd rule it would cut a hole.
    """
    result = polygons[0]
    for polygon in polygons[1:]:
        first = (float(polygon[0, 0]), float(polygon[0, 1]))
        if cv2.pointPolygonTest(result.astype(np.float32).reshape(-1, 1, 2), first, False) > 0:
            continue
        # Squared distances: the same nearest pair (vertices lie on a quarter-pixel grid) without roots.
        dx = result[:, 0, None] - polygon[None, :, 0]
        dy = result[:, 1, None] - polygon[None, :, 1]
        gaps = dx * dx + dy * dy
        i, j = np.unravel_index(int(np.argmin(gaps)), gaps.shape)
        around = np.roll(polygon, -j, axis=0)
        result = np.concatenate([result[: i + 1], around, around[:1], result[i:]])
    return result


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

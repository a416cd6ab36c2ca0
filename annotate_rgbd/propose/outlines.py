"""One polygon per plane that covers every piece of its mask (CVAT tracks hold one shape per frame)."""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from annotate_rgbd.detect.outline import simplify, trace_pieces

#: Pieces of a plane's mask smaller than this are left out of its polygon (speckle, not area).
MIN_PIECE_PX = 20


def piece_outlines(labels: np.ndarray, tolerance_px: float, min_piece: int = MIN_PIECE_PX) -> dict[int, np.ndarray]:
    """One polygon per label that covers all its pieces, not only the largest.

    Each 8-connected piece of at least ``min_piece`` pixels is outlined as
    :func:`annotate_rgbd.detect.plane_outlines` outlines the largest; the pieces are then
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
    """Indices of the contours (:func:`~annotate_rgbd.detect.outline.trace_pieces`) of pieces of
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


def fill_window(polygon: np.ndarray, height: int, width: int) -> tuple[int, int, np.ndarray]:
    """The pixels of a polygon, as a boolean window of the image, filled by OpenCV.

    A fast stand-in for :func:`annotate_rgbd.segment.rasterize.shape_mask` where a pixel more or less on
    the outline does not matter (draw order, drop statistics, overlap of reprojected outlines):
    ``cv2.fillPoly`` at 1/16 pixel takes the outline's pixels too, and is ~20x faster on the
    long outlines of real planes.

    Parameters
    ----------
    polygon : ndarray, shape (V, 2)
        CVAT image coordinates (pixel ``(col, row)`` has its centre at ``(col + 0.5, row + 0.5)``).
    height, width : int

    Returns
    -------
    top, left : int
    window : ndarray of bool, shape (rows, cols)
        Empty when the polygon lies outside the image.
    """
    points = np.asarray(polygon, dtype=np.float64) - 0.5  # OpenCV puts pixel centres at integers
    left = int(np.clip(np.floor(points[:, 0].min()), 0, width))
    right = int(np.clip(np.ceil(points[:, 0].max()) + 1, 0, width))
    top = int(np.clip(np.floor(points[:, 1].min()), 0, height))
    bottom = int(np.clip(np.ceil(points[:, 1].max()) + 1, 0, height))
    window = np.zeros((max(bottom - top, 0), max(right - left, 0)), dtype=np.uint8)
    if window.size:
        fixed = np.round((points - (left, top)) * 16).astype(np.int32)
        cv2.fillPoly(window, [fixed.reshape(-1, 1, 2)], 1, lineType=cv2.LINE_8, shift=4)
    return top, left, window.view(bool)

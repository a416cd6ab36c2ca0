"""One polygon per plane that covers every piece of its mask (CVAT tracks hold one shape per frame)."""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from ..detect import plane_outlines

#: Pieces of a plane's mask smaller than this are left out of its polygon (speckle, not area).
MIN_PIECE_PX = 20


def piece_outlines(labels: np.ndarray, tolerance_px: float, min_piece: int = MIN_PIECE_PX) -> dict[int, np.ndarray]:
    """One polygon per label that covers all its pieces, not only the largest.

    Each 8-connected piece of at least ``min_piece`` pixels is outlined
    (:func:`annotate_rgbd.detect.plane_outlines`); the pieces are then chained into one polygon
    by zero-width bridges, each walked there and back, which enclose no pixel centre under the
    even-odd rule CVAT and :mod:`annotate_rgbd.rasterize` fill with.

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
    outlines: dict[int, np.ndarray] = {}
    for label, window in enumerate(ndimage.find_objects(labels), start=1):
        if window is None:
            continue
        pieces, count = ndimage.label(labels[window] == label, structure=np.ones((3, 3), dtype=bool))
        sizes = np.bincount(pieces.ravel(), minlength=count + 1)[1:]
        keep = np.flatnonzero(sizes >= min_piece) + 1
        if keep.size == 0:
            keep = np.array([int(np.argmax(sizes)) + 1])
        table = np.zeros(count + 1, dtype=np.int32)
        table[keep] = np.arange(1, keep.size + 1)
        polygons = plane_outlines(table[pieces], tolerance_px)
        offset = np.array([window[1].start, window[0].start], dtype=np.float64)
        chain = [polygons[k] + offset for k in sorted(polygons, key=lambda k: -sizes[keep[k - 1] - 1])]
        outlines[label] = bridge(chain)
    return outlines


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
        gaps = np.linalg.norm(result[:, None, :] - polygon[None, :, :], axis=2)
        i, j = np.unravel_index(int(np.argmin(gaps)), gaps.shape)
        around = np.roll(polygon, -j, axis=0)
        result = np.concatenate([result[: i + 1], around, around[:1], result[i:]])
    return result

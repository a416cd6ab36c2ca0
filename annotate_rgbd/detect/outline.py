"""Label image -> simplified outer outlines, as CVAT polygons.

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

"""Label image -> simplified outer outlines, as CVAT polygons.

CVAT (and :mod:`annotate_rgbd.rasterize`) puts the centre of pixel ``(col, row)`` at
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
    outlines: dict[int, np.ndarray] = {}
    for position, window in enumerate(ndimage.find_objects(labels.astype(np.int64, copy=False))):
        if window is None:
            continue
        label = position + 1
        top, left = window[0].start, window[1].start
        # One pixel of margin so that outlines along the window's edge close properly.
        mask = np.pad(labels[window] == label, 1).astype(np.uint8)
        fine = cv2.resize(mask, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
        contours, _ = cv2.findContours(fine, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        if not contours:
            continue
        largest = contours[int(np.argmax([cv2.contourArea(c) for c in contours]))]
        simple = cv2.approxPolyDP(largest, 2.0 * tolerance_px, closed=True)
        if len(simple) < 3:
            simple = largest
        # Fine pixel j has its centre at (j + 0.5) / 2 in coarse CVAT coordinates; undo the
        # margin and place the window.
        xy = (simple.reshape(-1, 2).astype(np.float64) + 0.5) / 2.0 - 1.0
        xy += (left, top)
        outlines[label] = xy
    return outlines

"""Shapes -> plane label image on the depth grid.

A pixel belongs to a shape when its centre lies inside it. In CVAT coordinates the image's
top-left corner is (0, 0), so the centre of pixel ``(col, row)`` is ``(col + 0.5, row + 0.5)``.
TUM and ICL-NUIM depth images are registered to the RGB images, so the labeller's pixel
coordinates carry over to the depth grid unchanged.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np
from skimage.draw import polygon as polygon_pixels

from .annotation import Shape


def rasterize_frame(shapes: Iterable[tuple[int, Shape]], height: int, width: int) -> np.ndarray:
    """Draw one frame's shapes into a label image.

    Shapes are drawn in ascending ``z_order``; at equal ``z_order`` later shapes (later tracks in
    the export) are drawn on top, as CVAT shows them.

    Parameters
    ----------
    shapes : iterable of (int, Shape)
        ``(plane id, shape)`` pairs in track order; plane ids are > 0.
    height, width : int
        Size of the depth image.

    Returns
    -------
    ndarray of int32, shape (height, width)
        The plane id on top at each pixel, 0 where no shape covers it.
    """
    labels = np.zeros((height, width), dtype=np.int32)
    ordered = sorted(shapes, key=lambda item: item[1].z_order)  # stable: keeps track order
    for plane_id, shape in ordered:
        rows, cols = shape_pixels(shape, height, width)
        labels[rows, cols] = plane_id
    return labels


def shape_pixels(shape: Shape, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the pixels whose centres lie inside ``shape``, clipped to the image.

    Parameters
    ----------
    shape : Shape
        A polygon, box or mask.
    height, width : int
        Image size.

    Returns
    -------
    rows, cols : ndarray of intp
    """
    if shape.kind == "polygon":
        # Shift to pixel-centre coordinates, where skimage tests pixel centres at integers.
        return polygon_pixels(shape.points[:, 1] - 0.5, shape.points[:, 0] - 0.5, shape=(height, width))
    if shape.kind == "box":
        (xtl, ytl), (xbr, ybr) = shape.points
        col0, col1 = max(int(np.ceil(xtl - 0.5)), 0), min(int(np.floor(xbr - 0.5)), width - 1)
        row0, row1 = max(int(np.ceil(ytl - 0.5)), 0), min(int(np.floor(ybr - 0.5)), height - 1)
        if col1 < col0 or row1 < row0:
            return np.empty(0, np.intp), np.empty(0, np.intp)
        rows, cols = np.mgrid[row0 : row1 + 1, col0 : col1 + 1]
        return rows.ravel(), cols.ravel()
    if shape.kind == "mask":
        left, top = (int(round(v)) for v in shape.points[0])
        rows, cols = np.nonzero(shape.bitmap)
        rows, cols = rows + top, cols + left
        inside = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
        return rows[inside], cols[inside]
    raise ValueError(f"unsupported shape kind {shape.kind!r}")

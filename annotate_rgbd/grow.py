"""Exact edges: grow each refined plane a few pixels beyond its drawn shape, where depth agrees.

A labeller's polygon follows a plane's edge to within a few pixels. Refinement can only remove
pixels from the drawn shape, so where the polygon was drawn inside the true edge the mask stays
short of it. Growing adds back, in a thin band around the drawn shape, the pixels whose 3-D point
lies on the plane within the noise band at its own depth, and that nothing else claims.
"""

from __future__ import annotations

from typing import Mapping

import cv2
import numpy as np
from scipy import ndimage

from .camera import Camera, backproject
from .noise import NoiseModel, inlier_band
from .planefit import point_plane_distance


def grow_planes(
    refined: np.ndarray,
    drawn: np.ndarray,
    depth_m: np.ndarray,
    equations: Mapping[int, np.ndarray],
    camera: Camera,
    model: NoiseModel,
    k: float,
    floor: float,
    cap: float,
    grow_pixels: int,
) -> tuple[np.ndarray, dict[int, int]]:
    """Grow each plane into the pixels around its drawn shape that lie on it.

    Plane ``p`` may take a pixel when all of these hold:

    - its Euclidean distance to the nearest pixel of ``p``'s drawn shape is at most
      ``grow_pixels`` (and it is not in that shape);
    - no plane's drawn shape covers it (``drawn == 0``) and no plane holds it (``refined == 0``);
    - its depth is valid (finite, > 0);
    - its back-projected 3-D point lies within ``clip(k sigma(z), floor, cap)`` of ``p``'s plane,
      ``z`` being the pixel's own depth.

    A pixel that several planes may take goes to the plane it is nearest to in 3-D, a tie to
    the lowest plane id, so the result does not depend on the order of ``equations``. Growth is
    not required to be connected: within a band of a few pixels, a pixel on the plane's surface
    is part of it even behind a one-pixel gap (an invalid-depth speck, a thin cable).

    Parameters
    ----------
    refined : ndarray of uint8, uint16 or int32, shape (H, W)
        Plane ids after refinement (0 = none).
    drawn : ndarray of non-negative int, shape (H, W)
        The rasterised polygons (plane ids, 0 = none), as refinement received them.
    depth_m : ndarray of float, shape (H, W)
        Depth in metres, NaN where invalid.
    equations : mapping of int to ndarray, shape (4,)
        The plane ``(a, b, c, d)`` of each plane to grow (unit normal), e.g. from refinement.
    camera : Camera
        Intrinsics (``fy`` may be negative).
    model : ConstantNoise or QuadraticNoise
    k, floor, cap : float
        The band, as in :func:`annotate_rgbd.noise.inlier_band`.
    grow_pixels : int
        Largest distance in pixels from the drawn shape; 0 returns ``refined`` unchanged.

    Returns
    -------
    labels : ndarray, shape (H, W), of the type of ``refined``
        ``refined`` with the grown pixels set to their plane's id (a new array).
    grown : dict of int to int
        Number of pixels each plane of ``equations`` gained.
    """
    if grow_pixels < 0:
        raise ValueError(f"grow_pixels must be >= 0, got {grow_pixels}")
    labels = refined.copy()
    grown = {int(plane_id): 0 for plane_id in equations}
    if grow_pixels == 0 or not grown:
        return labels, grown
    drawn = np.asarray(drawn)
    height, width = drawn.shape
    g = int(grow_pixels)
    offsets = np.arange(-g, g + 1)
    disk = (offsets[:, None] ** 2 + offsets[None, :] ** 2 <= g * g).astype(np.uint8)
    boxes = ndimage.find_objects(drawn, max_label=max(grown))  # bounding box per plane id
    found_rows, found_cols, found_dist, found_ids = [], [], [], []
    for plane_id in sorted(grown):
        if not 0 < plane_id <= len(boxes) or boxes[plane_id - 1] is None:
            continue  # nothing drawn for this plane
        rows_box, cols_box = boxes[plane_id - 1]
        r0, r1 = max(rows_box.start - g, 0), min(rows_box.stop + g, height)
        c0, c1 = max(cols_box.start - g, 0), min(cols_box.stop + g, width)
        drawn_w = drawn[r0:r1, c0:c1]
        near = cv2.dilate((drawn_w == plane_id).astype(np.uint8), disk, borderValue=0)
        free = (near > 0) & (drawn_w == 0) & (refined[r0:r1, c0:c1] == 0)
        rows, cols = np.nonzero(free)
        if rows.size == 0:
            continue
        rows, cols = rows + r0, cols + c0
        z = depth_m[rows, cols].astype(np.float64)
        valid = np.isfinite(z) & (z > 0)
        rows, cols, z = rows[valid], cols[valid], z[valid]
        points = backproject(cols, rows, z, camera)
        distance = point_plane_distance(points, np.asarray(equations[plane_id], dtype=np.float64))
        on_plane = distance <= inlier_band(z, model, k, floor, cap)
        found_rows.append(rows[on_plane])
        found_cols.append(cols[on_plane])
        found_dist.append(distance[on_plane])
        found_ids.append(np.full(np.count_nonzero(on_plane), plane_id, dtype=np.int64))
    if not found_rows:
        return labels, grown
    rows, cols = np.concatenate(found_rows), np.concatenate(found_cols)
    distance, ids = np.concatenate(found_dist), np.concatenate(found_ids)
    # One winner per pixel: sort by pixel, then distance, then plane id; keep each pixel's first.
    pixel = rows * width + cols
    order = np.lexsort((ids, distance, pixel))
    first = np.ones(order.size, dtype=bool)
    first[1:] = pixel[order][1:] != pixel[order][:-1]
    winners = order[first]
    labels[rows[winners], cols[winners]] = ids[winners]
    counts = np.bincount(ids[winners])
    for plane_id in grown:
        grown[plane_id] = int(counts[plane_id]) if plane_id < counts.size else 0
    return labels, grown

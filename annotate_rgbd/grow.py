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

from .camera import Camera, backproject
from .noise import NoiseModel, inlier_band


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
    the lowest plane id, so the result does not depend on the order of ``equations``. The
    candidates of a pixel are the lowest and the highest id among the planes whose shapes lie
    within ``grow_pixels`` of it (where three or more shapes meet, the others are not
    considered): two image-wide dilations find them, whatever the number of planes. Growth is
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
    g = int(grow_pixels)
    offsets = np.arange(-g, g + 1)
    disk = (offsets[:, None] ** 2 + offsets[None, :] ** 2 <= g * g).astype(np.uint8)
    # Two candidate planes per pixel, from two dilations of the growing planes' shapes over the
    # whole image: the highest and the lowest id within g pixels (a pixel within g pixels of
    # three or more growing planes at once, where three shapes meet, considers those two).
    top = max(grown)
    growing = np.zeros(max(top, int(drawn.max(initial=0))) + 1, dtype=bool)
    growing[list(grown)] = True
    work = np.float32 if top >= 2**16 else (np.uint16 if top >= 2**8 else np.uint8)  # types cv2.dilate takes
    shapes = np.where(growing[drawn], drawn, 0).astype(work)
    highest = cv2.dilate(shapes, disk, borderValue=0)
    ceiling = work(top + 1)
    lowest = cv2.dilate(np.where(shapes > 0, ceiling - shapes, 0).astype(work), disk, borderValue=0)
    free = (highest > 0) & (drawn == 0) & (refined == 0)
    rows, cols = np.nonzero(free)
    z = depth_m[rows, cols].astype(np.float64)
    valid = np.isfinite(z) & (z > 0)
    rows, cols, z = rows[valid], cols[valid], z[valid]
    if rows.size == 0:
        return labels, grown
    points = backproject(cols, rows, z, camera)
    band = inlier_band(z, model, k, floor, cap)
    table = np.zeros((top + 1, 4))
    for plane_id, equation in equations.items():
        table[int(plane_id)] = equation
    best_id = np.zeros(rows.size, dtype=np.int64)
    best_distance = np.full(rows.size, np.inf)
    # Lowest id first, so that an equal distance keeps the lower id.
    for candidates in (top + 1 - lowest[rows, cols].astype(np.int64), highest[rows, cols].astype(np.int64)):
        candidates = np.where(candidates > top, 0, candidates)
        plane = table[candidates]
        distance = np.abs(np.einsum("ij,ij->i", points, plane[:, :3]) + plane[:, 3])
        better = (candidates > 0) & (distance <= band) & (distance < best_distance)
        best_id[better], best_distance[better] = candidates[better], distance[better]
    taken = best_id > 0
    labels[rows[taken], cols[taken]] = best_id[taken]
    counts = np.bincount(best_id[taken], minlength=top + 1)
    for plane_id in grown:
        grown[plane_id] = int(counts[plane_id])
    return labels, grown

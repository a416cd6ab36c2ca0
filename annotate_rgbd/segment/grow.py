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

from annotate_rgbd.config.settings import RefineConfig
from annotate_rgbd.geometry.camera import Camera, backproject, ray_grid
from annotate_rgbd.geometry.noise import NoiseSettings
from .distances import plane_distance, signed_distances
from .refine import label_lookup, window_scores
from .rims import ids_nearby


def grow_planes(
    refined: np.ndarray,
    drawn: np.ndarray,
    depth_m: np.ndarray,
    equations: Mapping[int, np.ndarray],
    camera: Camera,
    noise: NoiseSettings,
    grow_pixels: int,
    excluded: Mapping[int, np.ndarray] | None = None,
) -> tuple[np.ndarray, dict[int, int]]:
    """Grow each plane into the pixels around its drawn shape that lie on it.

    Plane ``p`` may take a pixel when all of these hold:

    - its Euclidean distance to the nearest pixel of ``p``'s drawn shape is at most
      ``grow_pixels`` (and it is not in that shape);
    - no plane's drawn shape covers it (``drawn == 0``) and no plane holds it (``refined == 0``);
    - its depth is valid (finite, > 0);
    - its back-projected 3-D point lies within ``clip(k sigma(z), floor, cap)`` of ``p``'s plane,
      ``z`` being the pixel's own depth;
    - it is not among the pixels ``excluded`` for ``p`` (what the keyframes of a plane carried
      by poses left out: a carried outline lands a pixel or two off, and what touches the plane
      there would otherwise come back in).

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
    noise : NoiseSettings
        The inlier band (:meth:`annotate_rgbd.geometry.noise.NoiseSettings.band`).
    grow_pixels : int
        Largest distance in pixels from the drawn shape; 0 returns ``refined`` unchanged.
    excluded : mapping of int to ndarray of bool, shape (H, W), optional
        Pixels a plane may not take (:mod:`annotate_rgbd.propagate.evidence`). Measured on TUM
        fr1_rpy (benchmarks/bench_real.py, keyframe every 10th frame with poses, 2026-11-27):
        mean IoU 0.904 -> 0.909, leak 2.4 -> 1.8 %.

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
    # Two candidate planes per pixel: the highest and the lowest id of the growing planes' shapes
    # within grow_pixels (a pixel that near three or more of them, where three shapes meet,
    # considers those two).
    top = max(grown)
    growing = np.zeros(max(top, int(drawn.max(initial=0))) + 1, dtype=drawn.dtype)
    growing[list(grown)] = list(grown)  # each growing plane's id, 0 for the others
    lowest, highest = ids_nearby(label_lookup(growing, drawn), int(grow_pixels))
    free = (highest > 0) & (drawn == 0) & (refined == 0)
    rows, cols = np.nonzero(free)
    z = depth_m[rows, cols].astype(np.float64)
    valid = np.isfinite(z) & (z > 0)
    rows, cols, z = rows[valid], cols[valid], z[valid]
    if rows.size == 0:
        return labels, grown
    points = backproject(cols, rows, z, camera)
    band = noise.band(z)
    table = np.zeros((top + 1, 4))
    for plane_id, equation in equations.items():
        table[int(plane_id)] = equation
    # Each growing plane's excluded pixels among the free ones, read once for both candidates.
    barred = [(plane_id, mask[rows, cols]) for plane_id, mask in (excluded or {}).items() if plane_id in grown]
    best_id = np.zeros(rows.size, dtype=np.int64)
    best_distance = np.full(rows.size, np.inf)
    # Lowest id first, so that an equal distance keeps the lower id.
    for candidates in (lowest[rows, cols], highest[rows, cols]):
        plane = table[candidates]
        distance = np.abs(np.einsum("ij,ij->i", points, plane[:, :3]) + plane[:, 3])
        better = (candidates > 0) & (distance <= band) & (distance < best_distance)
        for plane_id, out in barred:
            better &= ~((candidates == plane_id) & out)
        best_id[better], best_distance[better] = candidates[better], distance[better]
    taken = best_id > 0
    labels[rows[taken], cols[taken]] = best_id[taken]
    counts = np.bincount(best_id[taken], minlength=top + 1)
    for plane_id in grown:
        grown[plane_id] = int(counts[plane_id])
    return labels, grown


def grow_connected(
    labels: np.ndarray,
    drawn: np.ndarray,
    claimed: np.ndarray,
    depth_m: np.ndarray,
    equations: Mapping[int, np.ndarray],
    camera: Camera,
    noise: NoiseSettings,
    refine: RefineConfig = RefineConfig(),
    excluded: Mapping[int, np.ndarray] | None = None,
) -> tuple[np.ndarray, dict[int, int]]:
    """Grow each plane of ``equations``, without a distance limit, over the pixels that lie on it
    and connect to it: for planes whose shapes camera poses carried from keyframes, where the
    plane went on beyond every keyframe's view (the labeller never outlined that part).

    Plane ``p`` takes a pixel outside its own shape when it is not ``claimed`` and no plane
    holds it (``labels == 0``), its depth is valid, its 3-D point lies within ``clip(k sigma(z),
    floor, cap)`` of ``p``'s plane and of no other growing plane more closely (a tie: the lowest
    id), the mean residual of its window (:func:`annotate_rgbd.segment.refine.window_scores` over these
    pixels and the planes' own, in units of the model's noise) lies within
    ``refine.coherence_limit`` of 0 (a doormat on a floor lies within its band; no such test
    when ``refine.coherence_window`` is 0), and a chain of such pixels (8-connected) links it to
    ``p``'s own pixels. Unlike refinement's window test there is no per-plane centre and spread,
    and the band is the model's (not scaled by the plane's noise): on a sensor noisier than its
    model it grows less, never more.

    Parameters
    ----------
    labels : ndarray of non-negative int, shape (H, W)
        Plane ids after refinement and edge growing (0 = none).
    drawn : ndarray of non-negative int, shape (H, W)
        The rasterised shapes.
    claimed : ndarray of bool, shape (H, W)
        Pixels that only their own shape's plane may take (those of shapes a labeller drew on
        this frame; a shape carried by poses claims only the pixels its plane keeps).
    depth_m : ndarray of float, shape (H, W)
        Depth in metres, NaN where invalid.
    equations : mapping of int to ndarray, shape (4,)
        The planes to grow (unit normal, camera frame).
    camera : Camera
    noise : NoiseSettings
        The inlier band (:meth:`annotate_rgbd.geometry.noise.NoiseSettings.band`).
    refine : RefineConfig
        The window test's tunables (``coherence_window``, ``min_window_inliers``,
        ``coherence_limit``).
    excluded : mapping of int to ndarray of bool, shape (H, W), optional
        Pixels a plane may not take (what its keyframes' labellers left out,
        :mod:`annotate_rgbd.propagate.evidence`); growth does not pass through them.

    Returns
    -------
    labels : ndarray, shape (H, W), of the type of ``labels``
        A new array with the grown pixels set to their plane's id.
    grown : dict of int to int
        Pixels each plane gained.
    """
    labels = labels.copy()
    grown = {int(plane_id): 0 for plane_id in equations}
    if not grown:
        return labels, grown
    depth = np.asarray(depth_m, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        free = np.isfinite(depth) & (depth > 0) & ~np.asarray(claimed, dtype=bool) & (labels == 0)
    if not free.any():
        return labels, grown
    drawn = np.asarray(drawn)
    ids = sorted(grown)
    growing = np.zeros(max(int(labels.max(initial=0)), ids[-1]) + 1, dtype=np.uint8)
    growing[ids] = 1
    plane_table = np.zeros((len(growing), 4), dtype=np.float32)  # (a, b, c, d) per id; 0: not growing
    for plane_id in ids:
        plane_table[plane_id] = equations[plane_id]
    ray_x, ray_y = ray_grid(camera, *labels.shape, np.float32)
    k = np.float32(noise.k)
    # Each free pixel goes to the nearest plane it lies on (a tie: the lowest id), but never to a
    # plane whose own shape covers it: those pixels refinement left out (a whiteboard on a wall).
    # On the free pixels only, gathered once.
    free_at = np.flatnonzero(free)
    z = depth.ravel()[free_at]
    x, y = ray_x[free_at % labels.shape[1]], ray_y[free_at // labels.shape[1]]
    band = np.asarray(noise.band(z), dtype=np.float32)
    drawn_free = drawn.ravel()[free_at]
    candidate_free = np.zeros(free_at.size, dtype=labels.dtype)
    best = np.full(free_at.size, np.inf, dtype=np.float32)
    residual_free = np.zeros(free_at.size, dtype=np.float32)
    for plane_id in ids:
        signed = plane_distance(z, x, y, *plane_table[plane_id])
        distance = np.abs(signed)
        closer = (distance <= band) & (distance < best) & (drawn_free != plane_id)
        if excluded and plane_id in excluded:
            closer &= ~np.asarray(excluded[plane_id]).ravel()[free_at]
        candidate_free[closer] = plane_id
        best[closer] = distance[closer]
        residual_free[closer] = (signed * k / band)[closer]
    if not candidate_free.any():
        return labels, grown
    candidate = np.zeros(labels.shape, dtype=labels.dtype)
    candidate.ravel()[free_at] = candidate_free
    # The window test of refinement (a doormat on the floor lies within its band): residuals in
    # noise units, averaged over each candidate's window, must look like the plane's noise.
    # ``coherence_window = 0``: no window test, as in refinement.
    if refine.coherence_window > 0:
        # The growing planes' own pixels with depth: their residuals to their own plane.
        own = label_lookup(growing, labels).view(bool)
        signed = signed_distances(depth, *(label_lookup(plane_table[:, i], labels) for i in range(4)), camera)
        residual = np.zeros(labels.shape, dtype=np.float32)
        with np.errstate(invalid="ignore"):
            np.copyto(residual, signed * k / np.asarray(noise.band(depth), dtype=np.float32),
                      where=own & np.isfinite(signed))
        residual.ravel()[free_at] = residual_free
        score, usable = window_scores(residual, own | (candidate > 0), refine.coherence_window,
                                      refine.min_window_inliers)
        candidate[~(usable & (np.abs(score) <= refine.coherence_limit))] = 0
    candidates_left = np.bincount(candidate.ravel()[free_at], minlength=len(growing))
    for plane_id in ids:
        if not candidates_left[plane_id]:
            continue  # nothing to take
        mine = labels == plane_id
        if not mine.any():
            continue
        reach = (mine | (candidate == plane_id)).view(np.uint8)
        # On the window of what the plane may reach (a small plane's is a small part of the image).
        left, top, width, height = cv2.boundingRect(reach)
        window = (slice(top, top + height), slice(left, left + width))
        count, components = cv2.connectedComponents(reach[window], connectivity=8)
        mine = mine[window]
        linked = np.bincount(components[mine], minlength=count) > 0
        linked[0] = False
        take = np.take(linked, components) & ~mine
        labels[window][take] = plane_id
        grown[plane_id] = int(np.count_nonzero(take))
    return labels, grown

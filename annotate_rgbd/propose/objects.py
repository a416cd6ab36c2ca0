"""Planes that are objects on a larger plane: a book on a desk, a picture or a rack on a wall.

Real scenes are full of flat things that lie on or hang on a plane a few centimetres proud of it:
books, keyboards and papers on desks, posters, frames, whiteboards and racks on walls. The
detector finds their tops as planes of their own, parallel to the plane they are on, inside its
outline, within a few centimetres in front of it. A labeller annotating a room's planes does not
draw them (the plane-instance ground truth of ScanNet-style benchmarks has them as clutter: the
depth there is not the plane's), so they are not proposed (:func:`objects_on_planes`).
"""

from __future__ import annotations

import numpy as np


def polygon_coverage(labels: np.ndarray, windows: list) -> np.ndarray:
    """How many pixels of each plane lie inside each plane's polygon.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Planes 1..K, 0 for none.
    windows : list of (int, int, ndarray of bool)
        The filled polygon of plane ``k`` at position ``k - 1`` as ``(top, left, window)``
        (:func:`annotate_rgbd.propose.outlines.fill_window`).

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


def objects_on_planes(
    planes: np.ndarray,
    areas: np.ndarray,
    centroids: np.ndarray,
    coverage: np.ndarray,
    max_height: float,
    min_inside: float,
    angle_deg: float,
) -> np.ndarray:
    """Which planes are objects on a larger plane.

    Plane ``p`` is an object on plane ``q`` when ``q`` has more pixels, their normals agree within
    ``angle_deg``, ``p``'s centroid stands in front of ``q`` (on the camera's side) by more than 0
    and at most ``max_height`` metres, and at least ``min_inside`` of ``p``'s pixels lie inside
    ``q``'s polygon (holes filled: a picture lies in the wall's outline, not on its pixels).

    Parameters
    ----------
    planes : ndarray of float, shape (K, 4)
        ``(a, b, c, d)``, unit normal towards the camera, ``d > 0``: ``n . x + d > 0`` on the
        camera's side.
    areas : ndarray of int, shape (K,)
        Pixels of each plane.
    centroids : ndarray of float, shape (K, 3)
        Camera frame, metres.
    coverage : ndarray of int, shape (K, K)
        :func:`polygon_coverage`.
    max_height, min_inside, angle_deg : float

    Returns
    -------
    ndarray of bool, shape (K,)
    """
    k = len(areas)
    if k < 2:
        return np.zeros(k, dtype=bool)
    planes = np.asarray(planes, dtype=np.float64)
    # height[p, q]: how far p's centroid stands in front of q's plane.
    height = centroids @ planes[:, :3].T + planes[:, 3][None, :]
    parallel = planes[:, :3] @ planes[:, :3].T >= np.cos(np.radians(angle_deg))
    larger = np.asarray(areas)[None, :] > np.asarray(areas)[:, None]
    inside = coverage.T / np.maximum(np.asarray(areas), 1)[:, None]  # [p, q]: share of p inside q's polygon
    on = parallel & larger & (height > 0) & (height <= max_height) & (inside >= min_inside)
    return on.any(axis=1)

"""Planes that are objects on a larger plane: a book on a desk, a picture or a rack on a wall.

Real scenes are full of flat things that lie on or hang on a plane a few centimetres proud of it:
books, keyboards and papers on desks, posters, frames, whiteboards and racks on walls. The
detector finds their tops as planes of their own, parallel to the plane they are on, inside its
outline, within a few centimetres in front of it. A labeller annotating a room's planes does not
draw them (the plane-instance ground truth of ScanNet-style benchmarks has them as clutter: the
depth there is not the plane's), so they are not proposed (:func:`object_hosts`); one inside
the plane's own noise band is the plane itself and joins it (:func:`join_table`).
"""

from __future__ import annotations

import cv2
import numpy as np

from annotate_rgbd.cvat.pieces import label_boxes
from annotate_rgbd.geometry.noise import NoiseSettings


def neighbour_shares(labels: np.ndarray, ring_px: int, boxes: list | None = None) -> np.ndarray:
    """Which planes surround each plane: of the labelled pixels within ``ring_px`` pixels around
    a plane's mask (other planes' pixels; unlabelled ones, such as an object's rims, do not
    count), the share each plane holds.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Planes 1..K, 0 for none.
    ring_px : int
        Width of the ring, pixels (>= 1).
    boxes : list, optional
        :func:`annotate_rgbd.cvat.pieces.label_boxes` of ``labels``, when known.

    Returns
    -------
    ndarray of float64, shape (K, K)
        ``[p, q]``: share of plane ``p + 1``'s ring held by plane ``q + 1`` (a row of zeros when
        no other plane is near).
    """
    labels = np.asarray(labels)
    k = int(labels.max(initial=0))
    shares = np.zeros((k, k))
    height, width = labels.shape
    kernel = np.ones((2 * ring_px + 1, 2 * ring_px + 1), np.uint8)
    for p, window in enumerate(label_boxes(labels, k) if boxes is None else boxes):
        if window is None:
            continue
        rows = slice(max(window[0].start - ring_px, 0), min(window[0].stop + ring_px, height))
        cols = slice(max(window[1].start - ring_px, 0), min(window[1].stop + ring_px, width))
        around = labels[rows, cols]
        mask = (around == p + 1).view(np.uint8)
        ring = (cv2.dilate(mask, kernel) > 0) & (mask == 0)
        counts = np.bincount(around[ring].astype(np.intp), minlength=k + 1)[1 : k + 1]
        if counts.sum():
            shares[p] = counts / counts.sum()
    return shares


def object_hosts(
    planes: np.ndarray,
    areas: np.ndarray,
    centroids: np.ndarray,
    coverage: np.ndarray,
    neighbours: np.ndarray,
    max_height: float,
    min_inside: float,
    angle_deg: float,
) -> np.ndarray:
    """The larger plane each plane is an object on, if any.

    Plane ``p`` is an object on plane ``q`` when ``q`` has more pixels, their normals agree within
    ``angle_deg``, ``p``'s centroid stands in front of ``q`` (on the camera's side) by more than 0
    and at most ``max_height`` metres, and ``q`` holds ``p``: at least ``min_inside`` of ``p``'s
    pixels lie inside ``q``'s polygon (holes filled: a picture lies in the wall's outline, not
    on its pixels), or at least ``min_inside`` of the planes around ``p`` are ``q`` (a book at
    the desk's edge is not inside the desk's outline, but the desk is all around it).

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
        :func:`annotate_rgbd.cvat.from_masks.polygon_coverage`.
    neighbours : ndarray of float, shape (K, K)
        :func:`neighbour_shares`.
    max_height, min_inside, angle_deg : float

    Returns
    -------
    ndarray of intp, shape (K,)
        The host of each plane (0-based; of several, the largest), -1 for a plane that is no object.
    """
    k = len(areas)
    if k < 2:
        return np.full(k, -1, dtype=np.intp)
    planes = np.asarray(planes, dtype=np.float64)
    areas = np.asarray(areas)
    # height[p, q]: how far p's centroid stands in front of q's plane.
    height = centroids @ planes[:, :3].T + planes[:, 3][None, :]
    parallel = planes[:, :3] @ planes[:, :3].T >= np.cos(np.radians(angle_deg))
    larger = areas[None, :] > areas[:, None]
    inside = coverage.T / np.maximum(areas, 1)[:, None]  # [p, q]: share of p inside q's polygon
    held = (inside >= min_inside) | (np.asarray(neighbours) >= min_inside)
    on = parallel & larger & (height > 0) & (height <= max_height) & held
    host = np.argmax(np.where(on, areas[None, :], -1), axis=1)
    return np.where(on.any(axis=1), host, -1).astype(np.intp)


def shares_in_band(
    labels: np.ndarray, points: np.ndarray, planes: np.ndarray, hosts: np.ndarray, scales: np.ndarray,
    noise: NoiseSettings, boxes: list,
) -> np.ndarray:
    """The share of each object's pixels that lie within its host plane's noise band.

    An object a centimetre proud of its plane by the sensor's error, or thinner than the plane's
    band (a paper, a mouse pad, a strip of desk the sensor bends), is the plane to ``cvat2mask``:
    a polygon drawn over both keeps such pixels as the plane's.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Planes 1..K.
    points : ndarray of float, shape (H, W, 3)
        Camera-frame point of every pixel, metres.
    planes : ndarray of float, shape (K, 4)
        Unit normals.
    hosts : ndarray of int, shape (K,)
        :func:`object_hosts`.
    scales : ndarray of float, shape (K,)
        Each plane's noise scale (:func:`annotate_rgbd.propose.extent.plane_scales`).
    noise : NoiseSettings
        The band: ``clip(k * scale * sigma(z), floor, cap)``.
    boxes : list
        :func:`annotate_rgbd.cvat.pieces.label_boxes` of ``labels``.

    Returns
    -------
    ndarray of float64, shape (K,)
        0 for a plane that is no object.
    """
    shares = np.zeros(len(hosts))
    for p in np.flatnonzero(np.asarray(hosts) >= 0).tolist():
        q = int(hosts[p])
        if boxes[p] is None:
            continue
        box = points[boxes[p]]
        mine = box[labels[boxes[p]] == p + 1]
        distance = np.abs(mine @ np.asarray(planes[q, :3], dtype=np.float32) + np.float32(planes[q, 3]))
        shares[p] = np.mean(distance <= noise.scaled(float(scales[q])).band(mine[:, 2])) if len(mine) else 0.0
    return shares


def join_table(hosts: np.ndarray, part: np.ndarray) -> np.ndarray:
    """The relabelling table (labels 0..K) that gives each plane ``part`` selects to its host,
    following hosts that join their own host in turn.

    Parameters
    ----------
    hosts : ndarray of int, shape (K,)
        Host of each plane (0-based; -1: none).
    part : ndarray of bool, shape (K,)
        The planes that join their host.

    Returns
    -------
    ndarray of intp, shape (K + 1,)
    """
    table = np.arange(len(hosts) + 1)
    table[np.flatnonzero(part) + 1] = np.asarray(hosts)[part] + 1
    for _ in range(len(hosts)):  # hosts are larger than their objects: no cycles
        chained = table[table]
        if (chained == table).all():
            break
        table = chained
    return table


def ends_on_object(hosts: np.ndarray, part: np.ndarray) -> np.ndarray:
    """The planes of ``part`` whose chain of hosts ends on a plane that is itself an object and
    does not join (so is dropped): they are objects too, not part of a plane.

    Parameters
    ----------
    hosts : ndarray of int, shape (K,)
        Host of each plane (0-based; -1: none).
    part : ndarray of bool, shape (K,)
        The planes that would join their host.

    Returns
    -------
    ndarray of bool, shape (K,)
    """
    hosts, part = np.asarray(hosts), np.asarray(part, dtype=bool).copy()
    ends_dropped = np.zeros(len(hosts), dtype=bool)
    while part.any():
        end = join_table(hosts, part)[1:] - 1
        bad = part & (hosts[end] >= 0)
        if not bad.any():
            break
        ends_dropped |= bad
        part &= ~bad
    return ends_dropped

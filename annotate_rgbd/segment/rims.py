"""Rims: the pixels a plane gives up next to the edges of other surfaces.

Depth sensors are least reliable at depth edges: Kinect v1's correlation window and stereo
matching smear a nearer surface's depth a few pixels across its edge. So a plane gives up a thin
rim next to a surface standing *in front* of it inside its shape (the foot of a book on a table,
:func:`near_surfaces_in_front`), and next to a surface *behind* it (its own occluding edge, where
the smeared pixels beyond the edge carry the plane's depth: :func:`near_surfaces_behind`).
"""

from __future__ import annotations

from typing import Mapping

import cv2
import numpy as np

from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.geometry.noise import NoiseSettings
from .distances import band_image, signed_distances


def near_surfaces_in_front(in_front: np.ndarray, labels: np.ndarray, rim_pixels: int) -> np.ndarray:
    """The pixels of each plane's shape within ``rim_pixels`` of a surface in front of the plane.

    Where an object stands on a plane (a book on a table, a whiteboard on a wall), the foot of
    its sides lies within the plane's noise band: depth cannot tell those pixels from the plane,
    and a 7x7 window (:func:`window_scores`) straddling both surfaces cannot either. And depth
    sensors smear depth across the edge of a nearer surface (Kinect v1's correlation window,
    stereo matching): the plane's pixels next to it are the least reliable ones. So a plane
    gives up a thin rim around whatever stands in front of it inside its shape. Specks of noise
    beyond the band are not surfaces: only pixels in front of the plane that fill a 3x3 square
    (a morphological opening) count. A surface in front of one plane takes no rim from another
    plane's pixels: where two planes' shapes meet, each is judged against its own plane.

    Parameters
    ----------
    in_front : ndarray of bool, shape (H, W)
        Pixels with depth in a plane's shape whose 3-D point lies in front of that plane (on
        the camera's side) and off it.
    labels : ndarray of non-negative int, shape (H, W)
        The plane id of each pixel's shape (0 = none).
    rim_pixels : int
        Width of the rim (px, Euclidean; 0: nothing).

    Returns
    -------
    ndarray of bool, shape (H, W)
        Pixels of a shape within ``rim_pixels`` of a surface in front of the same shape's plane.
    """
    if rim_pixels <= 0:
        return np.zeros(labels.shape, dtype=bool)
    surfaces = cv2.morphologyEx(in_front.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)) > 0
    if not surfaces.any():
        return surfaces
    # Where three planes' surfaces meet within a rim, the middle one is missed.
    lowest, highest = ids_nearby(labels * surfaces, rim_pixels)
    return (labels > 0) & ((highest == labels) | (lowest == labels))


def ids_nearby(ids: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray]:
    """The lowest and the highest non-zero id within ``radius`` pixels (Euclidean) of each pixel.

    Two image-wide dilations, whatever the number of ids (a pixel near three or more ids sees
    only these two).

    Parameters
    ----------
    ids : ndarray of non-negative int, shape (H, W)
        0 = none.
    radius : int

    Returns
    -------
    lowest, highest : ndarray of int, shape (H, W)
        0 where no id lies within ``radius``; uint8 or uint16 when those hold every id, else int64.
    """
    disk = _disk(radius)
    top = int(ids.max(initial=0))
    # The narrowest type cv2.dilate takes that holds every id and top + 1 (float32: exact to 2^24).
    work = np.float32 if top + 1 >= 2**16 else (np.uint16 if top + 1 >= 2**8 else np.uint8)
    shapes = ids.astype(work, copy=False)
    highest = cv2.dilate(shapes, disk, borderValue=0)
    # The lowest id as the highest of top + 1 - id (0 stays 0), and back.
    present = shapes > 0
    flipped = cv2.dilate((work(top + 1) - shapes) * present, disk, borderValue=0)
    lowest = (work(top + 1) - flipped) * (flipped > 0)
    if work is np.float32:  # ids beyond uint16 (rare): back to integers
        return lowest.astype(np.int64), highest.astype(np.int64)
    return lowest, highest


def near_surfaces_behind(
    labels: np.ndarray, depth_m: np.ndarray, equations: Mapping[int, np.ndarray], camera: Camera,
    noise: NoiseSettings, rim_pixels: int,
) -> np.ndarray:
    """The pixels of each plane within ``rim_pixels`` of a surface behind the plane: its
    occluding edges.

    Where a plane ends in front of a farther surface (a desk's edge over the floor, a monitor
    before the wall), a depth sensor gives the farther surface's first pixels beyond the edge
    the plane's depth (Kinect v1's correlation window spans several pixels; stereo matching
    fattens the foreground the same way), so they pass the inlier test and growing takes them.
    The plane gives up its pixels within ``rim_pixels`` of the nearest pixels whose 3-D point
    lies behind it (on the far side from the camera) by more than the inlier band at their
    depth: what is left ends near the true edge. Specks beyond the band are not surfaces: only
    pixels behind the plane that fill a 3x3 square (a morphological opening) count, as for
    :func:`near_surfaces_in_front`. Missing depth is not a surface. A plane meeting another
    in a concave corner (a wall and the floor) has it in front, not behind, and loses nothing.
    Each plane is examined on its own window (its bounding box and the rim).

    Parameters
    ----------
    labels : ndarray of non-negative int, shape (H, W)
        Plane ids (0 = none), e.g. refined and grown.
    depth_m : ndarray of float32, shape (H, W)
        Depth in metres, NaN where invalid.
    equations : mapping of int to ndarray, shape (4,)
        Each plane's ``(a, b, c, d)``: unit normal towards the camera (``d > 0``), metres.
    camera : Camera
    noise : NoiseSettings
        The inlier band at each pixel's depth.
    rim_pixels : int
        Width of the rim (px, Euclidean; 0: nothing).

    Returns
    -------
    ndarray of bool, shape (H, W)
        The pixels of ``labels``'s planes within ``rim_pixels`` of a surface behind their plane.
    """
    rim = np.zeros(labels.shape, dtype=bool)
    if rim_pixels <= 0:
        return rim
    height, width = labels.shape
    disk = _disk(rim_pixels)
    margin = rim_pixels + 1  # the opening needs one pixel beyond the rim
    for plane_id, equation in equations.items():
        own = labels == plane_id
        x, y, w, h = cv2.boundingRect(own.view(np.uint8))
        if w == 0:
            continue
        top, left = max(y - margin, 0), max(x - margin, 0)
        window = (slice(top, min(y + h + margin, height)), slice(left, min(x + w + margin, width)))
        depth = depth_m[window]
        a, b, c, d = (np.float32(v) for v in equation)
        signed = signed_distances(depth, a, b, c, d, camera, (*window, height, width))
        with np.errstate(invalid="ignore"):
            behind = signed < -band_image(depth, noise)
        if not behind.any():
            continue
        surfaces = cv2.morphologyEx(behind.view(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
        near = cv2.dilate(surfaces, disk, borderValue=0) > 0
        rim[window] |= near & own[window]
    return rim


def _disk(radius: int) -> np.ndarray:
    """A Euclidean disk of ``radius`` pixels, as OpenCV's structuring element."""
    offsets = np.arange(-radius, radius + 1)
    return (offsets[:, None] ** 2 + offsets[None, :] ** 2 <= radius * radius).astype(np.uint8)

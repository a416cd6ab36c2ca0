"""Rims: the pixels a plane gives up next to a surface standing in front of it.

Depth sensors are least reliable at depth edges: Kinect v1's correlation window and stereo
matching smear a nearer surface's depth a few pixels across its edge, and the foot of an object
standing on a plane lies within the plane's band. So a plane gives up a thin rim next to a
surface standing in front of it inside its shape (:func:`near_surfaces_in_front`).
"""

from __future__ import annotations

import cv2
import numpy as np


def near_surfaces_in_front(in_front: np.ndarray, labels: np.ndarray, rim_pixels: int) -> np.ndarray:
    """The pixels of each plane's shape within ``rim_pixels`` of a surface in front of the plane.

    Where an object stands on a plane (a book on a table, a whiteboard on a wall), the foot of
    its sides lies within the plane's noise band: depth cannot tell those pixels from the plane,
    and a 7x7 window (:func:`annotate_rgbd.segment.refine.window_scores`) straddling both
    surfaces cannot either. And depth sensors smear depth across the edge of a nearer surface
    (Kinect v1's correlation window, stereo matching): the plane's pixels next to it are the
    least reliable ones. So a plane gives up a thin rim around whatever stands in front of it
    inside its shape. Specks of noise beyond the band are not surfaces: only pixels in front of
    the plane that fill a 3x3 square (a morphological opening) count. A surface in front of one
    plane takes no rim from another plane's pixels: where two planes' shapes meet, each is
    judged against its own plane.

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
    offsets = np.arange(-radius, radius + 1)
    disk = (offsets[:, None] ** 2 + offsets[None, :] ** 2 <= radius * radius).astype(np.uint8)
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

"""What a keyframe says a plane is not: the surfaces its labeller saw and left outside the outline.

A labeller's outline says where a plane ends. Where it ends against something depth tells apart
(an occluder far in front, the floor far below a table's edge), every frame's refinement finds
that end again. Where it ends against something depth cannot tell apart — a picture frame, a TV,
a magazine rack a few centimetres proud of a wall, the wall's own continuation behind a cabinet
that the labeller left out, a chair back beside a table — only the outline knows. A shape carried
to another frame by the poses lands a few pixels off (pose error, parallax between keyframes),
and a carried plane grows over what lies on it (:func:`annotate_rgbd.segment.grow.grow_connected`):
both would take those surfaces. So each keyframe also hands on **what it excluded**: the pixels
outside its outline whose depth lies within reach of its plane (inside the plane's band, or up to
``near`` in front of or behind it) and that connect to the outline through such pixels: the
surfaces touching the plane that the labeller saw and did not draw. Lifted onto the plane and
projected like the outline, they are taken from the carried plane on the other frames where that
keyframe is among the nearest (unless a nearer keyframe outlined them).

Pure functions of arrays: :func:`excluded_regions` on the keyframe's image, :func:`region_outlines`
to carry them as polygons.
"""

from __future__ import annotations

import cv2
import numpy as np

from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.geometry.noise import NoiseSettings
from annotate_rgbd.segment.distances import band_image, signed_distances


def excluded_regions(
    own: np.ndarray, depth_m: np.ndarray, plane: np.ndarray, camera: Camera, noise: NoiseSettings, near: float,
    margin: int,
) -> np.ndarray:
    """The pixels a keyframe's labeller saw on (or touching) a plane and left outside its outline.

    A pixel is excluded when it lies outside the outline (``own``), has depth, lies within
    ``max(band(z), near)`` of the plane (either side), is linked to the outline by an
    8-connected chain of such pixels, and lies more than ``margin`` pixels from the outline
    (``propagate.exclude_margin``, 0 by default: a margin leaves the carried plane a strip of
    what touches it, and on real frames that strip is more clutter than plane).

    Parameters
    ----------
    own : ndarray of bool, shape (H, W)
        The keyframe shape's pixels.
    depth_m : ndarray of float, shape (H, W)
        Depth in metres, NaN where invalid.
    plane : ndarray, shape (4,)
        The plane fitted under the shape, camera frame (unit normal).
    camera : Camera
    noise : NoiseSettings
        The inlier band (scaled by the plane's own noise).
    near : float
        Reach (m) beyond the band: surfaces standing up to this far off the plane that touch it.
    margin : int
        Pixels next to the outline that are never excluded.

    Returns
    -------
    ndarray of bool, shape (H, W)
    """
    own = np.asarray(own, dtype=bool)
    if not own.any():
        return np.zeros(own.shape, dtype=bool)
    depth = np.asarray(depth_m, dtype=np.float32)
    signed = signed_distances(depth, *(np.float32(v) for v in plane), camera)
    band = band_image(depth, noise)
    reach = np.maximum(band, np.float32(near))
    with np.errstate(invalid="ignore"):
        touching = np.isfinite(signed) & (np.abs(signed) <= reach) & ~own
    count, components, stats, _ = cv2.connectedComponentsWithStats(touching.view(np.uint8), connectivity=8)
    # The ring around the outline, on the outline's window (and a pixel round it).
    near_own = _window(own, 1)
    ring = cv2.dilate(own[near_own].view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
    linked = np.bincount(components[near_own][ring & touching[near_own]], minlength=count) > 0
    linked[0] = False
    excluded = np.zeros(own.shape, dtype=bool)
    if not linked.any():
        return excluded
    # Only the linked pieces' window is looked at again (the pieces' boxes, from their statistics).
    left, top = stats[linked, cv2.CC_STAT_LEFT].min(), stats[linked, cv2.CC_STAT_TOP].min()
    right = (stats[linked, cv2.CC_STAT_LEFT] + stats[linked, cv2.CC_STAT_WIDTH]).max()
    bottom = (stats[linked, cv2.CC_STAT_TOP] + stats[linked, cv2.CC_STAT_HEIGHT]).max()
    window = (slice(int(top), int(bottom)), slice(int(left), int(right)))
    found = linked[components[window]]
    if margin > 0 and found.any():
        # The outline's pixels within the margin of the window, dilated, cut back to it.
        height, width = own.shape
        outer = (slice(max(int(top) - margin, 0), min(int(bottom) + margin, height)),
                 slice(max(int(left) - margin, 0), min(int(right) + margin, width)))
        size = 2 * margin + 1
        disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
        grown = cv2.dilate(own[outer].view(np.uint8), disk).view(bool)
        found &= ~grown[int(top) - outer[0].start : int(bottom) - outer[0].start,
                        int(left) - outer[1].start : int(right) - outer[1].start]
    excluded[window] = found
    return excluded


def _window(mask: np.ndarray, pad: int) -> tuple[slice, slice]:
    """The box of a mask's pixels, ``pad`` pixels wider on every side (within the image)."""
    left, top, width, height = cv2.boundingRect(mask.view(np.uint8))
    rows, cols = mask.shape
    return (slice(max(top - pad, 0), min(top + height + pad, rows)),
            slice(max(left - pad, 0), min(left + width + pad, cols)))


def region_outlines(region: np.ndarray, min_pixels: int, tolerance: float) -> list[np.ndarray]:
    """The outer outlines of a region's connected pieces, as polygons in CVAT image coordinates.

    Parameters
    ----------
    region : ndarray of bool, shape (H, W)
    min_pixels : int
        Pieces with fewer pixels are left out.
    tolerance : float
        Largest distance (px) of the simplified outline from the traced one (Douglas-Peucker).

    Returns
    -------
    list of ndarray of float64, shape (V, 2)
        One polygon per piece (V >= 3), holes filled, through the centres of its border
        pixels (filled again, the piece loses at most part of its one-pixel border).
    """
    contours, _ = cv2.findContours(np.asarray(region, dtype=np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    outlines = []
    for contour in contours:
        if cv2.contourArea(contour) + 0.5 * cv2.arcLength(contour, True) < min_pixels:
            continue
        simple = cv2.approxPolyDP(contour, tolerance, True).reshape(-1, 2).astype(np.float64)
        if len(simple) < 3:
            continue
        outlines.append(simple + 0.5)
    return outlines

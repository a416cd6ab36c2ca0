"""Per-plane depth statistics and the rules that drop a plane from a frame."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from annotate_rgbd.geometry.camera import Camera, ray_grid
from annotate_rgbd.config.settings import FilterConfig

#: Reasons a plane is dropped from a frame, as written to the report.
INVALID_DEPTH = "invalid_depth"
TOO_FAR = "too_far"
TOO_FEW_POINTS = "too_few_points"
#: A plane carried by camera poses whose depth there is another surface (segment.refine).
NOT_WHERE_EXPECTED = "not_where_expected"
#: A plane whose valid depth spans no plane: on one pixel row or column (a strip of depth one
#: row high, the rest of the shape without depth), or on one line in space (segment.refine).
NO_PLANE = "no_plane"


@dataclass(frozen=True)
class PlaneStats:
    """Depth statistics of the planes drawn on one frame (one entry per plane id).

    Parameters
    ----------
    plane_ids : ndarray of int32
        The planes present on the label image, ascending.
    pixels : ndarray of int64
        Pixels of each plane after z-order (what the labeller's polygon covers and is on top).
    valid_pixels : ndarray of int64
        Of those, pixels with valid depth.
    mean_distance : ndarray of float64
        Mean Euclidean distance from the camera centre of the valid pixels, in metres
        (NaN where there are none).
    """

    plane_ids: np.ndarray
    pixels: np.ndarray
    valid_pixels: np.ndarray
    mean_distance: np.ndarray

    @property
    def invalid_ratio(self) -> np.ndarray:
        """Share of each plane's pixels without valid depth."""
        return 1.0 - self.valid_pixels / np.maximum(self.pixels, 1)


def plane_statistics(labels: np.ndarray, depth_m: np.ndarray, camera: Camera) -> PlaneStats:
    """Pixel counts and mean camera distance of every plane on a label image.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Plane ids, 0 = none.
    depth_m : ndarray of float, shape (H, W)
        Depth in metres, NaN where invalid.
    camera : Camera
        Intrinsics (the distance along a pixel's ray is depth times the ray's length at z = 1).

    Returns
    -------
    PlaneStats
    """
    return statistics_of_distances(labels, camera_distances(depth_m, camera), ~np.isnan(depth_m))


def camera_distances(depth_m: np.ndarray, camera: Camera) -> np.ndarray:
    """Each pixel's distance from the camera centre (float64 metres), 0 where the depth is invalid.

    ``fmax`` turns the NaN of invalid pixels into 0, so they add nothing to a sum; bincount sums
    in float64 and takes float64 weights several times faster than float32 ones.
    """
    return np.fmax(depth_m * ray_lengths(camera, *depth_m.shape), 0).astype(np.float64)


def statistics_of_distances(labels: np.ndarray, distance: np.ndarray, valid: np.ndarray) -> PlaneStats:
    """:func:`plane_statistics` from a frame's :func:`camera_distances` and valid-depth pixels
    (computed once for several label images of one frame).

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
    distance : ndarray of float64, shape (H, W)
        Distance of each pixel from the camera centre, metres, 0 where the depth is invalid.
    valid : ndarray of bool, shape (H, W)
        Pixels with valid depth.

    Returns
    -------
    PlaneStats
    """
    n = int(labels.max(initial=0)) + 1
    pixels = label_histogram(labels, n)
    valid_pixels = label_histogram(labels, n, where=valid)
    distance_sum = np.bincount(labels.ravel(), weights=distance.ravel(), minlength=n)
    plane_ids = np.flatnonzero(pixels[1:]) + 1
    pixels, valid_pixels, distance_sum = pixels[plane_ids], valid_pixels[plane_ids], distance_sum[plane_ids]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_distance = np.where(valid_pixels > 0, distance_sum / np.maximum(valid_pixels, 1), np.nan)
    return PlaneStats(plane_ids.astype(np.int32), pixels, valid_pixels, mean_distance)


def label_histogram(labels: np.ndarray, n: int, where: np.ndarray | None = None) -> np.ndarray:
    """Pixel count of every label 0..n-1 (of the pixels where ``where`` is true, if given).

    Parameters
    ----------
    labels : ndarray of non-negative int, shape (H, W)
    n : int
        Number of bins (> the largest label).
    where : ndarray of bool, shape (H, W), optional

    Returns
    -------
    ndarray of int64, shape (n,)
    """
    if labels.dtype == np.uint8:  # OpenCV's histogram is several times faster than bincount
        mask = None if where is None else where.view(np.uint8)
        counts = cv2.calcHist([labels], [0], mask, [256], [0, 256]).ravel()[:n]
        return np.rint(counts).astype(np.int64)
    selected = labels.ravel() if where is None else labels[where]
    return np.bincount(selected, minlength=n)[:n]


@lru_cache(maxsize=4)
def ray_lengths(camera: Camera, height: int, width: int) -> np.ndarray:
    """Length of each pixel's viewing ray at z = 1 (so that distance = depth x length).

    Returns
    -------
    ndarray of float32, shape (height, width)
        Read-only (cached: every frame of a sequence uses the same one).
    """
    ray_x, ray_y = ray_grid(camera, height, width, np.float32)
    ray = np.sqrt((ray_y**2)[:, None] + (ray_x**2)[None, :] + np.float32(1.0))
    ray.setflags(write=False)
    return ray


def drop_reasons(stats: PlaneStats, config: FilterConfig) -> list[str | None]:
    """Why each plane is dropped from the frame, or ``None`` when it is kept.

    The rules, checked in this order (the first that applies is the reason):

    * ``invalid_depth``: the share of pixels without valid depth exceeds ``max_invalid_ratio``;
    * ``too_few_points``: fewer than ``min_valid_pixels`` valid pixels remain to fit a plane;
    * ``too_far``: the mean camera distance of the valid pixels exceeds ``max_mean_distance``.

    Parameters
    ----------
    stats : PlaneStats
    config : FilterConfig

    Returns
    -------
    list of str or None
        One entry per plane of ``stats``.
    """
    reasons: list[str | None] = []
    for invalid, valid, distance in zip(stats.invalid_ratio, stats.valid_pixels, stats.mean_distance):
        if invalid > config.max_invalid_ratio:
            reasons.append(INVALID_DEPTH)
        elif valid < config.min_valid_pixels:
            reasons.append(TOO_FEW_POINTS)
        elif distance > config.max_mean_distance:
            reasons.append(TOO_FAR)
        else:
            reasons.append(None)
    return reasons

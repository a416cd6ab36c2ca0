"""Pinhole camera model: raw depth -> metres -> 3-D points, and 3-D points -> pixels.

Pixel centres sit at integer coordinates here (OpenCV / TUM convention): pixel ``(col, row)``
looks along the ray through ``((col - cx) / fx, (row - cy) / fy, 1)``. ``fy`` may be negative
(ICL-NUIM's TUM-format files use fy = -480 for a y-up camera frame).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np


@dataclass(frozen=True)
class Camera:
    """Intrinsics of the depth camera and the scale of its raw depth values.

    Parameters
    ----------
    fx, fy : float
        Focal lengths in pixels; either may be negative (flipped axis) but not zero.
    cx, cy : float
        Principal point in pixels.
    depth_scale : float
        Raw depth units per metre (5000 for TUM RGB-D and ICL-NUIM PNGs).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    depth_scale: float


def depth_to_metres(depth_raw: np.ndarray, depth_scale: float) -> np.ndarray:
    """Convert raw depth to metres, with NaN wherever the depth is invalid.

    Parameters
    ----------
    depth_raw : ndarray
        Raw depth image (any numeric dtype).
    depth_scale : float
        Raw units per metre.

    Returns
    -------
    ndarray of float32
        Depth in metres; zero, negative, NaN and infinite raw values become NaN.
    """
    metres = np.asarray(depth_raw, dtype=np.float32) / np.float32(depth_scale)
    metres[~(np.isfinite(metres) & (metres > 0))] = np.nan
    return metres


def backproject(
    cols: np.ndarray, rows: np.ndarray, depth_m: np.ndarray, camera: Camera
) -> np.ndarray:
    """3-D points in the camera frame for the given pixels.

    Parameters
    ----------
    cols, rows : ndarray, shape (N,)
        Pixel coordinates (column = x, row = y).
    depth_m : ndarray, shape (N,)
        Depth (the z coordinate) of each pixel in metres.
    camera : Camera
        Intrinsics.

    Returns
    -------
    ndarray of float64, shape (N, 3)
        ``(x, y, z)`` per pixel.
    """
    z = np.asarray(depth_m, dtype=np.float64)
    points = np.empty((z.size, 3), dtype=np.float64)
    points[:, 0] = (np.asarray(cols, dtype=np.float64) - camera.cx) * z / camera.fx
    points[:, 1] = (np.asarray(rows, dtype=np.float64) - camera.cy) * z / camera.fy
    points[:, 2] = z
    return points


@lru_cache(maxsize=16)
def ray_grid(camera: Camera, height: int, width: int, dtype=np.float64) -> tuple[np.ndarray, np.ndarray]:
    """The viewing rays of an image's pixels at depth 1: pixel ``(col, row)`` looks along
    ``(ray_x[col], ray_y[row], 1)``, so its 3-D point is ``z`` times that (a pinhole ray's x
    depends on the column only, its y on the row only).

    Parameters
    ----------
    camera : Camera
        Intrinsics (``fx``, ``fy`` may be negative).
    height, width : int
        Image size.
    dtype : numpy float type
        The type the rays are computed in: ``float64`` (then rounded to ``float32`` by callers
        that store them so), or ``float32`` for float32 images (the intrinsics rounded to float32
        first; the two can differ in the last bit).

    Returns
    -------
    ray_x : ndarray of ``dtype``, shape (W,), read-only
        ``(col - cx) / fx``.
    ray_y : ndarray of ``dtype``, shape (H,), read-only
        ``(row - cy) / fy``. Cached: every frame of a sequence shares them.
    """
    kind = np.dtype(dtype).type
    ray_x = (np.arange(width, dtype=kind) - kind(camera.cx)) / kind(camera.fx)
    ray_y = (np.arange(height, dtype=kind) - kind(camera.cy)) / kind(camera.fy)
    ray_x.flags.writeable = ray_y.flags.writeable = False
    return ray_x, ray_y


def project(points: np.ndarray, camera: Camera) -> np.ndarray:
    """Pixel coordinates of 3-D points in the camera frame (inverse of :func:`backproject`).

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        Points with z > 0.
    camera : Camera
        Intrinsics.

    Returns
    -------
    ndarray of float64, shape (N, 2)
        ``(col, row)`` per point, pixel centres at integers.
    """
    points = np.asarray(points, dtype=np.float64)
    z = points[:, 2]
    return np.stack(
        [points[:, 0] * camera.fx / z + camera.cx, points[:, 1] * camera.fy / z + camera.cy], axis=1
    )

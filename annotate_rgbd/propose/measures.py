"""What a proposed plane's polygon measures: the pixels it fills and their fit with the plane's
(:func:`polygon_fit`), the surface it covers on the plane (:func:`surface_areas`), and the
planes' pixel counts (:func:`label_counts`)."""

from __future__ import annotations

import numpy as np

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.segment.rasterize import fill_window, shape_mask


def polygon_fit(labels: np.ndarray, polygons: list, unlimited: list, filled: list | None = None,
                areas: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """How well each plane's polygon fits its pixels, on the pixels ``cvat2mask`` fills
    (:func:`annotate_rgbd.segment.rasterize.shape_mask`), and what the vertex budget cost: the
    IoU of the polygon at the tolerance alone less the polygon's, both filled as
    :func:`annotate_rgbd.segment.rasterize.fill_window` fills them (an outline of hundreds of
    vertices fills 30 times faster so; the difference is within a few thousandths of the exact one).

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Planes 1..K.
    polygons : list of ndarray, shape (V, 2)
        The polygon of each plane.
    unlimited : list of (ndarray or None)
        Each plane's polygon at the tolerance alone, where the budget stopped it earlier.
    filled : list of (int, int, ndarray of bool), optional
        ``fill_window`` of each polygon, when already drawn.
    areas : ndarray of int, shape (K,), optional
        Pixels of each plane, when already counted.

    Returns
    -------
    pixels : ndarray of int64, shape (K,)
        Pixels inside each polygon.
    iou : ndarray of float64, shape (K,)
        IoU of the polygon's pixels with the plane's.
    cost : ndarray of float64, shape (K,)
        IoU of the polygon at the tolerance alone minus ``iou``; NaN where the budget did not
        stop the simplification.
    """
    areas = label_counts(labels, len(polygons)) if areas is None else areas

    def fit(k: int, window: tuple) -> tuple[int, float]:
        top, left, inside_polygon = window
        rows, cols = inside_polygon.shape
        inside = np.count_nonzero((labels[top : top + rows, left : left + cols] == k + 1) & inside_polygon)
        pixels = np.count_nonzero(inside_polygon)
        return pixels, inside / max(pixels + int(areas[k]) - inside, 1)

    pixels, iou = np.zeros(len(polygons), dtype=np.int64), np.zeros(len(polygons))
    cost = np.full(len(polygons), np.nan)
    for k, polygon in enumerate(polygons):
        pixels[k], iou[k] = fit(k, shape_mask(Shape("polygon", polygon), *labels.shape))
        if unlimited[k] is not None:
            drawn = fill_window(polygon, *labels.shape) if filled is None else filled[k]
            cost[k] = fit(k, fill_window(unlimited[k], *labels.shape))[1] - fit(k, drawn)[1]
    return pixels, iou, cost


def label_counts(labels: np.ndarray, n: int) -> np.ndarray:
    """Pixels of each label 1..n (``np.bincount(labels.ravel())[1:n + 1]``, one comparison per
    label: several times faster for the few labels of a frame).

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
    n : int

    Returns
    -------
    ndarray of int64, shape (n,)
    """
    if n > 64:
        return np.bincount(labels.ravel(), minlength=n + 1)[1 : n + 1].astype(np.int64)
    return np.array([np.count_nonzero(labels == k) for k in range(1, n + 1)], dtype=np.int64)


def surface_areas(windows: list, planes: np.ndarray, camera: Camera) -> np.ndarray:
    """Area of each plane inside its outline, square metres: what the polygon covers on the
    plane, whether or not the sensor returned depth there (a black screen's depth is speckled).

    A pixel looking along ``r = ((u - cx) / fx, (v - cy) / fy, 1)`` meets the plane ``n . X + d
    = 0`` at depth ``z = d / |n . r|`` and covers ``z**2 / (|fx fy| |n . r|)`` of it (``z**2 /
    |fx fy|`` where the plane faces the camera; more as it turns away, counted up to grazing
    rays at ``|n . r| = 0.1``).

    Parameters
    ----------
    windows : list of (int, int, ndarray of bool)
        The filled outline of plane ``k`` at position ``k - 1`` as ``(top, left, window)``.
    planes : ndarray of float, shape (K, 4)
        Unit normals, ``d > 0``.
    camera : Camera

    Returns
    -------
    ndarray of float64, shape (K,)
    """
    areas = np.zeros(len(planes))
    for k, (top, left, window) in enumerate(windows):
        if not window.any():
            continue
        a, b, c, d = np.asarray(planes[k], dtype=np.float64)
        # |n . r| on the window's rows and columns, then at its pixels in raster order.
        across = a * (np.arange(left, left + window.shape[1]) - camera.cx) / camera.fx
        down = b * (np.arange(top, top + window.shape[0]) - camera.cy) / camera.fy
        inverse = np.reciprocal(np.maximum(np.abs(across[None, :] + down[:, None] + c)[window], 0.1))
        cubes = inverse * inverse
        cubes *= inverse  # not ** -3.0: a general power is several times slower
        areas[k] = d * d / abs(camera.fx * camera.fy) * np.sum(cubes)
    return areas

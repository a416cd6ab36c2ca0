"""Each proposed plane's pixels: what lies on it, within its own noise, inside its outline.

The detector assigns pixels with bands of the published noise model (``band_k * sigma(z)``). Real
sensors are noisier than their published axial noise (Kinect depth distortion, stereo ripples:
up to ``ransac.max_noise_scale`` times), so a real desk comes out speckled and
frayed at its far end, short of the plane a labeller would outline. As ``cvat2mask`` does for a
drawn polygon, each plane's noise is scaled by its own residuals
(:func:`annotate_rgbd.geometry.noise.noise_scale`), and the pixels inside the plane's outline
(holes filled: what a labeller's polygon would hold) are given to the nearest plane whose scaled
band holds them.
"""

from __future__ import annotations

import cv2
import numpy as np

from annotate_rgbd.config.masks import RansacConfig
from annotate_rgbd.cvat.from_masks import MIN_PIECE_PX, to_image, trace_pieces
from annotate_rgbd.cvat.pieces import kept_pieces, label_boxes
from annotate_rgbd.geometry.noise import NoiseSettings, noise_scale
from annotate_rgbd.segment.rasterize import fill_window

#: Points per plane the noise scale is estimated on (every n-th pixel): the median of a few
#: thousand residuals varies by a few per cent, well under ``ransac.min_noise_scale``.
SCALE_POINTS = 4000


def plane_scales(
    labels: np.ndarray, points: np.ndarray, planes: np.ndarray, noise: NoiseSettings, ransac: RansacConfig | None = None,
    boxes: list | None = None,
) -> np.ndarray:
    """How much noisier than the model each plane's pixels are, as ``cvat2mask``'s fits find it.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Planes 1..K (every labelled pixel has valid depth).
    points : ndarray of float, shape (H, W, 3)
        Camera-frame point of every pixel, metres.
    planes : ndarray of float, shape (K, 4)
    noise : NoiseSettings
    ransac : RansacConfig, optional
        Its ``min_noise_scale`` and ``max_noise_scale``, as ``cvat2mask`` uses them (defaults).
    boxes : list, optional
        :func:`annotate_rgbd.cvat.pieces.label_boxes` of ``labels`` for labels 1..K, when known.

    Returns
    -------
    ndarray of float64, shape (K,)
        1 when the model fits; at most ``ransac.max_noise_scale``.
    """
    ransac = RansacConfig() if ransac is None else ransac
    labels = np.asarray(labels)
    width = labels.shape[1]
    cloud = points.reshape(-1, 3)
    scales = np.ones(len(planes))
    for k, box in enumerate(label_boxes(labels, len(planes)) if boxes is None else boxes):
        if box is None:
            members = np.zeros(0, dtype=np.intp)
        else:
            # The label's pixels in raster order, found in its box.
            inside = np.flatnonzero(labels[box] == k + 1)
            inside = inside[:: max(len(inside) // SCALE_POINTS, 1)]
            rows, cols = np.divmod(inside, box[1].stop - box[1].start)
            members = (rows + box[0].start) * width + (cols + box[1].start)
        scale = 1.0
        for _ in range(2):  # the first estimate sees a band truncated at the model's k sigma
            found = noise_scale(cloud[members], planes[k], noise.scaled(scale))
            if found < (ransac.min_noise_scale if scale == 1.0 else 1.02):
                break
            scale = min(scale * found, ransac.max_noise_scale)
        scales[k] = scale
    return scales


def assign_in_outlines(
    points: np.ndarray, planes: np.ndarray, windows: list, scales: np.ndarray, noise: NoiseSettings, behind: float = 1.0,
) -> np.ndarray:
    """Give each pixel inside a plane's outline to the nearest such plane whose band holds it.

    Parameters
    ----------
    points : ndarray of float, shape (H, W, 3)
        Camera-frame point of every pixel, metres (NaN where the depth is invalid).
    planes : ndarray of float, shape (K, 4)
        Unit normals.
    windows : list of (int, int, ndarray of bool)
        The filled outline of plane ``k`` at position ``k - 1`` as ``(top, left, window)``.
    scales : ndarray of float, shape (K,)
        Each plane's noise scale (:func:`plane_scales`).
    noise : NoiseSettings
        The band: ``clip(k * scale * sigma(z), floor, cap)``.
    behind : float
        The band behind a plane (away from the camera) is this many times wider, as
        ``cvat2mask``'s (``refine.behind_band``).

    Returns
    -------
    ndarray of uint8 (K < 256) or int32, shape (H, W)
        Plane 1..K of each pixel, 0 for none.
    """
    height, width = points.shape[:2]
    labels = np.zeros((height, width), dtype=np.uint8 if len(planes) < 256 else np.int32)
    best = np.full((height, width), np.inf, dtype=np.float32)
    for k, (top, left, window) in enumerate(windows):
        rows, cols = window.shape
        if window.size == 0:
            continue
        inside = points[top : top + rows, left : left + cols]
        signed = inside @ planes[k, :3].astype(np.float32) + np.float32(planes[k, 3])  # > 0: the camera's side
        distance = np.abs(signed)
        band = noise.scaled(float(scales[k])).band(inside[..., 2]).astype(np.float32)
        with np.errstate(invalid="ignore"):
            take = window & (signed <= band) & (signed >= band * np.float32(-behind))
            take &= distance < best[top : top + rows, left : left + cols]
        np.copyto(labels[top : top + rows, left : left + cols], k + 1, where=take)
        np.copyto(best[top : top + rows, left : left + cols], distance, where=take)
    return labels


def piece_windows(labels: np.ndarray, tolerance_px: float, min_piece: int = MIN_PIECE_PX, boxes: list | None = None) -> list:
    """Each label's extent: the pixels inside the simplified outline of any of its pieces of at
    least ``min_piece`` pixels (the largest when none is), holes filled.

    What the label's CVAT polygon (:func:`annotate_rgbd.cvat.from_masks.outline_planes`) covers,
    less its corridors, in a fraction of the time on speckled detector masks: the pieces are
    outlined one by one (Douglas-Peucker, ``cv2.approxPolyDP``) and filled by
    :func:`annotate_rgbd.segment.rasterize.fill_window`.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        0 = none, else 1..K, each present.
    tolerance_px : float
    min_piece : int
    boxes : list, optional
        :func:`annotate_rgbd.cvat.pieces.label_boxes` of ``labels``, when known.

    Returns
    -------
    list of (int, int, ndarray of bool)
        ``(top, left, window)`` of label ``k`` at position ``k - 1``.
    """
    height, width = labels.shape
    windows = []
    for label, box in enumerate(label_boxes(labels) if boxes is None else boxes, start=1):
        if box is None:
            windows.append((0, 0, np.zeros((0, 0), dtype=bool)))
            continue
        top, left = box[0].start, box[1].start
        pieces = []
        for contour in trace_pieces(kept_pieces(labels[box] == label, min_piece)[0]):
            simple = cv2.approxPolyDP(contour, 2.0 * tolerance_px, closed=True)
            pieces.append(fill_window(to_image(simple if len(simple) >= 3 else contour, left, top), height, width))
        low = min(p[0] for p in pieces), min(p[1] for p in pieces)
        high = max(p[0] + p[2].shape[0] for p in pieces), max(p[1] + p[2].shape[1] for p in pieces)
        window = np.zeros((high[0] - low[0], high[1] - low[1]), dtype=bool)
        for row, col, piece in pieces:
            window[row - low[0] : row - low[0] + piece.shape[0], col - low[1] : col - low[1] + piece.shape[1]] |= piece
        windows.append((low[0], low[1], window))
    return windows

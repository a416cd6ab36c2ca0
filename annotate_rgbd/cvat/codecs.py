"""CVAT's geometry encodings: mask run-length encoding and rotated boxes (pure numpy)."""

from __future__ import annotations

import numpy as np


def rotated_box_corners(corners: np.ndarray, rotation: float) -> np.ndarray:
    """The four corners of a CVAT box turned by ``rotation`` degrees about its centre.

    Parameters
    ----------
    corners : ndarray, shape (2, 2)
        ``[[xtl, ytl], [xbr, ybr]]`` before rotation.
    rotation : float
        Degrees, clockwise on screen (image y points down), as CVAT stores it.

    Returns
    -------
    ndarray of float64, shape (4, 2)
        Top-left, top-right, bottom-right, bottom-left corners after rotation.
    """
    (x0, y0), (x1, y1) = np.asarray(corners, dtype=np.float64)
    box = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    centre = box.mean(axis=0)
    angle = np.radians(rotation)
    turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    return (box - centre) @ turn.T + centre


def decode_rle(runs: np.ndarray, width: int, height: int) -> np.ndarray:
    """Decode CVAT's mask RLE into a bitmap.

    Parameters
    ----------
    runs : ndarray of int
        Run lengths over the ``width x height`` box in row-major order, alternating and
        starting with unset pixels; they must add up to ``width * height``.
    width, height : int
        Size of the mask's box.

    Returns
    -------
    ndarray of bool, shape (height, width)
    """
    runs = np.asarray(runs, dtype=np.int64)
    if np.any(runs < 0) or runs.sum() != width * height:
        raise ValueError(f"RLE runs add up to {runs.sum()}, not {width} x {height}")
    values = np.arange(len(runs)) % 2 == 1
    return np.repeat(values, runs).reshape(height, width)


def encode_rle(bitmap: np.ndarray) -> np.ndarray:
    """Encode a bitmap as CVAT's mask RLE (inverse of :func:`decode_rle`).

    Parameters
    ----------
    bitmap : ndarray of bool, shape (height, width)

    Returns
    -------
    ndarray of int64
        Run lengths in row-major order, starting with unset pixels (possibly a zero run).
    """
    flat = np.asarray(bitmap, dtype=bool).ravel()
    changes = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    runs = np.diff(np.concatenate([[0], changes, [flat.size]]))
    if flat.size and flat[0]:
        runs = np.concatenate([[0], runs])
    return runs.astype(np.int64)

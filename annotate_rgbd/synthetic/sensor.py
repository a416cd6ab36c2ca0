"""The depth sensor: Kinect-like axial noise, missing depth (glass, depth discontinuities,
small holes), the range limits and quantisation to raw units."""

from __future__ import annotations

import cv2
import numpy as np

#: Kinect range: no depth nearer than this or farther than ``MAX_DEPTH`` (metres).
MIN_DEPTH = 0.4
MAX_DEPTH = 5.0


def kinect_noise_sigma(depth: np.ndarray) -> np.ndarray:
    """Axial noise standard deviation of a Kinect at ``depth`` metres (Nguyen et al. 2012).

    Parameters
    ----------
    depth : ndarray
        Metres.

    Returns
    -------
    ndarray
        ``0.0012 + 0.0019 * (depth - 0.4) ** 2`` metres.
    """
    return 0.0012 + 0.0019 * (depth - 0.4) ** 2


def sensor_depth(
    depth: np.ndarray,
    valid_probability: np.ndarray,
    rng: np.random.Generator,
    *,
    depth_scale: float,
    hole_rate: float = 8.0,
) -> np.ndarray:
    """Turn a clean depth image into what a Kinect-like sensor records.

    Adds axial Gaussian noise (:func:`kinect_noise_sigma`), drops pixels at random where
    ``valid_probability`` is below 1 (glass), drops about half of the pixels next to depth
    discontinuities, punches small elliptic holes, removes depth outside
    [``MIN_DEPTH``, ``MAX_DEPTH``] and quantises.

    Parameters
    ----------
    depth : ndarray of float, shape (H, W)
        Clean z depth in metres, 0 where nothing is seen.
    valid_probability : ndarray of float, shape (H, W)
        Chance that a pixel returns depth at all.
    rng : numpy.random.Generator
    depth_scale : float
        Raw units per metre.
    hole_rate : float
        Mean number of holes per 640 x 480 pixels.

    Returns
    -------
    ndarray of uint16, shape (H, W)
        Raw depth, 0 = missing.
    """
    height, width = depth.shape
    noisy = depth + rng.standard_normal(depth.shape, dtype=np.float32) * kinect_noise_sigma(depth)
    valid = (depth >= MIN_DEPTH) & (noisy >= MIN_DEPTH) & (noisy <= MAX_DEPTH)
    valid &= rng.random(depth.shape, dtype=np.float32) < valid_probability

    # Discontinuities: a jump of more than 5 % between 4-neighbours, dilated by one pixel.
    jump_x = np.abs(np.diff(depth, axis=1)) > 0.05 * np.minimum(depth[:, 1:], depth[:, :-1]) + 1e-6
    jump_y = np.abs(np.diff(depth, axis=0)) > 0.05 * np.minimum(depth[1:], depth[:-1]) + 1e-6
    edge = np.zeros(depth.shape, dtype=bool)
    edge[:, 1:] |= jump_x
    edge[:, :-1] |= jump_x
    edge[1:] |= jump_y
    edge[:-1] |= jump_y
    grown = edge.copy()
    grown[1:] |= edge[:-1]
    grown[:-1] |= edge[1:]
    grown[:, 1:] |= edge[:, :-1]
    grown[:, :-1] |= edge[:, 1:]
    edge_rows, edge_cols = np.nonzero(grown)
    dropped = rng.random(edge_rows.size) < 0.5
    valid[edge_rows[dropped], edge_cols[dropped]] = False

    # Small elliptic holes, sized relative to a 640-pixel-wide image.
    scale = width / 640.0
    n_holes = rng.poisson(hole_rate * width * height / (640 * 480))
    centres = rng.random((n_holes, 2)) * (width, height)
    radii = rng.uniform(1.5, 6.0, (n_holes, 2)) * scale + 0.5
    angles = rng.uniform(0.0, 180.0, n_holes)
    holes = np.zeros(depth.shape, dtype=np.uint8)
    for (x, y), (rx, ry), angle in zip(centres, radii, angles):
        # cv2 draws with 4 fractional bits: integer coordinates in units of 1/16 pixel.
        cv2.ellipse(holes, (int(x * 16), int(y * 16)), (int(rx * 16), int(ry * 16)), angle, 0, 360,
                    1, -1, cv2.LINE_8, 4)
    valid &= holes == 0

    raw = np.rint(noisy * np.float32(depth_scale))  # float32 resolves ~0.002 raw units at 5 m
    raw[~valid] = 0
    return np.clip(raw, 0, 65535).astype(np.uint16)


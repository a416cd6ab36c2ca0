"""Organised point cloud and the planarity of its cells (the first stage of the detector).

The image is cut into square cells; each cell gets a plane by PCA of its valid points. All
cells are fitted at once: with ``x = z * ray_x[col]`` and ``y = z * ray_y[row]``, every sum
over a cell's points is a sum of ``z**p * ray_x**i * ray_y**j``, which two batched matrix
products (along the cells' rows, then their columns) give for every cell at once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from annotate_rgbd.geometry.camera import Camera, ray_grid
from annotate_rgbd.geometry.planes import fit_planes, residual_ms

NoiseModel = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class CloudCells:
    """The point cloud and per-cell plane fits of one depth frame.

    The point of pixel ``(r, c)`` is ``depth[r, c] * (ray_x[c], ray_y[r], 1)``. ``C = rows *
    cols`` cells in raster order; the cell of pixel ``(r, c)`` is ``(min(r // cell_px, rows -
    1), min(c // cell_px, cols - 1))`` (pixels of a margin too thin for a whole cell belong to
    the last cell of their row or column for refinement, but take no part in the cell fits).

    Attributes
    ----------
    depth : ndarray of float32, shape (H, W)
        Depth in metres, NaN where invalid.
    ray_x : ndarray of float32, shape (W,)
        ``x / z`` of each column's ray.
    ray_y : ndarray of float32, shape (H,)
        ``y / z`` of each row's ray.
    sigma : ndarray of float32, shape (H, W)
        Noise standard deviation at each pixel's depth in metres (NaN where invalid).
    cell_px : int
        Cell side in pixels.
    grid : tuple of int
        ``(rows, cols)`` of the cell grid.
    count : ndarray of int, shape (C,)
        Valid pixels per cell.
    mean : ndarray of float64, shape (C, 3)
        Centroid of each cell's points (NaN for an empty cell).
    scatter : ndarray of float64, shape (C, 3, 3)
        Sum of outer products of the centred points.
    normal : ndarray of float64, shape (C, 3)
        Unit normal of the cell's plane, oriented towards the camera.
    offset : ndarray of float64, shape (C,)
        ``d`` of the plane ``normal . p + d = 0`` (positive for a plane facing the camera).
    mse : ndarray of float64, shape (C,)
        Mean squared distance of the cell's points to its plane (smallest eigenvalue / count).
    cell_sigma : ndarray of float64, shape (C,)
        Noise standard deviation at the cell's mean depth.
    half_width : ndarray of float64, shape (C,)
        Half-width of the cell's points across their narrower in-plane direction in metres,
        ``sqrt(3 * lambda_2 / count)`` (lambda_2 the middle eigenvalue of the scatter; exact
        for evenly spread points).
    planar : ndarray of bool, shape (C,)
        Cells with enough valid pixels and a residual within the noise bound.
    """

    depth: np.ndarray
    ray_x: np.ndarray
    ray_y: np.ndarray
    sigma: np.ndarray
    cell_px: int
    grid: tuple[int, int]
    count: np.ndarray
    mean: np.ndarray
    scatter: np.ndarray
    normal: np.ndarray
    offset: np.ndarray
    mse: np.ndarray
    cell_sigma: np.ndarray
    half_width: np.ndarray
    planar: np.ndarray


def cloud_cells(
    depth_m: np.ndarray,
    camera: Camera,
    cell_px: int,
    noise: NoiseModel,
    planar_k: float,
    min_valid_fraction: float,
) -> CloudCells:
    """Back-project a depth image and fit a plane to every cell.

    Parameters
    ----------
    depth_m : ndarray of float, shape (H, W)
        Depth in metres, NaN (or <= 0) where invalid.
    camera : Camera
        Intrinsics.
    cell_px : int
        Cell side in pixels; the image must hold at least one cell.
    noise : callable
        ``sigma(z)``: axial noise standard deviation in metres at depth ``z`` (elementwise).
    planar_k : float
        A cell is planar when its RMS plane residual is at most ``planar_k * sigma``.
    min_valid_fraction : float
        Share of valid pixels a cell needs to be tested.

    Returns
    -------
    CloudCells
    """
    height, width = depth_m.shape
    rows, cols = height // cell_px, width // cell_px
    if rows == 0 or cols == 0:
        raise ValueError(f"a {height} x {width} depth image holds no {cell_px} x {cell_px} cell")
    z = np.asarray(depth_m, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        # NaN stays NaN; zero and negative become NaN (depth_to_metres leaves none: a copy then)
        z = np.where(z > 0, z, np.float32(np.nan)) if (z <= 0).any() else z.copy()
    ray_x, ray_y = (ray.astype(np.float32) for ray in ray_grid(camera, height, width))
    sigma = np.asarray(noise(z), dtype=np.float32)

    count, mean, scatter = cell_sums(z, ray_x, ray_y, rows, cols, cell_px)

    planes, eigenvalues = fit_planes(mean, scatter)
    normal, offset = np.ascontiguousarray(planes[:, :3]), planes[:, 3].copy()
    mse = residual_ms(count, eigenvalues)
    cell_sigma = np.asarray(noise(mean[:, 2]), dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        half_width = np.sqrt(3 * np.maximum(eigenvalues[:, 1], 0) / count)
        enough = (count >= min_valid_fraction * cell_px * cell_px) & (count >= 3)
        planar = enough & (mse <= (planar_k * cell_sigma) ** 2) & (half_width > 0)
    return CloudCells(
        depth=z,
        ray_x=ray_x,
        ray_y=ray_y,
        sigma=sigma,
        cell_px=cell_px,
        grid=(rows, cols),
        count=count,
        mean=mean,
        scatter=scatter,
        normal=normal,
        offset=offset,
        mse=mse,
        cell_sigma=cell_sigma,
        half_width=half_width,
        planar=planar,
    )


def cell_sums(
    z: np.ndarray, ray_x: np.ndarray, ray_y: np.ndarray, rows: int, cols: int, cell_px: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Point count, centroid and centred scatter matrix of the valid points of every cell.

    Parameters
    ----------
    z : ndarray of float32, shape (H, W)
        Depth, metres, NaN where invalid.
    ray_x, ray_y : ndarray of float32, shapes (W,), (H,)
        The pixels' rays (:func:`annotate_rgbd.geometry.camera.ray_grid`).
    rows, cols, cell_px : int
        The cell grid (pixels beyond ``rows * cell_px``, ``cols * cell_px`` take no part).

    Returns
    -------
    count : ndarray of int64, shape (rows * cols,)
    mean : ndarray of float64, shape (rows * cols, 3)
        NaN for a cell without valid points.
    scatter : ndarray of float64, shape (rows * cols, 3, 3)
        Zero for a cell without valid points.
    """
    crop = z[: rows * cell_px, : cols * cell_px]
    valid = np.isfinite(crop)
    # Raw sums in float64: the centred scatter (millimetre residuals of points metres away)
    # keeps about 9 significant digits after the subtraction.
    images = np.empty((3, rows * cell_px, cols * cell_px))  # z**0 (valid), z, z**2
    images[0] = valid
    np.copyto(images[1], crop)
    images[1][~valid] = 0
    np.multiply(images[1], images[1], out=images[2])
    rx = ray_x[: cols * cell_px].astype(np.float64).reshape(cols, cell_px)
    ry = ray_y[: rows * cell_px].astype(np.float64).reshape(rows, cell_px)
    across = np.stack([np.ones_like(rx), rx, rx * rx], axis=-1)  # (cols, cell_px, 3)
    down = np.stack([np.ones_like(ry), ry, ry * ry], axis=1)  # (rows, 3, cell_px)
    # Along each cell's rows first (contiguous image rows), then along its columns:
    # sums[p, cell, i, j] = sum over the cell of z**p * ray_y**i * ray_x**j.
    along = np.matmul(down, images.reshape(3, rows, cell_px, cols * cell_px))  # (3, rows, 3, W)
    sums = np.matmul(along.reshape(3, rows, 3, cols, cell_px).transpose(0, 1, 3, 2, 4), across)
    sums = sums.reshape(3, rows * cols, 3, 3)  # cells in raster order
    count = np.rint(sums[0, :, 0, 0]).astype(np.int64)
    first, second = sums[1], sums[2]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.stack([first[:, 0, 1], first[:, 1, 0], first[:, 0, 0]], axis=1) / count[:, None]
    raw = np.empty((rows * cols, 3, 3))
    # x x: z^2 rx^2; y y: z^2 ry^2; z z: z^2; x y: z^2 rx ry; x z: z^2 rx; y z: z^2 ry.
    for (i, j), (a, b) in {(0, 0): (0, 2), (1, 1): (2, 0), (2, 2): (0, 0), (0, 1): (1, 1), (0, 2): (0, 1), (1, 2): (1, 0)}.items():
        raw[:, i, j] = raw[:, j, i] = second[:, a, b]
    centre = np.nan_to_num(mean)
    scatter = raw - count[:, None, None] * centre[:, :, None] * centre[:, None, :]
    return count, mean, scatter

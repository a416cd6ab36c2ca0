"""Region growing of coplanar cells, and merging of coplanar segments, on the cell grid.

A set of cells is summarised by the raw sums over its points (:func:`cell_totals`: count, sum of
the points, sum of their outer products, sum of the noise variances), which add up when sets are
joined; its least-squares plane follows exactly (:func:`totals_moments`,
:func:`annotate_rgbd.geometry.planes.fit_planes`). The grid holds a few hundred cells, so growing
walks it cell by cell; every test against a region's plane is evaluated for all cells at once.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from annotate_rgbd.config.propose import DetectorConfig
from annotate_rgbd.geometry.planes import Moments, fit_planes, mean_squared_distance, moments_from_sums
from .cells import CloudCells

#: Columns of a row of totals: the number of points, the sum of the points (3), the sum of
#: their outer products about the camera centre (9, row-major) and the sum of ``sigma(z)**2``.
COUNT, FIRST, SECOND, NOISE = 0, slice(1, 4), slice(4, 13), 13
TOTALS_COLUMNS = 14


def cell_totals(cells: CloudCells) -> np.ndarray:
    """The totals of every cell's valid points (cells count their noise at the cell's depth).

    Returns
    -------
    ndarray of float64, shape (C, 14)
        One row per cell, columns as :data:`COUNT`, :data:`FIRST`, :data:`SECOND`, :data:`NOISE`.
    """
    count = cells.count.astype(np.float64)
    mean = np.nan_to_num(cells.mean)
    second = cells.scatter + count[:, None, None] * mean[:, :, None] * mean[:, None, :]
    noise = count * np.nan_to_num(cells.cell_sigma) ** 2
    return np.concatenate([count[:, None], mean * count[:, None], second.reshape(-1, 9), noise[:, None]], axis=1)


def group_totals(totals: np.ndarray, groups: np.ndarray, n_groups: int) -> np.ndarray:
    """Add up cell totals per group.

    Parameters
    ----------
    totals : ndarray of float64, shape (C, 14)
        Per-cell totals (:func:`cell_totals`).
    groups : ndarray of int, shape (C,)
        Group of each cell in ``[0, n_groups)``, or -1 for none.
    n_groups : int

    Returns
    -------
    ndarray of float64, shape (n_groups, 14)
    """
    keep = groups >= 0
    out = np.zeros((n_groups, totals.shape[1]), dtype=np.float64)
    np.add.at(out, groups[keep], totals[keep])
    return out


def totals_moments(totals: np.ndarray) -> Moments:
    """The :class:`~annotate_rgbd.geometry.planes.Moments` of sets given by their totals, shape (K, 14)."""
    return moments_from_sums(totals[:, COUNT], totals[:, FIRST], totals[:, SECOND].reshape(-1, 3, 3))


def angle_limit(sigma: np.ndarray, half_width: np.ndarray, config: DetectorConfig) -> np.ndarray:
    """Largest tilt of a patch's normal (radians) that its noise band explains.

    ``atan(band_k * sigma / half_width)``: the tilt that moves the patch's edge by the band,
    clipped to ``[min_angle_deg, max_angle_deg]`` (the ceiling where it is undefined).
    """
    low, high = np.deg2rad(config.min_angle_deg), np.deg2rad(config.max_angle_deg)
    with np.errstate(invalid="ignore"):
        tilt = np.arctan2(config.band_k * sigma, half_width)
    return np.clip(np.nan_to_num(tilt, nan=high), low, high)


def cell_angle_limits(cells: CloudCells, config: DetectorConfig) -> np.ndarray:
    """:func:`angle_limit` of every cell, radians, shape (C,)."""
    return angle_limit(cells.cell_sigma, cells.half_width, config)


def neighbour_pairs(cells: CloudCells, config: DetectorConfig) -> tuple[list[list[int]], np.ndarray]:
    """For every cell, the 4-neighbours it may share a plane with.

    Two planar neighbours qualify when their normals agree within the :func:`angle_limit` of
    the less certain one and the points of each lie within the band of the other's plane:
    mean squared distance at most ``(band_k * sigma) ** 2`` (a step between parallel surfaces
    fails this).

    Returns
    -------
    neighbours : list of list of int
        Neighbours of each cell, in raster order of the cells.
    inner : ndarray of bool, shape (C,)
        Cells with a qualifying neighbour both along their row and along their column: the
        cells inside a plane, as opposed to a strip of cells along a crease.
    """
    rows, cols = cells.grid
    index = np.arange(rows * cols).reshape(rows, cols)
    a = np.concatenate([index[:, :-1].ravel(), index[:-1, :].ravel()])
    b = np.concatenate([index[:, 1:].ravel(), index[1:, :].ravel()])
    planes = np.concatenate([cells.normal, cells.offset[:, None]], axis=1)
    mean, count = np.nan_to_num(cells.mean), cells.count
    band2 = (config.band_k * cells.cell_sigma) ** 2
    limit = cell_angle_limits(cells, config)
    cos = np.einsum("ij,ij->i", cells.normal[a], cells.normal[b])
    with np.errstate(invalid="ignore"):
        ok = cells.planar[a] & cells.planar[b] & (cos >= np.cos(np.maximum(limit[a], limit[b])))
        ok &= mean_squared_distance(planes[a], Moments(count[b], mean[b], cells.scatter[b])) <= band2[b]
        ok &= mean_squared_distance(planes[b], Moments(count[a], mean[a], cells.scatter[a])) <= band2[a]
    neighbours: list[list[int]] = [[] for _ in range(rows * cols)]
    for i, j in zip(a[ok].tolist(), b[ok].tolist()):
        neighbours[i].append(j)
        neighbours[j].append(i)
    along_row = np.zeros(rows * cols, dtype=bool)
    along_column = np.zeros(rows * cols, dtype=bool)
    horizontal = np.arange(a.size) < rows * (cols - 1)  # the first pairs are left-right ones
    for side, pairs in ((along_row, ok & horizontal), (along_column, ok & ~horizontal)):
        side[a[pairs]] = side[b[pairs]] = True
    return neighbours, along_row & along_column


def grow_regions(cells: CloudCells, config: DetectorConfig) -> np.ndarray:
    """Group planar cells into regions that share a plane.

    Seeds are taken best first (smallest residual relative to the noise, ties in raster
    order) among the cells that agree with a neighbour in their row and one in their column
    (cells across a crease may fit a plane within the noise of a far wall, but they line up
    along the crease). A region spreads over neighbouring cells that pass :func:`neighbour_pairs` and
    whose points lie within the band of the region's current plane (mean squared distance at
    most ``(band_k * sigma) ** 2``, normal within the angle limit); the plane is refitted each
    time the region doubles, and the region's cells are then offered their neighbours again.

    Returns
    -------
    ndarray of int32, shape (C,)
        Region of each cell, 0 for none, regions numbered 1, 2, ... in the order grown.
    """
    neighbours, inner = neighbour_pairs(cells, config)
    totals = cell_totals(cells)  # a region's totals: one reduction over its cells' rows
    fits_plane = _plane_test(cells, config)
    with np.errstate(invalid="ignore", divide="ignore"):
        score = np.where(cells.planar, cells.mse / cells.cell_sigma**2, np.inf)
    # The walk below visits cells one by one: Python lists are read faster than numpy arrays.
    region = [0] * (cells.grid[0] * cells.grid[1])
    planar, inner = cells.planar.tolist(), inner.tolist()
    n_regions = 0
    for seed in np.argsort(score, kind="stable").tolist():
        if not planar[seed]:
            break  # the rest score inf
        if region[seed] or not inner[seed]:
            continue  # taken, or not inside a plane
        n_regions += 1
        region[seed] = n_regions
        members = [seed]
        plane = np.append(cells.normal[seed], cells.offset[seed])
        fits = fits_plane(plane)
        queue = deque(members)
        next_refit = 2
        while queue:
            cell = queue.popleft()
            for other in neighbours[cell]:
                if region[other] == 0 and fits[other]:
                    region[other] = n_regions
                    members.append(other)
                    queue.append(other)
            if len(members) >= next_refit:
                next_refit = 2 * len(members)
                moments = totals_moments(totals[members].sum(axis=0)[None])
                plane = fit_planes(moments.mean, moments.scatter)[0][0]
                fits = fits_plane(plane)
                queue.extend(members)  # the new plane may admit cells the old one refused
    return np.array(region, dtype=np.int32)


def _plane_test(cells: CloudCells, config: DetectorConfig):
    """``fits(plane)``: which cells (a list of bool) are planar, lie within the band of
    ``plane`` (mean squared distance ``n^T S n / N + (n . m + d) ** 2`` at most
    ``(band_k * sigma) ** 2``) and face its way (normal
    within the cell's angle limit)."""
    cos_limit = np.cos(cell_angle_limits(cells, config))
    band2 = (config.band_k * cells.cell_sigma) ** 2
    mean, count = np.nan_to_num(cells.mean), np.maximum(cells.count, 1)
    scatter = cells.scatter.reshape(-1, 9)

    def fits(plane: np.ndarray) -> list[bool]:
        normal = plane[:3]
        # n^T S n for every cell at once: the scatter matrices flattened against n n^T.
        spread = scatter @ np.outer(normal, normal).ravel() / count
        with np.errstate(invalid="ignore"):
            ok = cells.planar & (spread + (mean @ normal + plane[3]) ** 2 <= band2) & (cells.normal @ normal >= cos_limit)
        return ok.tolist()

    return fits


def merge_segments(region: np.ndarray, cells: CloudCells, config: DetectorConfig) -> np.ndarray:
    """Merge regions that lie on one plane and touch (or nearly touch) on the cell grid.

    Candidate pairs are regions within ``merge_gap_cells`` cells of each other. They merge
    when the points of each lie within the band of their joint plane (:func:`merge_costs`).
    Merging goes in rounds: all pairs of current groups are costed at once and the cheapest
    merges are made (ties by region numbers), each group at most once per round; the next
    round tests the merged groups, so a chain of small tilts cannot bend a plane.

    Parameters
    ----------
    region : ndarray of int, shape (C,)
        Regions from :func:`grow_regions` (0 = none).
    cells : CloudCells
    config : DetectorConfig

    Returns
    -------
    ndarray of int32, shape (C,)
        Merged regions, renumbered 1, 2, ... by their smallest original number.
    """
    n = int(region.max())
    if n == 0:
        return region.astype(np.int32)
    rows, cols = cells.grid
    grid = region.reshape(rows, cols)
    reach = config.merge_gap_cells + 1
    pairs = set()
    # Offsets past the grid's size find nothing (and would slice the grid out of step).
    for dy in range(0, min(reach, rows - 1) + 1):
        for dx in range(-min(reach, cols - 1), min(reach, cols - 1) + 1):
            if dy == 0 and dx <= 0:
                continue
            a = grid[dy:, max(dx, 0) : cols + min(dx, 0)]
            b = grid[: rows - dy, max(-dx, 0) : cols - max(dx, 0)]
            touch = (a > 0) & (b > 0) & (a != b)
            lo, hi = np.minimum(a[touch], b[touch]), np.maximum(a[touch], b[touch])
            pairs.update(zip(lo.tolist(), hi.tolist()))
    root = np.arange(n + 1)
    if pairs:
        groups = np.concatenate([np.zeros((1, TOTALS_COLUMNS)), group_totals(cell_totals(cells), region - 1, n)])
        pairs = np.array(sorted(pairs))
        # Rounds: cost every pair of current groups at once, merge the cheapest pairs whose
        # groups no earlier merge of the round has changed, repeat until nothing merges.
        while pairs.size:
            costs = merge_costs(groups[pairs[:, 0]], groups[pairs[:, 1]], config)
            changed = np.zeros(n + 1, dtype=bool)
            for index in np.lexsort((np.arange(len(pairs)), costs)).tolist():
                if costs[index] > 1.0:
                    break
                low, high = pairs[index]
                if changed[low] or changed[high]:
                    continue
                changed[low] = changed[high] = True
                root[root == high] = low
                groups[low] += groups[high]
            if not changed.any():
                break
            pairs = np.sort(root[pairs], axis=1)
            pairs = np.unique(pairs[pairs[:, 0] != pairs[:, 1]], axis=0)
    _, renumbered = np.unique(root, return_inverse=True)  # root 0 stays 0
    return renumbered[region].astype(np.int32)


def merge_costs(a: np.ndarray, b: np.ndarray, config: DetectorConfig) -> np.ndarray:
    """How far pairs of point sets are from sharing one plane: <= 1 where they may merge.

    The cost is infinite when their normals differ by more than the :func:`angle_limit` of the
    less certain set; otherwise it is the larger of the two sets' mean squared distances to the plane
    fitted to both, each divided by ``band_k ** 2`` times that set's mean noise variance.

    Parameters
    ----------
    a, b : ndarray of float64, shape (P, 14)
        The totals of ``P`` point sets each (:func:`cell_totals`).
    config : DetectorConfig

    Returns
    -------
    ndarray of float64, shape (P,)
    """
    moments_a, moments_b = totals_moments(a), totals_moments(b)
    both = totals_moments(a + b)
    plane_a = fit_planes(moments_a.mean, moments_a.scatter)[0]
    plane_b = fit_planes(moments_b.mean, moments_b.scatter)[0]
    plane_ab = fit_planes(both.mean, both.scatter)[0]
    cos = np.abs(np.einsum("ij,ij->i", plane_a[:, :3], plane_b[:, :3]))
    count_a, count_b = np.maximum(moments_a.count, 1), np.maximum(moments_b.count, 1)
    sigma2_a, sigma2_b = a[:, NOISE] / count_a, b[:, NOISE] / count_b
    # eigvalsh, as the merge was tuned with (its last bit may differ from eigh's).
    width_a = np.sqrt(3 * np.maximum(np.linalg.eigvalsh(moments_a.scatter)[:, 1], 0) / count_a)
    width_b = np.sqrt(3 * np.maximum(np.linalg.eigvalsh(moments_b.scatter)[:, 1], 0) / count_b)
    limit = np.maximum(angle_limit(np.sqrt(sigma2_a), width_a, config), angle_limit(np.sqrt(sigma2_b), width_b, config))
    ms_a = mean_squared_distance(plane_ab, moments_a)
    ms_b = mean_squared_distance(plane_ab, moments_b)
    cost = np.maximum(ms_a / sigma2_a, ms_b / sigma2_b) / config.band_k**2
    return np.where(cos >= np.cos(limit), cost, np.inf)

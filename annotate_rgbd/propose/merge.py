"""Which detected pieces are one plane: greedy merging of coplanar pieces by the residual
their joint fit adds, in units of the sensor's noise, and the relabelling that follows."""

from __future__ import annotations

import numpy as np

from annotate_rgbd.detect.refine import relabel
from annotate_rgbd.geometry.planes import Moments, fit_planes, merge_pairs, pool_groups, residual_ms


def join_moments(moments: Moments, group: np.ndarray) -> Moments:
    """Moments of groups of labels, held by each group's head (the label ``group`` names); the
    other members get a count of 0.

    Parameters
    ----------
    moments : Moments
        ``K`` labels.
    group : ndarray of int, shape (K,)
        Head (0-based label) of each label's group; a head is its own head.

    Returns
    -------
    Moments
        ``K`` rows.
    """
    group = np.asarray(group)
    heads = np.unique(group)
    pooled = pool_groups(moments, group, heads)
    count, mean, scatter = np.zeros_like(moments.count), moments.mean.copy(), np.zeros_like(moments.scatter)
    count[heads], mean[heads], scatter[heads] = pooled.count, pooled.mean, pooled.scatter
    return Moments(count, mean, scatter)


def merge_groups(moments: Moments, sigma, excess_k: float, scales: np.ndarray | None = None) -> np.ndarray:
    """Which labels are one plane: greedy merging of the pair whose joint fit adds the least
    residual, while it adds at most ``excess_k * (s * sigma(z))**2`` (z: the pair's mean depth;
    ``s``: the pair's noise scale, the pixel-weighted root mean square of its labels' ``scales``).

    Parameters
    ----------
    moments : Moments
        Of each label's points (label k in row k - 1).
    sigma : callable
        Axial noise standard deviation at a depth, metres.
    excess_k : float
    scales : ndarray of float, shape (K,), optional
        How much noisier than ``sigma`` each label's pixels are
        (:func:`annotate_rgbd.propose.extent.plane_scales`); default 1.

    Returns
    -------
    ndarray of intp, shape (K,)
        Group of each label (the smallest label of its group, 0-based), so that groups keep
        the order of their largest member.
    """
    n = len(moments.count)
    group = np.arange(n)
    current = Moments(moments.count.copy(), moments.mean.copy(), moments.scatter.copy())
    scale2 = np.ones(n) if scales is None else np.asarray(scales, dtype=np.float64) ** 2
    alive = current.count > 0
    # Every pair's joint moments, noise scale and ratio, (a, b) at [a, b] with a < b: a merge
    # changes only the pairs of the label that grew (the others' values are as before, bit for bit).
    ratio, pair_scale2 = np.full((n, n), np.inf), np.zeros((n, n))
    joint = Moments(np.zeros((n, n)), np.zeros((n, n, 3)), np.zeros((n, n, 3, 3)))

    def update(a: np.ndarray, b: np.ndarray) -> None:
        pairs = merge_pairs(current, a, b)
        joint_ms = residual_ms(pairs.count, fit_planes(pairs.mean, pairs.scatter)[1])
        ms_a = residual_ms(current.count[a], fit_planes(current.mean[a], current.scatter[a])[1])
        ms_b = residual_ms(current.count[b], fit_planes(current.mean[b], current.scatter[b])[1])
        added = joint_ms - (current.count[a] * ms_a + current.count[b] * ms_b) / pairs.count
        pair_scale2[a, b] = (current.count[a] * scale2[a] + current.count[b] * scale2[b]) / pairs.count
        ratio[a, b] = added / (excess_k * pair_scale2[a, b] * sigma(pairs.mean[:, 2]) ** 2)
        joint.count[a, b], joint.mean[a, b], joint.scatter[a, b] = pairs.count, pairs.mean, pairs.scatter

    idx = np.flatnonzero(alive)
    i, j = np.triu_indices(len(idx), 1)
    update(idx[i], idx[j])
    while alive.sum() > 1:
        idx = np.flatnonzero(alive)
        i, j = np.triu_indices(len(idx), 1)
        a, b = idx[i], idx[j]
        best = int(np.argmin(ratio[a, b]))  # first minimum: deterministic
        if ratio[a[best], b[best]] > 1:
            break
        keep, gone = a[best], b[best]
        current.count[keep], current.mean[keep], current.scatter[keep] = (
            joint.count[keep, gone], joint.mean[keep, gone], joint.scatter[keep, gone])
        scale2[keep] = pair_scale2[keep, gone]
        alive[gone] = False
        group[group == gone] = keep
        others = np.flatnonzero(alive)
        others = others[others != keep]
        update(np.minimum(others, keep), np.maximum(others, keep))
    return group


def apply_groups(labels, moments: Moments, group: np.ndarray, min_area: float):
    """Relabel merged groups of at least ``min_area`` pixels 1..G by area (largest first; ties
    by smallest member label); the others become 0. ``moments.count`` counts each label's
    pixels (the detector's moments)."""
    n = len(group)
    if n == 0:
        return labels, np.zeros((0, 4)), np.zeros(0, np.int64), np.zeros((0, 3))
    heads = np.unique(group)
    pooled = pool_groups(moments, group, heads)
    area = pooled.count.astype(np.int64)
    order = np.lexsort((heads, -area))
    order = order[area[order] >= min_area]
    rank = np.full(len(heads), -1, dtype=np.intp)
    rank[order] = np.arange(len(order))
    table = np.zeros(n + 1, dtype=labels.dtype)
    table[1:] = rank[np.searchsorted(heads, group)] + 1
    planes = fit_planes(pooled.mean[order], pooled.scatter[order])[0]
    return relabel(labels, table, labels.dtype), planes, area[order], pooled.mean[order]

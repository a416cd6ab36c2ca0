"""The time offset between a camera trajectory and the depth camera's clock, from the keyframes.

Motion-capture trajectories are recorded on another clock than the camera's: TUM RGB-D's
``groundtruth.txt`` is offset from its images by a few tens of milliseconds (for freiburg1_rpy
the fused surfaces are sharpest with the trajectory read 0.02 s earlier), which at the camera's
50-70 degrees per second is a degree or more: a carried outline 10 px off. A plane is rigid and
static, so every keyframe of a track must put its fitted plane at the same place in the world;
with the wrong offset the poses rotate each keyframe's plane by the motion over that offset,
differently for each, and they disagree. :func:`estimate_time_offset` takes the offset under
which they agree best.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from annotate_rgbd.io.poses import Trajectory, poses_at


@dataclass(frozen=True)
class KeyframeSample:
    """One keyframe's plane as its own depth frame saw it (camera frame).

    Parameters
    ----------
    group : int
        Which surface (one per track): only keyframes of one group are compared.
    time : float
        The depth frame's timestamp (s).
    points : ndarray of float64, shape (V, 3)
        Points on the fitted plane, camera frame (m): the fit's inliers among the grid points it
        was fitted to (:func:`annotate_rgbd.propagate.keyframes.keyframe_planes`).
    plane : ndarray of float64, shape (4,)
        The fitted plane, camera frame (unit normal).
    """

    group: int
    time: float
    points: np.ndarray
    plane: np.ndarray


@dataclass(frozen=True)
class TimeOffset:
    """What :func:`estimate_time_offset` found.

    Parameters
    ----------
    offset : float
        Seconds to add to a frame's timestamp before reading the trajectory (0 when no offset
        explains the keyframes clearly better than none).
    residual_at_zero, residual : float
        The keyframes' median disagreement (m) without an offset and with ``offset``.
    pairs : int
        Keyframe pairs compared (0: too few keyframes to tell; the offset is 0).
    """

    offset: float = 0.0
    residual_at_zero: float = float("nan")
    residual: float = float("nan")
    pairs: int = 0

    def to_json(self) -> dict:
        """The report's entry."""
        def rounded(value: float) -> float | None:
            return None if not np.isfinite(value) else round(float(value), 5)

        return {"offset_s": round(self.offset, 4), "residual_at_zero_m": rounded(self.residual_at_zero),
                "residual_m": rounded(self.residual), "pairs": self.pairs}


def keyframe_pairs(samples: list[KeyframeSample], max_per_group: int) -> tuple[np.ndarray, np.ndarray]:
    """The keyframe pairs to compare: within each group, every pair among at most
    ``max_per_group`` of its keyframes taken evenly in time.

    Returns
    -------
    first, second : ndarray of int, shape (P,)
        Indices into ``samples``.
    """
    groups: dict[int, list[int]] = {}
    for i, sample in enumerate(samples):
        groups.setdefault(sample.group, []).append(i)
    first, second = [], []
    for members in groups.values():
        members.sort(key=lambda i: samples[i].time)
        if len(members) > max_per_group:
            members = [members[int(j)] for j in np.linspace(0, len(members) - 1, max_per_group).round()]
        for a in range(len(members)):
            for b in range(a + 1, len(members)):
                first.append(members[a])
                second.append(members[b])
    return np.asarray(first, dtype=np.int64), np.asarray(second, dtype=np.int64)


def pair_residuals(samples: list[KeyframeSample], first: np.ndarray, second: np.ndarray,
                   rotations: np.ndarray, translations: np.ndarray) -> np.ndarray:
    """How far apart each pair's planes are in the world under each of several sets of poses:
    the median distance of the first keyframe's points to the second's plane and of the second's
    points to the first's (m; NaN where a pair has no points).

    The world is never built point by point: the second keyframe's world plane, seen from the
    first keyframe's camera, is a plane in that camera's frame (rotated normal
    ``R_a^T R_b n_b``, offset ``d_b + (R_b n_b) . (t_a - t_b)``), so each keyframe's points are
    measured once against one such plane per set of poses.

    Parameters
    ----------
    samples : list of KeyframeSample
    first, second : ndarray of int, shape (P,)
    rotations : ndarray, shape (O, K, 3, 3)
        Camera-to-world rotation of every sample's depth frame, for each of ``O`` sets of poses
        (one per tried time offset).
    translations : ndarray, shape (O, K, 3)

    Returns
    -------
    ndarray of float64, shape (O, P)
    """
    rotations = np.asarray(rotations, dtype=np.float64)
    translations = np.asarray(translations, dtype=np.float64)
    sets = rotations.shape[0]
    planes = np.array([s.plane for s in samples], dtype=np.float64).reshape(-1, 4)
    world_normals = np.einsum("okij,kj->oki", rotations, planes[:, :3])  # (O, K, 3)

    def seen_from(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Keyframe b's plane in keyframe a's camera frame, per pair and set: (O, P, 3), (O, P)."""
        normals = np.einsum("opji,opj->opi", rotations[:, a], world_normals[:, b])
        shift = np.einsum("opi,opi->op", world_normals[:, b], translations[:, a] - translations[:, b])
        return normals, planes[b, 3] + shift

    second_in_first, second_in_first_offset = seen_from(first, second)
    first_in_second, first_in_second_offset = seen_from(second, first)
    residuals = np.full((sets, len(first)), np.nan)
    finite = [bool(np.isfinite(s.points).all()) for s in samples]
    planes_finite = (np.isfinite(second_in_first).all(axis=2) & np.isfinite(second_in_first_offset)
                     & np.isfinite(first_in_second).all(axis=2) & np.isfinite(first_in_second_offset))  # (O, P)
    for j, (a, b) in enumerate(zip(first.tolist(), second.tolist())):
        points_a, points_b = samples[a].points, samples[b].points
        count = len(points_a) + len(points_b)
        if count == 0:
            continue
        # Both keyframes' distances in one array, written in place; the median by partitioning it
        # in place (what np.median does, without its copies: a quarter faster, the same values).
        # einsum, not ``@``: no BLAS threads (geometry.planes._fit says why).
        distances = np.empty((sets, count))
        here, there = distances[:, :len(points_a)], distances[:, len(points_a):]
        np.einsum("oi,ni->on", second_in_first[:, j], points_a, out=here)
        here += second_in_first_offset[:, j, None]
        np.einsum("oi,ni->on", first_in_second[:, j], points_b, out=there)
        there += first_in_second_offset[:, j, None]
        np.abs(distances, out=distances)
        # np.median's NaN for a row holding one; finite points and planes (as always but in a
        # broken input) give none, and the look for it is skipped.
        unknown = None if finite[a] and finite[b] and planes_finite[:, j].all() else np.isnan(distances).any(axis=1)
        half = count // 2
        if count % 2:
            distances.partition(half, axis=1)
            residuals[:, j] = distances[:, half]
        else:
            distances.partition([half - 1, half], axis=1)
            residuals[:, j] = np.mean(distances[:, half - 1 : half + 1], axis=1)
        if unknown is not None:
            residuals[unknown, j] = np.nan
    return residuals


def estimate_time_offset(
    trajectory: Trajectory, samples: list[KeyframeSample], search: float, step: float, max_gap: float,
    same_surface: float, sigma=None, max_per_group: int = 12,
) -> TimeOffset:
    """The offset to add to the depth timestamps under which the keyframes' planes agree best.

    Every pair of keyframes of one group (track) is compared (:func:`pair_residuals`); pairs
    whose planes lie more than ``same_surface`` apart at every tried offset are not the same
    surface (a shape drawn over another one) and are left out. A pair's residual is counted in
    units of the sensor's noise at the farther keyframe's depth (a plane 3 m away is fitted to
    points ten times noisier than one at 1 m) and clipped at ``same_surface``; the score of an
    offset is the mean over the pairs. The offset is searched on a grid of ``step`` over
    ``[-search, search]``, then on a grid a tenth as fine around the best point. It is kept only
    when it brings more of the pairs closer than chance would: a sign test at two standard
    deviations (share of pairs closer than at 0 above ``1/2 + 1/sqrt(pairs)``); with exact poses
    the best offset is about 0 and about half the pairs move either way.

    Parameters
    ----------
    trajectory : Trajectory
    samples : list of KeyframeSample
    search, step : float
        The range and the grid of offsets tried (s).
    max_gap : float
        As in :func:`annotate_rgbd.poses.poses_at`.
    same_surface : float
        Residual (m) beyond which a pair counts as two surfaces.
    sigma : callable, optional
        The sensor's noise (m) at a depth (m), vectorised (:meth:`NoiseModel.sigma`); None: every
        pair counts the same.
    max_per_group : int
        Keyframes of a group compared pairwise, at most (taken evenly in time).

    Returns
    -------
    TimeOffset
    """
    first, second = keyframe_pairs(samples, max_per_group)
    if len(first) == 0 or step <= 0 or search <= 0:
        return TimeOffset(pairs=0)
    times = np.array([s.time for s in samples])
    depths = np.array([float(np.median(s.points[:, 2])) for s in samples])
    scale = np.ones(len(first)) if sigma is None else np.asarray(sigma(np.maximum(depths[first], depths[second])))

    def residuals(offsets: np.ndarray) -> np.ndarray:
        """(offsets, pairs): NaN where a keyframe has no pose."""
        poses = poses_at(trajectory, (times[None, :] + offsets[:, None]).reshape(-1), max_gap)
        shape = (len(offsets), len(samples))
        found = pair_residuals(samples, first, second, np.nan_to_num(poses.rotations).reshape(*shape, 3, 3),
                               np.nan_to_num(poses.translations).reshape(*shape, 3))
        ok = poses.ok.reshape(shape)
        found[~(ok[:, first] & ok[:, second])] = np.nan
        return found

    coarse = np.unique(np.append(np.arange(-search, search + step / 2, step), 0.0))
    table = residuals(coarse)  # (offsets, pairs)
    usable = np.isfinite(table).all(axis=0) & (np.where(np.isfinite(table), table, np.inf).min(axis=0) <= same_surface)
    zero = table[int(np.flatnonzero(coarse == 0.0)[0])]
    if not usable.any():
        return TimeOffset(pairs=0)

    def scores(found: np.ndarray) -> np.ndarray:
        """Per offset (row): NaN where a usable pair has no pose."""
        return np.mean(np.minimum(found[:, usable], same_surface) / scale[usable], axis=1)

    best = float(coarse[int(np.argmin(scores(table)))])
    # The fine grid holds the best coarse offset exactly (its score is finite); it may reach past
    # the trajectory, where offsets without poses score NaN.
    fine = best + np.arange(-10, 11) * (step / 10)
    fine_rows = residuals(fine)
    best_index = int(np.nanargmin(scores(fine_rows)))
    best, at_best = float(fine[best_index]), fine_rows[best_index]
    pairs = int(np.count_nonzero(usable))
    at_zero = float(np.median(zero[usable]))
    closer = float(np.mean(at_best[usable] < zero[usable]))
    if closer <= 0.5 + 1.0 / np.sqrt(pairs):
        return TimeOffset(0.0, at_zero, at_zero, pairs)
    return TimeOffset(round(best, 6), at_zero, float(np.median(at_best[usable])), pairs)

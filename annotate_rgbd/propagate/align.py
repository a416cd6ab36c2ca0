"""Frame alignment: every frame's pose refined against the depth of the keyframes it takes
outlines from.

A carried outline lands where the frame's pose and its keyframe's pose say, so what matters is
that the two agree, not that either is right in the world. Real trajectories do not agree to
the centimetre: TUM freiburg1_rpy's motion capture is off from poses registered to a fused
model of its own depth by a median 1.3 degrees and 2 cm, mostly short-lived error that differs
from frame to frame. So before the keyframes are lifted, their poses are aligned to each other
(each keyframe's depth to that of its neighbouring keyframes, a few rounds), and then every other
frame's to the nearest keyframes on both sides of it (:func:`align_frames`).

The alignment is point-to-plane ICP with projective data association, as KinectFusion tracks a
camera (Newcombe et al., 2011): a frame's depth points (every ``align_step``-th pixel) are taken
into each keyframe's camera with the current poses, paired with the keyframe's depth point at the
pixel they land on, and the pose is moved so that they lie on the keyframe's surface there
(:func:`align_pose`). Pairs farther apart than the reach (first 5 cm, then 2 cm) are not used. A
correction larger than ``align_max_shift`` or ``align_max_turn`` is not believed (the given pose
is kept), nor is one resting on too few pairs. Frames without a pose stay without one.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from annotate_rgbd.config.settings import Config
from annotate_rgbd.errors import InputError
from annotate_rgbd.geometry.camera import Camera, backproject, depth_to_metres, ray_grid
from annotate_rgbd.io.images import read_depth
from annotate_rgbd.io.poses import FramePoses
from annotate_rgbd.io.rotations import rotation_angles
from annotate_rgbd.logs import counted
from annotate_rgbd.pool import HelperPool, run_jobs

log = logging.getLogger("annotate_rgbd")

#: The ICP's two stages: the reach of their pairs (m), and the step (m, degrees) below which a
#: stage ends. The first pulls in poses a few centimetres off, the second fits on pairs within a
#: Kinect's noise at 2-3 m.
STAGES = ((0.05, 1e-3, 0.02), (0.02, 1e-4, 0.002))
#: Gauss-Newton steps per stage at most.
STEPS = 8
#: Half-width (px, on the keyframe's grid) of the differences a keyframe's normals are taken
#: from, on its depth smoothed over a square of twice that plus one: a Kinect's depth steps of
#: several millimetres make neighbouring pixels' normals useless.
NORMAL_REACH = 3
#: Directions of the pose whose eigenvalue in the normal equations is below this share of the
#: largest are not moved (:func:`_step`).
FREE = 1e-3
#: A pose resting on fewer pairs is not corrected.
MIN_PAIRS = 300


@dataclass(frozen=True)
class KeyframeView:
    """A keyframe's depth as a surface to align to, on every other pixel of its grid.

    Parameters
    ----------
    points : ndarray of float32, shape (ceil(H/2), ceil(W/2), 3)
        Its depth points (its camera frame, m); NaN where there is no depth.
    normals : ndarray of float32, shape (ceil(H/2), ceil(W/2), 3)
        Unit normals there (its camera frame); NaN where there is none.
    """

    points: np.ndarray
    normals: np.ndarray


@dataclass(frozen=True)
class Keyframes:
    """The keyframes a frame is aligned to, their :class:`KeyframeView` arrays stacked and
    taken to the world.

    Parameters
    ----------
    points, normals : ndarray of float32, shape (K, H/2, W/2, 3)
        Depth points and normals, world frame.
    rotations : ndarray, shape (K, 3, 3)
    translations : ndarray, shape (K, 3)
        The keyframes' poses (camera to world).
    """

    points: np.ndarray
    normals: np.ndarray
    rotations: np.ndarray
    translations: np.ndarray


def stack_views(views: list[KeyframeView], rotations: np.ndarray, translations: np.ndarray) -> Keyframes:
    """Several keyframes' views, with their poses (camera to world: (K, 3, 3) and (K, 3)), as
    one :class:`Keyframes`."""
    rotations = np.asarray(rotations, dtype=np.float64)
    translations = np.asarray(translations, dtype=np.float64)
    turn = rotations.transpose(0, 2, 1).astype(np.float32)[:, None]
    points = np.matmul(np.stack([v.points for v in views]), turn) + translations.astype(np.float32)[:, None, None, :]
    normals = np.matmul(np.stack([v.normals for v in views]), turn)
    return Keyframes(points, normals, rotations, translations)


def keyframe_view(depth_m: np.ndarray, camera: Camera, max_depth: float) -> KeyframeView:
    """A keyframe's depth image as a :class:`KeyframeView`.

    Parameters
    ----------
    depth_m : ndarray, shape (H, W)
        Depth in metres, NaN where invalid (:func:`annotate_rgbd.geometry.camera.depth_to_metres`).
    camera : Camera
    max_depth : float
        Depth beyond this (m) is left out.

    Returns
    -------
    KeyframeView
    """
    depth = np.asarray(depth_m, dtype=np.float32)[::2, ::2]
    valid = np.isfinite(depth) & (depth <= max_depth)
    size = 2 * NORMAL_REACH + 1
    weight = cv2.boxFilter(valid.astype(np.float32), -1, (size, size), normalize=False)
    total = cv2.boxFilter(np.where(valid, depth, 0).astype(np.float32), -1, (size, size), normalize=False)
    with np.errstate(invalid="ignore", divide="ignore"):
        smooth = np.where(weight >= size * size / 2, total / weight, np.nan).astype(np.float32)
    points = _grid_points(depth, camera)
    points[~valid] = np.nan
    rough = _grid_points(smooth, camera)
    r = NORMAL_REACH
    across = np.full_like(rough, np.nan)
    down = np.full_like(rough, np.nan)
    across[:, r:-r] = rough[:, 2 * r:] - rough[:, :-2 * r]
    down[r:-r] = rough[2 * r:] - rough[:-2 * r]
    normals = np.cross(across, down)
    length = np.linalg.norm(normals, axis=2, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        normals = (normals / length).astype(np.float32)
    normals[~valid | ~np.isfinite(length[..., 0]) | (length[..., 0] == 0)] = np.nan
    return KeyframeView(points, normals)


def _grid_points(depth: np.ndarray, camera: Camera) -> np.ndarray:
    """The 3-D points (H', W', 3) of a depth image taken at every other pixel of the camera's grid."""
    height, width = depth.shape
    ray_x, ray_y = ray_grid(camera, 2 * height, 2 * width, np.float32)
    x, y = ray_x[::2], ray_y[::2]
    return np.stack([depth * x[None, :], depth * y[:, None], depth], axis=2)


def frame_points(depth_m: np.ndarray, camera: Camera, step: int, max_depth: float) -> np.ndarray:
    """A frame's depth points at every ``step``-th pixel both ways (camera frame, m; float32 (N, 3))."""
    rows, cols = np.mgrid[0:depth_m.shape[0]:step, 0:depth_m.shape[1]:step]
    z = np.asarray(depth_m[::step, ::step], dtype=np.float64)
    keep = np.isfinite(z) & (z <= max_depth)
    return backproject(cols[keep], rows[keep], z[keep], camera).astype(np.float32)


@dataclass(frozen=True)
class Correction:
    """What :func:`align_pose` found for one frame.

    Parameters
    ----------
    rotation, translation : ndarray
        The aligned pose (the given one when not ``applied``).
    shift : float
        How far the alignment moved the camera centre (m).
    turn : float
        By how much it turned the camera (degrees).
    pairs : int
        Point pairs of the last step.
    applied : bool
        Whether the aligned pose is used (within the limits, on enough pairs).
    """

    rotation: np.ndarray
    translation: np.ndarray
    shift: float
    turn: float
    pairs: int
    applied: bool


def align_pose(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray,
               views: Keyframes, camera: Camera, max_shift: float, max_turn: float) -> Correction:
    """Align one frame's depth to its keyframes' (point-to-plane ICP, projective pairs).

    Parameters
    ----------
    points : ndarray of float32, shape (N, 3)
        The frame's depth points (camera frame, m; :func:`frame_points`).
    rotation, translation : ndarray, shapes (3, 3) and (3,)
        Its pose to start from (camera to world).
    views : Keyframes
        The keyframes to align to (:func:`stack_views`).
    camera : Camera
        The depth camera (the frame's and the keyframes').
    max_shift, max_turn : float
        The largest correction believed (m, degrees).

    Returns
    -------
    Correction
    """
    given_r = np.asarray(rotation, dtype=np.float64)
    given_t = np.asarray(translation, dtype=np.float64)
    r, t = given_r.copy(), given_t.copy()
    pairs = 0
    for reach, shortest, least_turn in STAGES:
        for _ in range(STEPS):
            rows, residuals, pairs = _pairs(points, r, t, views, camera, reach)
            if pairs < MIN_PAIRS:
                break
            step = _step(rows.T @ rows, rows.T @ residuals)
            turn, _ = cv2.Rodrigues(step[:3].reshape(3, 1))
            t = t + r @ step[3:]
            r = r @ turn
            if np.linalg.norm(step[3:]) < shortest and np.degrees(np.linalg.norm(step[:3])) < least_turn:
                break
    return judged(given_r, given_t, r, t, pairs, max_shift, max_turn)


def judged(given_r: np.ndarray, given_t: np.ndarray, r: np.ndarray, t: np.ndarray, pairs: int,
           max_shift: float, max_turn: float) -> Correction:
    """The correction from the pose ``(given_r, given_t)`` to ``(r, t)``, found on ``pairs``
    pairs, applied only within ``max_shift`` (m) and ``max_turn`` (degrees) and on at least
    :data:`MIN_PAIRS` pairs."""
    turned = float(np.degrees(rotation_angles(given_r[None], r[None])[0]))
    shifted = float(np.linalg.norm(t - given_t))
    applied = pairs >= MIN_PAIRS and shifted <= max_shift and turned <= max_turn
    return Correction(r if applied else given_r, t if applied else given_t, shifted, turned, int(pairs), applied)


def _step(hessian: np.ndarray, gradient: np.ndarray) -> np.ndarray:
    """The Gauss-Newton step ``(w, v)`` in the directions the pairs constrain: those of the
    normal equations' eigenvalues above :data:`FREE` of the largest. A plane seen alone leaves
    the camera free to slide along it and turn about its normal; noise must not move it there."""
    values, vectors = np.linalg.eigh(hessian)
    held = values > FREE * values[-1]
    return -vectors[:, held] @ ((vectors[:, held].T @ gradient) / values[held])


def _pairs(points, r, t, views: Keyframes, camera, reach):
    """The Jacobian rows (M, 6) and residuals (M,) of every pair of the frame's points with the
    keyframes' surfaces within ``reach``, for a step ``(w, v)`` applied in the frame's camera."""
    world = points @ r.T.astype(np.float32) + t.astype(np.float32)
    local = np.matmul(world[None] - views.translations.astype(np.float32)[:, None, :], views.rotations.astype(np.float32))
    count, height, width = views.points.shape[:3]
    z = local[..., 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.rint((local[..., 0] / z * np.float32(camera.fx) + np.float32(camera.cx)) * np.float32(0.5))
        v = np.rint((local[..., 1] / z * np.float32(camera.fy) + np.float32(camera.cy)) * np.float32(0.5))
        pair = np.flatnonzero((z > 0) & (u >= 0) & (u < width) & (v >= 0) & (v < height))
    u, v = u.ravel()[pair].astype(np.intp), v.ravel()[pair].astype(np.intp)
    point = pair % len(points)
    flat = ((pair // len(points)) * height + v) * width + u
    gap = np.take(world, point, axis=0) - np.take(views.points.reshape(-1, 3), flat, axis=0)
    normal = np.take(views.normals.reshape(-1, 3), flat, axis=0)
    distance = np.einsum("ij,ij->i", gap, normal)
    with np.errstate(invalid="ignore"):
        near = (np.einsum("ij,ij->i", gap, gap) < reach * reach) & np.isfinite(distance)
    point, normal = point[near], normal[near] @ r.astype(np.float32)  # normals in the frame's camera
    rows = _jacobian(np.take(points, point, axis=0), normal)
    return rows, distance[near].astype(np.float64), len(rows)


def _jacobian(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The point-to-plane Jacobian rows ``(p x n, n)`` (M, 6, float64) of points and normals
    (float32 (M, 3), the frame's camera): the cross product in float32 as ``np.cross`` computes it,
    one column at a time."""
    (px, py, pz), (nx, ny, nz) = points.T, normals.T
    rows = np.empty((len(points), 6))
    rows[:, 0] = py * nz - pz * ny
    rows[:, 1] = pz * nx - px * nz
    rows[:, 2] = px * ny - py * nx
    rows[:, 3:] = normals
    return rows


@dataclass
class Alignment:
    """What aligning the frames did, for the report (:func:`align_frames`).

    Parameters
    ----------
    keyframes : int
        Depth frames of keyframes aligned to each other.
    frames : int
        Other frames aligned to their keyframes.
    corrected : int
        Frames (keyframes too) whose pose was corrected.
    kept : int
        Frames whose correction was not believed (beyond the limits, or on too few pairs).
    unread : int
        Frames not aligned because their depth, or every keyframe's they are aligned to, could
        not be read (the frame jobs say why).
    shifts, turns : list of float
        The corrections applied (m, degrees).
    beyond : list of (int, float, float)
        The frames whose correction was beyond the limits: (depth frame, m, degrees). Their
        trajectory pose disagrees with the depth by that much (a trajectory jump, a drop-out
        interpolated over, a clock off), or ICP paired the wrong surfaces: frames to check.
    rounds : int
        The keyframes' rounds (0: no alignment).
    """

    keyframes: int = 0
    frames: int = 0
    corrected: int = 0
    kept: int = 0
    unread: int = 0
    shifts: list = field(default_factory=list)
    turns: list = field(default_factory=list)
    beyond: list = field(default_factory=list)
    rounds: int = 0

    def add(self, frame: int, correction: Correction) -> None:
        """Count one depth frame's correction."""
        if correction.applied:
            self.corrected += 1
            self.shifts.append(correction.shift)
            self.turns.append(correction.turn)
            return
        self.kept += 1
        if correction.pairs >= MIN_PAIRS:  # not too few pairs: a correction beyond the limits
            self.beyond.append((frame, correction.shift, correction.turn))

    def to_json(self, depth_times: np.ndarray | None = None) -> dict:
        """The report's ``propagation.alignment`` (with the depth frames' timestamps, when
        given, each frame beyond the limits is named by its timestamp too)."""
        beyond = [{"depth_frame": frame, "shift_cm": round(100 * shift, 1), "turn_deg": round(turn, 2)}
                  for frame, shift, turn in self.beyond]
        if depth_times is not None:
            for entry in beyond:
                entry["depth_timestamp"] = float(depth_times[entry["depth_frame"]])
        return {
            "rounds": self.rounds, "keyframes": self.keyframes, "frames": self.frames, "corrected": self.corrected,
            "kept": self.kept, "unread": self.unread,
            "beyond_limits": beyond,
            "median_shift_cm": round(100 * float(np.median(self.shifts)), 2) if self.shifts else None,
            "median_turn_deg": round(float(np.median(self.turns)), 3) if self.turns else None,
        }


def align_frames(depth_poses: FramePoses, keyframes: list[int], depth_files: list[Path], config: Config,
                 helpers: HelperPool | None = None) -> tuple[FramePoses, Alignment]:
    """Align the keyframes' poses to each other, then every other frame's to its keyframes'.

    Parameters
    ----------
    depth_poses : FramePoses
        Every depth frame's pose from the trajectory.
    keyframes : list of int
        The depth frames of the keyframes (any track's).
    depth_files : list of Path
        The sequence's depth files, in depth order.
    config : Config
        Camera, ``filter.max_mean_distance`` (depth beyond it is left out) and ``[propagate]``:
        ``align_rounds`` rounds of the keyframes against their ``align_neighbours`` (n) nearest
        keyframes on each side (each moving to where it and they agree: ``2 n / (2 n + 1)`` of
        the way to the pose aligned to its ``n`` on each side, :func:`part_way`), then
        each other frame against its ``keyframes_each_side`` on each side, at every ``align_step``-th
        pixel, within ``align_max_shift`` and ``align_max_turn``.
    helpers : HelperPool, optional
        Helper processes that align frames too; the poses are the same either way.

    Returns
    -------
    FramePoses
        The aligned poses (a new record; ``depth_poses`` is not changed).
    Alignment
    """
    settings = config.propagate
    rotations, translations = depth_poses.rotations.copy(), depth_poses.translations.copy()
    alignment = Alignment()
    keys = sorted({k for k in keyframes if depth_poses.ok[k]})
    if settings.align_rounds == 0 or len(keys) < 2:
        return depth_poses, alignment
    alignment.keyframes, alignment.rounds = len(keys), settings.align_rounds
    log.info("poses: aligning %s to each other (%d rounds), then the other frames' to their keyframes' depth "
             "(propagate.align_rounds = 0: off)", counted(len(keys), "keyframe"), settings.align_rounds)
    limits = (config.camera, config.filter.max_mean_distance, settings.align_step, settings.align_max_shift,
              settings.align_max_turn)
    side = settings.align_neighbours
    try:
        unread: set[int] = set()
        for _ in range(settings.align_rounds):  # every keyframe against its neighbours' poses of the round before
            jobs = []
            for n, key in enumerate(keys):
                near = [k for k in keys[max(0, n - side):n + side + 1] if k != key]
                jobs.append(([key], [(depth_files[k], rotations[k], translations[k]) for k in near],
                             [(depth_files[key], rotations[key], translations[key])], limits, True))
            found = _corrections(jobs, helpers)
            unread = {key for key, correction in found.items() if correction is None}
            for key, correction in found.items():
                if correction is not None:
                    rotations[key], translations[key] = part_way(rotations[key], translations[key], correction,
                                                                 2 * side / (2 * side + 1))
        for key in keys:  # a keyframe's correction over all rounds is held to the limits
            if key in unread:
                alignment.unread += 1
                continue
            overall = judged(depth_poses.rotations[key], depth_poses.translations[key], rotations[key],
                             translations[key], MIN_PAIRS, settings.align_max_shift, settings.align_max_turn)
            rotations[key], translations[key] = overall.rotation, overall.translation
            alignment.add(key, overall)
        jobs = []
        for before, after, frames in _between(keys, np.flatnonzero(depth_poses.ok), settings.keyframes_each_side):
            jobs.append((frames, [(depth_files[k], rotations[k], translations[k]) for k in (*before, *after)],
                         [(depth_files[f], rotations[f], translations[f]) for f in frames], limits, False))
        for frame, correction in _corrections(jobs, helpers).items():
            alignment.frames += 1
            if correction is None:
                alignment.unread += 1
                continue
            rotations[frame], translations[frame] = correction.rotation, correction.translation
            alignment.add(frame, correction)
    finally:
        _keyframe.cache_clear()  # this process goes on to make masks
    return FramePoses(rotations, translations, depth_poses.ok, depth_poses.reasons), alignment


def part_way(rotation: np.ndarray, translation: np.ndarray, correction: Correction,
             share: float) -> tuple[np.ndarray, np.ndarray]:
    """The pose ``share`` of the way from ``(rotation, translation)`` to a correction's (the
    rotation along the shortest turn, the translation along the straight line)."""
    turn, _ = cv2.Rodrigues(rotation.T @ correction.rotation)
    part, _ = cv2.Rodrigues(turn * share)
    return rotation @ part, translation + share * (correction.translation - translation)


def _between(keys: list[int], frames: np.ndarray, each_side: int):
    """Runs of the frames (not keyframes) that share their nearest ``each_side`` keyframes on each
    side: ``(before, after, frames)`` each."""
    runs: dict[tuple, list[int]] = {}
    keyset = set(keys)
    for frame in frames:
        if frame in keyset:
            continue
        n = int(np.searchsorted(keys, frame))
        window = (tuple(keys[max(0, n - each_side):n]), tuple(keys[n:n + each_side]))
        runs.setdefault(window, []).append(int(frame))
    return [(before, after, run) for (before, after), run in runs.items()]


def _corrections(jobs: list, helpers: HelperPool | None) -> dict[int, Correction | None]:
    """Run alignment jobs (:func:`align_job`); frame -> its correction, None where it was not
    aligned for want of depth (the frame jobs say why)."""
    found: dict[int, Correction | None] = {}
    for outcome in run_jobs(jobs, align_job, helpers):
        if outcome.error is None:
            found.update(outcome.value)
        else:  # a job given up on (a helper hung on it twice)
            found.update(dict.fromkeys(jobs[outcome.index][0]))
    return dict(sorted(found.items()))


def align_job(job: tuple) -> dict[int, Correction | None]:
    """Align the frames of one job ``(frame indices, keyframes [(path, rotation, translation)],
    frames [(path, rotation, translation)], (camera, max_depth, step, max_shift, max_turn),
    whether the frames are keyframes)`` to the job's keyframes: the function
    :func:`align_frames` gives :func:`annotate_rgbd.pool.run_jobs`. A frame whose depth, or
    every keyframe's, cannot be read gets None; a keyframe that cannot be read is left out."""
    indices, keyframes, frames, (camera, max_depth, step, max_shift, max_turn), of_keyframes = job
    readable = []
    for path, r, t in keyframes:
        try:
            readable.append((_keyframe(path, camera, max_depth)[1], r, t))
        except InputError:
            continue  # the others still align the frames
    if not readable:
        return dict.fromkeys(indices)
    views = stack_views([v for v, _, _ in readable], [r for _, r, _ in readable], [t for _, _, t in readable])
    corrections: dict[int, Correction | None] = {}
    for index, (path, r, t) in zip(indices, frames):
        try:
            depth = _keyframe(path, camera, max_depth)[0] if of_keyframes else _depth(path, camera)
        except InputError:
            corrections[index] = None
            continue
        corrections[index] = align_pose(frame_points(depth, camera, step, max_depth), r, t, views, camera,
                                        max_shift, max_turn)
    return corrections


@lru_cache(maxsize=8)
def _keyframe(path: Path, camera: Camera, max_depth: float) -> tuple[np.ndarray, KeyframeView]:
    """A keyframe's depth and view, kept for the next jobs: successive jobs share most of their
    keyframes (a keyframe's neighbours, a run of frames between keyframes). 8 of them hold 25 MB
    at 640 x 480."""
    depth = _depth(path, camera)
    return depth, keyframe_view(depth, camera, max_depth)


def _depth(path: Path, camera: Camera) -> np.ndarray:
    """A depth frame in metres (NaN where invalid)."""
    return depth_to_metres(read_depth(path), camera.depth_scale)

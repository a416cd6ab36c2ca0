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
camera (:mod:`annotate_rgbd.propagate.icp`): a frame's depth points (every ``align_step``-th
pixel) are taken into each keyframe's camera with the current poses, paired with the keyframe's
depth point at the pixel they land on, and the pose is moved so that they lie on the keyframe's
surface there. Pairs farther apart than the reach (first 5 cm, then 2 cm) are not used. A
correction larger than ``align_max_shift`` or ``align_max_turn`` is not believed (the given pose
is kept), nor is one resting on too few pairs. Frames without a pose stay without one.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from collections import OrderedDict
from pathlib import Path

import cv2
import numpy as np

from annotate_rgbd.config.settings import Config
from annotate_rgbd.errors import InputError
from annotate_rgbd.geometry.camera import Camera, depth_to_metres
from annotate_rgbd.io.images import read_depth
from annotate_rgbd.io.poses import FramePoses
from annotate_rgbd.logs import counted
from annotate_rgbd.pool import HelperPool, run_jobs
from annotate_rgbd.propagate.icp import MIN_PAIRS, Correction, KeyframeView, align_pose, frame_points, judged, \
    keyframe_view, stack_views

log = logging.getLogger("annotate_rgbd")

#: Keyframes whose views a process keeps (:func:`_keyframe`): about 1.3 MB each at 640 x 480,
#: and at most :data:`KEPT_BYTES` of them. A sequence with no more keyframes than that reads and
#: prepares each keyframe once for all the rounds and the other frames; with more, each round
#: reads again those the last one did not end on. The other frames' jobs let go of the keyframes
#: they have gone past (:func:`_forget_past`); a helper that aligned only keyframes (every frame a
#: keyframe, or another helper took the other frames) keeps what it holds, at most this much,
#: while it goes on to make masks.
KEPT_KEYFRAMES = 48
KEPT_BYTES = 64 << 20
#: The kept keyframes, least recently used first: (path, camera, max_depth, step) -> (depth frame,
#: its own points to align, its view to align to).
_kept: OrderedDict = OrderedDict()


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
    apart : list of (int, float)
        The frames whose depth does not meet their keyframes' (:attr:`Correction.apart`): (depth
        frame, the share of its points on their surfaces that met them). Their pose is off by more
        than the pairs reach, or they see what no keyframe saw: frames to check too.
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
    apart: list = field(default_factory=list)
    rounds: int = 0

    def add(self, frame: int, correction: Correction) -> None:
        """Count one depth frame's correction."""
        if correction.applied:
            self.corrected += 1
            self.shifts.append(correction.shift)
            self.turns.append(correction.turn)
            return
        self.kept += 1
        if correction.apart:
            self.apart.append((frame, correction.pairs / correction.landed))
        elif correction.pairs >= MIN_PAIRS:  # not too few pairs: a correction beyond the limits
            self.beyond.append((frame, correction.shift, correction.turn))

    def to_json(self, depth_times: np.ndarray | None = None) -> dict:
        """The report's ``propagation.alignment`` (with the depth frames' timestamps, when
        given, each frame beyond the limits or apart from its keyframes is named by its timestamp
        too)."""
        beyond = [{"depth_frame": frame, "shift_cm": round(100 * shift, 1), "turn_deg": round(turn, 2)}
                  for frame, shift, turn in self.beyond]
        apart = [{"depth_frame": frame, "met_share": round(share, 3)} for frame, share in sorted(self.apart)]
        if depth_times is not None:
            for entry in beyond + apart:
                entry["depth_timestamp"] = float(depth_times[entry["depth_frame"]])
        return {
            "rounds": self.rounds, "keyframes": self.keyframes, "frames": self.frames, "corrected": self.corrected,
            "kept": self.kept, "unread": self.unread,
            "beyond_limits": beyond,
            "apart_from_keyframes": apart,
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
        for round_ in range(settings.align_rounds):  # every keyframe against its neighbours' poses of the round before
            jobs = []
            for n, key in _back_and_forth(keys, round_):
                near = [k for k in keys[max(0, n - side):n + side + 1] if k != key]
                jobs.append(([key], [(k, depth_files[k], rotations[k], translations[k]) for k in near],
                             [(key, depth_files[key], rotations[key], translations[key])], limits, None))
            found = _corrections(jobs, helpers)
            for key, correction in found.items():
                if correction is not None:
                    rotations[key], translations[key] = part_way(rotations[key], translations[key], correction,
                                                                 2 * side / (2 * side + 1))
        for key in keys:  # a keyframe's correction over all rounds is held to the limits
            last = found[key]  # its last round's
            if last is None:
                alignment.unread += 1
                continue
            if last.apart:  # in the last round it did not meet its neighbours' depth: its pose is kept
                rotations[key], translations[key] = depth_poses.rotations[key], depth_poses.translations[key]
                alignment.add(key, last)  # not applied: kept, and listed apart
                continue
            overall = judged(depth_poses.rotations[key], depth_poses.translations[key], rotations[key],
                             translations[key], MIN_PAIRS, settings.align_max_shift, settings.align_max_turn)
            rotations[key], translations[key] = overall.rotation, overall.translation
            alignment.add(key, overall)
        jobs = []
        runs = _between(keys, np.flatnonzero(depth_poses.ok), settings.keyframes_each_side)
        downwards = settings.align_rounds % 2 == 1  # from where the last round ended
        for _, (before, after, frames) in _back_and_forth(runs, settings.align_rounds):
            window = (*before, *after)
            jobs.append((frames, [(k, depth_files[k], rotations[k], translations[k]) for k in window],
                         [(f, depth_files[f], rotations[f], translations[f]) for f in frames], limits,
                         (max(window), -1) if downwards else (min(window), 1)))
        for frame, correction in _corrections(jobs, helpers).items():
            alignment.frames += 1
            if correction is None:
                alignment.unread += 1
                continue
            rotations[frame], translations[frame] = correction.rotation, correction.translation
            alignment.add(frame, correction)
    finally:
        _kept.clear()  # this process goes on to make masks
    return FramePoses(rotations, translations, depth_poses.ok, depth_poses.reasons), alignment


def part_way(rotation: np.ndarray, translation: np.ndarray, correction: Correction,
             share: float) -> tuple[np.ndarray, np.ndarray]:
    """The pose ``share`` of the way from ``(rotation, translation)`` to a correction's (the
    rotation along the shortest turn, the translation along the straight line)."""
    turn, _ = cv2.Rodrigues(rotation.T @ correction.rotation)
    part, _ = cv2.Rodrigues(turn * share)
    return rotation @ part, translation + share * (correction.translation - translation)


def _back_and_forth(items: list, round_: int) -> list[tuple[int, object]]:
    """``items`` with their indices, in order on even rounds and in reverse on odd ones: the order
    of a round's jobs changes no pose, but a round that starts where the last one ended finds
    those keyframes still kept (:func:`_keyframe`)."""
    numbered = list(enumerate(items))
    return numbered[::-1] if round_ % 2 else numbered


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
    """Align the frames of one job ``(frame indices, keyframes [(depth frame, path, rotation,
    translation)], frames [(depth frame, path, rotation, translation)], (camera, max_depth, step,
    max_shift, max_turn), past)`` to the job's keyframes: the function :func:`align_frames` gives
    :func:`annotate_rgbd.pool.run_jobs`. ``past`` is None when the frames are keyframes (aligned
    to each other), else ``(bound, direction)``: the jobs of the other frames go over the
    keyframes in one direction, and no job after this one takes a keyframe before ``bound``
    (:func:`_forget_past`). A frame whose depth, or every keyframe's, cannot be read gets None; a
    keyframe that cannot be read is left out."""
    indices, keyframes, frames, (camera, max_depth, step, max_shift, max_turn), past = job
    if past is not None:
        _forget_past(*past)
    readable = []
    for key, path, r, t in keyframes:
        try:
            readable.append((_keyframe(key, path, camera, max_depth, step)[2], r, t))
        except InputError:
            continue  # the others still align the frames
    if not readable:
        return dict.fromkeys(indices)
    views = stack_views([v for v, _, _ in readable], [r for _, r, _ in readable], [t for _, _, t in readable])
    corrections: dict[int, Correction | None] = {}
    for index, (key, path, r, t) in zip(indices, frames):
        try:
            if past is None:  # a keyframe
                points = _keyframe(key, path, camera, max_depth, step)[1]
            else:
                points = frame_points(_depth(path, camera), camera, step, max_depth)
        except InputError:
            corrections[index] = None
            continue
        corrections[index] = align_pose(points, r, t, views, camera, max_shift, max_turn)
    return corrections


def _keyframe(frame: int, path: Path, camera: Camera, max_depth: float,
              step: int) -> tuple[int, np.ndarray, KeyframeView]:
    """A keyframe's depth frame, its own points to align
    (:func:`annotate_rgbd.propagate.icp.frame_points`) and its view to align to, kept for the
    next jobs and rounds: successive jobs share most of their keyframes (a keyframe's
    neighbours, a run of frames between keyframes), and the rounds go over the keyframes back and
    forth, so that each round starts on the keyframes the last one ended on. The
    :data:`KEPT_KEYFRAMES` most recently used stay kept, within :data:`KEPT_BYTES`."""
    key = (path, camera, max_depth, step)
    found = _kept.pop(key, None)
    if found is None:
        depth = _depth(path, camera)
        found = frame, frame_points(depth, camera, step, max_depth), keyframe_view(depth, camera, max_depth)
    _kept[key] = found
    while len(_kept) > KEPT_KEYFRAMES or (len(_kept) > 1 and _kept_bytes() > KEPT_BYTES):
        _kept.popitem(last=False)
    return found


def _kept_bytes() -> int:
    """The memory the kept keyframes hold (their points and views)."""
    return sum(points.nbytes + view.nbytes for _, points, view in _kept.values())


def _forget_past(bound: int, direction: int) -> None:
    """Let go of the kept keyframes before depth frame ``bound`` in ``direction`` (1: those
    below it, -1: those above it): the jobs of the other frames go over the keyframes one way,
    so that, when the last of them is done, a process (a helper going on to make masks) keeps
    only the last few."""
    for key in [key for key, (frame, _, _) in _kept.items() if direction * (frame - bound) < 0]:
        del _kept[key]


def _depth(path: Path, camera: Camera) -> np.ndarray:
    """A depth frame in metres (NaN where invalid)."""
    return depth_to_metres(read_depth(path), camera.depth_scale)

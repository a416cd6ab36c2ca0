"""Camera trajectories in any of the common forms, and the camera pose at any timestamp.

A trajectory is the camera-to-world transform of the camera's optical centre (``X_world = R @
X_camera + t``, metres) over time. :func:`read_trajectory` reads it from

* a TUM file (``timestamp tx ty tz qx qy qz qw``; TUM RGB-D, ICL-NUIM, most SLAM systems) or a
  KITTI file (12 numbers a line: the 3 x 4 matrix, one line per frame), read streaming
  (:mod:`annotate_rgbd.io.trajectory_text`);
* a folder of per-frame 4 x 4 pose files, ScanNet's ``pose/<frame>.txt`` or 7-Scenes'
  ``frame-000000.pose.txt`` (:mod:`annotate_rgbd.io.pose_files`).

TUM timestamps are seconds; KITTI rows and pose files count frames (``clock``). Every pose must be
a rigid transform; :func:`load_trajectory` then fits a trajectory to a sequence's frames and says,
in one line each, what does not look right (:mod:`annotate_rgbd.io.trajectory_checks`): motion
implausible for an RGB-D camera (1e300 m, millimetres, world-to-camera), and frames outside it
with the two time ranges and the likely unit or offset (:func:`missing_poses_text`).

A depth frame's pose is interpolated at its own timestamp between the two trajectory samples that
bracket it: translation linearly, rotation by SLERP along the shorter arc (``q`` and ``-q`` are the
same rotation). Motion capture loses the markers now and then, so a frame whose bracketing samples
are not both close to it gets no pose (see :data:`DEFAULT_MAX_POSE_GAP`). Frame-numbered poses
are exact per frame: a frame without one (ScanNet's lost tracking) gets none.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np

from annotate_rgbd.errors import InputError
from annotate_rgbd.io.layouts.model import FRAME_NUMBERS, SECONDS
from annotate_rgbd.io.pose_files import read_pose_files
from annotate_rgbd.io.rotations import matrix_quaternions, quaternion_matrices, slerp
from annotate_rgbd.io.trajectory_checks import coverage_text, motion_problem, spacing_text
from annotate_rgbd.io.trajectory_text import KITTI, MAX_BYTES, MAX_LINES, UNIT_TOLERANCE, read_text_poses

#: Default of ``max_gap`` in :func:`poses_at`, seconds. TUM RGB-D's motion capture samples at
#: 100 Hz, so normally both samples bracketing a depth frame lie within 0.01 s of it. With 0.05 s
#: every frame in a drop-out up to 0.05 s long (four lost samples) gets a pose, frames in the
#: middle part of one up to 0.1 s long too, frames in longer ones none. The worst case let
#: through is the middle of a 0.1 s bracket. Measured on the real ``freiburg1_rpy`` trajectory (a
#: fast hand-held sweep, median 67 degrees/s) by leaving samples out and interpolating at a
#: left-out one in the middle of the hole: there the rotation is off by 0.43 degrees median, 1.1
#: at the 95th percentile (about 4 and 10 px at fx = 517) and the translation by 0.06 / 0.14 cm,
#: against 0.08 / 0.21 degrees in a 0.02 s bracket and 0.9 / 2.9 degrees in a 0.2 s one. A few
#: pixels of outline offset are small beside the fallback's error (2-D interpolation of the
#: keyframes' polygons: mean IoU 0.80 with keyframes every 10 frames, as measured in issue 16),
#: and the frame's own depth refinement trims what the offset puts off the plane. That trajectory has 8 brackets
#: longer than 0.015 s (0.02 to 0.13 s): 4 of 831 frames at 30 Hz along it fall in gaps (8 with
#: a 0.02 s limit, 2 with 0.1 s).
DEFAULT_MAX_POSE_GAP = 0.05

#: Reasons for a frame without a pose, as :func:`poses_at` gives them.
OUTSIDE_TRAJECTORY = "outside_trajectory"
POSE_GAP = "pose_gap"

__all__ = [
    "DEFAULT_MAX_POSE_GAP", "FRAME_NUMBERS", "MAX_BYTES", "MAX_LINES", "OUTSIDE_TRAJECTORY", "POSE_GAP", "SECONDS",
    "UNIT_TOLERANCE", "FramePoses", "LoadedTrajectory", "Trajectory", "load_trajectory", "matrix_quaternions",
    "missing_poses_text", "poses_at", "poses_of_frames", "quaternion_matrices", "read_trajectory", "slerp",
]


@dataclass(frozen=True)
class Trajectory:
    """Camera-to-world poses at strictly increasing timestamps (arrays are read-only).

    Parameters
    ----------
    timestamps : ndarray of float64, shape (N,)
        Strictly increasing: seconds, or frame numbers (``clock``).
    translations : ndarray of float64, shape (N, 3)
        Camera centre in world coordinates, metres.
    quaternions : ndarray of float64, shape (N, 4)
        Camera-to-world rotation as unit quaternions ``(x, y, z, w)``.
    clock : str
        :data:`SECONDS` (TUM) or :data:`FRAME_NUMBERS` (KITTI rows, pose files).
    form : str
        "TUM", "KITTI", "ScanNet pose files" or "7-Scenes pose files".
    without_pose : int
        Pose files that hold ``-inf`` or NaN (frames whose tracking was lost).
    """

    timestamps: np.ndarray
    translations: np.ndarray
    quaternions: np.ndarray
    clock: str = SECONDS
    form: str = "TUM"
    without_pose: int = 0

    def __len__(self) -> int:
        return len(self.timestamps)


class FramePoses(NamedTuple):
    """Poses at query timestamps, from :func:`poses_at`.

    Parameters
    ----------
    rotations : ndarray of float64, shape (M, 3, 3)
        Camera-to-world rotation matrices; NaN where ``ok`` is False.
    translations : ndarray of float64, shape (M, 3)
        Camera centres in world coordinates, metres; NaN where ``ok`` is False.
    ok : ndarray of bool, shape (M,)
        Whether the frame has a pose.
    reasons : ndarray of str, shape (M,)
        ``""`` where ``ok``, else :data:`OUTSIDE_TRAJECTORY` or :data:`POSE_GAP`.
    """

    rotations: np.ndarray
    translations: np.ndarray
    ok: np.ndarray
    reasons: np.ndarray


class LoadedTrajectory(NamedTuple):
    """A trajectory fitted to a sequence's frames, from :func:`load_trajectory`.

    Parameters
    ----------
    trajectory : Trajectory
        On the sequence's clock.
    warnings : list of str
        One line each: implausible motion (:func:`~annotate_rgbd.io.trajectory_checks.motion_problem`).
    notes : list of str
        One line each: how frame-numbered poses were matched to timestamped frames, frames whose
        pose file holds ``-inf``.
    """

    trajectory: Trajectory
    warnings: list[str]
    notes: list[str]


def read_trajectory(path: str | Path) -> Trajectory:
    """Read a trajectory: a TUM or KITTI file, or a folder of per-frame pose files.

    Parameters
    ----------
    path : str or Path
        The file, or the folder (a ScanNet scene or its ``pose/``, a 7-Scenes sequence).

    Returns
    -------
    Trajectory
        The poses, quaternions of unit length.

    Raises
    ------
    InputError
        One line naming the file (and the line) and the problem: unreadable, not a regular file
        (a FIFO is refused), too large, not UTF-8, wrong number of fields, not a number, NaN or
        infinite, non-unit quaternion, not a rigid transform, timestamps not strictly
        increasing, no poses at all.
    """
    path = Path(path)
    if path.is_dir():
        found = read_pose_files(path)
        arrays = (found.frames, found.translations, found.quaternions)
        extra = {"clock": FRAME_NUMBERS, "form": found.form, "without_pose": found.without_pose}
    else:
        text = read_text_poses(path)
        arrays = (text.timestamps, text.translations, text.quaternions)
        extra = {"clock": FRAME_NUMBERS if text.form == KITTI else SECONDS, "form": text.form}
    for array in arrays:
        array.flags.writeable = False
    return Trajectory(*arrays, **extra)


def load_trajectory(path: str | Path, frame_times: np.ndarray, clock: str) -> LoadedTrajectory:
    """Read a trajectory for a sequence's depth frames and check it.

    Frame-numbered poses (KITTI rows, pose files) on a sequence with timestamps are taken as the
    depth frames in order: pose ``k`` is the ``k``-th depth frame's (a note says so).

    Parameters
    ----------
    path : str or Path
    frame_times : ndarray, shape (M,)
        The depth frames' timestamps, increasing.
    clock : str
        What they count: :data:`SECONDS` or :data:`FRAME_NUMBERS`.

    Returns
    -------
    LoadedTrajectory

    Raises
    ------
    InputError
        As :func:`read_trajectory`, or frame-numbered poses beyond the sequence's depth frames.
    """
    trajectory = read_trajectory(path)
    notes = []
    if trajectory.without_pose:
        notes.append(f"{path}: {trajectory.without_pose} of {trajectory.without_pose + len(trajectory)} "
                     f"{trajectory.form} hold -inf or NaN (tracking lost): those frames have no pose")
    if trajectory.clock == FRAME_NUMBERS and clock == SECONDS:
        frames = trajectory.timestamps.astype(np.int64)
        if frames[-1] >= len(frame_times):
            raise InputError(path, f"{trajectory.form} poses count frames (no timestamps) and go up to frame "
                             f"{frames[-1]}, but the sequence has {len(frame_times)} depth frames: "
                             "give this sequence's trajectory, or one with timestamps (TUM)")
        times = np.asarray(frame_times, dtype=np.float64)[frames]
        times.flags.writeable = False
        trajectory = replace(trajectory, timestamps=times, clock=SECONDS)
        notes.append(f"{path}: {trajectory.form} poses count frames (no timestamps): pose k is taken as the "
                     "k-th depth frame's")
    problem = motion_problem(trajectory.timestamps, trajectory.translations, trajectory.quaternions,
                             trajectory.clock)
    warnings = [f"{path}: {problem}"] if problem else []
    return LoadedTrajectory(trajectory, warnings, notes)


def poses_of_frames(
    trajectory: Trajectory, path: str | Path, times: np.ndarray, max_gap: float, clock: str, frames: str,
) -> tuple[FramePoses, str]:
    """:func:`poses_at` for frames a command needs poses for, refusing a trajectory that gives
    none of them one.

    Parameters
    ----------
    trajectory : Trajectory
    path : str or Path
        Where it was read from, for the message.
    times : ndarray, shape (M,)
        The frames' timestamps.
    max_gap : float
        As in :func:`poses_at`.
    clock : str
        What the timestamps count.
    frames : str
        What the frames are, for the message ("processed depth frame", "written frame").

    Returns
    -------
    poses : FramePoses
    ranges : str
        :func:`missing_poses_text` for the frames without a pose (``""`` when all have one).

    Raises
    ------
    InputError
        Frames given and none has a pose: the two time ranges and the likely unit or offset said.
    """
    found = poses_at(trajectory, times, max_gap)
    ranges = "" if found.ok.all() else missing_poses_text(trajectory, times, found.reasons, clock)
    if len(times) and not found.ok.any():
        raise InputError(path, f"no {frames} has a pose{': ' + ranges if ranges else ''}")
    return found, ranges


def missing_poses_text(trajectory: Trajectory, times: np.ndarray, reasons: np.ndarray, clock: str) -> str:
    """Why frames have no pose, in a phrase: the two time ranges and the likely unit or offset
    when some lie outside the trajectory; the samples' spacing (and the likely unit) when most
    fall between samples too far apart; when a few do (tracking lost for a moment), their
    timestamps; else ``""``.

    Parameters
    ----------
    trajectory : Trajectory
    times : ndarray, shape (M,)
        The frames' timestamps.
    reasons : ndarray of str, shape (M,)
        :func:`poses_at`'s reasons for them.
    clock : str
        What the timestamps count.
    """
    if np.any(reasons == OUTSIDE_TRAJECTORY):
        return coverage_text(trajectory.timestamps, np.asarray(times), clock)
    if clock == SECONDS and len(trajectory) > 1 and 2 * np.count_nonzero(reasons == POSE_GAP) > len(reasons):
        return spacing_text(float(np.median(np.diff(trajectory.timestamps))))
    in_gaps = np.asarray(times)[reasons == POSE_GAP]
    if in_gaps.size:
        named = ", ".join(f"{value:.6f}" if clock == SECONDS else f"{value:.0f}" for value in in_gaps[:3])
        more = f" and {in_gaps.size - 3} more" if in_gaps.size > 3 else ""
        unit = " s" if clock == SECONDS else ""
        return f"the trajectory has no sample close to {'them' if in_gaps.size > 1 else 'it'} (a gap in tracking): {named}{unit}{more}"
    return ""


def poses_at(
    trajectory: Trajectory, times: np.ndarray, max_gap: float = DEFAULT_MAX_POSE_GAP
) -> FramePoses:
    """Camera poses at the given timestamps, interpolated between the bracketing samples.

    A time equal to a sample's gets that sample. Otherwise the samples just before and just
    after it are interpolated (translation linearly, rotation by SLERP along the shorter arc)
    when both lie within ``max_gap`` of it.

    Parameters
    ----------
    trajectory : Trajectory
    times : array_like of float, shape (M,)
        Query timestamps, seconds, in any order.
    max_gap : float
        Largest distance in seconds from a query time to either of its bracketing samples.

    Returns
    -------
    FramePoses
        ``(rotations (M, 3, 3), translations (M, 3), ok (M,), reasons (M,))``; a time before the
        first sample, after the last or NaN is :data:`OUTSIDE_TRAJECTORY`, one whose bracketing
        samples are too far from it :data:`POSE_GAP`.
    """
    if not (np.isfinite(max_gap) and max_gap >= 0):
        raise ValueError(f"max_gap must be a non-negative number of seconds, not {max_gap!r}")
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    stamps = trajectory.timestamps
    n = len(stamps)
    if n == 0:
        raise ValueError("the trajectory holds no poses")
    after = np.searchsorted(stamps, times, side="left")  # first sample at or after each time
    exact = (after < n) & (stamps[np.minimum(after, n - 1)] == times)
    inside = exact | ((after > 0) & (after < n))
    lower = np.where(exact, after, np.clip(after - 1, 0, n - 1))
    upper = np.where(exact, after, np.clip(after, 0, n - 1))
    with np.errstate(invalid="ignore"):
        near = (times - stamps[lower] <= max_gap) & (stamps[upper] - times <= max_gap)
    ok = inside & near
    reasons = np.where(inside, np.where(near, "", POSE_GAP), OUTSIDE_TRAJECTORY)

    span = stamps[upper] - stamps[lower]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(ok & (span > 0), (times - stamps[lower]) / span, 0.0)
    t0, t1 = trajectory.translations[lower], trajectory.translations[upper]
    translations = t0 + u[:, None] * (t1 - t0)
    q0, q1 = trajectory.quaternions[lower], trajectory.quaternions[upper]
    quaternions = np.where(exact[:, None], q0, slerp(q0, q1, u))
    rotations = quaternion_matrices(quaternions)
    translations[~ok] = np.nan
    rotations[~ok] = np.nan
    return FramePoses(rotations, translations, ok, reasons)

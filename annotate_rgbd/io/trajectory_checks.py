"""Checks of a camera trajectory: rigid poses, plausible motion, and whether it covers the frames.

A trajectory is read as camera-to-world (``X_world = R @ X_camera + t``, metres). What can be
checked of that convention is checked: every pose must be a rigid transform (an orthonormal
rotation, not a reflection; a 4 x 4 matrix ends in ``0 0 0 1``), and the camera must move as a
hand-held or robot-borne RGB-D camera does. A trajectory whose motion is implausible read as
camera-to-world but plausible read as world-to-camera is said to look like the latter. Whether a
trajectory belongs to a sequence is told by the two time ranges; a unit (nanoseconds,
microseconds, milliseconds) or an offset that would make them agree is suggested.
"""

from __future__ import annotations

import numpy as np

from annotate_rgbd.io.layouts.model import SECONDS
from annotate_rgbd.io.rotations import quaternion_matrices, rotation_angles

#: Farthest a camera may be from the world origin, metres: no RGB-D sequence spans 10 km; a
#: trajectory in millimetres, or garbage, does.
MAX_POSITION = 1e4
#: Largest median speed between consecutive poses, m/s: hand-held and robot-borne RGB-D cameras
#: move well under 2 m/s (TUM RGB-D's fastest hand-held sequences about 1 m/s).
MAX_SPEED = 10.0
#: Largest median turn rate, degrees/s (TUM ``freiburg1_rpy``, a fast hand-held sweep: median 67).
MAX_TURN_RATE = 360.0
#: Frame rate assumed for trajectories whose "timestamps" are frame numbers (ScanNet, 7-Scenes
#: and KITTI-form files): 30 Hz, as both datasets were recorded.
FRAME_RATE = 30.0
#: Closest average spacing of a trajectory's samples or of frames, seconds, for a unit to be
#: suggested: motion capture runs at up to about 1 kHz, cameras slower.
MIN_SAMPLE_SPACING = 1e-4
#: Units a trajectory's (or the frames') timestamps may be in instead of seconds.
UNITS = ((1e9, "nanoseconds"), (1e6, "microseconds"), (1e3, "milliseconds"))


def motion_problem(timestamps: np.ndarray, translations: np.ndarray, quaternions: np.ndarray, clock: str) -> str | None:
    """One line when a trajectory's motion is implausible for an RGB-D camera, else ``None``.

    Parameters
    ----------
    timestamps : ndarray, shape (N,)
        Strictly increasing; seconds, or frame numbers (``clock``, taken at :data:`FRAME_RATE`).
    translations : ndarray, shape (N, 3)
        Camera-to-world translations (camera centres), metres.
    quaternions : ndarray, shape (N, 4)
        Camera-to-world rotations ``(x, y, z, w)``.
    clock : str
        :data:`~annotate_rgbd.io.layouts.model.SECONDS` or ``FRAME_NUMBERS``.

    Returns
    -------
    str or None
        A camera beyond :data:`MAX_POSITION` from the origin, or a median speed above
        :data:`MAX_SPEED` or turn rate above :data:`MAX_TURN_RATE` (with, when read as
        world-to-camera or in millimetres the speed is plausible, that suggestion).
    """
    farthest = float(np.max(np.abs(translations)))  # a coordinate: a norm of 1e300 overflows
    if not farthest <= MAX_POSITION:
        return (f"the camera lies {farthest:.3g} m from the world origin (on an axis): not a camera-to-world "
                "trajectory in metres (millimetres? corrupt values?)")
    if len(timestamps) < 2:
        return None
    seconds = np.diff(timestamps) / (1.0 if clock == SECONDS else FRAME_RATE)
    rotations = quaternion_matrices(quaternions)
    speed = _median_speed(translations, seconds)
    turns = np.degrees(rotation_angles(rotations[:-1], rotations[1:])) / seconds
    turn_rate = float(np.median(turns))
    if speed > MAX_SPEED:
        line = (f"the camera moves {speed:.3g} m/s (median between consecutive poses), implausible for an "
                "RGB-D camera read as camera-to-world in metres")
        centres = -np.einsum("nji,nj->ni", rotations, translations)  # read as world-to-camera
        if _median_speed(centres, seconds) <= MAX_SPEED:
            line += (f"; read as world-to-camera it moves {_median_speed(centres, seconds):.3g} m/s: "
                     "is the file world-to-camera? (invert every pose)")
        elif speed / 1000.0 <= MAX_SPEED:
            line += (f"; in millimetres it would move {speed / 1000.0:.3g} m/s: are the translations in "
                     "millimetres? (divide them by 1000)")
        return line
    if turn_rate > MAX_TURN_RATE:
        return (f"the camera turns {turn_rate:.3g} degrees/s (median between consecutive poses), implausible "
                "for an RGB-D camera: are these poses of this sequence, in the order of its frames?")
    return None


def coverage_text(stamps: np.ndarray, times: np.ndarray, clock: str) -> str:
    """The trajectory's and the frames' time ranges in one phrase, with a likely fix.

    Parameters
    ----------
    stamps : ndarray, shape (N,)
        The trajectory's timestamps (N >= 1), increasing.
    times : ndarray, shape (M,)
        The frames' timestamps (M >= 1).
    clock : str
        What both count: :data:`SECONDS` or frame numbers.

    Returns
    -------
    str
        ``"the trajectory spans 0.5 to 30 s (3000 poses), the depth frames 1305031102 to 1305031130
        s: ..."`` with the suggestion of :func:`coverage_hint`, if any.
    """
    a0, a1 = float(stamps[0]), float(stamps[-1])
    b0, b1 = float(np.min(times)), float(np.max(times))
    if clock == SECONDS:
        span = (f"the trajectory spans {_time(a0)} to {_time(a1)} s ({len(stamps)} poses), the depth frames "
                f"{_time(b0)} to {_time(b1)} s")
    else:
        span = (f"the trajectory holds frames {a0:.0f} to {a1:.0f} ({len(stamps)} poses), the sequence "
                f"depth frames {b0:.0f} to {b1:.0f}")
    hint = coverage_hint(a0, a1, b0, b1, clock, len(stamps), len(times))
    return f"{span}: {hint}" if hint else span


def coverage_hint(a0: float, a1: float, b0: float, b1: float, clock: str, n_poses: int = 2,
                  n_frames: int = 2) -> str | None:
    """The likely reason why a trajectory ``[a0, a1]`` of ``n_poses`` misses ``n_frames`` frames
    ``[b0, b1]``, or ``None`` when it covers most of them.

    A unit: the ranges overlap once the trajectory's (or the frames') timestamps are divided by
    1e9, 1e6 or 1e3, and the samples are then no closer than :data:`MIN_SAMPLE_SPACING` on
    average (no sensor runs faster). An offset: the durations agree (within a factor of 2, in
    some unit) but the ranges do not overlap. A trajectory that covers one end of the frames but
    stops (or starts) inside them: cut short. Otherwise the trajectory is likely another sequence's.
    Frame numbers (``clock``) have no unit: only the last is said.
    """
    covered = _overlap(a0, a1, b0, b1)
    if covered >= 0.5:
        return None
    if clock == SECONDS:
        for scale, name in UNITS:
            spacing = ((a1 - a0) / scale / max(n_poses - 1, 1), (b1 - b0) / scale / max(n_frames - 1, 1))
            if _overlap(a0 / scale, a1 / scale, b0, b1) >= 0.5 and spacing[0] >= MIN_SAMPLE_SPACING:
                return f"the trajectory's timestamps look like {name}: divide them by {scale:g}"
            if _overlap(a0, a1, b0 / scale, b1 / scale) >= 0.5 and spacing[1] >= MIN_SAMPLE_SPACING:
                return (f"the depth frames' timestamps look like {name} and the trajectory's like seconds: "
                        "write both in one unit")
        for scale, name in ((1.0, "seconds"), *UNITS):
            da, db = (a1 - a0) / scale, b1 - b0
            if db > 0 and 0.5 <= da / db <= 2.0:
                unit = "" if scale == 1.0 else f" with the trajectory in {name}"
                late = a0 / scale - b0  # what propagate.time_offset adds to the frames' timestamps
                fix = f" (propagate.time_offset = {late:.3f} lines them up)" if scale == 1.0 else ""
                return (f"the durations agree{unit} but the trajectory starts {abs(late):.3f} s "
                        f"{'after' if late > 0 else 'before'} the first depth frame{fix}: a clock offset, or the "
                        "trajectory of another recording of the same length")
        if covered > 0.0 and (a0 <= b0 or a1 >= b1):  # one end inside the frames: cut short?
            where = (f"ends {b1 - a1:.3g} s before the last depth frame" if a0 <= b0 else
                     f"starts {a0 - b0:.3g} s after the first depth frame")
            return (f"the trajectory {where} and covers {covered:.0%} of the frames' time: was it recorded or cut "
                    "short? (frames outside it get no pose)")
        if covered == 0.0:
            return f"the ranges do not overlap ({_apart(a0, a1, b0, b1)}): is it this sequence's trajectory?"
        return "the ranges hardly overlap: is it this sequence's trajectory?"
    return ("the ranges hardly overlap: is it this sequence's trajectory? (its frames are numbers, and poses are "
            "matched to them by frame number: a TUM line's timestamp must be the frame's number)")


def _apart(a0: float, a1: float, b0: float, b1: float) -> str:
    """How far a trajectory ``[a0, a1]`` lies from frames ``[b0, b1]`` it does not overlap."""
    gap, where = (a0 - b1, "starts {} s after the last") if a0 > b1 else (b0 - a1, "ends {} s before the first")
    return f"the trajectory {where.format(f'{gap:.3g}' if gap < 100 else f'{gap:.0f}')} depth frame"


def spacing_text(spacing: float) -> str:
    """Why frames inside a trajectory get no pose: its samples (``spacing`` apart, seconds, the
    median) are too far apart; with the likely unit when that spacing is one in another unit."""
    text = f"the trajectory's samples lie {spacing:.6g} s apart (median), too far apart to interpolate a pose"
    for scale, name in UNITS:
        if MIN_SAMPLE_SPACING <= spacing / scale <= 1.0:
            return f"{text}: its timestamps look like {name}: divide them by {scale:g}"
    return text


def _overlap(a0: float, a1: float, b0: float, b1: float) -> float:
    """The share of ``[b0, b1]`` inside ``[a0, a1]`` (1 or 0 for a single time)."""
    if b1 <= b0:
        return float(a0 <= b0 <= a1)
    return max(0.0, min(a1, b1) - max(a0, b0)) / (b1 - b0)


def _time(value: float) -> str:
    return f"{value:.13g}"


def _median_speed(centres: np.ndarray, seconds: np.ndarray) -> float:
    with np.errstate(over="ignore", invalid="ignore"):
        return float(np.median(np.linalg.norm(np.diff(centres, axis=0), axis=1) / seconds))


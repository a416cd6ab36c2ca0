"""Camera trajectories in TUM format, and the camera pose at any timestamp.

A trajectory file holds one pose per line, ``timestamp tx ty tz qx qy qz qw``: the camera-to-world
transform of the camera's optical centre (TUM RGB-D ``groundtruth.txt``, ICL-NUIM's TUM-format
trajectories, what most SLAM systems write), metres and seconds, the rotation as a unit quaternion
with the scalar last. ``#`` starts a comment that runs to the end of the line; blank lines are
skipped. A world point is ``X_world = R @ X_camera + t``.

A depth frame's pose is interpolated at its own timestamp between the two trajectory samples that
bracket it: translation linearly, rotation by SLERP along the shorter arc (``q`` and ``-q`` are the
same rotation). Motion capture loses the markers now and then, so a frame whose bracketing samples
are not both close to it gets no pose (see :data:`DEFAULT_MAX_POSE_GAP`).
"""

from __future__ import annotations

import io
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from annotate_rgbd.errors import InputError

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

#: Largest deviation of a quaternion's norm from 1 accepted (and then renormalised). TUM writes 4
#: decimals, which leaves deviations up to about 1e-4; anything much larger is not a rotation.
UNIT_TOLERANCE = 1e-3

#: Refuse trajectory files larger than these: a one-hour 100 Hz trajectory has 360 000 lines.
MAX_BYTES = 1 << 30
MAX_LINES = 10_000_000

#: Reasons for a frame without a pose, as :func:`poses_at` gives them.
OUTSIDE_TRAJECTORY = "outside_trajectory"
POSE_GAP = "pose_gap"

FIELDS = ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw")


@dataclass(frozen=True)
class Trajectory:
    """Camera-to-world poses at strictly increasing timestamps (arrays are read-only).

    Parameters
    ----------
    timestamps : ndarray of float64, shape (N,)
        Seconds, strictly increasing.
    translations : ndarray of float64, shape (N, 3)
        Camera centre in world coordinates, metres.
    quaternions : ndarray of float64, shape (N, 4)
        Camera-to-world rotation as unit quaternions ``(x, y, z, w)``.
    """

    timestamps: np.ndarray
    translations: np.ndarray
    quaternions: np.ndarray

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


def read_trajectory(path: str | Path) -> Trajectory:
    """Read a TUM-format trajectory file.

    Parameters
    ----------
    path : str or Path
        The file: ``timestamp tx ty tz qx qy qz qw`` per line, ``#`` comments, blank lines.

    Returns
    -------
    Trajectory
        The poses, quaternions renormalised to unit length.

    Raises
    ------
    InputError
        One line naming the file, the line and the problem: unreadable, too large, not UTF-8,
        wrong number of fields, not a number, NaN or infinite, non-unit quaternion, timestamps
        not strictly increasing, no poses at all.
    """
    path = Path(path)
    # One line break for both readers below: "\n", "\r\n" or a lone "\r".
    data = _read_bytes(path).replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    if data.count(b"\n") + (not data.endswith(b"\n")) > MAX_LINES:
        raise InputError(path, f"more than {MAX_LINES:,} lines: too large for a trajectory file")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        line = data[: error.start].count(b"\n") + 1
        raise InputError(path, f"line {line}: not UTF-8 text") from None
    values, line_numbers = _parse(path, text)
    if len(values) == 0:
        raise InputError(path, "no poses: the file holds no 'timestamp tx ty tz qx qy qz qw' lines")

    def line_of(row: int) -> int:
        # Line numbers are only worked out when a problem must be reported.
        numbers = line_numbers if line_numbers is not None else _data_line_numbers(text)
        return int(numbers[row])

    finite = np.isfinite(values)
    if not finite.all():
        row, col = np.argwhere(~finite)[0]
        raise InputError(path, f"line {line_of(row)}: {FIELDS[col]} is {values[row, col]}")
    norms = np.linalg.norm(values[:, 4:], axis=1)
    off = np.abs(norms - 1.0) > UNIT_TOLERANCE
    if off.any():
        row = int(np.argmax(off))
        raise InputError(
            path,
            f"line {line_of(row)}: quaternion (qx qy qz qw) has length {norms[row]:.6g}, "
            f"not 1 (tolerance {UNIT_TOLERANCE:g})",
        )
    timestamps = values[:, 0]
    unordered = np.diff(timestamps) <= 0
    if unordered.any():
        row = int(np.argmax(unordered)) + 1
        raise InputError(
            path,
            f"line {line_of(row)}: timestamp {float(timestamps[row])!r} is not after "
            f"{float(timestamps[row - 1])!r} on line {line_of(row - 1)}; timestamps must be strictly increasing",
        )
    arrays = (
        np.ascontiguousarray(timestamps),
        np.ascontiguousarray(values[:, 1:4]),
        values[:, 4:] / norms[:, None],
    )
    for array in arrays:
        array.flags.writeable = False
    return Trajectory(*arrays)


def _read_bytes(path: Path) -> bytes:
    """The file's bytes, refusing files larger than :data:`MAX_BYTES`."""
    try:
        with open(path, "rb") as stream:
            size = os.fstat(stream.fileno()).st_size
            if size <= MAX_BYTES:  # a pipe reports 0: read at most one byte too many to tell
                data = stream.read(MAX_BYTES + 1)
                size = max(size, len(data))
    except OSError as error:
        raise InputError(path, f"cannot read the trajectory file ({error.strerror or error})") from None
    if size > MAX_BYTES:
        raise InputError(
            path, f"{size / 2**30:.1f} GiB: larger than the {MAX_BYTES / 2**30:g} GiB a trajectory may have"
        )
    return data


def _parse(path: Path, text: str) -> tuple[np.ndarray, np.ndarray | None]:
    """The (N, 8) values of the data lines; their line numbers when already known.

    numpy's C reader takes the common case (thousands of lines in milliseconds); on anything it
    rejects, the line-by-line reader finds the first problem and names its line.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data": reported by the caller
            values = np.loadtxt(io.StringIO(text), dtype=np.float64, comments="#", ndmin=2)
    except ValueError:
        return _parse_lines(path, text)
    if values.shape[1] != len(FIELDS) and values.size:
        return _parse_lines(path, text)
    return values.reshape(-1, len(FIELDS)), None


def _parse_lines(path: Path, text: str) -> tuple[np.ndarray, np.ndarray]:
    """Line-by-line reader: values and line numbers (from 1) of the data lines.

    Raises
    ------
    InputError
        At the first line with the wrong number of fields or a field that is not a number.
    """
    rows, numbers = [], []
    for number, line in enumerate(text.split("\n"), start=1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        if len(fields) != len(FIELDS):
            raise InputError(
                path,
                f"line {number}: expected {len(FIELDS)} fields ({' '.join(FIELDS)}), found {len(fields)}",
            )
        try:
            rows.append([float(field) for field in fields])
        except ValueError:
            col = next(k for k, field in enumerate(fields) if not _is_number(field))
            raise InputError(
                path, f"line {number}: {FIELDS[col]} {fields[col][:40]!r} is not a number"
            ) from None
        numbers.append(number)
    return np.array(rows, dtype=np.float64).reshape(-1, len(FIELDS)), np.array(numbers, dtype=np.int64)


def _data_line_numbers(text: str) -> np.ndarray:
    """Line numbers (from 1) of the lines holding data, as both readers see them."""
    lines = text.split("\n")
    return np.array([k for k, line in enumerate(lines, start=1) if line.split("#", 1)[0].strip()], dtype=np.int64)


def _is_number(field: str) -> bool:
    try:
        float(field)
    except ValueError:
        return False
    return True


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


def slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions along the shorter arc.

    Parameters
    ----------
    q0, q1 : ndarray, shape (M, 4)
        Unit quaternions at ``u = 0`` and ``u = 1``; ``q1`` is negated where that is nearer.
    u : ndarray, shape (M,)
        Interpolation parameters in [0, 1].

    Returns
    -------
    ndarray of float64, shape (M, 4)
        Unit quaternions.
    """
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)[:, None]
    q1 = np.where(np.sum(q0 * q1, axis=1, keepdims=True) < 0, -q1, q1)
    # The angle between the two 4-vectors; atan2 of chord lengths keeps it accurate when small,
    # which it always is between neighbouring samples (arccos of the dot product is not).
    angle = 2.0 * np.arctan2(
        np.linalg.norm(q0 - q1, axis=1, keepdims=True), np.linalg.norm(q0 + q1, axis=1, keepdims=True)
    )
    sine = np.sin(angle)
    small = sine < 1e-12  # equal rotations: weights (1 - u, u) are the limit
    with np.errstate(invalid="ignore", divide="ignore"):
        w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * angle) / sine)
        w1 = np.where(small, u, np.sin(u * angle) / sine)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def quaternion_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of unit quaternions ``(x, y, z, w)``.

    Parameters
    ----------
    q : ndarray, shape (M, 4)

    Returns
    -------
    ndarray of float64, shape (M, 3, 3)
    """
    x, y, z, w = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=-1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=-1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )

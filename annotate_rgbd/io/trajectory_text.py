"""Trajectory text files, read streaming: TUM rows and KITTI rows.

* **TUM** (8 numbers a line): ``timestamp tx ty tz qx qy qz qw``, seconds and metres, the
  camera-to-world rotation as a unit quaternion, scalar last (TUM RGB-D ``groundtruth.txt``,
  ICL-NUIM's TUM-format trajectories, what most SLAM systems write).
* **KITTI** (12 numbers a line): ``r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz``, the top three
  rows of the 4 x 4 camera-to-world matrix, row by row; line ``k`` (of the data lines) is frame
  ``k``: there are no timestamps.

The form is told by the first data line; every data line must have its number of fields. ``#``
starts a comment that runs to the end of the line; blank lines are skipped; ``\\n``, ``\\r\\n`` and
a lone ``\\r`` end lines; a UTF-8 byte order mark at the start is skipped.

The file is read in blocks of :data:`CHUNK_BYTES`, each parsed at once by numpy's C reader (the
line-by-line reader only finds and names a line numpy refused), so memory stays a small multiple
of the poses kept (64 bytes a pose) whatever the file holds: a line longer than
:data:`MAX_LINE_BYTES` (binary data) is refused as soon as it is seen.
"""

from __future__ import annotations

import io
import os
import warnings
from typing import NamedTuple

import numpy as np

from annotate_rgbd.errors import InputError
from annotate_rgbd.io.inputs import open_input
from annotate_rgbd.io.rotations import first_rigid_problem, matrix_quaternions

#: Refuse trajectory files larger than these: a one-hour 100 Hz trajectory has 360 000 lines.
MAX_BYTES = 1 << 30
MAX_LINES = 10_000_000
#: Bytes read and parsed at a time.
CHUNK_BYTES = 1 << 20
#: Longest line accepted: a pose line has about 100 bytes, with a comment a few hundred.
MAX_LINE_BYTES = 64 << 10
#: Largest deviation of a quaternion's norm from 1 accepted (and then renormalised). TUM writes 4
#: decimals, which leaves deviations up to about 1e-4; anything much larger is not a rotation.
UNIT_TOLERANCE = 1e-3

TUM = "TUM"
KITTI = "KITTI"
FIELDS = {
    TUM: ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw"),
    KITTI: ("r11", "r12", "r13", "tx", "r21", "r22", "r23", "ty", "r31", "r32", "r33", "tz"),
}
EXPECTED = {
    TUM: "8 fields (timestamp tx ty tz qx qy qz qw)",
    KITTI: "12 fields (KITTI: a 3 x 4 camera-to-world matrix, row by row)",
}
BOM = b"\xef\xbb\xbf"


class TextPoses(NamedTuple):
    """The poses of a trajectory text file.

    Parameters
    ----------
    form : str
        :data:`TUM` or :data:`KITTI`.
    timestamps : ndarray of float64, shape (N,)
        Seconds (TUM), or the frame numbers 0, 1, ... (KITTI).
    translations : ndarray of float64, shape (N, 3)
    quaternions : ndarray of float64, shape (N, 4)
        Unit quaternions ``(x, y, z, w)``.
    """

    form: str
    timestamps: np.ndarray
    translations: np.ndarray
    quaternions: np.ndarray


def read_text_poses(path) -> TextPoses:
    """Read a TUM or KITTI trajectory file, streaming.

    Raises
    ------
    InputError
        One line naming the file, the line and the problem: unreadable or not a regular file
        (a FIFO is refused, never waited on), too large, a line too long, a NUL byte, not UTF-8,
        the wrong number of fields, not a number, NaN or infinite, a non-unit quaternion or a
        non-rigid matrix, timestamps not strictly increasing, no poses at all.
    """
    try:
        handle = open_input(path, None)
    except InputError as error:
        raise InputError(path, f"cannot read the trajectory file ({error.message})") from None
    with handle:
        size = os.fstat(handle.fileno()).st_size
        if size > MAX_BYTES:
            raise InputError(
                path, f"{size / 2**30:.1f} GiB: larger than the {MAX_BYTES / 2**30:g} GiB a trajectory may have"
            )
        parser = _Parser(path)
        carry = handle.read(len(BOM))
        if carry == BOM:
            carry = b""
        while True:
            try:
                block = handle.read(CHUNK_BYTES)
            except OSError as error:
                raise InputError(path, f"cannot read the trajectory file ({error.strerror or error})") from None
            buffer = carry + block
            if not block:
                parser.feed(buffer, last=True)
                break
            # Cut after the last line break; a final "\r" stays, its "\n" may follow.
            cut = max(buffer.rfind(b"\n"), buffer.rfind(b"\r", 0, len(buffer) - 1))
            carry = buffer[cut + 1:]
            if len(carry) > MAX_LINE_BYTES:
                parser.feed(buffer[: cut + 1])
                raise InputError(path, f"line {parser.lines + 1}: longer than {MAX_LINE_BYTES // 1024} KiB: "
                                 "not a trajectory file (binary data?)")
            if cut >= 0:
                parser.feed(buffer[: cut + 1])
    return parser.result()


class _Parser:
    """Parses a trajectory's text block by block, checking every pose as it comes."""

    def __init__(self, path):
        self.path = path
        self.form: str | None = None
        self.lines = 0  # lines before the current block
        self.rows = 0  # data lines before the current block
        self.last_time: float | None = None
        self.last_line = 0
        self.parts: tuple[list[np.ndarray], ...] = ([], [], [])  # timestamps, translations, quaternions

    def feed(self, data: bytes, last: bool = False) -> None:
        """Parse one block of whole lines (``last``: the file's end, its last line may lack a break)."""
        data = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        count = data.count(b"\n") + (1 if last and data and not data.endswith(b"\n") else 0)
        if self.lines + count > MAX_LINES:
            raise InputError(self.path, f"more than {MAX_LINES:,} lines: too large for a trajectory file")
        nul = data.find(b"\x00")
        if nul >= 0:
            line = self.lines + data.count(b"\n", 0, nul) + 1
            raise InputError(self.path, f"line {line}: holds a NUL byte: not a trajectory file (binary data?)")
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError as error:
            line = self.lines + data.count(b"\n", 0, error.start) + 1
            raise InputError(self.path, f"line {line}: not UTF-8 text") from None
        values = self._values(text)
        if len(values):
            self._check_and_keep(values, text)
        self.lines += count

    def _values(self, text: str) -> np.ndarray:
        """The block's data rows; numpy's C reader first, the line reader when it refuses."""
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # "input contained no data"
                values = np.loadtxt(io.StringIO(text), dtype=np.float64, comments="#", ndmin=2)
        except ValueError:
            values = None
        if values is None or (values.size and values.shape[1] != self._width(values.shape[1], text)):
            values = self._parse_lines(text)
        return values.reshape(-1, len(FIELDS[self.form])) if self.form else values.reshape(0, 8)

    def _width(self, columns: int, text: str) -> int:
        """The number of fields of the form (told by the first data line of the file)."""
        if self.form is None and columns in (8, 12):
            self.form = TUM if columns == 8 else KITTI
        return len(FIELDS[self.form]) if self.form else -1

    def _parse_lines(self, text: str) -> np.ndarray:
        """Line-by-line: the data rows, or an error naming the first bad line."""
        rows = []
        for number, line in enumerate(text.split("\n"), start=self.lines + 1):
            fields = line.split("#", 1)[0].split()
            if not fields:
                continue
            if self.form is None and len(fields) in (8, 12):
                self.form = TUM if len(fields) == 8 else KITTI
            if self.form is None or len(fields) != len(FIELDS[self.form]):
                expected = EXPECTED[self.form] if self.form else f"{EXPECTED[TUM]} or {EXPECTED[KITTI]}"
                raise InputError(self.path, f"line {number}: expected {expected}, found {len(fields)}")
            try:
                rows.append([float(field) for field in fields])
            except ValueError:
                col = next(k for k, field in enumerate(fields) if not _is_number(field))
                raise InputError(
                    self.path, f"line {number}: {FIELDS[self.form][col]} {fields[col][:40]!r} is not a number"
                ) from None
        return np.array(rows, dtype=np.float64)

    def _check_and_keep(self, values: np.ndarray, text: str) -> None:
        numbers = None

        def line_of(row: int) -> int:
            nonlocal numbers  # the data lines' numbers are only worked out for a message
            if numbers is None:
                numbers = [k for k, line in enumerate(text.split("\n"), start=self.lines + 1)
                           if line.split("#", 1)[0].strip()]
            return numbers[row]

        fields = FIELDS[self.form]
        finite = np.isfinite(values)
        if not finite.all():
            row, col = np.argwhere(~finite)[0]
            raise InputError(self.path, f"line {line_of(row)}: {fields[col]} is {values[row, col]}")
        if self.form == TUM:
            times, translations, quaternions = self._tum(values, line_of)
        else:
            matrices = values.reshape(-1, 3, 4)
            row, problem = first_rigid_problem(matrices)
            if problem is not None:
                raise InputError(self.path, f"line {line_of(row)}: {problem}")
            times = np.arange(self.rows, self.rows + len(values), dtype=np.float64)
            translations = np.ascontiguousarray(matrices[:, :, 3])
            quaternions = matrix_quaternions(matrices[:, :, :3])
        for column, part in zip(self.parts, (times, translations, quaternions)):
            column.append(part)
        self.rows += len(values)
        self.last_time = float(times[-1])
        self.last_line = _last_data_line(text, self.lines + 1)

    def _tum(self, values: np.ndarray, line_of) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        norms = np.linalg.norm(values[:, 4:], axis=1)
        off = np.abs(norms - 1.0) > UNIT_TOLERANCE
        if off.any():
            row = int(np.argmax(off))
            raise InputError(self.path, f"line {line_of(row)}: quaternion (qx qy qz qw) has length {norms[row]:.6g}, "
                             f"not 1 (tolerance {UNIT_TOLERANCE:g})")
        times = np.ascontiguousarray(values[:, 0])
        previous = np.concatenate(([self.last_time], times[:-1])) if self.last_time is not None else times[:-1]
        later = times if self.last_time is not None else times[1:]
        unordered = later <= previous
        if unordered.any():
            row = int(np.argmax(unordered)) + (0 if self.last_time is not None else 1)
            before = line_of(row - 1) if row > 0 else self.last_line
            prior = float(times[row - 1]) if row > 0 else self.last_time
            raise InputError(self.path, f"line {line_of(row)}: timestamp {float(times[row])!r} is not after "
                             f"{prior!r} on line {before}; timestamps must be strictly increasing")
        return times, np.ascontiguousarray(values[:, 1:4]), values[:, 4:] / norms[:, None]

    def result(self) -> TextPoses:
        if not self.parts[0]:
            raise InputError(self.path, "no poses: the file holds no 'timestamp tx ty tz qx qy qz qw' lines "
                             "(TUM) nor 12-number rows (KITTI)")
        columns = []
        for column in self.parts:  # each column's blocks are let go once joined: at most 1.5 times what is kept
            columns.append(np.concatenate(column))
            column.clear()
        return TextPoses(self.form, *columns)


def _last_data_line(text: str, first: int) -> int:
    """The number of the last line holding data in ``text``, whose first line is ``first``
    (scanned from the end: the usual answer is the last line)."""
    end = len(text) - 1 if text.endswith("\n") else len(text)
    number = first + text.count("\n", 0, end)
    while end >= 0:
        start = text.rfind("\n", 0, end) + 1
        if text[start:end].split("#", 1)[0].strip():
            return number
        end, number = start - 1, number - 1
    return first


def _is_number(field: str) -> bool:
    try:
        float(field)
    except ValueError:
        return False
    return True

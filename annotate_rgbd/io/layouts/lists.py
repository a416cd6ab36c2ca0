"""What the layout readers share: frame lists, numbered frame files, small matrix files, bounds.

A listed file must lie inside the sequence folder (no absolute path, no ``..``, no symbolic link
leading out of it), so that a list can never make the tool read elsewhere; depth file names must
be distinct, since each names its mask. Lists, folders, matrices and timestamps are bounded
(``MAX_*`` below), so that no input costs unbounded time or memory.
"""

from __future__ import annotations

import io
import math
import os
import re
from collections.abc import Iterator
from pathlib import Path, PurePosixPath, PureWindowsPath

import numpy as np

from annotate_rgbd.errors import InputError
from annotate_rgbd.io.inputs import open_input
from .model import FrameList

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")

from annotate_rgbd.io.limits import MAX_FRAMES, MAX_TIMESTAMP  # the input bounds, in one place
#: Largest frame list read (checked before reading): a million ``associate.py`` lines of about
#: 90 bytes, with room for comments.
MAX_LIST_BYTES = 128 * 2**20
#: Most lines of a frame list, comments and blank lines included.
MAX_LIST_LINES = 2 * MAX_FRAMES
#: Largest small matrix file read (intrinsics, extrinsics, one pose): 16 numbers need ~300 bytes.
MAX_MATRIX_BYTES = 64 * 2**10


def check_inside(root: Path, files: tuple[str, ...]) -> None:
    """Refuse files that a symbolic link puts outside the sequence folder.

    Every folder of a listed file is resolved (symbolic links followed) and must lie inside the
    resolved sequence folder, and so must every listed file that is a symbolic link. Each folder
    is resolved and listed once, so a long list costs no system call per file. A missing file is
    left to fail with its frame.

    Parameters
    ----------
    root : Path
        The sequence folder.
    files : tuple of str
        Paths relative to ``root``, as listed.

    Raises
    ------
    InputError
        Naming the first file that resolves outside ``root``.
    """
    inside = os.path.join(os.path.realpath(root), "")
    folders: dict[str, tuple[str, frozenset[str]]] = {}  # listed folder -> (resolved, names of its links)
    for file in files:
        folder, _, name = file.rpartition("/")  # list paths are POSIX paths
        if folder not in folders:
            path = os.path.join(root, folder)
            try:
                with os.scandir(path) as entries:
                    links = frozenset(e.name for e in entries if e.is_symlink())
            except OSError:  # no such folder: its files fail with their frames
                links = frozenset()
            folders[folder] = (os.path.join(os.path.realpath(path), ""), links)
        real, links = folders[folder]
        if not real.startswith(inside) or (name in links and not os.path.realpath(real + name).startswith(inside)):
            raise InputError(root / file, "a symbolic link leads outside the sequence folder; refused")


def check_depth_names(depth: FrameList, source: Path) -> None:
    """Refuse two depth files with one file name: each names its mask, one would overwrite the other.

    Raises
    ------
    InputError
        Naming ``source`` (the depth list) and both files.
    """
    first: dict[str, str] = {}
    for file in depth.files:
        name = file.rpartition("/")[2]
        if name in ("", "."):  # "a/b/" or "a/b/.": the slow, general way
            name = PurePosixPath(file).name
        if name in first:
            raise InputError(
                source,
                f"depth files {first[name]!r} and {file!r} have one file name; masks are named "
                "after depth files, so each needs its own",
            )
        first[name] = file



def parse_timestamp(text: str) -> float:
    """A timestamp in seconds, finite and within ``MAX_TIMESTAMP``.

    Raises
    ------
    ValueError
        Saying why ``text`` is none ("is not a timestamp", "is out of range ...").
    """
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):  # NaN would scramble the frame order, infinity every time offset
        raise ValueError("is not a timestamp")
    if abs(value) > MAX_TIMESTAMP:
        raise ValueError(f"is out of range (timestamps are within +-{MAX_TIMESTAMP:g})")
    return value


def read_rows(path: Path, min_columns: int) -> Iterator[tuple[int, list[str]]]:
    """Non-comment lines of a TUM-style list as (line number, columns), read line by line.

    Raises
    ------
    InputError
        The list is unreadable, larger than ``MAX_LIST_BYTES``, has more than
        ``MAX_LIST_LINES`` lines or ``MAX_FRAMES`` rows, or a row has too few columns.
    """
    try:
        binary = open_input(path, MAX_LIST_BYTES)
    except InputError as exc:
        raise InputError(path, f"cannot read frame list: {exc.message}") from None
    with io.TextIOWrapper(binary, encoding="utf-8") as handle:
        try:
            rows = 0
            for number, raw in enumerate(handle, start=1):
                if number > MAX_LIST_LINES:
                    raise InputError(path, f"more than {MAX_LIST_LINES} lines; refused")
                columns = raw.split()
                if not columns or columns[0][0] == "#":
                    continue
                if len(columns) < min_columns:
                    raise InputError(path, f"line {number}: expected {min_columns} columns, got {len(columns)}")
                rows += 1
                if rows > MAX_FRAMES:
                    raise InputError(path, f"line {number}: more than {MAX_FRAMES} frames listed; at most {MAX_FRAMES} are read")
                yield number, columns
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(path, f"cannot read frame list: {exc}") from None


def listed_path(path: Path, line: int, file: str) -> str:
    """``file`` as listed, if it names a file inside the sequence folder."""
    if not file.startswith((".", "/")) and "\\" not in file and ":" not in file and ".." not in file:
        return file  # the usual "depth/1305031102.160407.png": none of the cases below
    posix = PurePosixPath(file.replace("\\", "/"))
    if posix.is_absolute() or PureWindowsPath(file).drive:
        raise InputError(path, f"line {line}: {file!r} is an absolute path; list files relative to the sequence folder")
    if ".." in posix.parts:
        raise InputError(path, f"line {line}: {file!r} leads outside the sequence folder ('..')")
    if posix.name in ("", "."):
        raise InputError(path, f"line {line}: {file!r} is not a file name")
    return file


def top_folder(file: str) -> str:
    """The first component of a listed path (``Path(file).parts[0]``, fast for the usual case)."""
    return file.split("/", 1)[0] if not file.startswith((".", "/")) else Path(file).parts[0]


def timestamp_at(path: Path, line: int, text: str) -> float:
    """:func:`parse_timestamp` of a list's field; an error names the list and the line."""
    try:
        return parse_timestamp(text)
    except ValueError as exc:
        shown = text if len(text) <= 40 else text[:37] + "..."
        raise InputError(path, f"line {line}: '{shown}' {exc}") from None


def unique_entries(entries: list[tuple[float, str, int]]) -> list[tuple[float, str, int]]:
    """Drop repeated (timestamp, file) pairs: associations list an RGB frame once per depth frame."""
    seen = set()
    out = []
    for ts, file, line in entries:
        if (ts, file) not in seen:
            seen.add((ts, file))
            out.append((ts, file, line))
    return out


def frame_list(source: Path, entries: list[tuple[float, str, int]], numbered: bool = False) -> FrameList:
    """The entries (timestamp, file, line) ordered by timestamp; a repeated timestamp is refused
    (``numbered``: the timestamps are frame numbers, and the message says so)."""
    times = np.array([e[0] for e in entries], dtype=np.float64)
    order = np.argsort(times, kind="stable")
    times = times[order]
    repeated = np.flatnonzero(np.diff(times) == 0)
    if repeated.size:
        ts, file, line = entries[order[repeated[0] + 1]]
        where = f"line {line}: " if line else ""
        what = f"timestamp {ts:.6f}" if line or not numbered else f"frame {ts:.0f}"
        raise InputError(source, f"{where}{what} appears twice ({file})")
    return FrameList(timestamps=times, files=tuple(entries[i][1] for i in order.tolist()))


def numbered_files(folder: Path, root: Path, pattern: str, what: str) -> FrameList:
    """The files of ``folder`` whose name matches ``pattern``, its first group the frame number.

    Parameters
    ----------
    folder : Path
        Where the files are (``root`` itself for 7-Scenes).
    root : Path
        The sequence folder: listed paths are relative to it.
    pattern : str
        A regular expression matched against whole file names; group 1 is the frame number.
    what : str
        The expected name, for the error about one that does not fit (e.g. ``"<frame>.png"``).

    Returns
    -------
    FrameList
        Timestamps are the frame numbers, in increasing order.

    Raises
    ------
    InputError
        More than :data:`MAX_FRAMES` matching files, an image file (by suffix) in ``folder``
        whose name does not fit (named, with what was expected), a frame number out of range,
        or one frame twice (``0.png`` and ``00.png``).
    """
    matcher = re.compile(pattern)
    entries = []
    prefix = folder.relative_to(root).as_posix() if folder != root else ""
    with os.scandir(folder) as scan:
        for entry in scan:
            found = matcher.fullmatch(entry.name)
            if found is None:
                if folder != root and entry.name.lower().endswith(IMAGE_SUFFIXES):
                    raise InputError(folder / entry.name, f"not a frame of this layout (expected {what})")
                continue
            try:
                number = parse_timestamp(found.group(1))
            except ValueError as exc:
                raise InputError(folder / entry.name, f"frame number {exc}") from None
            entries.append((number, f"{prefix}/{entry.name}" if prefix else entry.name, 0))
            if len(entries) > MAX_FRAMES:
                raise InputError(folder, f"more than {MAX_FRAMES} frames; at most {MAX_FRAMES} are read")
    return frame_list(folder, entries, numbered=True)


def read_matrix(path: Path, shapes: tuple[tuple[int, int], ...] = ((4, 4),), finite: bool = True) -> np.ndarray:
    """A small matrix written as text, one row per line (ScanNet's intrinsics and poses, 7-Scenes'
    poses), of one of the given shapes.

    Parameters
    ----------
    path : Path
    shapes : tuple of (int, int)
        The accepted shapes, e.g. ``((3, 3), (4, 4))``.
    finite : bool
        Refuse NaN and infinite values (a pose may hold ``-inf``: tracking was lost).

    Returns
    -------
    ndarray of float64

    Raises
    ------
    InputError
        Unreadable, larger than :data:`MAX_MATRIX_BYTES`, not UTF-8, not numbers, a shape not
        accepted, or a value not finite when ``finite``.
    """
    with open_input(path, MAX_MATRIX_BYTES) as handle:
        try:
            text = handle.read().decode("utf-8-sig")
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(path, f"cannot read the matrix: {exc}") from None
    rows = [line.split() for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    shape = (len(rows), len(rows[0])) if rows and all(len(row) == len(rows[0]) for row in rows) else None
    if shape not in shapes:
        found = "x".join(map(str, shape)) if shape else ("nothing" if not rows else "rows of different lengths")
        expected = " or ".join(f"{r}x{c}" for r, c in shapes)
        raise InputError(path, f"expected a {expected} matrix, found {found}")
    try:
        matrix = np.array([[float(v) for v in row] for row in rows], dtype=np.float64)
    except ValueError:
        raise InputError(path, "not a matrix: a value is not a number") from None
    if finite and not np.isfinite(matrix).all():
        raise InputError(path, "the matrix holds a value that is not finite")
    return matrix

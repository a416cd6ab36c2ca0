"""RGB-D sequences on disk: TUM RGB-D and ICL-NUIM (TUM format) layouts.

A sequence folder holds either

* ``rgb.txt`` and ``depth.txt`` (TUM): ``#`` comment lines, then ``timestamp path`` per line;
* ``associations.txt`` (ICL-NUIM in TUM format): ``depth_ts depth_path rgb_ts rgb_path`` per
  line (TUM's ``associate.py`` output: ``rgb_ts rgb_path depth_ts depth_path`` is recognised by
  the folder names in the paths);
* or only ``rgb/`` and ``depth/`` folders, whose file names (without extension) are the
  timestamps, sorted numerically.

Frames are always ordered by their timestamp as a number: sorting names as text, or by the
integer part of the timestamp only, mixes up frames within the same second (a pitfall of the
original EVOPS tooling).

A listed file must lie inside the sequence folder (no absolute path, no ``..``), so that a list
can never make the tool read elsewhere; depth file names must be distinct, since each names its
mask.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path, PurePosixPath, PureWindowsPath

import cv2
import numpy as np

from .errors import InputError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclass(frozen=True)
class FrameList:
    """Timestamps and files of one stream, ordered by timestamp.

    Parameters
    ----------
    timestamps : ndarray of float64, shape (N,)
        Seconds, strictly increasing.
    files : tuple of str
        Paths relative to the sequence folder, as written in the list file.
    """

    timestamps: np.ndarray
    files: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.files)


@dataclass(frozen=True)
class Sequence:
    """An RGB-D sequence: where it is and its two streams."""

    root: Path
    rgb: FrameList
    depth: FrameList


def read_sequence(root: str | Path) -> Sequence:
    """Read the frame lists of a TUM or ICL-NUIM sequence folder.

    Parameters
    ----------
    root : str or Path
        The sequence folder.

    Returns
    -------
    Sequence

    Raises
    ------
    InputError
        The folder or its lists are missing, malformed or empty.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(root, "sequence folder not found")
    if (root / "rgb.txt").is_file() and (root / "depth.txt").is_file():
        rgb = read_frame_list(root / "rgb.txt")
        depth_source = root / "depth.txt"
        depth = read_frame_list(depth_source)
    elif (root / "associations.txt").is_file():
        depth_source = root / "associations.txt"
        rgb, depth = read_associations(depth_source)
    elif (root / "rgb").is_dir() and (root / "depth").is_dir():
        rgb = list_image_folder(root / "rgb", root)
        depth_source = root / "depth"
        depth = list_image_folder(depth_source, root)
    else:
        raise InputError(
            root, "not an RGB-D sequence: expected rgb.txt and depth.txt, associations.txt, "
            "or rgb/ and depth/ folders"
        )
    for name, frames in (("RGB", rgb), ("depth", depth)):
        if len(frames) == 0:
            raise InputError(root, f"the sequence lists no {name} frames")
    check_depth_names(depth, depth_source)
    return Sequence(root=root, rgb=rgb, depth=depth)


def check_depth_names(depth: FrameList, source: Path) -> None:
    """Refuse two depth files with one file name: each names its mask, one would overwrite the other.

    Raises
    ------
    InputError
        Naming ``source`` (the depth list) and both files.
    """
    first: dict[str, str] = {}
    for file in depth.files:
        name = PurePosixPath(file).name
        if name in first:
            raise InputError(
                source,
                f"depth files {first[name]!r} and {file!r} have one file name; masks are named "
                "after depth files, so each needs its own",
            )
        first[name] = file


def read_frame_list(path: Path) -> FrameList:
    """Read a TUM ``rgb.txt`` / ``depth.txt``: ``#`` comments, then ``timestamp path`` lines."""
    rows = _read_rows(path, min_columns=2)
    return _frame_list(path, [(ts, _inside(path, line, row[1]), line) for line, ts, row in rows])


def read_associations(path: Path) -> tuple[FrameList, FrameList]:
    """Read an ICL-NUIM / ``associate.py`` ``associations.txt`` into RGB and depth lists.

    Each line pairs one depth and one RGB frame; which pair of columns is which is told by the
    folder in the path (``depth/...`` or ``rgb/...``), since both orders are in use.
    """
    rows = _read_rows(path, min_columns=4)
    rgb, depth = [], []
    for line, first_ts, row in rows:
        second_ts = _timestamp(path, line, row[2])
        pairs = [(first_ts, _inside(path, line, row[1])), (second_ts, _inside(path, line, row[3]))]
        if "depth" in Path(row[3]).parts[0].lower() or "rgb" in Path(row[1]).parts[0].lower():
            pairs.reverse()
        (d_ts, d_file), (r_ts, r_file) = pairs
        depth.append((d_ts, d_file, line))
        rgb.append((r_ts, r_file, line))
    return _frame_list(path, _unique(rgb)), _frame_list(path, _unique(depth))


def list_image_folder(folder: Path, root: Path) -> FrameList:
    """Image files in ``folder`` with their name (without extension) as the timestamp."""
    entries = []
    for file in folder.iterdir():
        if file.suffix.lower() not in IMAGE_SUFFIXES:
            continue
        try:
            ts = float(file.stem)
        except ValueError:
            raise InputError(file, "image name is not a timestamp (expected e.g. 1305031102.175304.png)") from None
        entries.append((ts, file.relative_to(root).as_posix(), 0))
    return _frame_list(folder, entries)


def associate(depth_times: np.ndarray, rgb_times: np.ndarray, max_time_diff: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every depth frame, the RGB frame nearest in time.

    Unlike TUM's ``associate.py`` (greedy one-to-one pairing), an RGB frame may serve several
    depth frames: every depth frame gets the annotation of the image the labeller saw closest
    to it.

    Parameters
    ----------
    depth_times, rgb_times : ndarray of float64
        Timestamps in seconds, each strictly increasing.
    max_time_diff : float
        Largest accepted |t_depth - t_rgb| in seconds.

    Returns
    -------
    nearest : ndarray of int64, shape (N_depth,)
        Index of the nearest RGB frame.
    time_diff : ndarray of float64, shape (N_depth,)
        ``t_rgb - t_depth`` for that frame.
    matched : ndarray of bool, shape (N_depth,)
        Whether the nearest RGB frame is within ``max_time_diff``.
    """
    depth_times = np.asarray(depth_times, dtype=np.float64)
    rgb_times = np.asarray(rgb_times, dtype=np.float64)
    if len(rgb_times) == 1:
        nearest = np.zeros(len(depth_times), dtype=np.int64)
    else:
        after = np.clip(np.searchsorted(rgb_times, depth_times), 1, len(rgb_times) - 1)
        before = after - 1
        pick_after = np.abs(rgb_times[after] - depth_times) < np.abs(depth_times - rgb_times[before])
        nearest = np.where(pick_after, after, before).astype(np.int64)
    time_diff = rgb_times[nearest] - depth_times
    # A tiny tolerance: timestamps are printed with 6 decimals, so 0.02 must not read as 0.0200001.
    matched = np.abs(time_diff) <= max_time_diff + 1e-9
    return nearest, time_diff, matched


def camera_problem(cx: float, cy: float, width: int, height: int) -> str | None:
    """Why intrinsics with principal point ``(cx, cy)`` look wrong for ``width x height`` images.

    The principal point of a real RGB-D camera lies near the image centre; one outside the
    middle half of the image usually means intrinsics for another resolution (TUM's 640x480
    values on half-size images, or the other way round).

    Parameters
    ----------
    cx, cy : float
        Principal point in pixels.
    width, height : int
        Size of the depth images.

    Returns
    -------
    str or None
        A one-line warning, or ``None`` when the principal point is plausible.
    """
    if abs(cx - width / 2) <= width / 4 and abs(cy - height / 2) <= height / 4:
        return None
    where = "outside" if not (0 <= cx <= width and 0 <= cy <= height) else "far from the centre of"
    return (
        f"the camera's principal point ({cx:g}, {cy:g}) is {where} the {width}x{height} depth "
        "images: are the [camera] intrinsics for another resolution?"
    )


def read_depth(path: Path, data: np.ndarray | None = None) -> np.ndarray:
    """Read a depth image as a single-channel array of raw values.

    Parameters
    ----------
    path : Path
    data : ndarray of uint8, optional
        The file's bytes, when already read (:func:`read_bytes`).

    Raises
    ------
    InputError
        Missing or undecodable file, an image with colour channels or an 8-bit image (not a
        depth map).
    """
    image = decode_image(read_bytes(path) if data is None else data, path, cv2.IMREAD_UNCHANGED)
    if image.ndim != 2:
        raise InputError(path, f"depth image has {image.shape[2]} channels; expected a single-channel depth map")
    if image.dtype.itemsize == 1:
        # An 8-bit image is a preview or a visualisation: its values are not depth.
        raise InputError(path, "depth image is 8-bit; expected 16-bit depth (TUM / ICL-NUIM PNG)")
    return image


def read_rgb(path: Path) -> np.ndarray:
    """Read an RGB image as an ``(H, W, 3)`` uint8 array in RGB order."""
    return cv2.cvtColor(read_image(path, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def read_image(path: Path, flags: int) -> np.ndarray:
    """Read any image with OpenCV's ``imread`` ``flags``.

    Raises
    ------
    InputError
        Missing, unreadable, empty or undecodable file (one line naming the file).
    """
    return decode_image(read_bytes(path), path, flags)


def read_bytes(path: Path) -> np.ndarray:
    """A file's bytes as a uint8 array.

    Raises
    ------
    InputError
        Missing or unreadable file.
    """
    try:
        return np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        reason = "file not found" if isinstance(exc, FileNotFoundError) else f"cannot read ({exc.strerror})"
        raise InputError(path, reason) from None


def decode_image(data: np.ndarray, path: Path, flags: int) -> np.ndarray:
    """Decode an image file's bytes with OpenCV's ``imread`` ``flags``.

    Raises
    ------
    InputError
        Empty or undecodable data (the message names ``path``).
    """
    image = cv2.imdecode(data, flags) if data.size else None
    if image is None:
        raise InputError(path, "not a readable image (corrupt or unsupported format)")
    return image


def _read_rows(path: Path, min_columns: int) -> list[tuple[int, float, list[str]]]:
    """Non-comment lines of a TUM-style list as (line number, first timestamp, columns)."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot read frame list: {exc}") from None
    rows = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        columns = line.split()
        if len(columns) < min_columns:
            raise InputError(path, f"line {number}: expected {min_columns} columns, got {len(columns)}")
        rows.append((number, _timestamp(path, number, columns[0]), columns))
    return rows


def _inside(path: Path, line: int, file: str) -> str:
    """``file`` as listed, if it names a file inside the sequence folder."""
    posix = PurePosixPath(file.replace("\\", "/"))
    if posix.is_absolute() or PureWindowsPath(file).drive:
        raise InputError(path, f"line {line}: {file!r} is an absolute path; list files relative to the sequence folder")
    if ".." in posix.parts:
        raise InputError(path, f"line {line}: {file!r} leads outside the sequence folder ('..')")
    if posix.name in ("", "."):
        raise InputError(path, f"line {line}: {file!r} is not a file name")
    return file


def _timestamp(path: Path, line: int, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not np.isfinite(value):
        raise InputError(path, f"line {line}: '{text}' is not a timestamp")
    return value


def _unique(entries: list[tuple[float, str, int]]) -> list[tuple[float, str, int]]:
    """Drop repeated (timestamp, file) pairs: associations list an RGB frame once per depth frame."""
    seen = set()
    out = []
    for ts, file, line in entries:
        if (ts, file) not in seen:
            seen.add((ts, file))
            out.append((ts, file, line))
    return out


def _frame_list(source: Path, entries: list[tuple[float, str, int]]) -> FrameList:
    entries = sorted(entries, key=lambda e: e[0])
    times = np.array([e[0] for e in entries], dtype=np.float64)
    repeated = np.flatnonzero(np.diff(times) == 0)
    if repeated.size:
        ts, file, line = entries[repeated[0] + 1]
        where = f"line {line}: " if line else ""
        raise InputError(source, f"{where}timestamp {ts:.6f} appears twice ({file})")
    return FrameList(timestamps=times, files=tuple(e[1] for e in entries))

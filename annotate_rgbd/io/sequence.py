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

A listed file must lie inside the sequence folder (no absolute path, no ``..``, no symbolic link
leading out of it), so that a list can never make the tool read elsewhere; depth file names must
be distinct, since each names its mask. Only regular files are read (a FIFO or a device would
block or never end), and lists, images and timestamps are bounded (``MAX_*`` below), so that no
input costs unbounded time or memory.
"""

from __future__ import annotations

import errno
import io
import math
import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path, PurePosixPath, PureWindowsPath

import cv2
import numpy as np

from annotate_rgbd.errors import InputError
from .files import FileTooLarge, NotRegularFile, open_regular
from .limits import MAX_FRAMES, MAX_IMAGE_PIXELS, MAX_TIMESTAMP  # noqa: F401 (read from here too)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")

#: Largest frame list read (checked before reading): a million ``associate.py`` lines of about
#: 90 bytes, with room for comments.
MAX_LIST_BYTES = 128 * 2**20
#: Most lines of a frame list, comments and blank lines included.
MAX_LIST_LINES = 2 * MAX_FRAMES
#: Largest image file read, in bytes: an uncompressed 16-bit RGBA image of MAX_IMAGE_PIXELS.
MAX_IMAGE_BYTES = 8 * MAX_IMAGE_PIXELS
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


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
        The folder or its lists are missing, malformed, empty or too long, a timestamp is not
        finite or out of range, or a symbolic link leads a listed file out of the folder.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(root, "sequence folder not found")
    # exists(), not is_file(): a FIFO or a folder named rgb.txt is refused by name, not skipped.
    if (root / "rgb.txt").exists() and (root / "depth.txt").exists():
        check_inside(root, ("rgb.txt", "depth.txt"))
        rgb = read_frame_list(root / "rgb.txt")
        depth_source = root / "depth.txt"
        depth = read_frame_list(depth_source)
    elif (root / "associations.txt").exists():
        check_inside(root, ("associations.txt",))
        depth_source = root / "associations.txt"
        rgb, depth = read_associations(depth_source)
    elif (root / "rgb").is_dir() and (root / "depth").is_dir():
        check_inside(root, ("rgb", "depth"))
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
    check_inside(root, rgb.files + depth.files)
    return Sequence(root=root, rgb=rgb, depth=depth)


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


def read_frame_list(path: Path) -> FrameList:
    """Read a TUM ``rgb.txt`` / ``depth.txt``: ``#`` comments, then ``timestamp path`` lines."""
    rows = _read_rows(path, min_columns=2)
    return _frame_list(path, [(_timestamp(path, line, row[0]), _inside(path, line, row[1]), line) for line, row in rows])


def read_associations(path: Path) -> tuple[FrameList, FrameList]:
    """Read an ICL-NUIM / ``associate.py`` ``associations.txt`` into RGB and depth lists.

    Each line pairs one depth and one RGB frame; which pair of columns is which is told by the
    folder in the path (``depth/...`` or ``rgb/...``), since both orders are in use.
    """
    rows = _read_rows(path, min_columns=4)
    rgb, depth = [], []
    for line, row in rows:
        first_ts, second_ts = _timestamp(path, line, row[0]), _timestamp(path, line, row[2])
        pairs = [(first_ts, _inside(path, line, row[1])), (second_ts, _inside(path, line, row[3]))]
        if "depth" in _top_folder(row[3]).lower() or "rgb" in _top_folder(row[1]).lower():
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
            ts = parse_timestamp(file.stem)
        except ValueError as exc:
            raise InputError(file, f"image name {exc} (expected e.g. 1305031102.175304.png)") from None
        entries.append((ts, file.relative_to(root).as_posix(), 0))
        if len(entries) > MAX_FRAMES:
            raise InputError(folder, f"more than {MAX_FRAMES} images; at most {MAX_FRAMES} frames are read")
    return _frame_list(folder, entries)


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
        Missing or undecodable file, not a PNG file, an image larger than ``MAX_IMAGE_PIXELS``
        (by its header, before decoding), an image with colour channels or an 8-bit image (not
        a depth map).
    """
    data = read_bytes(path) if data is None else data
    if bytes(data[: len(PNG_SIGNATURE)]) != PNG_SIGNATURE:
        raise InputError(path, "not a readable image (not a PNG file; depth images are 16-bit PNGs, as in TUM / ICL-NUIM)")
    image = decode_image(data, path, cv2.IMREAD_UNCHANGED)
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


def read_bytes(path: Path, max_bytes: int = MAX_IMAGE_BYTES) -> np.ndarray:
    """A regular file's bytes as a uint8 array.

    Parameters
    ----------
    path : Path
    max_bytes : int
        Largest size read; a larger file is refused before reading.

    Raises
    ------
    InputError
        Missing, unreadable, not a regular file (FIFO, device, folder) or too large.
    """
    with open_input(path, max_bytes) as handle:
        try:
            return np.fromfile(handle, dtype=np.uint8)
        except OSError as exc:
            raise InputError(path, f"cannot read ({exc.strerror})") from None


def open_input(path: Path, max_bytes: int):
    """Open an input file (links followed: the user named it) of at most ``max_bytes`` for reading
    in binary mode, a regular file only (:func:`annotate_rgbd.io.files.open_regular`).

    Raises
    ------
    InputError
        Missing, unreadable, not a regular file or larger than ``max_bytes``.
    """
    try:
        return open_regular(path, max_bytes)
    except FileNotFoundError:
        raise InputError(path, "file not found") from None
    except NotRegularFile as exc:
        if exc.kind == "a folder":
            raise InputError(path, f"cannot read ({os.strerror(errno.EISDIR)})") from None
        raise InputError(path, f"not a regular file ({exc.kind}); refused") from None
    except FileTooLarge as exc:
        raise InputError(path, f"file is {exc.size / 2**20:.0f} MiB; at most {max_bytes / 2**20:.0f} MiB are read") from None
    except OSError as exc:
        raise InputError(path, f"cannot read ({exc.strerror})") from None


def decode_image(data: np.ndarray, path: Path, flags: int) -> np.ndarray:
    """Decode an image file's bytes with OpenCV's ``imread`` ``flags``.

    A PNG's size is read from its header first (:func:`png_size`): one larger than
    ``MAX_IMAGE_PIXELS`` is refused before anything is allocated.

    Raises
    ------
    InputError
        Empty or undecodable data, or a PNG too large (the message names ``path``).
    """
    if bytes(data[: len(PNG_SIGNATURE)]) == PNG_SIGNATURE:
        width, height = png_size(data, path)
        if width * height > MAX_IMAGE_PIXELS:
            raise InputError(
                path, f"the PNG header says {width}x{height} pixels ({width * height / 1e6:.0f} Mpixel); images over "
                f"{MAX_IMAGE_PIXELS / 1e6:.0f} Mpixel are refused (a corrupt file or a decompression bomb)",
            )
    try:
        image = cv2.imdecode(data, flags) if data.size else None
    except cv2.error:  # e.g. beyond OpenCV's own size limit in a format whose header is not read here
        image = None
    if image is None:
        raise InputError(path, "not a readable image (corrupt or unsupported format)")
    return image


def png_size(data: np.ndarray | bytes, path: Path) -> tuple[int, int]:
    """Width and height from a PNG's header, without decoding the image.

    The header is the 8-byte signature and the IHDR chunk (length 13, type, width, height, bit
    depth, colour type, compression, filter, interlace, CRC): the file's first 33 bytes.

    Parameters
    ----------
    data : ndarray of uint8 or bytes
        The file's bytes (at least its first 33).
    path : Path
        For messages.

    Returns
    -------
    (int, int)
        (width, height) in pixels, each at least 1.

    Raises
    ------
    InputError
        Not a PNG, or its header is truncated or corrupt.
    """
    head = bytes(data[:33])
    if head[:8] != PNG_SIGNATURE:
        raise InputError(path, "not a readable image (not a PNG file)")
    if len(head) < 33:
        raise InputError(path, "not a readable image (truncated PNG header)")
    length, kind, width, height = struct.unpack(">I4sII", head[8:24])
    if length != 13 or kind != b"IHDR" or struct.unpack(">I", head[29:33])[0] != zlib.crc32(head[12:29]):
        raise InputError(path, "not a readable image (corrupt PNG header)")
    if width == 0 or height == 0:
        raise InputError(path, f"not a readable image (the PNG header says {width}x{height} pixels)")
    return width, height


def _read_rows(path: Path, min_columns: int) -> Iterator[tuple[int, list[str]]]:
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


def _inside(path: Path, line: int, file: str) -> str:
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


def _top_folder(file: str) -> str:
    """The first component of a listed path (``Path(file).parts[0]``, fast for the usual case)."""
    return file.split("/", 1)[0] if not file.startswith((".", "/")) else Path(file).parts[0]


def _timestamp(path: Path, line: int, text: str) -> float:
    try:
        return parse_timestamp(text)
    except ValueError as exc:
        shown = text if len(text) <= 40 else text[:37] + "..."
        raise InputError(path, f"line {line}: '{shown}' {exc}") from None


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
    """The entries (timestamp, file, line) ordered by timestamp; a repeated timestamp is refused."""
    times = np.array([e[0] for e in entries], dtype=np.float64)
    order = np.argsort(times, kind="stable")
    times = times[order]
    repeated = np.flatnonzero(np.diff(times) == 0)
    if repeated.size:
        ts, file, line = entries[order[repeated[0] + 1]]
        where = f"line {line}: " if line else ""
        raise InputError(source, f"{where}timestamp {ts:.6f} appears twice ({file})")
    return FrameList(timestamps=times, files=tuple(entries[i][1] for i in order.tolist()))

"""Output files, each written atomically: a temporary file in the same folder, then a rename.

An interrupted run therefore leaves either the previous file or the complete new one, never a
truncated PNG or JSON.
"""

from __future__ import annotations

import csv
import errno
import io
import json
import math
import os
import re
import secrets
import stat
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any, Iterable, Iterator, Sequence

import cv2
import numpy as np

from annotate_rgbd.errors import InputError, OutputError


def prepare_output(folder: Path) -> None:
    """Create the output folder if needed and check that files can be created in it.

    Called before any work, so that an unusable folder is reported at once rather than after
    the first mask has been computed.

    Raises
    ------
    OutputError
        The folder cannot be created (a file is in the way, no permission) or written.
    """
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except FileExistsError:
        raise OutputError(folder, "cannot create the output folder: a file of that name is in the way") from None
    except NotADirectoryError:
        # A file where one of the folders above it should be (--out notes.txt/run).
        blocking = next((p for p in reversed(folder.parents) if p.exists() and not p.is_dir()), None)
        where = f": {blocking} is a file" if blocking is not None else ""
        raise OutputError(folder, f"cannot create the output folder{where}") from None
    except OSError as exc:
        raise OutputError(folder, f"cannot write to the output folder: {exc.strerror or exc}") from None


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and an atomic rename.

    Raises
    ------
    OutputError
        The folder cannot be written (permissions, full disk, ...); no partial file remains.
    """
    path = Path(path)
    try:
        # Only the file's own folder (masks/): an output folder removed or moved during the run
        # is an error here, never silently made again at its old path.
        path.parent.mkdir(exist_ok=True)
    except FileNotFoundError:
        raise OutputError(path, FOLDER_GONE) from None
    except OSError as exc:
        raise OutputError(path, f"cannot write output: {exc.strerror or exc}") from None
    with _atomic_output(path) as handle:
        handle.write(data)


#: Why a file cannot be written when its folder is gone.
FOLDER_GONE = "cannot write output: its folder is gone (the output folder removed or moved during the run?)"


#: The output name that stands for standard output.
STDOUT = "-"
#: Paths that name an open descriptor of this process (``/dev/stdout``, ``/dev/fd/3``).
_DESCRIPTOR = re.compile(r"^/(?:dev/(?:fd/(\d+)|(stdout)|(stderr))|proc/self/fd/(\d+))$")


def descriptor_of(path: str | Path) -> int | None:
    """The descriptor an output path names: 1 for ``-`` and ``/dev/stdout``, ``N`` for
    ``/dev/fd/N`` and ``/proc/self/fd/N``, 2 for ``/dev/stderr``; None for any other path."""
    if str(path) == STDOUT:
        return 1
    found = _DESCRIPTOR.match(os.path.abspath(path))
    if found is None:
        return None
    fd, out, err, proc = found.groups()
    return 1 if out else 2 if err else int(fd or proc)


def is_stream(path: str | Path) -> bool:
    """Whether an output path names a stream to write into rather than a file to replace:
    ``-``, a descriptor (:func:`descriptor_of`), or an existing character device, FIFO or
    socket (``/dev/null``, a named pipe)."""
    if descriptor_of(path) is not None:
        return True
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return stat.S_ISCHR(mode) or stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode)


def names_stdout(path: str | Path) -> bool:
    """Whether writing to ``path`` writes to this process's standard output (then a command's
    summary goes to standard error, not into the data)."""
    if descriptor_of(path) == 1:
        return True
    try:
        return os.path.samestat(os.stat(path), os.fstat(1)) and not stat.S_ISREG(os.fstat(1).st_mode)
    except OSError:
        return False


@contextmanager
def open_output(path: str | Path) -> Iterator[IO[bytes]]:
    """A user-named output file, open for writing in binary.

    A stream (:func:`is_stream`: ``-``, ``/dev/stdout``, a device, a FIFO) is written into as it
    is, never replaced; a FIFO without a reader is refused rather than waited for. Any other
    path is written atomically: a temporary file beside it, renamed over it at the end of the
    block (nothing is left when the block raises).

    Raises
    ------
    OutputError
        The stream or file cannot be opened or written (one line naming it).
    """
    with (_stream_output if is_stream(path) else _atomic_output)(Path(path)) as handle:
        yield handle


@contextmanager
def _atomic_output(path: Path) -> Iterator[IO[bytes]]:
    """A file written through a temporary file beside ``path`` and an atomic rename; no partial
    file remains on any error or interrupt."""
    # Named before it exists, so that an interrupt at any point (even inside the open call)
    # leaves nothing behind: the finally clause removes whatever was created.
    tmp = path.parent / f".{path.name}.{secrets.token_hex(4)}.tmp"
    done = False
    try:
        # Mode 0o666 minus the umask, like any file the user creates (mkstemp's 0o600 is not).
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(fd, "wb") as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
        done = True
    except FileNotFoundError:
        raise OutputError(path, FOLDER_GONE) from None
    except OSError as exc:
        raise OutputError(path, f"cannot write output: {exc.strerror or exc}") from None
    finally:
        if not done:
            try:
                tmp.unlink()
            except OSError:  # never created (no folder, no permission): nothing to remove
                pass


@contextmanager
def _stream_output(path: Path) -> Iterator[IO[bytes]]:
    sys.stdout.flush()  # what this process printed comes first
    if str(path) == STDOUT:
        handle, own = sys.stdout.buffer, False
    else:
        descriptor = descriptor_of(path)
        try:
            if descriptor is not None:
                fd = os.dup(descriptor)
            else:
                fd = os.open(path, os.O_WRONLY | os.O_NONBLOCK)  # a FIFO without a reader: ENXIO, not a hang
                os.set_blocking(fd, True)
        except OSError as exc:
            reason = "a FIFO without a reader" if exc.errno == errno.ENXIO else exc.strerror or str(exc)
            raise OutputError(path, f"cannot write output: {reason}") from None
        handle, own = os.fdopen(fd, "wb"), True
    try:
        yield handle
        handle.flush()
    except OSError as exc:
        raise OutputError(path, f"cannot write output: {exc.strerror or exc}") from None
    finally:
        if own:
            try:
                handle.close()
            except OSError:  # what flush could not write: reported above
                pass


def write_output(path: str | Path, data: bytes) -> None:
    """Write ``data`` to a user-named output (:func:`open_output`: a stream as it is, a file
    atomically)."""
    with open_output(path) as handle:
        handle.write(data)


def write_png(path: Path, image: np.ndarray) -> bytes:
    """Write an image as PNG atomically (``(H, W, 3)`` arrays are taken as RGB); returns the
    bytes written."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, encoded = cv2.imencode(".png", image)
    if not ok:  # pragma: no cover - cv2 encodes any uint8/uint16 array
        raise InputError(path, "PNG encoding failed")
    data = encoded.tobytes()
    write_bytes_atomic(path, data)
    return data


def write_json(path: Path, data: Any) -> None:
    """Write strict JSON (indented, UTF-8) atomically.

    NaN and infinity are not JSON (Python writes them as ``NaN`` / ``Infinity``, which most
    readers refuse): the producers turn undefined numbers into ``None`` (``null``), and one that
    slips through stops the write rather than leave an invalid file.

    Raises
    ------
    OutputError
        ``data`` holds NaN or infinity (the message says where), or the file cannot be written.
    """
    try:
        text = json.dumps(data, indent=1, ensure_ascii=False, allow_nan=False)
    except ValueError as exc:
        if "float" not in str(exc):  # not a NaN ("Out of range float values ..."): a circular structure
            raise
        where = _non_finite(data, "") or ("", math.nan)
        raise OutputError(path, f"{where[0] or 'the value'} is {where[1]}, which JSON cannot hold (a bug: please report it)") from None
    write_bytes_atomic(path, (text + "\n").encode("utf-8"))


def _non_finite(data: Any, where: str) -> tuple[str, float] | None:
    """Where in ``data`` (as ``frames[3].time_offset``) the first NaN or infinity is, and its value."""
    if isinstance(data, float):
        return None if math.isfinite(data) else (where, data)
    if isinstance(data, dict):
        items = ((f"{where}.{k}" if where else str(k), v) for k, v in data.items())
    elif isinstance(data, (list, tuple)):
        items = ((f"{where}[{i}]", v) for i, v in enumerate(data))
    else:
        return None
    return next((found for key, value in items if (found := _non_finite(value, key)) is not None), None)


#: First characters that make a spreadsheet read a cell as a formula (OWASP, "CSV Injection").
FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")
#: A number as written in a cell (``-0.5``, ``+1e-3``, ``-inf``): no formula, left as it is.
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?|[+-]?(inf|nan)", re.IGNORECASE)


def write_csv(path: Path, header: Sequence[str], rows: Iterable[Sequence[Any]]) -> None:
    """Write a CSV table atomically (:func:`csv_bytes`)."""
    write_bytes_atomic(path, csv_bytes(header, rows))


def csv_bytes(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> bytes:
    """A CSV table as UTF-8 bytes, with text cells made safe for spreadsheets.

    A text cell starting with ``=``, ``+``, ``-``, ``@``, a tab or a carriage return (a label
    such as ``=HYPERLINK(...)``) would run as a formula when the file is opened in a
    spreadsheet; it is written with a leading ``'``, which spreadsheets show as text (OWASP's
    advice). Numbers, and text that is a number (``-0.5``), are written unchanged.
    """
    buffer = io.StringIO()
    table = csv.writer(buffer, lineterminator="\n")
    # The csv module quotes a cell with a line break only if the break is in lineterminator:
    # a row with a carriage return in a cell is written with every cell quoted.
    quoted = csv.writer(buffer, lineterminator="\n", quoting=csv.QUOTE_ALL)
    for row in [header, *rows]:
        cells = [safe_cell(cell) for cell in row]
        (quoted if any(isinstance(c, str) and "\r" in c for c in cells) else table).writerow(cells)
    return buffer.getvalue().encode("utf-8")


def safe_cell(cell: Any) -> Any:
    """``cell``, or ``"'" + cell`` for text a spreadsheet would read as a formula."""
    if isinstance(cell, str) and cell.startswith(FORMULA_STARTS) and not _NUMBER.fullmatch(cell):
        return "'" + cell
    return cell

"""Output files, each written atomically: a temporary file in the same folder, then a rename.

An interrupted run therefore leaves either the previous file or the complete new one, never a
truncated PNG or JSON.
"""

from __future__ import annotations

import csv
import io
import json
import os
import secrets
import tempfile
from pathlib import Path
from typing import Any, Iterable, Sequence

import cv2
import numpy as np

from .errors import InputError, OutputError


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
    # Named before it exists, so that an interrupt at any point (even inside the open call)
    # leaves nothing behind: the finally clause removes whatever was created.
    tmp = path.parent / f".{path.name}.{secrets.token_hex(4)}.tmp"
    done = False
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # Mode 0o666 minus the umask, like any file the user creates (mkstemp's 0o600 is not).
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
        done = True
    except OSError as exc:
        raise OutputError(path, f"cannot write output: {exc.strerror or exc}") from None
    finally:
        if not done:
            try:
                tmp.unlink()
            except OSError:  # never created (no folder, no permission): nothing to remove
                pass


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
    """Write JSON (indented, UTF-8) atomically."""
    write_bytes_atomic(path, (json.dumps(data, indent=1, ensure_ascii=False) + "\n").encode("utf-8"))


def write_csv(path: Path, header: Sequence[str], rows: Iterable[Sequence[Any]]) -> None:
    """Write a CSV table atomically."""
    buffer = io.StringIO()
    table = csv.writer(buffer, lineterminator="\n")
    table.writerow(header)
    table.writerows(rows)
    write_bytes_atomic(path, buffer.getvalue().encode("utf-8"))

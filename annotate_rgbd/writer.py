"""Output files, each written atomically: a temporary file in the same folder, then a rename.

An interrupted run therefore leaves either the previous file or the complete new one, never a
truncated PNG or JSON.
"""

from __future__ import annotations

import csv
import io
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Iterable, Sequence

import cv2
import numpy as np

from .errors import InputError


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and an atomic rename.

    Raises
    ------
    InputError
        The folder cannot be written (permissions, full disk, ...); no partial file remains.
    """
    path = Path(path)
    tmp_name = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp_name, path)
        tmp_name = None
    except OSError as exc:
        raise InputError(path, f"cannot write output: {exc.strerror or exc}") from None
    finally:
        if tmp_name is not None:
            Path(tmp_name).unlink(missing_ok=True)


def write_png(path: Path, image: np.ndarray) -> None:
    """Write an image as PNG atomically (``(H, W, 3)`` arrays are taken as RGB)."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, encoded = cv2.imencode(".png", image)
    if not ok:  # pragma: no cover - cv2 encodes any uint8/uint16 array
        raise InputError(path, "PNG encoding failed")
    write_bytes_atomic(path, encoded.tobytes())


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

"""Opening a file the user named, with its problems worded as one-line input errors."""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import IO

from annotate_rgbd.errors import InputError
from .files import FileTooLarge, NotRegularFile, open_regular


def open_input(path: Path, max_bytes: int | None) -> IO[bytes]:
    """Open an input file (links followed: the user named it) of at most ``max_bytes`` (None: any
    size) for reading in binary mode, a regular file only (:func:`annotate_rgbd.io.files.open_regular`).

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
        raise InputError(path, f"file is {exc.size / 2**20:.0f} MiB; at most {exc.limit / 2**20:.0f} MiB are read") from None
    except OSError as exc:
        raise InputError(path, f"cannot read ({exc.strerror})") from None

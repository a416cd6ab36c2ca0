"""Opening a regular file for reading: never blocking on a FIFO, never reading a device.

For inputs the user named (images, frame lists: :func:`annotate_rgbd.io.sequence.open_input`,
which words the problems as one-line input errors) and for the tool's own records in an output
folder (:mod:`annotate_rgbd.io.outdir`), which are never read through a symbolic link.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path
from typing import IO


class NotRegularFile(OSError):
    """The path is a folder, a FIFO, a device or a socket (``errno`` EINVAL).

    Attributes
    ----------
    kind : str
        What it is instead: ``"a folder"``, ``"a FIFO"`` or ``"a device or socket"``.
    """

    def __init__(self, path: Path, kind: str):
        super().__init__(errno.EINVAL, "not a regular file", str(path))
        self.kind = kind


class FileTooLarge(OSError):
    """The file holds more bytes than the reader takes (``errno`` EFBIG).

    Attributes
    ----------
    size, limit : int
        The file's size and the most bytes read.
    """

    def __init__(self, path: Path, size: int, limit: int):
        super().__init__(errno.EFBIG, f"larger than {limit} bytes", str(path))
        self.size = size
        self.limit = limit


def open_regular(path: Path, max_bytes: int | None = None, *, follow_links: bool = True) -> IO[bytes]:
    """Open a regular file for reading in binary mode.

    The file is opened without blocking and checked on the open descriptor (``fstat``): a FIFO
    would block the open or the read until a writer comes, a device (``/dev/zero``) never ends.

    Parameters
    ----------
    path : Path
    max_bytes : int, optional
        Refuse a larger file (by its size, before reading).
    follow_links : bool
        False: refuse a symbolic link (``ELOOP``): what the tool reads back from an output folder
        must be the file it wrote there, not one a link points to.

    Returns
    -------
    binary file object
        Positioned at the start; the caller closes it.

    Raises
    ------
    OSError
        Missing (``FileNotFoundError``), unreadable, a link when ``follow_links`` is False,
        :class:`NotRegularFile` or :class:`FileTooLarge`.
    """
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0)
    if not follow_links:
        flags |= os.O_NOFOLLOW
    fd = os.open(path, flags)
    try:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise NotRegularFile(path, "a folder")
        if not stat.S_ISREG(info.st_mode):
            raise NotRegularFile(path, "a FIFO" if stat.S_ISFIFO(info.st_mode) else "a device or socket")
        if max_bytes is not None and info.st_size > max_bytes:
            raise FileTooLarge(path, info.st_size, max_bytes)
    except OSError:
        os.close(fd)
        raise
    return os.fdopen(fd, "rb")

"""Reading a whole file within a size bound, in pieces: memory follows the file's size, never
the bound (``read(bound + 1)`` reserves the whole bound at once, a gigabyte for a 10 KB file
under a 1 GiB bound), and never blocks on a FIFO or reads a device without end.

No imports beyond the standard library: the light commands (``stats``, ``batch``'s manifest)
read with it.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path
from typing import IO

#: Size of the pieces read.
READ_CHUNK = 1 << 20


def read_stream_bounded(handle: IO[bytes], max_bytes: int, path: str | Path) -> bytes:
    """Read a binary stream to its end, in pieces of :data:`READ_CHUNK`, refusing more than
    ``max_bytes``.

    Parameters
    ----------
    handle : binary file object
    max_bytes : int
        Largest size accepted; the memory used is about the size read, whatever the bound.
    path : str or Path
        For the error.

    Returns
    -------
    bytes

    Raises
    ------
    OSError
        ``EFBIG``: the stream holds more than ``max_bytes``.
    """
    pieces, total = [], 0
    while True:
        piece = handle.read(min(READ_CHUNK, max_bytes + 1 - total))
        if not piece:
            return b"".join(pieces)
        pieces.append(piece)
        total += len(piece)
        if total > max_bytes:
            raise OSError(errno.EFBIG, f"larger than {max_bytes} bytes", str(path))


def read_input(path: str | Path, max_bytes: int) -> bytes:
    """Read a regular file the user named (links followed) of at most ``max_bytes``.

    The file is opened without blocking and checked on the open descriptor: a FIFO would block
    until a writer comes, a device (``/dev/zero``) never ends.

    Raises
    ------
    OSError
        Missing or unreadable; ``EINVAL`` not a regular file; ``EFBIG`` larger than ``max_bytes``.
    """
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    with os.fdopen(fd, "rb") as handle:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise OSError(errno.EISDIR, "is a folder", str(path))
        if not stat.S_ISREG(info.st_mode):
            raise OSError(errno.EINVAL, "not a regular file (a FIFO or a device): refused", str(path))
        if info.st_size > max_bytes:
            raise OSError(errno.EFBIG, f"larger than {max_bytes} bytes", str(path))
        return read_stream_bounded(handle, max_bytes, path)

"""Reading image files: bounded, regular files only, decoded with OpenCV.

Only regular files are read (:func:`annotate_rgbd.io.inputs.open_input`: a FIFO or a device
would block or never end); every file and image is bounded (``MAX_*`` below), and a PNG's size
is read from its header before decoding, so that no input costs unbounded time or memory.
"""

from __future__ import annotations

import errno
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np

from annotate_rgbd.errors import InputError
from .bounded import read_stream_bounded
from .inputs import open_input

#: Largest image decoded (:data:`annotate_rgbd.io.limits.MAX_IMAGE_PIXELS`), checked in a PNG's
#: header before decoding: a small file announcing a huge image (a decompression bomb) is refused
#: without allocating it.
from annotate_rgbd.io.limits import MAX_IMAGE_PIXELS  # noqa: E402
#: Largest image file read, in bytes: an uncompressed 16-bit RGBA image of MAX_IMAGE_PIXELS.
MAX_IMAGE_BYTES = 8 * MAX_IMAGE_PIXELS
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: A PNG ends with its IEND chunk (12 bytes), looked for in this many last bytes first (a few
#: writers append bytes after it, which decoders ignore), then in the whole file.
PNG_END_SEARCH = 64
#: PNG chunks that hold no pixel and choose none (text, time, physical size, colour space and
#: palette hints, ISO 15948 and its extensions): one failing its checksum is left out, not refused.
PNG_METADATA_CHUNKS = frozenset({
    b"tEXt", b"zTXt", b"iTXt", b"tIME", b"pHYs", b"gAMA", b"cHRM", b"sRGB", b"iCCP", b"sBIT", b"bKGD",
    b"hIST", b"sPLT", b"eXIf", b"cICP", b"oFFs", b"pCAL", b"sCAL",
})
#: A 16-bit depth value read as "no depth": the largest one. 7-Scenes marks invalid depth with it;
#: as a measurement it would be 65.5 m in millimetres, 13.1 m at TUM's 1/5000 m, beyond every
#: RGB-D sensor, so no dataset loses a real reading by it.
NO_DEPTH_16 = 65535


def read_depth(path: Path, data: np.ndarray | None = None) -> np.ndarray:
    """Read a depth image as a single-channel array of raw values (0: no depth).

    A 16-bit value of :data:`NO_DEPTH_16` is read as 0: no depth.

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
    if image.dtype == np.uint16:
        np.putmask(image, image == NO_DEPTH_16, 0)
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
    # Plain reads, not np.fromfile: numpy turns an interrupt (Ctrl-C, a KeyboardInterrupt
    # raised while it checks whether the handle is a path) into "TypeError: expected str, bytes
    # or os.PathLike object", and the run then ends with status 1 instead of 130. In pieces:
    # read(max_bytes + 1) would reserve the whole bound at once.
    with open_input(path, max_bytes) as handle:
        try:
            data = read_stream_bounded(handle, max_bytes, path)
        except OSError as exc:
            if exc.errno == errno.EFBIG:  # it grew after it was opened
                raise InputError(path, f"file is over {max_bytes / 2**20:.0f} MiB; at most "
                                       f"{max_bytes / 2**20:.0f} MiB are read") from None
            raise InputError(path, f"cannot read ({exc.strerror})") from None
    return np.frombuffer(data, dtype=np.uint8)


def decode_image(data: np.ndarray, path: Path, flags: int) -> np.ndarray:
    """Decode an image file's bytes with OpenCV's ``imread`` ``flags``.

    A PNG's size is read from its header first (:func:`png_size`): one larger than
    ``MAX_IMAGE_PIXELS`` is refused before anything is allocated; a PNG without its closing
    ``IEND`` chunk (a file cut short by a copy or a full disk), or whose pixel chunks fail their
    checksum (bytes overwritten: :func:`png_chunk_check`), is refused without decoding, where
    libpng would print a line of its own; metadata chunks that fail theirs are left out.

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
        if b"IEND" not in data[-PNG_END_SEARCH:].tobytes() and b"IEND" not in data.tobytes():
            raise InputError(path, "not a readable image (truncated PNG: its closing IEND chunk is missing, "
                                   "the file was cut short)")
        problem, metadata = png_chunk_check(data)
        if problem:
            raise InputError(path, f"not a readable image ({problem})")
        if metadata:  # no pixel in them: left out, as libpng would, without its warning line
            keep = np.ones(data.size, dtype=bool)
            for start, stop in metadata:
                keep[start:stop] = False
            data = data[keep]
    try:
        image = cv2.imdecode(data, flags) if data.size else None
    except cv2.error:  # e.g. beyond OpenCV's own size limit in a format whose header is not read here
        image = None
    if image is None:
        raise InputError(path, "not a readable image (corrupt or unsupported format)")
    return image


def png_chunk_check(data: np.ndarray) -> tuple[str | None, list[tuple[int, int]]]:
    """Check a PNG's chunks (length, type, data, CRC-32 of type and data) up to ``IEND``.

    A walk over the chunks, a few per cent of the decoding's time. A chunk that fails its
    checksum makes the file unreadable, unless it is one of :data:`PNG_METADATA_CHUNKS`, which
    hold no pixel and are only to be left out (libpng would skip it, printing a warning of its
    own): the type's letter case cannot tell, since a damaged type (``IDAT`` read as ``iDAT``) is
    what fails, and an animated PNG's ``fcTL`` and ``fdAT`` choose and hold a frame's pixels. So do
    a chunk whose type is not four letters, one whose length runs past the data's end, and data
    that ends before ``IEND``.

    Parameters
    ----------
    data : ndarray of uint8
        The whole file, signature first.

    Returns
    -------
    problem : str or None
        What makes the file unreadable, as words for a message (``corrupt PNG: ...``,
        ``truncated PNG: ...``); None when nothing does.
    metadata : list of (int, int)
        ``(start, stop)`` byte ranges of the metadata chunks that fail their checksum.
    """
    view = memoryview(np.ascontiguousarray(data)).cast("B")
    position, metadata = len(PNG_SIGNATURE), []
    while position + 12 <= len(view):
        length = struct.unpack(">I", view[position : position + 4])[0]
        kind = bytes(view[position + 4 : position + 8])
        if not kind.isalpha():  # ASCII letters only
            return "corrupt PNG: a chunk's type is not a PNG chunk type, its header was overwritten", metadata
        name = kind.decode("ascii")
        end = position + 8 + length
        if end + 4 > len(view):
            return f"corrupt PNG: its {name} chunk's length runs past the end of the file, the file was damaged", metadata
        if zlib.crc32(view[position + 4 : end]) != struct.unpack(">I", view[end : end + 4])[0]:
            if kind not in PNG_METADATA_CHUNKS:
                return f"corrupt PNG: its {name} chunk fails its checksum, the file was damaged", metadata
            metadata.append((position, end + 4))
        if kind == b"IEND":
            return None, metadata
        position = end + 4
    return "truncated PNG: it ends inside a chunk, before its closing IEND chunk, the file was cut short", metadata


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


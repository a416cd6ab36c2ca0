"""Per-frame plane label files: read any supported format into one integer label array.

Supported formats, chosen by file suffix (0 is always "no plane"):

- ``.png`` with three or four channels: a colour mask as ``cvat2mask`` writes it, black = 0 and one
  plane per distinct colour (an alpha channel is ignored).
- ``.png`` with one channel, 8 or 16 bit: the pixel value is the plane label.
- ``.npy``: a 2-D integer (or boolean) label array, or a flat one, row-major (EVOPS's layout, ``export --format evops``).
- ``.csv``: CAPE's label output, one line per image row, comma-separated integer labels, usually
  with a trailing comma on every line.

Plane ids are only meaningful within one file: the metrics never assume that two files number the
same plane alike.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import cv2
import numpy as np

from annotate_rgbd.errors import InputError
from .bounded import read_input
from .limits import MAX_IMAGE_PIXELS
from .sequence import read_image

#: Largest CAPE label CSV read: a 1920 x 1080 frame of three-digit labels takes 8 MiB.
MAX_CSV_BYTES = 128 << 20

#: File suffixes that :func:`read_label_map` understands.
LABEL_SUFFIXES = (".png", ".npy", ".csv")


def read_label_map(path: str | Path, values_needed: str | None = None) -> np.ndarray:
    """Read one frame's plane labels.

    Parameters
    ----------
    path : str or Path
        A label file in one of the formats of :data:`LABEL_SUFFIXES` (see the module docstring).
    values_needed : str, optional
        Why the file's own label values matter (``"--ignore 65535"``): a colour mask, whose
        labels are numbered here by colour, is then refused with that reason.

    Returns
    -------
    ndarray of int, shape (height, width), or (height * width,) for a flat ``.npy`` array
        Plane label per pixel, 0 where there is no plane. A flat array is EVOPS's layout (the
        pixels row after row): :func:`annotate_rgbd.evaluate.evaluate.score_frame` takes it in
        the other file's shape.

    Raises
    ------
    InputError
        When the file is missing, unreadable, or not a 2-D (or flat) integer label image.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in LABEL_SUFFIXES:
        supported = ", ".join(LABEL_SUFFIXES)
        raise InputError(path, f"unsupported label file type {path.suffix!r} (use {supported})")
    if not path.is_file():
        raise InputError(path, "label file not found")
    if suffix == ".png":
        return _read_png(path, values_needed)
    if suffix == ".npy":
        return _read_npy(path)
    return read_cape_csv(path)


def colours_to_labels(image: np.ndarray) -> np.ndarray:
    """Turn a colour mask into labels: 0 for black, 1..N for the other distinct colours.

    Parameters
    ----------
    image : ndarray of uint8, shape (height, width, 3)
        The colour mask, in any channel order (the numbering only needs to be consistent in a file).

    Returns
    -------
    ndarray of int32, shape (height, width)
        The label of each pixel; colours are numbered in order of their packed 24-bit value.
    """
    channels = image.astype(np.int32)
    packed = ((channels[..., 0] << 16) | (channels[..., 1] << 8) | channels[..., 2]).ravel()
    if packed.size == 0:
        return np.zeros(image.shape[:2], dtype=np.int32)
    # A mask is made of long runs of one colour along its rows: the colours are sorted once per
    # run, not once per pixel (np.unique over every pixel took 24 ms of a 640x480 frame).
    starts = np.flatnonzero(np.concatenate(([True], packed[1:] != packed[:-1])))
    run_colours = packed[starts]
    colours = np.unique(run_colours)
    run_labels = np.searchsorted(colours, run_colours).astype(np.int32)
    if colours.size and colours[0] != 0:  # no black pixel: every colour is a plane
        run_labels += 1
    return np.repeat(run_labels, np.diff(starts, append=packed.size)).reshape(image.shape[:2])


def read_cape_csv(path: str | Path) -> np.ndarray:
    """Read a CAPE label CSV: one line per image row, comma-separated integers.

    Parameters
    ----------
    path : str or Path
        The CSV file, at most :data:`MAX_CSV_BYTES`. A trailing comma on a line (as CAPE writes
        it) and blank lines are ignored.

    Returns
    -------
    ndarray of int64, shape (height, width)
        The labels as written.

    Raises
    ------
    InputError
        When the file is too large, a line is not all integers, the lines differ in length or
        they hold more than :data:`MAX_IMAGE_PIXELS` labels.
    """
    path = Path(path)
    try:
        text = read_input(path, MAX_CSV_BYTES).decode("ascii")
    except OSError as error:
        raise InputError(path, f"cannot read label CSV: {error.strerror or error}") from None
    except UnicodeDecodeError as error:
        raise InputError(path, f"cannot read label CSV: {error}") from None
    rows = [line.strip().rstrip(",") for line in text.splitlines() if line.strip()]
    del text
    if not rows:
        raise InputError(path, "label CSV is empty")
    widths = {row.count(",") + 1 for row in rows}
    if len(widths) != 1:
        raise InputError(path, f"label CSV rows differ in length ({min(widths)} to {max(widths)} values)")
    width = widths.pop()
    if len(rows) * width > MAX_IMAGE_PIXELS:
        raise InputError(path, f"label CSV holds {width} x {len(rows)} labels, more than {MAX_IMAGE_PIXELS} pixels")
    labels = np.empty((len(rows), width), dtype=np.int64)
    try:
        for index, row in enumerate(rows):  # one row at a time: no list of every label's text
            labels[index] = np.array(row.split(","), dtype=np.int64)
    except (ValueError, OverflowError):
        raise InputError(path, f"label CSV line {index + 1} holds a value that is not an integer") from None
    return labels


def _read_png(path: Path, values_needed: str | None = None) -> np.ndarray:
    try:
        image = read_image(path, cv2.IMREAD_UNCHANGED)
    except InputError as exc:
        raise InputError(path, f"cannot read PNG image: {exc.message}") from None
    if image.ndim == 2:
        if image.dtype not in (np.uint8, np.uint16):
            raise InputError(path, f"single-channel label PNG must be 8 or 16 bit, not {image.dtype}")
        return image
    if image.shape[2] not in (3, 4) or image.dtype != np.uint8:
        raise InputError(path, f"colour mask PNG must be 8-bit RGB, not {image.shape[2]} x {image.dtype}")
    if values_needed:
        raise InputError(path, f"a colour mask, whose colours have no label values: {values_needed} needs label "
                               "files (single-channel PNG, .npy or .csv)")
    return colours_to_labels(image[..., :3])


def _read_npy(path: Path) -> np.ndarray:
    """A ``.npy`` label array, its header checked before any allocation: a file claiming a
    74 GiB array is refused, not read."""
    try:
        with open(path, "rb") as handle:
            version = np.lib.format.read_magic(handle)
            read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, _, dtype = read_header(handle)
            data_bytes = os.fstat(handle.fileno()).st_size - handle.tell()
            if len(shape) not in (1, 2):  # 1-D: EVOPS's flat, row-major labels (export --format evops)
                raise InputError(path, f"label array must be 2-D (or flat, row-major), not of shape {shape}")
            if dtype != bool and dtype.kind not in "ui":
                raise InputError(path, f"label array must hold integers, not {dtype}")
            pixels = math.prod(shape)
            if pixels > MAX_IMAGE_PIXELS:
                raise InputError(path, f"label array of shape {shape} is larger than {MAX_IMAGE_PIXELS} pixels")
            if pixels * dtype.itemsize > data_bytes:
                raise InputError(path, f"label array of shape {shape} needs {pixels * dtype.itemsize} bytes; "
                                       f"the file holds {data_bytes} (truncated?)")
            handle.seek(0)
            labels = np.load(handle, allow_pickle=False)
    except OSError as error:
        raise InputError(path, f"cannot read .npy label array: {error.strerror or error}") from None
    except ValueError as error:
        raise InputError(path, f"cannot read .npy label array: {error}") from None
    return labels

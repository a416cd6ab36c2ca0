"""Find the CVAT XML in what the user gave: the XML itself, or the zip CVAT hands out.

CVAT's "Export task dataset" downloads a zip holding ``annotations.xml`` (and the images when
asked for). :func:`xml_source` accepts such a zip as it is: the member is read as a stream from
the archive, never extracted, so no name in the archive can reach the file system. Only a
top-level ``annotations.xml`` (or else the archive's single ``.xml`` file) is read, after its
declared size is checked, and the bytes actually unpacked are counted as they are read (a zip
bomb may state a false size). Other exports CVAT offers (COCO, Datumaro, Pascal VOC, YOLO ...),
zipped or as a JSON file, are named in a one-line error that says what to export instead.

No XML is parsed here (only :mod:`~annotate_rgbd.cvat.xmlstream` does).
"""

from __future__ import annotations

import re
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from annotate_rgbd.errors import InputError

from .format import MAX_ARCHIVE_MEMBERS, MAX_ARCHIVE_XML_BYTES

#: The two CVAT XML formats, as CVAT's export dialog names them.
EXPORT_ADVICE = "export the task as 'CVAT for video 1.1' or 'CVAT for images 1.1'"

#: Bytes a file is recognised by (a JSON export names its top-level keys early).
SNIFF_BYTES = 1 << 16

#: How other CVAT export formats lay out their zip: (what it is, a member name pattern).
ZIP_FORMATS = (
    ("a COCO export", re.compile(r"(^|/)annotations/(instances|person_keypoints)_[^/]*\.json$")),
    ("a Datumaro export", re.compile(r"(^|/)annotations/[^/]*\.json$")),
    ("a Pascal VOC export", re.compile(r"^(Annotations|ImageSets)/")),
    ("a YOLO export", re.compile(r"^(obj\.names|obj\.data|data\.yaml)$")),
    ("a MOT export", re.compile(r"^gt/gt\.txt$")),
    ("a segmentation mask export", re.compile(r"^labelmap\.txt$")),
)

_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")


@dataclass(frozen=True)
class XmlSource:
    """Where an export's XML is read from: a plain file or one member of a zip archive.

    Parameters
    ----------
    path : Path
        How messages name it: the file, or ``archive.zip/member``.
    file : Path
        The file on disk.
    member : str, optional
        The member of the zip archive ``file`` that holds the XML; None for a plain file.
    """

    path: Path
    file: Path
    member: str | None = None

    @contextmanager
    def open(self) -> Iterator[IO[bytes]]:
        """The XML as a binary stream (for a zip member: bounded, damage reported as InputError)."""
        if self.member is None:
            with open(self.file, "rb") as handle:
                yield handle
            return
        try:
            archive = zipfile.ZipFile(self.file)
            member = archive.open(self.member)
        except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError) as error:
            raise InputError(self.path, _damaged(error)) from None
        with archive, member:
            yield _BoundedReader(member, self.path)


def xml_source(path: Path) -> XmlSource:
    """The XML to read for ``path``: the file itself, or the CVAT XML in a zip archive.

    Raises
    ------
    InputError
        ``path`` is a COCO or other JSON export, a zip archive of another export format, a zip
        without a CVAT XML, a damaged or encrypted zip, or its XML unpacks to more than
        :data:`MAX_ARCHIVE_XML_BYTES` bytes or it holds more than :data:`MAX_ARCHIVE_MEMBERS`
        files.
    """
    try:
        with open(path, "rb") as handle:
            head = handle.read(SNIFF_BYTES)
    except OSError as error:
        raise InputError(path, f"cannot read the file: {error.strerror or error}") from None
    if head.startswith(_ZIP_MAGIC):
        return _zip_source(path)
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    if text.startswith((b"{", b"[")):
        raise InputError(path, f"this is {_json_kind(text)}, not CVAT XML: {EXPORT_ADVICE}")
    return XmlSource(path, path)


def _json_kind(head: bytes) -> str:
    """What a JSON file's first bytes say it is."""
    if b'"items"' in head:
        return "a Datumaro export (JSON)"
    if any(key in head for key in (b'"images"', b'"annotations"', b'"categories"')):
        return "a COCO export (JSON)"
    return "a JSON file"


def _zip_source(path: Path) -> XmlSource:
    try:
        with zipfile.ZipFile(path) as archive:
            members = [info for info in archive.infolist() if not info.is_dir()]
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as error:
        raise InputError(path, _damaged(error)) from None
    if len(members) > MAX_ARCHIVE_MEMBERS:
        raise InputError(
            path,
            f"a zip archive of {len(members)} files, more than the {MAX_ARCHIVE_MEMBERS} a CVAT "
            f"export holds: not read; {EXPORT_ADVICE}",
        )
    chosen = _cvat_member(path, members)
    where = Path(f"{path}/{chosen.filename}")
    if chosen.flag_bits & 0x1:
        raise InputError(where, "the zip archive is encrypted: export the task again without a password")
    if chosen.file_size > MAX_ARCHIVE_XML_BYTES:
        raise InputError(
            where,
            f"unpacks to {chosen.file_size} bytes, more than {MAX_ARCHIVE_XML_BYTES}: not read "
            "(unzip it yourself if it really is that large)",
        )
    return XmlSource(where, path, chosen.filename)


def _cvat_member(path: Path, members: list[zipfile.ZipInfo]) -> zipfile.ZipInfo:
    """``annotations.xml`` at the top, else another export's layout (an error), else one ``.xml``."""
    for info in members:
        if info.filename == "annotations.xml":
            return info
    names = [info.filename for info in members]
    for kind, pattern in ZIP_FORMATS:
        found = next((name for name in names if pattern.search(name)), None)
        if found is not None:
            raise InputError(
                path, f"this is {kind} (it holds {found}), not CVAT XML: {EXPORT_ADVICE}"
            )
    xml = [info for info in members if info.filename.lower().endswith(".xml")]
    if len(xml) == 1:
        return xml[0]
    if xml:
        raise InputError(
            path,
            f"a zip archive of {len(xml)} .xml files ({xml[0].filename}, ...) without "
            f"annotations.xml at its top: not a CVAT export; {EXPORT_ADVICE}",
        )
    shown = ", ".join(names[:3]) + (", ..." if len(names) > 3 else "") if names else "nothing"
    raise InputError(
        path, f"a zip archive without annotations.xml (it holds {shown}): {EXPORT_ADVICE}"
    )


def _damaged(error: Exception) -> str:
    return f"a damaged or incomplete zip archive ({error}): download the export again"


class _BoundedReader:
    """A zip member's stream that stops at :data:`MAX_ARCHIVE_XML_BYTES` unpacked bytes.

    The declared size is checked before; this counts what the decompressor really produces.
    Damage found while reading (a bad checksum, a cut-off stream) becomes an InputError.
    """

    def __init__(self, stream: IO[bytes], path: Path, limit: int | None = None):
        self._stream = stream
        self._path = path
        self._limit = MAX_ARCHIVE_XML_BYTES if limit is None else limit
        self._read = 0

    def read(self, size: int = -1) -> bytes:
        if size is None or size < 0:
            size = self._limit + 1 - self._read
        try:
            data = self._stream.read(min(size, self._limit + 1 - self._read))
        except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError) as error:
            raise InputError(self._path, _damaged(error)) from None
        self._read += len(data)
        if self._read > self._limit:
            raise InputError(
                self._path,
                f"unpacks to more than {self._limit} bytes: not read (a damaged archive or a "
                "zip bomb)",
            )
        return data

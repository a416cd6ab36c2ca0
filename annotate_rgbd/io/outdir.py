"""The output folder: one run at a time, no symbolic links, and only our own files removed.

* **Lock**: a run holds an exclusive ``flock`` on the output folder itself for as long as it
  writes there; a second run into the same folder stops at once with one line naming the
  folder and the process that holds it (its id is in :data:`OWNER`, removed when the run ends).
  The lock dies with its process, so a killed run never leaves the folder locked.
* **No links**: the files and folders a run writes (``masks/``, the journal, ``report.json``,
  ...) must not be symbolic links: a link would make the run write, or delete, elsewhere. The
  output folder itself may be a link: the user named it.
* **Only our files**: a run removes only files an earlier run of annotate-rgbd wrote into this
  folder, as its records (``report.json``, the journal, the review record) say; anything else
  is left alone, with a warning.
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import logging
import os
import re
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Iterable

from annotate_rgbd.errors import OutputError

log = logging.getLogger("annotate_rgbd")

#: Written while a run holds the folder: the process id, for the message a second run gives.
OWNER = ".annotate-rgbd.pid"
#: What ``review`` wrote (file name -> digest), so that a later run removes only those files.
REVIEW_RECORD = ".annotate-rgbd-review.json"
#: Folders of per-frame outputs: colour masks, raw masks, overlays, instance-id masks.
MASKS, RAW_MASKS, OVERLAYS, ID_MASKS = "masks", "masks_raw", "overlays", "masks_id"
OUTPUT_FOLDERS = (MASKS, RAW_MASKS, OVERLAYS, ID_MASKS)
#: Every name a run may write or remove at the top of the output folder.
TOP_LEVEL_NAMES = (
    *OUTPUT_FOLDERS, "report.json", "planes.csv", "tracks.csv", "review.html", "contact_sheet.png",
    ".annotate-rgbd-journal.jsonl", REVIEW_RECORD,
)
#: A temporary file of :func:`annotate_rgbd.writer.write_bytes_atomic` (``.<name>.<8 hex>.tmp``).
TEMPORARY = re.compile(r"^\..+\.[0-9a-f]{8}\.tmp$")


def file_digest(path: Path) -> str | None:
    """BLAKE2b digest (hex, 128 bits) of a file's bytes; None when it is missing or unreadable.

    What a run records for each file it writes, and checks before it reuses one.
    """
    try:
        digest = hashlib.blake2b(digest_size=16)
        with open_regular(path) as handle:
            for chunk in iter(lambda: handle.read(1 << 20), b""):
                digest.update(chunk)
        return digest.hexdigest()
    except OSError:
        return None


def open_regular(path: Path) -> IO[bytes]:
    """Open a regular file for reading: never through a symbolic link, never blocking on a FIFO.

    Raises
    ------
    OSError
        Missing, a link, or not a regular file.
    """
    fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    handle = os.fdopen(fd, "rb")
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        handle.close()
        raise OSError(errno.EINVAL, "not a regular file", str(path))
    return handle


def read_bounded(path: Path, max_bytes: int) -> bytes:
    """Read a regular file (:func:`open_regular`) of at most ``max_bytes``.

    Raises
    ------
    OSError
        As :func:`open_regular`, or the file is larger.
    """
    with open_regular(path) as handle:
        data = handle.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise OSError(errno.EFBIG, f"larger than {max_bytes} bytes", str(path))
    return data


def data_digest(data: bytes) -> str:
    """The digest :func:`file_digest` gives for a file holding ``data``."""
    return hashlib.blake2b(data, digest_size=16).hexdigest()


class OutputLock:
    """An exclusive lock on an output folder, held from :meth:`acquire` to :meth:`release`.

    Parameters
    ----------
    folder : Path
        An existing output folder.
    """

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self._fd: int | None = None

    def acquire(self) -> None:
        """Take the lock, or raise :class:`OutputError` naming the process that holds it."""
        try:
            fd = os.open(self.folder, os.O_RDONLY | os.O_DIRECTORY)
        except OSError as exc:
            raise OutputError(self.folder, f"cannot open the output folder: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise OutputError(self.folder, f"cannot lock the output folder: {exc.strerror or exc}") from None
            holder = _owner(self.folder)
            raise OutputError(
                self.folder,
                f"another annotate-rgbd run{f' (process {holder})' if holder else ''} is writing to this folder; "
                "wait for it to end or choose another --out",
            ) from None
        self._fd = fd
        try:
            check_not_link(self.folder / OWNER)
            (self.folder / OWNER).write_text(f"{os.getpid()}\n", encoding="ascii")
        except OSError:
            pass  # only for the message of a second run

    def release(self) -> None:
        """Remove the owner file and release the lock."""
        if self._fd is None:
            return
        try:
            if _owner(self.folder) == str(os.getpid()):
                (self.folder / OWNER).unlink(missing_ok=True)
        except OSError:
            pass
        os.close(self._fd)  # closing the descriptor releases the flock
        self._fd = None

    def __enter__(self) -> OutputLock:
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def _owner(folder: Path) -> str | None:
    try:
        text = read_bounded(folder / OWNER, 32).decode("ascii", "replace").strip()
    except OSError:
        return None
    return text if text.isdigit() else None


def check_not_link(path: Path) -> None:
    """Raise :class:`OutputError` when ``path`` is a symbolic link (dangling or not)."""
    if os.path.islink(path):
        raise OutputError(
            path, "is a symbolic link: annotate-rgbd never writes or deletes through links in its output folder; remove it"
        )


def check_output_names(folder: Path, names: Iterable[str] = TOP_LEVEL_NAMES) -> None:
    """Check that none of the names a run writes in ``folder`` is a symbolic link.

    Raises
    ------
    OutputError
        The first link found.
    """
    for name in names:
        check_not_link(Path(folder) / name)


@dataclass
class Cleanup:
    """What :func:`remove_stale_files` did.

    Parameters
    ----------
    removed : dict of str to int
        Files removed per output folder.
    foreign : list of str
        Files it left alone because annotate-rgbd did not write them (relative paths).
    """

    removed: dict[str, int] = field(default_factory=dict)
    foreign: list[str] = field(default_factory=list)

    def removals(self) -> list[str]:
        """One line per folder files were removed from, in the user's words."""
        what = {MASKS: "masks of frames that no longer get one", RAW_MASKS: "raw masks no longer asked for",
                OVERLAYS: "overlays no longer asked for", ID_MASKS: "instance-id masks no longer asked for"}
        return [f"removed {count} {what[folder]} ({folder}/)" for folder, count in self.removed.items() if count]

    def warnings(self) -> list[str]:
        """A warning naming the files left alone, if any."""
        if not self.foreign:
            return []
        shown = ", ".join(self.foreign[:3]) + (f" and {len(self.foreign) - 3} more" if len(self.foreign) > 3 else "")
        return [f"left alone {len(self.foreign)} file(s) in the output folder that annotate-rgbd did not write: {shown}"]


def remove_stale_files(folder: Path, ours: set[str], keep: set[str]) -> Cleanup:
    """Remove the per-frame outputs an earlier run wrote that this run did not.

    Parameters
    ----------
    folder : Path
        The output folder.
    ours : set of str
        Relative paths (``masks/<name>``) that annotate-rgbd wrote into this folder, by its records.
    keep : set of str
        Relative paths this run wrote.

    Returns
    -------
    Cleanup
    """
    cleanup = Cleanup()
    for sub in OUTPUT_FOLDERS:
        directory = folder / sub
        if os.path.islink(directory) or not directory.is_dir():
            continue
        removed = 0
        for path in sorted(directory.iterdir()):
            relative = f"{sub}/{path.name}"
            if relative in keep:
                continue
            if TEMPORARY.match(path.name) or (relative in ours and path.suffix == ".png"):
                try:
                    path.unlink()
                    removed += not TEMPORARY.match(path.name)
                except OSError:
                    pass
            else:
                cleanup.foreign.append(relative)
        cleanup.removed[sub] = removed
        try:
            directory.rmdir()  # only when empty: a folder this run does not fill is not left behind
        except OSError:
            pass
    return cleanup


def read_review_record(folder: Path) -> dict[str, str]:
    """What ``review`` recorded it wrote into ``folder``: file name -> digest (empty when none)."""
    try:
        record = json.loads(read_bounded(folder / REVIEW_RECORD, 1 << 16))
    except (OSError, ValueError, RecursionError):
        return {}
    if not isinstance(record, dict):
        return {}
    return {k: v for k, v in record.items() if isinstance(k, str) and isinstance(v, str)}


def remove_review_files(folder: Path) -> list[str]:
    """Remove the review page and contact sheet of an earlier run (they show its masks), if
    ``review`` wrote them and they are unchanged since; returns the names left alone."""
    recorded = read_review_record(folder)
    foreign = []
    for name in ("review.html", "contact_sheet.png"):
        path = folder / name
        if not path.exists() or os.path.islink(path):
            continue
        if recorded.get(name) is not None and recorded[name] == file_digest(path):
            path.unlink(missing_ok=True)
        else:
            foreign.append(name)
    (folder / REVIEW_RECORD).unlink(missing_ok=True)
    return foreign

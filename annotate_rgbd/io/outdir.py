"""The output folder: one run at a time, no symbolic links, and only our own files removed.

Every command that writes (``cvat2mask``, ``batch``, ``propose``, ``review``) holds its folder
through one :class:`OutputFolder`; commands that only read a run (``stats``, ``export-cvat``,
``export``) hold it with :func:`reading`, so that they never read a run half-way through.

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
* **Recorded before written**: before a run writes its first per-frame file it records every
  file it may write (:data:`OUTPUTS_RECORD`), so that no crash, kill or fatal error half-way can
  leave a file of ours that a later run takes for the user's.
* **One command per folder**: the record names the command whose output the folder holds; a
  ``propose`` into a ``cvat2mask`` folder (or the other way round) stops with one line instead
  of replacing the other's ``report.json``.
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import logging
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterable

from annotate_rgbd.errors import OutputError
from annotate_rgbd.io.bounded import read_stream_bounded
from .files import open_regular

if TYPE_CHECKING:
    from annotate_rgbd.io.layouts.model import Sequence

log = logging.getLogger("annotate_rgbd")

#: Written while a run holds the folder: the process id, for the message a second run gives.
OWNER = ".annotate-rgbd.pid"
#: The command whose output the folder holds, and every per-frame file a run of it may have
#: written (written before those files; see :class:`OutputFolder`).
OUTPUTS_RECORD = ".annotate-rgbd-outputs.json"
#: The drawn shapes of every frame of a finished ``cvat2mask`` run (what ``review`` draws).
SHAPES_RECORD = ".annotate-rgbd-shapes.jsonl"
#: The run's record, the journal of finished frames, and the ``propose`` outputs.
REPORT, JOURNAL, PROPOSALS = "report.json", ".annotate-rgbd-journal.jsonl", "proposals.xml"
#: Held by a ``propose`` run from before its first mask until its report is written (its
#: journal, without a resume: a run that left it behind mixed its masks with an earlier run's).
UNFINISHED = ".annotate-rgbd-unfinished"
#: The record of an ``export`` folder (its format and files; ``evaluate`` finds an EVOPS export's
#: ``labels/`` by it).
EXPORT_RECORD = "export.json"
#: Commands whose output a folder can hold.
COMMANDS = ("cvat2mask", "propose")
#: What ``review`` wrote (:class:`annotate_rgbd.io.cleanup.ReviewRecord`), so that a later run removes only those files.
REVIEW_RECORD = ".annotate-rgbd-review.json"
#: Folders of per-frame outputs: colour masks, raw masks, overlays, instance-id masks.
MASKS, RAW_MASKS, OVERLAYS, ID_MASKS = "masks", "masks_raw", "overlays", "masks_id"
OUTPUT_FOLDERS = (MASKS, RAW_MASKS, OVERLAYS, ID_MASKS)
#: The tables a ``cvat2mask`` run writes beside its masks.
TABLES = ("planes.csv", "tracks.csv")
#: Every name a run may write or remove at the top of the output folder.
TOP_LEVEL_NAMES = (
    *OUTPUT_FOLDERS, REPORT, *TABLES, "review.html", "contact_sheet.png", PROPOSALS,
    JOURNAL, UNFINISHED, REVIEW_RECORD, OUTPUTS_RECORD, SHAPES_RECORD,
)
#: Bound on the outputs record (a 100,000-frame run with every kind of per-frame output: ~12 MiB).
MAX_OUTPUTS_RECORD = 256 << 20
#: A temporary file of :func:`annotate_rgbd.io.writer.write_bytes_atomic` (``.<name>.<8 hex>.tmp``).
TEMPORARY = re.compile(r"^\..+\.[0-9a-f]{8}\.tmp$")


def file_digest(path: Path) -> str | None:
    """BLAKE2b digest (hex, 128 bits) of a file's bytes; None when it is missing or unreadable.

    What a run records for each file it writes, and checks before it reuses one.
    """
    try:
        digest = hashlib.blake2b(digest_size=16)
        with open_regular(path, follow_links=False) as handle:
            for chunk in iter(lambda: handle.read(1 << 20), b""):
                digest.update(chunk)
        return digest.hexdigest()
    except OSError:
        return None


def read_bounded(path: Path, max_bytes: int) -> bytes:
    """Read a regular file of at most ``max_bytes``, not through a symbolic link
    (:func:`annotate_rgbd.io.files.open_regular`), in pieces
    (:func:`annotate_rgbd.io.bounded.read_stream_bounded`).

    Raises
    ------
    OSError
        As :func:`~annotate_rgbd.io.files.open_regular`, or the file is larger.
    """
    with open_regular(path, follow_links=False) as handle:
        return read_stream_bounded(handle, max_bytes, path)


def data_digest(data: bytes) -> str:
    """The digest :func:`file_digest` gives for a file holding ``data``."""
    return hashlib.blake2b(data, digest_size=16).hexdigest()


class OutputLock:
    """An exclusive lock on an output folder, held from :meth:`acquire` to :meth:`release`.

    Parameters
    ----------
    folder : Path
        An existing output folder.
    owner_file : bool
        Also write the process id into the folder (:data:`OWNER`), for the message of a second
        run; an export folder, which holds only what an export wrote, goes without.
    """

    def __init__(self, folder: Path, owner_file: bool = True):
        self.folder = Path(folder)
        self.owner_file = owner_file
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
        if not self.owner_file:
            return
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
            if self.owner_file and _owner(self.folder) == str(os.getpid()):
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
class OutputFolder:
    """One command's hold on its output folder, from :meth:`open` to :meth:`release`.

    Parameters
    ----------
    path : Path
        The output folder (created by :meth:`open` when missing).
    command : {"cvat2mask", "propose"} or None
        The command whose output the folder is to hold; None for ``review``, which adds to a
        finished run of either.
    """

    path: Path
    command: str | None
    _lock: OutputLock | None = field(default=None, repr=False)
    _expected: set[str] = field(default_factory=set, repr=False)

    def open(self) -> None:
        """Create the folder if needed, refuse links where the command writes, lock it, and
        refuse a folder that holds another command's output.

        Raises
        ------
        OutputError
        """
        from annotate_rgbd.io.writer import prepare_output  # OpenCV: not for the command line's start

        self.path = Path(self.path)
        prepare_output(self.path)
        check_output_names(self.path)
        lock = OutputLock(self.path)
        lock.acquire()
        self._lock = lock
        try:
            holder, self._expected = read_outputs_record(self.path)
            holder = self._check_holder(holder)
            self.command = self.command or holder
        except BaseException:
            self.release()
            raise

    def check(self) -> None:
        """The refusals of :meth:`open` that need nothing written (links where the command writes,
        another command's output), for a command to give before it reads its inputs: the folder's
        error is then its only line. A folder not made yet passes.

        Raises
        ------
        OutputError
        """
        path = Path(self.path)
        if path.is_dir():
            check_output_names(path)
            self._check_holder(read_outputs_record(path)[0])

    def _check_holder(self, holder: str | None) -> str | None:
        """The command whose output the folder holds (by its record, else its report), refused
        when it is not this one's."""
        holder = holder or _command_of_report(Path(self.path))
        if self.command is not None and holder is not None and holder != self.command:
            raise OutputError(
                self.path, f"holds the output of `{holder}`, not of `{self.command}`: choose another --out "
                "(or remove this folder)"
            )
        return holder

    def expect(self, files: Iterable[str]) -> None:
        """Record that this run may write ``files`` (paths relative to the folder), before it
        writes any of them; what earlier runs recorded stays recorded until :meth:`settle`.

        Raises
        ------
        OutputError
            The record cannot be written (nothing of the run is written then).
        """
        self._expected |= set(files)
        self._write_record(self._expected)

    @property
    def expected(self) -> set[str]:
        """Every per-frame file this run or an earlier unfinished one may have written."""
        return set(self._expected)

    def settle(self, files: Iterable[str]) -> None:
        """After the run finished and removed its stale files: record exactly what it left."""
        self._expected = set(files)
        self._write_record(self._expected)

    def _write_record(self, files: set[str]) -> None:
        from annotate_rgbd.io.writer import write_bytes_atomic

        record = {"command": self.command, "files": sorted(files)}
        write_bytes_atomic(self.path / OUTPUTS_RECORD, json.dumps(record, indent=0).encode("utf-8"))

    def release(self) -> None:
        """Release the folder (idempotent)."""
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    def __enter__(self) -> OutputFolder:
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def read_outputs_record(folder: Path) -> tuple[str | None, set[str]]:
    """The command and the per-frame files :data:`OUTPUTS_RECORD` names (None, empty: none).

    Only names a run could write count: ``<one of OUTPUT_FOLDERS>/<file name>``.
    """
    try:
        record = json.loads(read_bounded(Path(folder) / OUTPUTS_RECORD, MAX_OUTPUTS_RECORD))
    except (OSError, ValueError, RecursionError):
        return None, set()
    if not isinstance(record, dict):
        return None, set()
    command = record.get("command") if record.get("command") in COMMANDS else None
    files = record.get("files")
    return command, {f for f in files if _is_output_name(f)} if isinstance(files, list) else set()


def _is_output_name(name: object) -> bool:
    if not isinstance(name, str):
        return False
    folder, _, leaf = name.partition("/")
    return folder in OUTPUT_FOLDERS and leaf not in ("", ".", "..") and "/" not in leaf and "\\" not in leaf


#: Bytes of an existing file :func:`check_output_file` reads to tell whether it is of the output's kind.
SNIFF_BYTES = 4096


def check_output_file(path: Path, example: str, what: str = "the file", kind: str = "file",
                      keep: Iterable[tuple[Path, str]] = (),
                      ours: tuple[Callable[[bytes], bool], str] | None = None) -> None:
    """Refuse to write a single output file (an export, a CSV) where it would lose something: at a
    folder, under a folder that does not exist, inside one of the ``keep`` folders (the inputs
    being read: ground truth, masks), over a file of an annotate-rgbd output folder (its
    report, tables, masks: the run would no longer be what it says), or over an existing file
    that is not of its kind (``ours``: a trajectory, a camera file or a frame list named by
    mistake would be lost). A stream (``-``, a pipe) is always fine.

    Parameters
    ----------
    path : Path
        The file to write.
    example : str
        A file name to suggest when ``path`` is a folder (``round2.xml``).
    what : str
        The output in words, for the messages (``the export``).
    kind : str
        Its kind of file (``XML file``).
    keep : iterable of (Path, str)
        Folders (or files) not to write into, each with its role (``the ground truth``).
    ours : (callable, str), optional
        Whether the first :data:`SNIFF_BYTES` bytes of an existing file are of the output's kind
        (an empty or blank file always is), and that kind in words (``a CVAT XML file``); None: any file
        may be replaced.

    Raises
    ------
    OutputError
    """
    from annotate_rgbd.io.writer import is_stream  # OpenCV: not for the command line's start

    if is_stream(path):
        return
    path = Path(path)
    if path.is_dir():
        raise OutputError(path, f"is a folder: name the {kind} to write (e.g. {path / example})")
    if not path.parent.is_dir():
        state = "is a file, not a folder" if path.parent.exists() else "does not exist"
        raise OutputError(path, f"cannot write output: its folder {path.parent} {state}")
    target = path.resolve()
    for folder, role in keep:
        folder = Path(folder).resolve()
        if target == folder or folder in target.parents:
            raise OutputError(path, f"is inside {role} ({folder}); write {what} elsewhere")
    for folder in (target.parent, target.parent.parent):  # a top-level file, or one in masks/ ...
        if target.relative_to(folder).parts[0] in TOP_LEVEL_NAMES and is_output_folder(folder):
            raise OutputError(path, f"is {target.relative_to(folder).as_posix()} of the annotate-rgbd output "
                                    f"folder {folder}; write {what} elsewhere")
    if ours is not None and target.is_file():
        looks_ours, described = ours
        try:
            with open(target, "rb") as existing:
                head = existing.read(SNIFF_BYTES)
        except OSError:  # unreadable: writing over it says what is wrong, if anything
            return
        if head.strip() and not looks_ours(head):
            first = head.lstrip().splitlines()[0][:40].decode("utf-8", "replace")
            raise OutputError(path, f"already exists and is not {described} (it begins {first!r}): it is not replaced;"
                                    f" write {what} elsewhere, or delete that file first")


def is_output_folder(folder: Path) -> bool:
    """Whether ``folder`` is an annotate-rgbd output folder: it holds the outputs record, or a
    report written by ``cvat2mask`` or ``propose`` (runs made before the record existed)."""
    folder = Path(folder)
    return (folder / OUTPUTS_RECORD).is_file() or _command_of_report(folder) is not None


def _command_of_report(folder: Path) -> str | None:
    """Which command wrote the folder's ``report.json`` (runs made before the outputs record)."""
    try:
        report = json.loads(read_bounded(Path(folder) / REPORT, 1 << 30))
    except (OSError, ValueError, RecursionError):
        return None
    if not isinstance(report, dict):
        return None
    tool = report.get("tool")
    if tool == "annotate-rgbd propose":
        return "propose"
    if isinstance(tool, dict) and tool.get("name") == "annotate-rgbd":
        return "cvat2mask"
    return None


class reading:
    """Hold a finished run's folder for reading (``stats``, ``export-cvat``): a shared lock, so
    that a command that reads never sees a run half-way through.

    Parameters
    ----------
    folder : Path

    Raises
    ------
    OutputError
        A run is writing to the folder.
    """

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self._fd: int | None = None

    def __enter__(self) -> Path:
        try:
            fd = os.open(self.folder, os.O_RDONLY | os.O_DIRECTORY)
        except OSError:
            return self.folder  # missing: the reader's own check says so in its words
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            holder = _owner(self.folder)
            raise OutputError(
                self.folder,
                f"an annotate-rgbd run{f' (process {holder})' if holder else ''} is writing to this folder; "
                "wait for it to end",
            ) from None
        self._fd = fd
        return self.folder

    def __exit__(self, *exc) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def check_outside_sequence(out_dir: str | Path, sequence: "Sequence") -> None:
    """Refuse an output folder that is the sequence folder or lies in one of its image folders.

    A run writes files of its own beside its masks (``contact_sheet.png``, ``report.json``): in
    a ``depth/`` or ``rgb/`` folder that a layout reads by listing it, the next run would take
    them for frames (or stop on them); in the sequence folder they mix with the inputs. A new
    folder inside the sequence folder (``seq/out``) is fine.

    Parameters
    ----------
    out_dir : str or Path
    sequence : Sequence
        :func:`annotate_rgbd.io.sequence.read_sequence`'s.

    Raises
    ------
    OutputError
        Naming the output folder and the input folder it would write into.
    """
    out = Path(out_dir).resolve()
    if out == sequence.root.resolve():
        raise OutputError(out_dir, "the output folder is the sequence folder: name a new folder (e.g. inside it, "
                                   f"{Path(out_dir) / 'out'})")
    for folder in sequence.image_folders():
        if out == folder or folder in out.parents:
            where = "is" if out == folder else "is inside"
            raise OutputError(out_dir, f"the output folder {where} the sequence's image folder {folder}, whose "
                                       "files are read as frames: name a folder outside it")

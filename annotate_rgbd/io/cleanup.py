"""Removing what an earlier run wrote into an output folder and this run did not: its per-frame
files (:func:`remove_stale_files`) and its review page (:func:`remove_review_files`), never a file
annotate-rgbd did not write (the records of :mod:`annotate_rgbd.io.outdir` say which are ours).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

from annotate_rgbd.io.outdir import (
    ID_MASKS, MASKS, OUTPUT_FOLDERS, OVERLAYS, RAW_MASKS, REVIEW_RECORD, TABLES, TEMPORARY, file_digest, read_bounded,
)
from annotate_rgbd.logs import counted


@dataclass
class Cleanup:
    """What :func:`remove_stale_files` did.

    Parameters
    ----------
    removed : dict of str to int
        Files removed per output folder.
    foreign : list of str
        Files it left alone because annotate-rgbd did not write them (relative paths).
    review : list of str
        The earlier review page and contact sheet removed (:func:`remove_review_files`).
    review_overlays : int
        Of the overlays removed, those an earlier ``review`` drew (not a run's ``--overlays``).
    page_of_run : bool
        The page and sheet removed were an earlier run's own (``--overlays``), not ``review``'s.
    """

    removed: dict[str, int] = field(default_factory=dict)
    foreign: list[str] = field(default_factory=list)
    review: list[str] = field(default_factory=list)
    review_overlays: int = 0
    page_of_run: bool = False

    def removals(self) -> list[str]:
        """One line per folder files were removed from, in the user's words."""
        what = {MASKS: ("mask of a frame that no longer gets one", "masks of frames that no longer get one"),
                RAW_MASKS: ("raw mask no longer asked for", "raw masks no longer asked for"),
                OVERLAYS: ("overlay no longer asked for", "overlays no longer asked for"),
                ID_MASKS: ("instance-id mask no longer asked for", "instance-id masks no longer asked for")}
        removed = {**self.removed, OVERLAYS: self.removed.get(OVERLAYS, 0) - self.review_overlays}
        lines = [f"removed {count} {what[folder][count != 1]} ({folder}/)" for folder, count in removed.items() if count]
        review = [*self.review, *([counted(self.review_overlays, "overlay") + f" ({OVERLAYS}/)"]
                                  if self.review_overlays else [])]
        if review:
            names = review[0] if len(review) == 1 else ", ".join(review[:-1]) + " and " + review[-1]
            lines.append(f"removed {names} of the earlier run's --overlays (they showed its overlays)" if self.page_of_run
                         else f"removed {names} of an earlier review (they showed the earlier output; run review again)")
        return lines

    def warnings(self) -> list[str]:
        """A warning naming the files left alone, if any."""
        if not self.foreign:
            return []
        shown = ", ".join(self.foreign[:3]) + (f" and {len(self.foreign) - 3} more" if len(self.foreign) > 3 else "")
        return [f"left alone {len(self.foreign)} file(s) in the output folder that annotate-rgbd did not write: {shown}"]


def remove_stale_files(folder: Path, ours: set[str], keep: set[str], review_overlays: Iterable[str] = ()) -> Cleanup:
    """Remove the per-frame outputs an earlier run wrote that this run did not.

    Parameters
    ----------
    folder : Path
        The output folder.
    ours : set of str
        Relative paths (``masks/<name>``) that annotate-rgbd wrote into this folder, by its records.
    keep : set of str
        Relative paths this run wrote.
    review_overlays : iterable of str
        Relative paths (``overlays/<name>``) of the overlays an earlier ``review`` drew: counted
        apart when removed (:attr:`Cleanup.review_overlays`).

    Returns
    -------
    Cleanup
    """
    cleanup = Cleanup()
    review_overlays = set(review_overlays)
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
                    cleanup.review_overlays += relative in review_overlays
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


@dataclass(frozen=True)
class ReviewRecord:
    """What ``review`` wrote into an output folder (:data:`~annotate_rgbd.io.outdir.REVIEW_RECORD`).

    Parameters
    ----------
    files : dict of str to str
        The page and contact sheet it wrote: file name -> digest
        (:func:`~annotate_rgbd.io.outdir.file_digest`), so that a later run removes them only
        while they are unchanged.
    overlays : tuple of str
        The overlays ``review`` drew (names in ``overlays/``), empty when it drew none: a page
        of a run's own ``--overlays`` shows overlays that a re-run without ``--overlays``
        removes, page and all.
    shows : str or None
        :func:`shown_digest` of the masks and tables the review showed when it was written: a
        ``cvat2mask`` re-run keeps the review only while they are the same.
    """

    files: dict[str, str] = field(default_factory=dict)
    overlays: tuple[str, ...] = ()
    shows: str | None = None

    def to_json(self) -> dict:
        return {"files": dict(self.files), "overlays": list(self.overlays), "shows": self.shows}

    @classmethod
    def from_json(cls, data) -> "ReviewRecord":
        """The record of ``data``; what is not of the record's shape is left out (an earlier
        version's record, file name -> digest, reads as its ``files``)."""
        if not isinstance(data, dict):
            return cls()
        files, overlays, shows = data.get("files", data), data.get("overlays"), data.get("shows")
        files = files if isinstance(files, dict) else {}
        overlays = overlays if isinstance(overlays, list) else []
        return cls({k: v for k, v in files.items() if isinstance(k, str) and isinstance(v, str)},
                   tuple(n for n in overlays if isinstance(n, str) and "/" not in n and "\\" not in n),
                   shows if isinstance(shows, str) else None)


def shown_digest(folder: Path, masks: Iterable[str]) -> str:
    """A digest of what a review of ``folder`` shows: the bytes of each of the ``masks``
    (relative paths, ``masks/<name>``) and of the run's tables (:data:`~annotate_rgbd.io.outdir.TABLES`)."""
    digest = hashlib.blake2b(digest_size=16)
    for name in [*sorted(masks), *TABLES]:
        digest.update(f"{name}\0{file_digest(folder / name)}\n".encode("utf-8"))
    return digest.hexdigest()


#: Bound on the review record (a 100,000-frame run's overlay names: ~3 MiB).
MAX_REVIEW_RECORD = 16 << 20


def read_review_record(folder: Path) -> ReviewRecord:
    """What ``review`` recorded it wrote into ``folder`` (empty when nothing, or unreadable)."""
    try:
        return ReviewRecord.from_json(json.loads(read_bounded(folder / REVIEW_RECORD, MAX_REVIEW_RECORD)))
    except (OSError, ValueError, RecursionError):
        return ReviewRecord()


def remove_review_files(folder: Path, cleanup: Cleanup) -> None:
    """Remove the review page and contact sheet of an earlier run (they show its masks), if
    ``review`` wrote them and they are unchanged since; ``cleanup`` gets the names removed
    (``review``) and those left alone (``foreign``)."""
    record = read_review_record(folder)
    recorded = record.files
    cleanup.page_of_run = not record.overlays  # review records the overlays it drew; a run's own page none
    for name in ("review.html", "contact_sheet.png"):
        path = folder / name
        if not path.exists() or os.path.islink(path):
            continue
        if recorded.get(name) is not None and recorded[name] == file_digest(path):
            path.unlink(missing_ok=True)
            cleanup.review.append(name)
        else:
            cleanup.foreign.append(name)
    (folder / REVIEW_RECORD).unlink(missing_ok=True)

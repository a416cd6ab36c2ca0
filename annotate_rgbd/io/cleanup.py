"""Removing what an earlier run wrote into an output folder and this run did not: its per-frame
files (:func:`remove_stale_files`) and its review page (:func:`remove_review_files`), never a file
annotate-rgbd did not write (the records of :mod:`annotate_rgbd.io.outdir` say which are ours).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from annotate_rgbd.io.outdir import (
    ID_MASKS, MASKS, OUTPUT_FOLDERS, OVERLAYS, RAW_MASKS, REVIEW_RECORD, TEMPORARY, file_digest, read_bounded,
)


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
    """

    removed: dict[str, int] = field(default_factory=dict)
    foreign: list[str] = field(default_factory=list)
    review: list[str] = field(default_factory=list)

    def removals(self) -> list[str]:
        """One line per folder files were removed from, in the user's words."""
        what = {MASKS: ("mask of a frame that no longer gets one", "masks of frames that no longer get one"),
                RAW_MASKS: ("raw mask no longer asked for", "raw masks no longer asked for"),
                OVERLAYS: ("overlay no longer asked for", "overlays no longer asked for"),
                ID_MASKS: ("instance-id mask no longer asked for", "instance-id masks no longer asked for")}
        lines = [f"removed {count} {what[folder][count != 1]} ({folder}/)" for folder, count in self.removed.items()
                 if count]
        if self.review:
            lines.append(f"removed {' and '.join(self.review)} of an earlier review (they showed the earlier output; "
                         "run review again)")
        return lines

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


def remove_review_files(folder: Path, cleanup: Cleanup) -> None:
    """Remove the review page and contact sheet of an earlier run (they show its masks), if
    ``review`` wrote them and they are unchanged since; ``cleanup`` gets the names removed
    (``review``) and those left alone (``foreign``)."""
    recorded = read_review_record(folder)
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

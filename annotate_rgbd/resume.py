"""Resuming: which masks of an earlier run in the same output folder can be kept.

Every mask gets a *fingerprint*: a hash of what it is made from — the depth image's bytes, the
frame's shapes and plane ids, the settings that change a mask (camera, filter, RANSAC) and the
tool version. A finished frame's fingerprint is recorded twice: in a journal appended as frames
finish (:data:`JOURNAL`, which survives an interrupted run) and in ``report.json`` at the end of
a run (when the journal is removed). A re-run reuses a mask whose recorded fingerprint matches
and whose files exist, and makes the others anew (the check is part of the frame's job, so it
runs in parallel and reads the depth image once); since every mask is written atomically and the
work is deterministic, an interrupted run followed by a re-run gives exactly the files of one
uninterrupted run.

This module writes the journal (:class:`Journal`) and reads it back with the report
(:func:`previous_results`).
"""

from __future__ import annotations

import hashlib
import json
from functools import lru_cache
from pathlib import Path
from typing import Sequence, TextIO

import numpy as np

from . import __version__
from .annotation import Shape
from .config import Config, config_to_dict
from .errors import OutputError
from .records import WRITTEN, MaskRecord, RecordError

#: The journal of finished frames, in the output folder.
JOURNAL = ".annotate-rgbd-journal.jsonl"
REPORT = "report.json"


def fingerprint(
    shapes: Sequence[tuple[int, Shape]], image_size: tuple[int, int] | None, config: Config, depth: bytes | np.ndarray
) -> str:
    """Hash of everything one mask depends on.

    Parameters
    ----------
    shapes : sequence of (int, Shape)
        The frame's ``(plane id, shape)`` pairs, in drawing order.
    image_size : (int, int) or None
        (width, height) of the annotated image, where the export states it.
    config : Config
    depth : bytes or ndarray of uint8
        The bytes of the job's depth image file.

    Returns
    -------
    str
        Hex digest; equal digests mean an equal mask.
    """
    digest = hashlib.blake2b(_mask_settings(config), digest_size=32)
    digest.update(depth)
    digest.update(json.dumps(image_size).encode())
    for plane_id, shape in shapes:
        digest.update(f"{plane_id}:{shape.kind}:{shape.z_order}:".encode())
        digest.update(np.ascontiguousarray(shape.points, dtype=np.float64).tobytes())
        if shape.bitmap is not None:
            digest.update(f"{shape.bitmap.shape}".encode())
            digest.update(np.packbits(shape.bitmap).tobytes())
    return digest.hexdigest()


@lru_cache(maxsize=16)
def _mask_settings(config: Config) -> bytes:
    """The tool version and the settings that change a mask (not stitching or part placement,
    whose effect is in the shapes' plane ids)."""
    settings = config_to_dict(config)
    return json.dumps([__version__, settings["camera"], settings["filter"], settings["ransac"]]).encode()


def previous_results(out_dir: Path) -> dict[str, MaskRecord]:
    """Finished frames of earlier runs in ``out_dir``: mask name -> its recorded result.

    Read from ``report.json`` and from the journal of an interrupted run (the journal is newer);
    a torn last journal line (the run was killed while writing it) is ignored, and so is
    anything else that does not have the records' layout (the frame is then made anew).
    """
    found: dict[str, MaskRecord] = {}
    try:
        report = json.loads((out_dir / REPORT).read_text(encoding="utf-8"))
        frames = report.get("frames", []) if isinstance(report, dict) else []
    except (OSError, ValueError):
        frames = []
    for entry in frames if isinstance(frames, list) else []:
        try:
            if entry.get("status") == WRITTEN and "fingerprint" in entry:
                found[Path(entry["mask"]).name] = MaskRecord.from_json(entry["fingerprint"], entry)
        except (RecordError, AttributeError, TypeError):
            continue
    try:
        lines = (out_dir / JOURNAL).read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError):
        lines = []
    for line in lines:
        try:
            record = json.loads(line)
            found[str(record["mask"])] = MaskRecord.from_json(record["fingerprint"], record["result"])
        except (ValueError, KeyError, TypeError, RecordError):
            continue
    return found


class Journal:
    """The journal of one run's finished frames, appended to as they finish.

    Parameters
    ----------
    out_dir : Path
        The run's output folder.
    """

    def __init__(self, out_dir: Path):
        self.path = out_dir / JOURNAL
        self._file: TextIO | None = open(self.path, "a", encoding="utf-8")

    def record(self, mask_name: str, result: MaskRecord) -> None:
        """Append one finished frame, flushed at once (an interrupted run keeps it).

        Raises
        ------
        OutputError
            The journal cannot be written.
        """
        line = json.dumps({"mask": mask_name, "fingerprint": result.fingerprint, "result": result.to_json()})
        try:
            self._file.write(line + "\n")
            self._file.flush()
        except OSError as exc:
            raise OutputError(self.path, f"cannot write output: {exc.strerror or exc}") from None

    def close(self) -> None:
        """Close the file (it stays on disk until :func:`remove_journal`)."""
        if self._file is not None:
            self._file.close()
            self._file = None


def remove_journal(out_dir: Path) -> None:
    """Remove a finished run's journal (its frames are in ``report.json`` now)."""
    (out_dir / JOURNAL).unlink(missing_ok=True)

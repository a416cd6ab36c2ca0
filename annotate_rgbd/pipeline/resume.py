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
import os
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import IO, Collection, Iterator, Sequence

import numpy as np

from annotate_rgbd import __version__
from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.config.settings import Config, config_to_dict
from annotate_rgbd.errors import OutputError
from annotate_rgbd.io.outdir import open_regular, read_bounded
from annotate_rgbd.report.records import WRITTEN, MaskRecord, RecordError

#: The journal of finished frames, in the output folder.
JOURNAL = ".annotate-rgbd-journal.jsonl"
REPORT = "report.json"
#: Reading bounds: a journal line longer than this is not a record (a frame with thousands of
#: planes has lines of a few hundred KiB) ...
MAX_JOURNAL_LINE = 4 << 20
#: ... and neither the journal nor the report is read past this size (a run of 100,000 frames
#: with 20 planes each journals about 300 MiB); what lies beyond is made anew.
MAX_RECORDS_BYTES = 1 << 30


def fingerprint(
    shapes: Sequence[tuple[int, Shape]], image_size: tuple[int, int] | None, config: Config, depth: bytes | np.ndarray,
    propagated: Collection[int] | None = None, expected_planes: Sequence[tuple[int, Sequence[float]]] = (),
    carried: Sequence[tuple] = (),
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
    propagated : collection of int, optional
        The planes whose shapes camera poses carried to the frame.
    expected_planes : sequence of (int, (a, b, c, d))
        Where the poses put them (:class:`annotate_rgbd.frame_job.FrameJob`).
    carried : sequence of (int, int, int, layers, beyond)
        What their keyframes say about them (``FrameJob.carried``).

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
    if propagated:
        digest.update(f"propagated:{sorted(propagated)}".encode())
    for plane_id, equation in expected_planes:
        digest.update(f"expected:{plane_id}:".encode())
        digest.update(np.asarray(equation, dtype=np.float64).tobytes())
    for position, plane_id, z_order, layers, beyond in carried:
        digest.update(f"carried:{position}:{plane_id}:{z_order}:".encode())
        for sign, polygon in (*layers, *((0, quad) for quad in beyond)):
            digest.update(f"{sign}:{len(polygon)}:".encode())
            digest.update(np.ascontiguousarray(polygon, dtype=np.float64).tobytes())
    return digest.hexdigest()


@lru_cache(maxsize=16)
def _mask_settings(config: Config) -> bytes:
    """The tool version and the settings that change a mask (not stitching or part placement,
    whose effect is in the shapes' plane ids)."""
    settings = config_to_dict(config)
    return json.dumps([__version__, *(settings[key] for key in ("camera", "filter", "ransac", "noise", "refine"))]).encode()


@dataclass
class Previous:
    """What earlier runs in an output folder recorded.

    Parameters
    ----------
    masks : dict of str to MaskRecord
        Mask file name -> the latest record of it.
    files : set of str
        Every per-frame file (``masks/<name>``, ...) any of the records says annotate-rgbd
        wrote: the only files a run may remove.
    """

    masks: dict[str, MaskRecord] = field(default_factory=dict)
    files: set[str] = field(default_factory=set)

    def add(self, mask_name: str, record: MaskRecord) -> None:
        self.masks[mask_name] = record
        self.files.add(f"masks/{mask_name}")
        self.files.update(path for path, _ in record.outputs)


def previous_results(out_dir: Path) -> Previous:
    """Finished frames of earlier runs in ``out_dir``.

    Read from ``report.json`` and from the journal of an interrupted run (the journal is newer),
    within bounds (:data:`MAX_JOURNAL_LINE`, :data:`MAX_RECORDS_BYTES`); a torn last journal
    line (the run was killed while writing it) is ignored, and so is anything else that does not
    have the records' layout: such a frame is made anew.
    """
    previous = Previous()
    try:
        report = json.loads(read_bounded(out_dir / REPORT, MAX_RECORDS_BYTES))
        frames = report.get("frames", []) if isinstance(report, dict) else []
    except (OSError, ValueError, RecursionError):
        frames = []
    for entry in frames if isinstance(frames, list) else []:
        try:
            if entry.get("status") == WRITTEN and "fingerprint" in entry:
                previous.add(Path(entry["mask"]).name, MaskRecord.from_json(entry["fingerprint"], entry))
        except (RecordError, AttributeError, TypeError):
            continue
    for line in _journal_lines(out_dir / JOURNAL):
        try:
            record = json.loads(line)
        except (ValueError, RecursionError):
            continue
        mask = record.get("mask") if isinstance(record, dict) else None
        if not isinstance(mask, str):
            continue
        try:
            previous.add(Path(mask).name, MaskRecord.from_json(record.get("fingerprint"), record.get("result")))
        except RecordError:
            previous.masks.pop(Path(mask).name, None)  # a newer record that makes no sense: redo the frame
    return previous


def _journal_lines(path: Path) -> Iterator[bytes]:
    """The journal's lines, skipping over-long ones, up to :data:`MAX_RECORDS_BYTES`."""
    try:
        handle = open_regular(path)
    except OSError:
        return
    with handle:
        total, skipping = 0, False
        while total < MAX_RECORDS_BYTES:
            line = handle.readline(MAX_JOURNAL_LINE + 1)
            if not line:
                return
            total += len(line)
            complete = line.endswith(b"\n")
            if not skipping and complete and len(line) <= MAX_JOURNAL_LINE:
                yield line
            skipping = not complete  # the rest of an over-long line follows


class Journal:
    """The journal of one run's finished frames, appended to as they finish.

    Parameters
    ----------
    out_dir : Path
        The run's output folder.
    """

    def __init__(self, out_dir: Path):
        self.path = out_dir / JOURNAL
        try:  # never through a link: it could append to any file the user can write
            fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW, 0o666)
        except OSError as exc:
            raise OutputError(self.path, f"cannot write output: {exc.strerror or exc}") from None
        self._file: IO[str] | None = os.fdopen(fd, "a", encoding="utf-8")

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

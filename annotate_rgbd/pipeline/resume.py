"""Resuming: which masks of an earlier run in the same output folder can be kept.

Every mask gets a *fingerprint*: a hash of what it is made from — the depth image's bytes, the
frame's shapes and plane ids, the settings that change a mask (camera, filter, RANSAC, noise,
refinement, propagation), the tool version and the *algorithm digest*: a hash of the source of
the code that makes a frame's files (:func:`algorithm_digest`, :data:`MASK_CODE`), so that a
re-run after any change to that code (an upgrade, a local edit) redoes its frames. A finished
frame's fingerprint is recorded twice: in a journal appended as frames finish (:data:`JOURNAL`, which survives an interrupted run) and in ``report.json`` at the end of
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
from typing import Collection, Iterator, Sequence

import numpy as np

from annotate_rgbd import __version__
from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.config.settings import Config, config_to_dict
from annotate_rgbd.errors import OutputError
from annotate_rgbd.io.files import open_regular
from annotate_rgbd.io.outdir import JOURNAL, REPORT, read_bounded
from annotate_rgbd.report.records import WRITTEN, MaskRecord, RecordError

#: Reading bounds: a journal line longer than this is not a record (a frame with thousands of
#: planes has lines of a few hundred KiB) ...
MAX_JOURNAL_LINE = 4 << 20
#: ... and neither the journal nor the report is read past this size (a run of 100,000 frames
#: with 20 planes each journals about 300 MiB); what lies beyond is made anew.
MAX_RECORDS_BYTES = 1 << 30

#: The package's folder (the paths of :data:`MASK_CODE` are relative to it).
PACKAGE = Path(__file__).resolve().parent.parent
#: The code that turns a fingerprint's inputs (depth bytes, shapes, plane ids, settings) into a
#: frame's files and record: a folder stands for every module in it. The per-frame stage
#: (``segment/``: rasterise, filter, fit, refine, grow) and the geometry it calls (``geometry/``:
#: camera, noise bands, plane fits); the frame's job (reading the depth image, segmenting, writing
#: the PNGs and the record) with the modules it calls for that: the depth reader, the palette
#: and id images, the PNG writer, the overlay, the records and their JSON readers (a reused mask
#: keeps its recorded planes), and ``Config.inlier_band`` (in ``config/settings.py``); and this
#: module (the fingerprint itself).
#: Left out, on purpose: code whose results are themselves hashed into the fingerprint (the CVAT
#: reader, interpolation, stitching, pose-guided propagation in ``propagate/``: they make the
#: shapes, plane ids and expected planes; the configuration's values), and code that cannot
#: change a frame's files (:data:`NOT_MASK_CODE`). tests/pipeline/test_algorithm_digest.py checks that
#: every module the frame job imports is in one of the two lists.
MASK_CODE = (
    "segment", "geometry", "pipeline/frame_job.py", "pipeline/resume.py", "io/sequence.py", "io/images.py",
    "io/writer.py", "report/palette.py", "report/records.py", "jsonfields.py", "review/overlay.py", "config/settings.py",
)
#: Modules the frame job imports whose code cannot change a frame's files: the package's and
#: subpackages' ``__init__`` (re-exports; ``__version__`` is hashed by value), the settings'
#: definitions, TOML reader and camera checks (their values are hashed; the checks only warn;
#: propose's and evaluate's are not used),
#: errors, the bounded file opener (and its input wording), reader and input limits, the output
#: folder's helpers (file digests for the up-to-date check), the sequence layouts (they list the
#: frames), camera poses and their rotations and the shape record (hashed as data).
NOT_MASK_CODE = (
    "__init__.py", "config/__init__.py", "io/__init__.py", "pipeline/__init__.py", "report/__init__.py",
    "review/__init__.py", "annotation/__init__.py", "config/masks.py", "config/annotation.py", "config/toml_input.py",
    "config/camera_checks.py", "errors.py", "io/outdir.py", "io/poses.py", "io/rotations.py", "annotation/model.py", "config/evaluate.py",
    "config/propose.py", "io/files.py", "io/bounded.py", "io/limits.py", "io/inputs.py", "io/layouts/__init__.py", "io/layouts/lists.py",
    "io/layouts/model.py", "io/layouts/scannet.py", "io/layouts/seven_scenes.py", "io/layouts/tum.py",
)


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
        Where the poses put them (:class:`annotate_rgbd.pipeline.frame_job.FrameJob`).
    carried : sequence of (int, int, int, layers, beyond)
        What their keyframes say about them (``FrameJob.carried``).

    Returns
    -------
    str
        Hex digest; equal digests mean an equal mask.
    """
    digest = hashlib.blake2b(_mask_settings(config, algorithm_digest()), digest_size=32)
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
def _mask_settings(config: Config, algorithm: str) -> bytes:
    """The tool version, the algorithm digest and the settings that change a mask (not stitching
    or part placement, whose effect is in the shapes' plane ids)."""
    settings = config_to_dict(config)
    sections = ("camera", "filter", "ransac", "noise", "refine", "propagate")
    sections += ("colour_camera",) if config.colour_camera else ()
    return json.dumps([__version__, algorithm, *(settings[key] for key in sections)]).encode()


@lru_cache(maxsize=4)
def algorithm_digest(root: Path = PACKAGE, parts: tuple[str, ...] = MASK_CODE) -> str:
    """Hash of the source of the code that makes a frame's files, computed once per process.

    Parameters
    ----------
    root : Path
        The package's folder.
    parts : tuple of str
        Modules (``"io/writer.py"``) and folders (``"segment"``: every ``.py`` file below it)
        relative to ``root``; :data:`MASK_CODE` by default.

    Returns
    -------
    str
        Hex digest of every module's relative path and bytes, in path order: one byte changed in
        any of them changes it; it is the same in any copy of the package. A listed module that
        is missing is hashed as missing.
    """
    files = set()
    for part in parts:
        path = root / part
        files.update(path.rglob("*.py") if path.is_dir() else [path])
    digest = hashlib.blake2b(digest_size=16)
    for path in sorted(files, key=lambda p: p.relative_to(root).as_posix()):
        try:
            data = path.read_bytes()
        except OSError:
            data = b"<missing>"
        name = path.relative_to(root).as_posix().encode()
        digest.update(b"%d:%s:%d:" % (len(name), name, len(data)))
        digest.update(data)
    return digest.hexdigest()


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
        handle = open_regular(path, follow_links=False)
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
        self._fd: int | None = fd

    def record(self, mask_name: str, result: MaskRecord) -> None:
        """Append one finished frame, written at once (an interrupted run keeps it).

        Unbuffered: a write that fails (a full disk) leaves nothing pending that closing the
        journal would try again; a torn last line is ignored when the journal is read.

        Raises
        ------
        OutputError
            The journal cannot be written (the message names it).
        """
        line = json.dumps({"mask": mask_name, "fingerprint": result.fingerprint, "result": result.to_json()})
        data = memoryview((line + "\n").encode("utf-8"))
        try:
            while data:
                data = data[os.write(self._fd, data):]
        except OSError as exc:
            raise OutputError(self.path, f"cannot write output: {exc.strerror or exc}") from None

    def close(self) -> None:
        """Close the file (it stays on disk until :func:`remove_journal`)."""
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)


def remove_journal(out_dir: Path) -> None:
    """Remove a finished run's journal (its frames are in ``report.json`` now)."""
    (out_dir / JOURNAL).unlink(missing_ok=True)

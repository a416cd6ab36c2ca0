"""Reading a finished run's folder: its report, its masks as plane ids, the shapes it drew.

Everything a command needs after ``cvat2mask`` (``review``, ``stats``, ``export-cvat``) is read
here, from the run's own records, never by running any stage again:

* ``report.json`` (:func:`read_report`);
* the colour masks, decoded to plane ids through the run's plane colours (:func:`mask_plane_ids`);
* the drawn shapes of every written frame (:data:`annotate_rgbd.io.outdir.SHAPES_RECORD`, one
  JSON line per mask, written by :func:`write_drawn_shapes` when the run finishes and read by
  :func:`read_drawn_shapes`): what the labeller drew and what the poses carried (the keyframes'
  signed layers, :func:`annotate_rgbd.segment.rasterize.carried_shapes`), as the frame's job
  drew them;
* the camera poses the masks were made with (each frame's ``camera_pose``, :func:`camera_poses`).
"""

from __future__ import annotations

import base64
import json
import shlex
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from annotate_rgbd.annotation.model import AREA_KINDS, Shape
from annotate_rgbd.errors import InputError
from annotate_rgbd.io.files import open_regular
from annotate_rgbd.io.poses import FramePoses
from annotate_rgbd.io.outdir import JOURNAL, REPORT, SHAPES_RECORD, UNFINISHED, read_bounded
from annotate_rgbd.report.proposals import DepthOnlyRun, is_proposals, proposals_record
from annotate_rgbd.report.records import FrameRecord, RecordError, RunRecord
from annotate_rgbd.report.validation import check_run, load_json

#: Why a frame has no pose in :func:`camera_poses` when its report entry says none.
NO_CAMERA_POSE = "no_camera_pose"
#: Reading bound of ``report.json`` (a run of 100,000 frames with 20 planes each: ~300 MiB).
MAX_REPORT_BYTES = 1 << 30
#: Reading bound of one line of the shapes record (thousands of vertices per frame fit easily).
MAX_SHAPES_LINE = 64 << 20
SHAPES_FORMAT = "annotate-rgbd drawn shapes"
#: Version 3 holds every polygon's vertices as base64 of little-endian float64 (x, y) pairs;
#: version 2 held them as JSON lists of numbers (still read).
SHAPES_VERSION = 3
#: Record versions :func:`read_drawn_shapes` reads.
SHAPES_VERSIONS_READ = (2, 3)


@dataclass(frozen=True)
class DrawnFrame:
    """What one frame's job drew: the shapes, and what camera poses carried to it.

    Attributes
    ----------
    shapes : list of (int, Shape)
        ``(plane id, shape)`` in track order.
    carried : list of (int, int, int, tuple, tuple)
        ``(position, plane id, z_order, layers, beyond)`` per carried plane
        (:func:`annotate_rgbd.segment.rasterize.carried_shapes`); empty without poses.
    """

    shapes: list
    carried: list = field(default_factory=list)


def read_report(out_dir: str | Path, proposals: bool = False) -> RunRecord:
    """Read ``report.json`` of a finished ``cvat2mask`` run.

    Parameters
    ----------
    out_dir : str or Path
    proposals : bool
        Also read a ``propose`` folder's report, as the run record of its proposals
        (:func:`annotate_rgbd.report.proposals.proposals_record`: what ``review`` draws).

    Raises
    ------
    InputError
        No report (the folder is not the output of a finished run), not a report, or a
        ``cvat2mask`` run in the folder did not finish (:func:`check_finished`).
    """
    path = Path(out_dir) / REPORT
    if not Path(out_dir).is_dir():  # not "<it>/report.json: no report", which reads as if the folder were there
        raise InputError(out_dir, "no such folder" if not Path(out_dir).exists() else "not a folder: give a run's output folder")
    check_finished(Path(out_dir))
    try:
        data = read_bounded(path, MAX_REPORT_BYTES)
    except FileNotFoundError:
        runs = "cvat2mask or propose run" if proposals else "cvat2mask run"
        raise InputError(path, f"no report: not the output folder of a finished {runs}") from None
    except OSError as exc:
        raise InputError(path, f"cannot read the report: {exc.strerror or exc}") from None
    report = load_json(data, path)  # strict: no NaN, no lone surrogate
    if is_proposals(report):
        if not proposals:
            raise InputError(path, "this is the output of `propose`, not of a cvat2mask run: " + _next_step(report, out_dir))
        try:
            record = proposals_record(report)
            check_run(record)
        except DepthOnlyRun:
            raise InputError(path, "a propose run of a depth-only sequence: review draws on the RGB frames, and it has "
                             "none; look at its masks/ (or proposals.xml in CVAT)") from None
        except RecordError as exc:
            raise InputError(path, f"not a propose report as annotate-rgbd writes it (edited or damaged?): {exc}") from None
        return record
    if not isinstance(report, dict) or not {"inputs", "config", "frames", "planes"} <= report.keys():
        raise InputError(path, "not a cvat2mask report (inputs, config, frames or planes missing)")
    try:
        record = RunRecord.from_json(report)
        check_run(record)  # every field within what a run writes: one line naming the field
    except RecordError as exc:
        raise InputError(path, f"not a cvat2mask report as annotate-rgbd writes it (edited or damaged?): {exc}") from None
    return record


def check_finished(out_dir: Path) -> None:
    """Refuse a folder where a ``cvat2mask`` or ``propose`` run started and did not finish.

    A ``cvat2mask`` run keeps its journal (:data:`annotate_rgbd.io.outdir.JOURNAL`) from its
    start until it has written ``report.json``, a ``propose`` run its marker
    (:data:`annotate_rgbd.io.outdir.UNFINISHED`). One left behind means the run was interrupted,
    stopped by a fatal problem, or is still running: the masks it made sit beside an earlier
    run's report and tables (or proposals), which no longer describe them.

    Raises
    ------
    InputError
        Naming the journal (or marker) and what to do.
    """
    for name, command, what, again in (
        (JOURNAL, "cvat2mask", "may not match report.json", "cvat2mask (or batch)"),
        (UNFINISHED, "propose", "may be incomplete or mixed with an earlier run's", "propose"),
    ):
        path = out_dir / name
        if path.is_file() or path.is_symlink():
            raise InputError(path, f"a {command} run in this folder did not finish (interrupted, stopped by an error, "
                                   f"or still running): its masks {what}; run the same {again} command again to "
                                   "finish it")


def colour_table(report: RunRecord) -> tuple[np.ndarray, np.ndarray]:
    """The run's plane colours as packed ``0xRRGGBB`` keys (ascending) and their plane ids."""
    packed = {int(p.colour.lstrip("#"), 16): p.plane for p in report.planes}
    keys = np.array(sorted(packed), dtype=np.int64)
    return keys, np.array([packed[k] for k in keys.tolist()], dtype=np.int64)


def mask_plane_ids(image_bgr: np.ndarray, keys: np.ndarray, values: np.ndarray, path: Path) -> np.ndarray:
    """Plane id of every pixel of a colour mask.

    Parameters
    ----------
    image_bgr : ndarray of uint8, shape (H, W, 3)
        As OpenCV reads it.
    keys, values : ndarray of int64
        Packed ``0xRRGGBB`` colours, ascending, and their plane ids (:func:`colour_table`).
    path : Path
        For messages.

    Returns
    -------
    ndarray of int64, shape (H, W)
        0 for black.

    Raises
    ------
    InputError
        A colour that is no plane of the run.
    """
    channels = image_bgr.astype(np.int64)
    packed = (channels[..., 2] << 16) | (channels[..., 1] << 8) | channels[..., 0]
    index = np.clip(np.searchsorted(keys, packed), 0, max(len(keys) - 1, 0))
    known = (keys[index] == packed) if len(keys) else np.zeros(packed.shape, dtype=bool)
    unknown = (packed != 0) & ~known
    if unknown.any():
        raise InputError(path, f"colour #{int(packed[unknown][0]):06x} is no plane of the run (planes.csv)")
    return np.where(known, values[index] if len(values) else 0, 0)


def points_to_json(points: np.ndarray) -> str:
    """Polygon vertices as a JSON value: base64 of their little-endian float64 bytes (exact, and
    a hundred times faster to write than numbers: a run's carried layers are millions of them).

    Parameters
    ----------
    points : ndarray, shape (V, 2)

    Returns
    -------
    str
    """
    return base64.b64encode(np.ascontiguousarray(points, dtype="<f8").tobytes()).decode("ascii")


def points_from_json(value: object) -> np.ndarray:
    """Inverse of :func:`points_to_json`; also reads a list of ``[x, y]`` (version 2 records).

    Returns
    -------
    ndarray of float64, shape (V, 2)

    Raises
    ------
    RecordError
        Not base64 of whole (x, y) pairs, nor a list of pairs.
    """
    if isinstance(value, str):
        try:
            data = base64.b64decode(value, validate=True)
        except ValueError:
            raise RecordError("points: not base64") from None
        if len(data) % 16:
            raise RecordError(f"points: {len(data)} bytes are no whole (x, y) pairs of float64")
        return np.frombuffer(data, dtype="<f8").astype(np.float64).reshape(-1, 2)
    return np.asarray(value, dtype=np.float64).reshape(-1, 2)


def shapes_to_json(shapes: Sequence[tuple[int, Shape]]) -> list[dict]:
    """A frame's ``(plane id, shape)`` pairs as JSON values (exact: floats round-trip)."""
    entries = []
    for plane, shape in shapes:
        entry = {"plane": int(plane), "kind": shape.kind, "z_order": int(shape.z_order),
                 "points": points_to_json(shape.points)}
        if shape.bitmap is not None:
            entry["size"] = list(shape.bitmap.shape)
            entry["bits"] = base64.b64encode(np.packbits(shape.bitmap, axis=None).tobytes()).decode("ascii")
        entries.append(entry)
    return entries


def shapes_from_json(entries: object) -> list[tuple[int, Shape]]:
    """Inverse of :func:`shapes_to_json`.

    Raises
    ------
    RecordError
        An entry of the wrong layout.
    """
    if not isinstance(entries, list):
        raise RecordError("shapes: not a list")
    shapes = []
    for entry in entries:
        try:
            kind = entry["kind"]
            if kind not in AREA_KINDS:
                raise RecordError(f"unknown shape kind {kind!r}")
            points = points_from_json(entry["points"])
            bitmap = None
            if "bits" in entry:
                height, width = (int(v) for v in entry["size"])
                if not (0 < height <= 1 << 15 and 0 < width <= 1 << 15):
                    raise RecordError(f"mask of {width}x{height} pixels")
                bits = np.frombuffer(base64.b64decode(entry["bits"], validate=True), dtype=np.uint8)
                bitmap = np.unpackbits(bits, count=height * width).reshape(height, width).astype(bool)
            shapes.append((int(entry["plane"]), Shape(kind, points, int(entry.get("z_order", 0)), bitmap=bitmap)))
        except RecordError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise RecordError(f"shape entry: {exc}") from None
    return shapes


def carried_to_json(carried: Sequence[tuple]) -> list[dict]:
    """A frame's carried planes (:class:`DrawnFrame`) as JSON values (exact: floats round-trip)."""
    return [{"position": int(position), "plane": int(plane), "z_order": int(z_order),
             "layers": [[int(sign), points_to_json(polygon)] for sign, polygon in layers],
             "beyond": [points_to_json(polygon) for polygon in beyond]}
            for position, plane, z_order, layers, beyond in carried]


def carried_from_json(entries: object) -> list[tuple]:
    """Inverse of :func:`carried_to_json`.

    Raises
    ------
    RecordError
        An entry of the wrong layout.
    """
    if not isinstance(entries, list):
        raise RecordError("carried: not a list")
    carried = []
    try:
        for entry in entries:
            layers = tuple((1 if int(sign) > 0 else -1, points_from_json(points)) for sign, points in entry["layers"])
            beyond = tuple(points_from_json(points) for points in entry["beyond"])
            carried.append((int(entry["position"]), int(entry["plane"]), int(entry["z_order"]), layers, beyond))
    except RecordError:
        raise
    except (KeyError, TypeError, ValueError) as exc:
        raise RecordError(f"carried entry: {exc}") from None
    return carried


def write_drawn_shapes(out_dir: Path, frames: Iterable[tuple[str, Sequence[tuple[int, Shape]], Sequence[tuple]]]) -> None:
    """Write the shapes record: one JSON line per written mask (``masks/<name>``, shapes, what
    the poses carried).

    Raises
    ------
    OutputError
        It cannot be written.
    """
    from annotate_rgbd.io.writer import write_bytes_atomic  # OpenCV: not at import time

    lines = [json.dumps({"format": SHAPES_FORMAT, "version": SHAPES_VERSION})]
    lines += [json.dumps({"mask": mask, "shapes": shapes_to_json(shapes),
                          **({"carried": carried_to_json(carried)} if carried else {})})
              for mask, shapes, carried in frames]
    write_bytes_atomic(out_dir / SHAPES_RECORD, ("\n".join(lines) + "\n").encode("utf-8"))


def read_drawn_shapes(out_dir: Path, masks: set[str], command: str = "cvat2mask") -> dict[str, DrawnFrame]:
    """What the jobs of the masks ``masks`` (``masks/<name>``) drew, from the shapes record.

    ``command`` (``cvat2mask`` or ``propose``) made the folder: the messages say to run it again.

    Raises
    ------
    InputError
        No record (a run made before annotate-rgbd kept one: run the command again), a malformed
        one, or a mask it does not hold.
    """
    path = Path(out_dir) / SHAPES_RECORD
    found: dict[str, DrawnFrame] = {}
    again = ("run cvat2mask again into this folder (it redoes nothing that is up to date)" if command == "cvat2mask"
             else f"run {command} again into this folder")
    try:
        handle = open_regular(path, follow_links=False)
    except OSError as exc:
        raise InputError(path, f"cannot read the run's drawn shapes ({exc.strerror or exc}); {again}") from None
    with handle:
        header = _json_line(handle.readline(MAX_SHAPES_LINE + 1), path, 1)
        if not isinstance(header, dict) or header.get("format") != SHAPES_FORMAT:
            raise InputError(path, "not a drawn-shapes record")
        if header.get("version") not in SHAPES_VERSIONS_READ:
            raise InputError(path, f"a drawn-shapes record of another version ({header.get('version')!r}, "
                                   f"this is {SHAPES_VERSION}); {again}")
        for number, line in enumerate(iter(lambda: handle.readline(MAX_SHAPES_LINE + 1), b""), start=2):
            entry = _json_line(line, path, number)
            mask = entry.get("mask") if isinstance(entry, dict) else None
            if mask in masks:
                try:
                    found[mask] = DrawnFrame(shapes_from_json(entry.get("shapes")),
                                             carried_from_json(entry.get("carried", [])))
                except RecordError as exc:
                    raise InputError(path, f"line {number}: {exc}") from None
    missing = sorted(masks - found.keys())
    if missing:
        raise InputError(path, f"holds no shapes for {missing[0]}: the run changed since; run {command} again")
    return found


def _json_line(line: bytes, path: Path, number: int):
    if len(line) > MAX_SHAPES_LINE or (line and not line.endswith(b"\n")):
        raise InputError(path, f"line {number}: too long or cut short")
    try:
        return json.loads(line)
    except (ValueError, RecursionError):
        raise InputError(path, f"line {number}: not JSON") from None


def _next_step(report: dict, out_dir: str | Path) -> str:
    """How a propose run's planes become a run the other commands read: ``cvat2mask`` on its
    ``proposals.xml``, with its sequence and trajectory (absolute paths) and configuration."""
    inputs = report.get("inputs") if isinstance(report.get("inputs"), dict) else {}
    frames = report.get("frames") if isinstance(report.get("frames"), list) else []
    if frames and all(isinstance(f, dict) and f.get("rgb") is None for f in frames):
        return ("a propose run of a depth-only sequence, which cvat2mask cannot take (it needs the RGB frames "
                "annotations are drawn on): its masks/ hold the proposals")
    sequence = inputs.get("sequence") if isinstance(inputs.get("sequence"), str) else "SEQUENCE"
    poses = f" --poses {shlex.quote(inputs['poses'])}" if isinstance(inputs.get("poses"), str) else ""
    proposals = Path(out_dir).absolute() / "proposals.xml"
    return (f"its planes become masks with `annotate-rgbd cvat2mask {shlex.quote(sequence)} "
            f"{shlex.quote(str(proposals))}{poses} --config CONFIG --out DIR` (CONFIG: the propose run's; after "
            "correcting the planes in CVAT, or as they are); then use DIR")


def camera_poses(frames: Sequence[FrameRecord]) -> FramePoses:
    """The poses a run made its frames' masks with (their ``camera_pose``), as
    :class:`~annotate_rgbd.io.poses.FramePoses`, one per frame (NaN, ``ok`` False and the frame's ``pose``
    as the reason where a frame has none: :data:`NO_CAMERA_POSE` where that says ``ok`` or nothing)."""
    pairs = [f.rotation_translation() for f in frames]
    ok = np.array([p is not None for p in pairs], dtype=bool)
    rotations = np.full((len(frames), 3, 3), np.nan)
    translations = np.full((len(frames), 3), np.nan)
    for i in np.flatnonzero(ok).tolist():
        rotations[i], translations[i] = pairs[i]
    reasons = np.array(["" if p is not None else f.pose if f.pose not in (None, "ok") else NO_CAMERA_POSE
                        for f, p in zip(frames, pairs)])
    return FramePoses(rotations, translations, ok, reasons)

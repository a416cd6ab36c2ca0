"""Checks of a run's records read back from ``report.json``, made once, on reading
(:func:`annotate_rgbd.report.run_folder.read_report`).

The report is a file users and other tools may edit. It is read as strict JSON (no ``NaN``, no
infinity, no lone surrogate: :func:`load_json`) into the typed records of
:mod:`annotate_rgbd.report.records`, whose every field is then checked against what a run can
write (:func:`check_run`: ranges bounded by :mod:`annotate_rgbd.io.limits`, colours, names
without control characters, mask paths inside ``masks/``): an edited or damaged report gives one
line naming the file and the field, never a traceback or a huge allocation later.

No image or geometry library is imported here: ``stats`` runs with little memory.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

from annotate_rgbd.errors import InputError
from annotate_rgbd.io.limits import MAX_FRAMES, MAX_IMAGE_PIXELS, MAX_PLANES, MAX_TIMESTAMP
from annotate_rgbd.jsonfields import RecordError
from annotate_rgbd.segment.plane_record import PlaneRecord

from .records import FrameRecord, RunRecord

#: Characters no name of a run holds (C0 and C1 controls, DEL): they break XML, CSV and terminals.
CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")
COLOUR = re.compile(r"#[0-9a-fA-F]{6}")
#: Counts of pixels in a plane record.
PIXEL_FIELDS = ("pixels", "valid_pixels", "inliers", "fit_points", "fit_inliers_ransac", "fit_inliers_refit", "grown")


def load_json(data: bytes, path: Path) -> Any:
    """Strict JSON: UTF-8, finite numbers only, every string encodable (no lone surrogate).

    Raises
    ------
    InputError
        One line naming ``path`` and the problem.
    """
    try:
        document = json.loads(data.decode("utf-8"), parse_constant=_refuse_constant, parse_float=_finite_float)
    except UnicodeDecodeError as exc:
        raise InputError(path, f"cannot read the report: not UTF-8 ({exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise InputError(path, f"cannot read the report: {exc}") from None
    except ValueError as exc:  # a constant or float refused below
        raise InputError(path, f"cannot read the report: {exc}") from None
    except RecursionError:
        raise InputError(path, "cannot read the report: nested too deeply") from None
    where = unencodable_string(document)
    if where is not None:
        raise InputError(path, f"{where or 'the document'}: a text with a lone surrogate (\\ud800-\\udfff), not Unicode text")
    return document


def unencodable_string(document: Any) -> str | None:
    """Where (``frames[3].depth``) the first string of a JSON document that UTF-8 cannot
    encode is, or None. Walks the document without recursion."""
    stack: list[tuple[str, Any]] = [("", document)]
    while stack:
        where, value = stack.pop()
        if isinstance(value, str):
            if not _encodable(value):
                return where
        elif isinstance(value, dict):
            for key, item in value.items():
                if not _encodable(key):
                    return f"{where}.<key>" if where else "<key>"
                stack.append((f"{where}.{key}" if where else key, item))
        elif isinstance(value, list):
            stack.extend((f"{where}[{i}]", item) for i, item in enumerate(value))
    return None


def check_run(record: RunRecord) -> None:
    """Check a run's records against what a run can write.

    Raises
    ------
    RecordError
        ``<field>: <problem>`` for the first field out of bounds.
    """
    _range(record.n_planes, 0, MAX_PLANES, "summary.planes")
    for i, part in enumerate(record.parts):
        where = f"inputs.parts[{i}]"
        for key in ("file", "name", "placed_by"):
            _name(getattr(part, key), f"{where}.{key}")
        _range(part.offset, -MAX_FRAMES, MAX_FRAMES, f"{where}.offset")
        _range(part.first_rgb, 0, MAX_FRAMES - 1, f"{where}.first_rgb")
        _range(part.last_rgb, 0, MAX_FRAMES - 1, f"{where}.last_rgb")
    for i, plane in enumerate(record.planes):
        where = f"planes[{i}]"
        _range(plane.plane, 1, record.n_planes, f"{where}.plane")
        if not COLOUR.fullmatch(plane.colour):
            raise RecordError(f"{where}.colour: {plane.colour!r} is not a colour #rrggbb")
        _name(plane.label, f"{where}.label")
        _name(plane.part, f"{where}.part")
    _range(len(record.frames), 0, MAX_FRAMES, "frames (their number)")
    for i, frame in enumerate(record.frames):
        check_frame(frame, record.n_planes, f"frames[{i}]")
    inconsistent = (record.propagation or {}).get("inconsistent_tracks", [])
    if not isinstance(inconsistent, list) or not all(isinstance(t, str) for t in inconsistent):
        raise RecordError("propagation.inconsistent_tracks is not a list of strings")
    check_alignment((record.propagation or {}).get("alignment"))


def check_alignment(alignment) -> None:
    """Check a report's ``propagation.alignment`` (absent in reports of earlier versions): an
    object whose lists of frames to check (``beyond_limits``, ``apart_from_keyframes``) hold
    objects naming a depth frame by index and timestamp.

    Raises
    ------
    RecordError
    """
    if alignment is None:
        return
    if not isinstance(alignment, dict):
        raise RecordError("propagation.alignment is not an object")
    for key in ("beyond_limits", "apart_from_keyframes"):
        entries = alignment.get(key, [])
        if not isinstance(entries, list):
            raise RecordError(f"propagation.alignment.{key} is not a list")
        for i, entry in enumerate(entries):
            frame = entry.get("depth_frame") if isinstance(entry, dict) else None
            time = entry.get("depth_timestamp") if isinstance(entry, dict) else None
            if (isinstance(frame, bool) or not isinstance(frame, int) or frame < 0 or isinstance(time, bool)
                    or not isinstance(time, (int, float)) or not math.isfinite(time)):
                raise RecordError(f"propagation.alignment.{key}[{i}] is not an object with a depth_frame (an index) "
                                  "and a depth_timestamp")


def check_frame(frame: FrameRecord, n_planes: int, where: str) -> None:
    """Check one frame record (see :func:`check_run`)."""
    for key in ("depth", "rgb", "status", "part", "reason", "pose"):
        if getattr(frame, key) is not None:
            _name(getattr(frame, key), f"{where}.{key}")
    _range(frame.rgb_index, 0, MAX_FRAMES - 1, f"{where}.rgb_index")
    if frame.cvat_frame is not None:
        _range(frame.cvat_frame, 0, MAX_FRAMES - 1, f"{where}.cvat_frame")
    if abs(frame.depth_timestamp) > MAX_TIMESTAMP:
        raise RecordError(f"{where}.depth_timestamp: {frame.depth_timestamp} is beyond {MAX_TIMESTAMP:g}")
    if frame.mask is not None:
        folder, _, name = frame.mask.partition("/")
        if folder != "masks" or not name or "/" in name or "\\" in name or name in (".", ".."):
            raise RecordError(f"{where}.mask: {frame.mask!r} is not masks/<file name>")
        _name(frame.mask, f"{where}.mask")
    for kind in ("kept", "dropped"):
        for k, plane in enumerate(getattr(frame, kind)):
            check_plane(plane, n_planes, f"{where}.{kind}[{k}]")


def check_plane(plane: PlaneRecord, n_planes: int, where: str) -> None:
    """Check one plane record (see :func:`check_run`)."""
    _range(plane.plane, 1, n_planes, f"{where}.plane")
    for key in PIXEL_FIELDS:
        if getattr(plane, key) is not None:
            _range(getattr(plane, key), 0, MAX_IMAGE_PIXELS, f"{where}.{key}")
    for key in ("inlier_ratio", "invalid_ratio"):
        value = getattr(plane, key)
        if value is not None and not 0 <= value <= 1:
            raise RecordError(f"{where}.{key}: {value} is not a share between 0 and 1")
    if plane.mean_distance is not None and plane.mean_distance < 0:
        raise RecordError(f"{where}.mean_distance: {plane.mean_distance} is negative")
    if plane.reason is not None:
        _name(plane.reason, f"{where}.reason")


def _range(value: int, low: int, high: int, where: str) -> None:
    if not low <= value <= high:
        shown = str(value) if abs(value) < 10**12 else f"{value:.3g}"
        raise RecordError(f"{where}: {shown} is out of range ({low} to {high})")


def _name(text: str, where: str) -> None:
    found = CONTROL.search(text)
    if found:
        raise RecordError(f"{where}: holds the control character U+{ord(found.group()):04X}")


def _encodable(text: str) -> bool:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _refuse_constant(name: str) -> float:
    raise ValueError(f"{name} is not a JSON number (strict JSON has no NaN or infinity)")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"the number {text[:20]} is beyond the range of a double")
    return value

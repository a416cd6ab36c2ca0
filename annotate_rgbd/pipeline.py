"""The ``cvat2mask`` job: CVAT export(s) + RGB-D sequence -> refined plane masks and a report.

:func:`process_frame` is the pure per-frame core (label image in, refined label image and
per-plane records out); :func:`run_cvat2mask` reads the inputs, walks the depth frames and
writes the outputs.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence as SequenceType

import numpy as np

from . import __version__
from .annotation import Annotation, Shape
from .camera import depth_to_metres
from .config import Config, config_to_dict
from .cvat import read_cvat
from .errors import InputError
from .filters import drop_reasons, plane_statistics
from .frames import rgb_indices
from .palette import colour_hex, colourize, plane_colours
from .rasterize import rasterize_frame
from .refine import refine_planes
from .sequence import Sequence, associate, read_depth, read_sequence
from .writer import write_csv, write_json, write_png

log = logging.getLogger("annotate_rgbd")

#: Why a depth frame gets no mask, as written to the report.
OUTSIDE_ANNOTATION = "outside_annotated_range"
NO_RGB_FRAME = "no_rgb_frame_within_max_time_diff"
RGB_NOT_ANNOTATED = "rgb_frame_not_in_annotation"
UNREADABLE_DEPTH = "unreadable_depth"


@dataclass(frozen=True)
class Plane:
    """One physical plane of the output: its id, colour and where it came from.

    Parameters
    ----------
    plane_id : int
        Global id, from 1; the mask colour is ``plane_colours(n)[plane_id - 1]``.
    label : str
        CVAT label.
    part : str
        The annotation file (part) the track is in.
    track_id : int
        CVAT track id within that part.
    """

    plane_id: int
    label: str
    part: str
    track_id: int


@dataclass
class FrameResult:
    """What :func:`process_frame` did on one depth frame."""

    labels: np.ndarray
    kept: list[dict] = field(default_factory=list)
    dropped: list[dict] = field(default_factory=list)


@dataclass
class RunReport:
    """Summary of a finished run (the content of ``report.json``)."""

    frames: list[dict]
    planes: list[Plane]
    warnings: list[str]
    notes: list[str]

    @property
    def written(self) -> int:
        """Number of masks written."""
        return sum(1 for f in self.frames if f["status"] == "written")


def process_frame(depth_raw: np.ndarray, shapes: SequenceType[tuple[int, Shape]], config: Config) -> FrameResult:
    """Rasterise, filter and refine the planes of one depth frame.

    Parameters
    ----------
    depth_raw : ndarray, shape (H, W)
        Raw depth image.
    shapes : sequence of (int, Shape)
        ``(plane id, shape)`` of the frame, in track order.
    config : Config

    Returns
    -------
    FrameResult
        ``labels`` holds the plane id of every pixel that lies on its plane (0 elsewhere);
        ``kept`` and ``dropped`` one record per plane drawn on the frame.
    """
    height, width = depth_raw.shape
    drawn = rasterize_frame(shapes, height, width)
    depth_m = depth_to_metres(depth_raw, config.camera.depth_scale)
    stats = plane_statistics(drawn, depth_m, config.camera)
    reasons = drop_reasons(stats, config.filter)
    keep_ids = stats.plane_ids[[r is None for r in reasons]]
    refined, fits = refine_planes(drawn, depth_m, keep_ids, config.camera, config.ransac)
    result = FrameResult(labels=refined)
    for i, plane_id in enumerate(stats.plane_ids.tolist()):
        record = {
            "plane": plane_id,
            "pixels": int(stats.pixels[i]),
            "valid_pixels": int(stats.valid_pixels[i]),
            "mean_distance": _rounded(stats.mean_distance[i]),
        }
        if reasons[i] is None:
            fit = fits[plane_id]
            inliers = int(fit.inliers.sum())
            record.update(
                inliers=inliers,
                inlier_ratio=round(inliers / max(int(stats.valid_pixels[i]), 1), 6),
                equation=[round(float(v), 9) for v in fit.equation],
            )
            result.kept.append(record)
        else:
            record.update(reason=reasons[i], invalid_ratio=round(float(stats.invalid_ratio[i]), 6))
            result.dropped.append(record)
    return result


def plan_planes(annotations: SequenceType[Annotation]) -> tuple[list[Plane], dict[tuple[int, int], int]]:
    """Give every track a global plane id.

    Parameters
    ----------
    annotations : sequence of Annotation
        The parts; a single export is one part.

    Returns
    -------
    planes : list of Plane
        Ordered by plane id.
    plane_of : dict of (int, int) to int
        ``(part index, track id) -> plane id``.
    """
    planes: list[Plane] = []
    plane_of: dict[tuple[int, int], int] = {}
    for part_index, annotation in enumerate(annotations):
        for track in sorted(annotation.tracks, key=lambda t: t.track_id):
            plane = Plane(len(planes) + 1, track.label, Path(annotation.path).name, track.track_id)
            planes.append(plane)
            plane_of[(part_index, track.track_id)] = plane.plane_id
    return planes, plane_of


def run_cvat2mask(
    sequence_dir: str | Path,
    annotation_paths: SequenceType[str | Path],
    out_dir: str | Path,
    config: Config,
    progress: Callable[[int, int], None] | None = None,
) -> RunReport:
    """Run the whole job and write ``masks/``, ``planes.csv`` and ``report.json`` in ``out_dir``.

    Parameters
    ----------
    sequence_dir : str or Path
        TUM / ICL-NUIM sequence folder.
    annotation_paths : sequence of str or Path
        CVAT exports (one for now: one annotation part).
    out_dir : str or Path
        Output folder (created if missing).
    config : Config
    progress : callable, optional
        Called as ``progress(done, total)`` after each depth frame.

    Returns
    -------
    RunReport

    Raises
    ------
    InputError
        A fatal problem with an input (missing files, malformed export, sizes that do not
        match): nothing sensible can be produced.
    """
    out_dir = Path(out_dir)
    if len(annotation_paths) != 1:
        raise InputError(None, "give exactly one CVAT export")
    sequence = read_sequence(sequence_dir)
    labels = config.annotation.labels or None
    annotations = [read_cvat(path, labels=labels) for path in annotation_paths]
    warnings: list[str] = []
    notes = [f"{Path(a.path).name}: {note}" for a in annotations for note in a.notes]

    annotation = annotations[0]
    frame_to_rgb, missing = rgb_indices(annotation, sequence.rgb)
    for line in missing:
        _warn(warnings, f"{annotation.path}: {line}; skipped")
    planes, plane_of = plan_planes(annotations)
    colours = plane_colours(len(planes))
    shapes_at = _shapes_by_rgb_index(annotation, frame_to_rgb, plane_of, part_index=0)
    size_at = {frame_to_rgb[f]: size for f, size in annotation.image_size.items() if f in frame_to_rgb}
    cvat_frame_at = {rgb: frame for frame, rgb in frame_to_rgb.items()}

    nearest, time_diff, matched = associate(
        sequence.depth.timestamps, sequence.rgb.timestamps, config.sequence.max_time_diff
    )
    first, last = min(cvat_frame_at), max(cvat_frame_at)
    frames = []
    for d, depth_file in enumerate(sequence.depth.files):
        rgb = int(nearest[d])
        entry = {
            "depth": depth_file,
            "depth_timestamp": float(sequence.depth.timestamps[d]),
            "rgb": sequence.rgb.files[rgb],
            "rgb_index": rgb,
            "time_offset": round(float(time_diff[d]), 6),
            "status": "skipped",
        }
        frames.append(entry)
        if progress:
            progress(d + 1, len(sequence.depth))
        if rgb < first or rgb > last:
            entry["reason"] = OUTSIDE_ANNOTATION
            continue
        if not matched[d]:
            entry["reason"] = NO_RGB_FRAME
            _warn(warnings, f"{sequence.root / depth_file}: no RGB frame within {config.sequence.max_time_diff} s; skipped")
            continue
        if rgb not in cvat_frame_at:
            entry["reason"] = RGB_NOT_ANNOTATED
            continue
        entry["cvat_frame"] = cvat_frame_at[rgb]
        try:
            depth_raw = read_depth(sequence.root / depth_file)
        except InputError as exc:
            entry["reason"] = UNREADABLE_DEPTH
            _warn(warnings, f"{exc}; skipped")
            continue
        _check_size(sequence, depth_file, depth_raw, size_at.get(rgb), annotation.path)
        result = process_frame(depth_raw, shapes_at.get(rgb, []), config)
        mask_name = Path(depth_file).name
        write_png(out_dir / "masks" / mask_name, colourize(result.labels, colours))
        entry.update(status="written", mask=f"masks/{mask_name}", kept=result.kept, dropped=result.dropped)
        entry.pop("reason", None)

    report = RunReport(frames=frames, planes=planes, warnings=warnings, notes=notes)
    write_csv(
        out_dir / "planes.csv",
        ["plane_id", "colour", "r", "g", "b", "label", "part", "track_id"],
        [[p.plane_id, colour_hex(c), *map(int, c), p.label, p.part, p.track_id] for p, c in zip(planes, colours)],
    )
    write_json(out_dir / "report.json", _report_json(report, sequence, annotation_paths, config, colours))
    return report


def _shapes_by_rgb_index(
    annotation: Annotation, frame_to_rgb: dict[int, int], plane_of: dict[tuple[int, int], int], part_index: int
) -> dict[int, list[tuple[int, Shape]]]:
    """RGB index -> (plane id, shape) pairs in track order."""
    shapes: dict[int, list[tuple[int, Shape]]] = {}
    for track in annotation.tracks:
        plane_id = plane_of[(part_index, track.track_id)]
        for frame, shape in track.shapes.items():
            if frame in frame_to_rgb:
                shapes.setdefault(frame_to_rgb[frame], []).append((plane_id, shape))
    return shapes


def _check_size(sequence: Sequence, depth_file: str, depth_raw: np.ndarray, size: tuple[int, int] | None, source: str) -> None:
    if size is None:
        return
    width, height = size
    if depth_raw.shape != (height, width):
        raise InputError(
            sequence.root / depth_file,
            f"depth image is {depth_raw.shape[1]}x{depth_raw.shape[0]} but {Path(source).name} "
            f"annotates {width}x{height} images",
        )


def _warn(warnings: list[str], message: str) -> None:
    warnings.append(message)
    log.warning(message)


def _rounded(value: float) -> float | None:
    return None if not np.isfinite(value) else round(float(value), 6)


def _report_json(report: RunReport, sequence: Sequence, annotation_paths, config: Config, colours) -> dict:
    written = [f for f in report.frames if f["status"] == "written"]
    skipped: dict[str, int] = {}
    for f in report.frames:
        if f["status"] == "skipped":
            skipped[f["reason"]] = skipped.get(f["reason"], 0) + 1
    return {
        "tool": {"name": "annotate-rgbd", "version": __version__},
        "inputs": {
            "sequence": str(sequence.root),
            "annotations": [str(p) for p in annotation_paths],
        },
        "config": config_to_dict(config),
        "summary": {
            "depth_frames": len(report.frames),
            "masks_written": len(written),
            "frames_skipped": skipped,
            "planes": len(report.planes),
            "planes_kept": sum(len(f["kept"]) for f in written),
            "planes_dropped": sum(len(f["dropped"]) for f in written),
        },
        "planes": [
            {"plane": p.plane_id, "colour": colour_hex(c), "label": p.label, "part": p.part, "track_id": p.track_id}
            for p, c in zip(report.planes, colours)
        ],
        "frames": report.frames,
        "warnings": report.warnings,
        "notes": report.notes,
    }

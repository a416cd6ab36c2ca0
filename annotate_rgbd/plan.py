"""Planning a run: what each depth frame gets, and from where, before any mask is made.

:func:`plan_run` reads the inputs (the sequence lists and the CVAT exports), places the parts,
measures how the tracks of consecutive parts overlap (:mod:`annotate_rgbd.part_overlap`) and
gives every track its global plane (:mod:`annotate_rgbd.stitch`); :func:`plan_frames`, a pure
function, then decides for every depth frame whether it gets a mask, and builds its
:class:`~annotate_rgbd.records.FrameRecord` and, for a mask, its
:class:`~annotate_rgbd.frame_job.FrameJob`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence as SequenceType

import numpy as np

from .annotation import Annotation
from .config import Config
from .cvat import read_cvat
from .errors import InputError
from .frame_job import OVERLAY_DIR, FrameJob
from .palette import plane_colours
from .part_overlap import part_pair_iou
from .parts import Part, frame_owners, place_parts
from .records import NO_RGB_FRAME, OUTSIDE_ANNOTATION, RGB_NOT_ANNOTATED, FrameRecord
from .sequence import Sequence, associate, camera_problem, read_depth, read_sequence
from .stitch import PartTracks, TrackPlane, assign_planes, label_conflicts

log = logging.getLogger("annotate_rgbd")


@dataclass(frozen=True)
class Association:
    """Each depth frame's RGB frame nearest in time.

    Parameters
    ----------
    nearest : ndarray of int, shape (n_depth,)
        Index of the nearest RGB frame.
    time_diff : ndarray of float64, shape (n_depth,)
        RGB minus depth timestamp (s).
    matched : ndarray of bool, shape (n_depth,)
        Whether that RGB frame is within ``max_time_diff``.
    """

    nearest: np.ndarray
    time_diff: np.ndarray
    matched: np.ndarray

    def depth_of_rgb(self) -> dict[int, int]:
        """RGB index -> the matched depth frame closest to it in time (the earlier one of two
        equally close)."""
        best: dict[int, int] = {}
        for d in np.flatnonzero(self.matched).tolist():
            rgb = int(self.nearest[d])
            if rgb not in best or abs(self.time_diff[d]) < abs(self.time_diff[best[rgb]]):
                best[rgb] = d
        return best


@dataclass
class RunPlan:
    """Everything decided before any mask is made.

    Parameters
    ----------
    sequence : Sequence
    parts : list of Part
        The annotation parts in sequence order.
    tracks : list of TrackPlane
        The global plane of every track.
    colours : ndarray of uint8, shape (n_planes, 3)
        Plane colours (row ``k - 1`` for plane id ``k``).
    frames : list of FrameRecord
        One per depth frame, in depth order; filled in as masks are made.
    jobs : list of (int, FrameJob)
        The frames that get a mask: index into ``frames`` and the job.
    warnings, notes : list of str
    """

    sequence: Sequence
    parts: list[Part]
    tracks: list[TrackPlane]
    colours: np.ndarray
    frames: list[FrameRecord]
    jobs: list[tuple[int, FrameJob]]
    warnings: list[str]
    notes: list[str]

    @property
    def n_planes(self) -> int:
        """Number of global planes."""
        return len(self.colours)


@dataclass(frozen=True)
class OutputOptions:
    """Where a run's files go and which extras it writes.

    Parameters
    ----------
    out_dir : Path
    raw_masks : bool
        Also write ``masks_raw/``.
    overlays : bool
        Also write ``overlays/``.
    """

    out_dir: Path
    raw_masks: bool = False
    overlays: bool = False


def plan_run(
    sequence_dir: str | Path,
    annotation_paths: SequenceType[str | Path],
    out_dir: str | Path,
    config: Config,
    offsets: Mapping[str, int] | None = None,
    raw_masks: bool = False,
    overlays: bool = False,
) -> RunPlan:
    """Read the inputs and decide, for every depth frame, whether and how it gets a mask.

    Parameters are those of :func:`annotate_rgbd.pipeline.run_cvat2mask`.

    Returns
    -------
    RunPlan

    Raises
    ------
    InputError
        A fatal problem with an input.
    """
    if not annotation_paths:
        raise InputError(None, "no CVAT export given")
    sequence = read_sequence(sequence_dir)
    labels = config.annotation.labels or None
    annotations = [read_cvat(path, labels=labels) for path in annotation_paths]
    notes = [f"{Path(a.path).name}: {note}" for a in annotations for note in a.notes]
    warnings: list[str] = []

    all_offsets = {p.file: p.offset for p in config.parts}
    all_offsets.update(offsets or {})
    parts, missing = place_parts(annotations, sequence.rgb, all_offsets)
    _warn(warnings, missing)
    association = Association(*associate(sequence.depth.timestamps, sequence.rgb.timestamps, config.sequence.max_time_diff))
    depth_of_rgb = association.depth_of_rgb()
    pair_iou = [part_pair_iou(sequence, depth_of_rgb, a, b, config) for a, b in zip(parts, parts[1:])]
    tracks = assign_planes(
        [PartTracks.of(p) for p in parts], pair_iou, config.matches, config.stitch.min_iou, "configuration"
    )
    _warn(warnings, label_warnings(annotations, config.annotation.labels))
    _warn(warnings, label_conflicts(tracks))
    colours = plane_colours(max((t.plane for t in tracks), default=0))
    output = OutputOptions(Path(out_dir), raw_masks, overlays)
    frames, jobs, frame_warnings = plan_frames(sequence, parts, tracks, association, output, config.sequence.max_time_diff)
    _warn(warnings, frame_warnings)
    _warn(warnings, camera_warnings(jobs, config))
    return RunPlan(sequence, parts, tracks, colours, frames, jobs, warnings, notes)


def label_warnings(annotations: SequenceType[Annotation], labels: SequenceType[str]) -> list[str]:
    """A warning for every wanted label that no track of the exports has."""
    present = {track.label for a in annotations for track in a.tracks}
    return [
        f"no shape in the exports has the label {label!r} (--label / [annotation] labels)"
        for label in sorted(set(labels) - present)
    ]


def plan_frames(
    sequence: Sequence,
    parts: SequenceType[Part],
    tracks: SequenceType[TrackPlane],
    association: Association,
    output: OutputOptions,
    max_time_diff: float,
) -> tuple[list[FrameRecord], list[tuple[int, FrameJob]], list[str]]:
    """Decide, for every depth frame, whether it gets a mask and from which part's shapes.

    A pure function: it reads no file.

    Parameters
    ----------
    sequence : Sequence
    parts : sequence of Part
        Placed, in sequence order.
    tracks : sequence of TrackPlane
        The global plane of every track.
    association : Association
    output : OutputOptions
    max_time_diff : float
        For the warning about a depth frame without RGB frame.

    Returns
    -------
    frames : list of FrameRecord
        One per depth frame; ``skipped`` with a reason, or (for now) without one for the frames
        that get a mask.
    jobs : list of (int, FrameJob)
        Index into ``frames`` and the job, for the frames that get a mask.
    warnings : list of str
    """
    plane_of = {(t.part, t.track): t.plane for t in tracks}
    owners = frame_owners(parts)
    first, last = min(owners), max(owners)
    frames: list[FrameRecord] = []
    jobs: list[tuple[int, FrameJob]] = []
    warnings: list[str] = []
    for d, depth_file in enumerate(sequence.depth.files):
        rgb = int(association.nearest[d])
        record = FrameRecord(
            depth=depth_file,
            depth_timestamp=float(sequence.depth.timestamps[d]),
            rgb=sequence.rgb.files[rgb],
            rgb_index=rgb,
            time_offset=round(float(association.time_diff[d]), 6),
        )
        frames.append(record)
        if rgb < first or rgb > last:
            record.reason = OUTSIDE_ANNOTATION
        elif not association.matched[d]:
            record.reason = NO_RGB_FRAME
            warnings.append(f"{sequence.root / depth_file}: no RGB frame within {max_time_diff} s; skipped")
        elif rgb not in owners:
            record.reason = RGB_NOT_ANNOTATED
        else:
            part = parts[owners[rgb]]
            frame = part.frame_of_rgb[rgb]
            record.part, record.cvat_frame = part.name, frame
            jobs.append((d, _frame_job(sequence, part, frame, rgb, depth_file, plane_of, output)))
    return frames, jobs, warnings


def _frame_job(
    sequence: Sequence, part: Part, frame: int, rgb: int, depth_file: str, plane_of: dict, output: OutputOptions
) -> FrameJob:
    name = Path(depth_file).name
    return FrameJob(
        depth_path=sequence.root / depth_file,
        mask_path=output.out_dir / "masks" / name,
        shapes=tuple(
            (plane_of[(part.name, track.track_id)], track.shapes[frame])
            for track in part.annotation.tracks
            if frame in track.shapes
        ),
        image_size=part.annotation.image_size.get(frame),
        part_path=part.annotation.path,
        raw_mask_path=output.out_dir / "masks_raw" / name if output.raw_masks else None,
        overlay_path=output.out_dir / OVERLAY_DIR / name if output.overlays else None,
        rgb_path=sequence.root / sequence.rgb.files[rgb],
    )


def camera_warnings(jobs: SequenceType[tuple[int, FrameJob]], config: Config) -> list[str]:
    """A warning when the camera's principal point does not fit the first masked depth frame
    (reads that frame)."""
    if not jobs:
        return []
    depth_path = jobs[0][1].depth_path
    try:
        height, width = read_depth(depth_path).shape
    except InputError:
        return []  # reported with its frame
    problem = camera_problem(config.camera.cx, config.camera.cy, width, height)
    return [] if problem is None else [f"{depth_path}: {problem}"]


def _warn(warnings: list[str], messages: SequenceType[str]) -> None:
    for message in messages:
        warnings.append(message)
        log.warning(message)

"""Planning a run: what each depth frame gets, and from where, before any mask is made.

:func:`plan_run` reads the inputs (the sequence lists and the CVAT exports), places the parts,
measures how the tracks of consecutive parts overlap (:mod:`annotate_rgbd.pipeline.part_overlap`) and
gives every track its global plane (:mod:`annotate_rgbd.annotation.stitch`); :func:`plan_frames`, a pure
function, then decides for every depth frame whether it gets a mask, and builds its
:class:`~annotate_rgbd.report.records.FrameRecord` and, for a mask, its
:class:`~annotate_rgbd.pipeline.frame_job.FrameJob`. With camera poses,
:func:`annotate_rgbd.pipeline.propagation.plan_propagation` lifts the keyframes first, and
:func:`plan_frames` carries them to every frame.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence as SequenceType

import numpy as np

from annotate_rgbd.annotation.model import Annotation
from annotate_rgbd.config.settings import Config
from annotate_rgbd.cvat import read_cvat
from annotate_rgbd.cvat.notes import SKIPPED
from annotate_rgbd.errors import InputError
from .frame_job import OVERLAY_DIR, FrameJob, check_size
from annotate_rgbd.geometry.depth_range import depth_scale_hint, median_raw_depth
from annotate_rgbd.geometry.lift import plane_to_camera
from annotate_rgbd.io.outdir import ID_MASKS, RAW_MASKS, check_outside_sequence
from annotate_rgbd.report.palette import plane_colours
from .part_overlap import part_pair_iou
from .propagation import Propagation, plan_propagation, propagation_warnings
from annotate_rgbd.annotation.parts import Part, frame_owners, place_parts
from annotate_rgbd.propagate import DISAGREE_BELOW
from annotate_rgbd.propagate.carry import carried_layers, keyframe_agreement
from annotate_rgbd.propagate.keyframes import keyframe_frames
from annotate_rgbd.report.records import NO_RGB_FRAME, OUTSIDE_ANNOTATION, RGB_NOT_ANNOTATED, FrameRecord
from annotate_rgbd.io.sequence import (
    Sequence, associate, camera_problem, intrinsics_problems, read_depth, read_sequence,
)
from annotate_rgbd.io.association_checks import unmatched_frames
from annotate_rgbd.annotation.stitch import PartTracks, TrackPlane, assign_planes, label_conflicts
from annotate_rgbd.pool import HelperPool

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
    propagation: Propagation | None = None

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
    instance_ids : bool
        Also write ``masks_id/``.
    """

    out_dir: Path
    raw_masks: bool = False
    overlays: bool = False
    instance_ids: bool = False


def plan_run(
    sequence_dir: str | Path,
    annotation_paths: SequenceType[str | Path],
    out_dir: str | Path,
    config: Config,
    offsets: Mapping[str, int] | None = None,
    raw_masks: bool = False,
    overlays: bool = False,
    poses: str | Path | None = None,
    instance_ids: bool = False,
    helpers: HelperPool | None = None,
) -> RunPlan:
    """Read the inputs and decide, for every depth frame, whether and how it gets a mask.

    Parameters are those of :func:`annotate_rgbd.pipeline.run_cvat2mask`; ``poses`` (else the
    configuration's ``sequence.poses``, else the layout's own poses) is a trajectory
    (:func:`annotate_rgbd.io.poses.read_trajectory`) that carries keyframe shapes to every frame
    (:mod:`annotate_rgbd.propagate.carry`); ``helpers`` (helper processes, already started for
    the frames) fit the keyframes' planes too.

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
    check_outside_sequence(out_dir, sequence)
    labels = config.annotation.labels or None
    annotations = [read_cvat(path, labels=labels) for path in annotation_paths]
    if labels and not any(a.tracks for a in annotations):
        known = sorted({label for a in annotations for label in a.labels})
        raise InputError(
            Path(annotation_paths[0]) if len(annotation_paths) == 1 else None,
            f"no shape has the label{'s' if len(labels) > 1 else ''} {', '.join(map(repr, labels))} "
            f"(--label / [annotation] labels): nothing to mask; the exports' labels: {', '.join(known) or 'none'}",
        )
    notes = [f"{Path(a.path).name}: {note}" for a in annotations for note in a.notes if not note.startswith(SKIPPED)]
    warnings: list[str] = []
    _warn(warnings, [f"{Path(a.path)}: {note}" for a in annotations for note in a.notes if note.startswith(SKIPPED)])

    all_offsets = {p.file: p.offset for p in config.parts}
    all_offsets.update(offsets or {})
    parts, missing = place_parts(annotations, sequence.rgb, all_offsets)
    _warn(warnings, missing)
    association = Association(*associate(sequence.depth.timestamps, sequence.rgb.timestamps, config.sequence.max_time_diff))
    depth_of_rgb = association.depth_of_rgb()
    pair_iou = [part_pair_iou(sequence, depth_of_rgb, a, b, config) for a, b in zip(parts, parts[1:])]
    part_tracks = [PartTracks.of(p) for p in parts]
    _warn(warnings, [line for p in part_tracks for line in p.problems])
    tracks = assign_planes(part_tracks, pair_iou, config.matches, config.stitch.min_iou, "configuration")
    _warn(warnings, label_warnings(annotations, config.annotation.labels))
    _warn(warnings, label_conflicts(tracks))
    colours = plane_colours(max((t.plane for t in tracks), default=0))
    output = OutputOptions(Path(out_dir), raw_masks, overlays, instance_ids)
    propagation = None
    poses = poses or config.sequence.poses
    if not poses and sequence.poses is not None:
        poses = sequence.poses
        log.info("poses: the %s layout's per-frame camera-to-world poses (%s); give --poses for another trajectory",
                 sequence.layout, poses)
    if poses:
        propagation = plan_propagation(Path(poses), sequence, parts, tracks, depth_of_rgb, config, helpers)
        _warn(warnings, propagation_warnings(propagation))
        if any(t.keyframes is not None and len(t.shapes) > len(t.keyframes) for a in annotations for t in a.tracks):
            notes.append("with poses, the shapes between keyframes (CVAT's interpolation) are not used: "
                         "keyframes are carried to every frame by the poses")
    frames, jobs, frame_warnings = plan_frames(sequence, parts, tracks, association, output,
                                               config.sequence.max_time_diff, propagation, config)
    first_frames = check_first_frames(jobs, config)  # a size mismatch stops here, before any frame warning
    _warn(warnings, frame_warnings)
    _warn(warnings, first_frames)
    return RunPlan(sequence, parts, tracks, colours, frames, jobs, warnings, notes, propagation)


def label_warnings(annotations: SequenceType[Annotation], labels: SequenceType[str]) -> list[str]:
    """A warning for every wanted label that no track of the exports has."""
    present = {track.label for a in annotations for track in a.tracks}
    known = sorted({label for a in annotations for label in a.labels} | present)
    return [
        f"no shape in the exports has the label {label!r} (--label / [annotation] labels); "
        f"their labels: {', '.join(known) if known else 'none'}"
        for label in sorted(set(labels) - present)
    ]


def plan_frames(
    sequence: Sequence,
    parts: SequenceType[Part],
    tracks: SequenceType[TrackPlane],
    association: Association,
    output: OutputOptions,
    max_time_diff: float,
    propagation: Propagation | None = None,
    config: Config | None = None,
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
    propagation : Propagation, optional
        With poses: tracks with lifted keyframes get their shapes projected with the depth
        frame's pose (frames without a pose keep the 2-D shapes; their record says why).
    config : Config, optional
        The camera, for projecting (needed with ``propagation``).

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
            camera_pose=None if propagation is None else propagation.camera_pose(d),
        )
        frames.append(record)
        if rgb < first or rgb > last:
            record.reason = OUTSIDE_ANNOTATION
        elif not association.matched[d]:
            record.reason = NO_RGB_FRAME
        elif rgb not in owners:
            record.reason = RGB_NOT_ANNOTATED
        else:
            part = parts[owners[rgb]]
            frame = part.frame_of_rgb[rgb]
            record.part, record.cvat_frame = part.name, frame
            shapes, propagated, expected, carried, agreement = _frame_shapes(part, frame, plane_of, propagation, config, d)
            if propagation is not None:
                record.pose = "ok" if propagation.depth_poses.ok[d] else str(propagation.depth_poses.reasons[d])
                record.keyframes_agree = agreement or None
            jobs.append((d, _frame_job(sequence, part, frame, rgb, depth_file, shapes, propagated, expected, output,
                                       carried)))
    # The frames of the annotated stretch: none with its RGB frame is an error, some a warning.
    annotated = [d for d, record in enumerate(frames) if record.reason != OUTSIDE_ANNOTATION]
    stretch = "" if len(annotated) == len(frames) else f"of the annotated stretch (RGB frames {first} to {last})"
    warnings += unmatched_frames(sequence.root, sequence.depth.files, association.time_diff, association.matched,
                                 max_time_diff, annotated, stretch)
    return frames, jobs, warnings


def _frame_shapes(
    part: Part, frame: int, plane_of: dict, propagation: Propagation | None, config: Config | None, depth: int
) -> tuple[tuple, frozenset[int] | None, tuple, tuple]:
    """The ``(plane id, shape)`` pairs of one frame, in track order, the planes whose shapes the
    poses carried there from other frames, ``(plane id, (a, b, c, d))`` where the poses put
    each of those (its nearest keyframe's plane, in the depth frame's camera frame; none for a
    track whose keyframes disagree about its plane), and
    ``(position, plane id, z_order, layers, beyond)`` of each: what its keyframes say about it
    (:func:`annotate_rgbd.propagate.carry.carried_layers`; every outline over every exclusion
    where the keyframes on either side disagree, :data:`annotate_rgbd.propagate.DISAGREE_BELOW`),
    to go among the shapes at ``position``, and how much the keyframes on either side agree
    about each of those planes (plane id -> agreement,
    :func:`annotate_rgbd.propagate.carry.keyframe_agreement`; planes with keyframes on one side
    only left out)."""
    shapes, propagated, expected, carried, agreement = [], set(), [], [], {}
    has_pose = propagation is not None and bool(propagation.depth_poses.ok[depth])
    for track in part.annotation.tracks:
        if frame not in track.shapes:
            continue  # outside the track's life
        plane = plane_of[(part.name, track.track_id)]
        lift = propagation.lifts.get((part.name, track.track_id)) if has_pose else None
        if lift is None or not lift.keyframes or frame in keyframe_frames(track):
            # 2-D: as drawn (on its own keyframe the labeller's shape is the best evidence there
            # is, and poses change nothing where every frame is drawn) or interpolated.
            shapes.append((plane, track.shapes[frame]))
            continue
        pose = (propagation.depth_poses.rotations[depth], propagation.depth_poses.translations[depth])
        agree = keyframe_agreement(lift, frame, config, pose, part.annotation.image_size.get(frame))
        agree = None if agree is None else round(agree, 3)  # as recorded: what stats lists is what was repainted
        disagree = agree is not None and agree < DISAGREE_BELOW
        layers, beyond = carried_layers(lift, frame, config, pose, disagree)
        nearest = min(lift.keyframes, key=lambda k: (abs(k.frame - frame), k.frame))
        if layers or beyond:
            carried.append((len(shapes), plane, nearest.z_order, layers, beyond))
        propagated.add(plane)
        if agree is not None:
            agreement[plane] = agree
        if lift.consistent:
            # A track whose keyframes disagree about its plane (listed for review) says no plane
            # to hold the frame's fit to: the frame's own depth decides.
            expected.append((plane, tuple(float(v) for v in plane_to_camera(nearest.plane, *pose))))
    return (tuple(shapes), (frozenset(propagated) if propagation is not None else None), tuple(expected),
            tuple(carried), agreement)


def _frame_job(
    sequence: Sequence, part: Part, frame: int, rgb: int, depth_file: str, shapes: tuple,
    propagated: frozenset[int] | None, expected: tuple, output: OutputOptions, carried: tuple = (),
) -> FrameJob:
    name = Path(depth_file).name
    return FrameJob(
        depth_path=sequence.root / depth_file,
        mask_path=output.out_dir / "masks" / name,
        shapes=shapes,
        propagated=propagated,
        expected_planes=expected,
        carried=carried,
        image_size=part.annotation.image_size.get(frame),
        part_path=part.annotation.path,
        raw_mask_path=output.out_dir / RAW_MASKS / name if output.raw_masks else None,
        id_mask_path=output.out_dir / ID_MASKS / name if output.instance_ids else None,
        overlay_path=output.out_dir / OVERLAY_DIR / name if output.overlays else None,
        rgb_path=sequence.root / sequence.rgb.files[rgb],
    )


#: Depth frames whose depth range is checked against the configured scale before any work.
FIRST_FRAMES = 3


def check_first_frames(jobs: SequenceType[tuple[int, FrameJob]], config: Config) -> list[str]:
    """Check the first masked depth frame of each annotation part before any work starts.

    Returns
    -------
    list of str
        A warning when the camera's principal point or focal lengths do not fit the first frame
        (:func:`annotate_rgbd.io.sequence.intrinsics_problems`), and one when
        the first frames' depth at the configured scale is not what an indoor sensor sees
        (:func:`annotate_rgbd.geometry.depth_range.depth_scale_hint`).

    Raises
    ------
    SizeMismatch
        A part's first depth frame does not have the size of the images it annotates (every
        frame would fail, after the helpers had started and a page of warnings).
    """
    warnings = []
    first_of_part = {}
    for _, job in jobs:
        first_of_part.setdefault(job.part_path, job)
    medians = []
    for number, job in enumerate(first_of_part.values()):
        try:
            depth = read_depth(job.depth_path)
        except InputError:
            continue  # reported with its frame
        height, width = depth.shape
        check_size(job, (height, width), config.colour_camera)
        medians.append(median_raw_depth(depth))
        if number == 0:
            warnings.extend(intrinsics_problems(config.camera, job.depth_path, width, height))
        colour = config.colour_camera
        problem = None if colour is None else camera_problem(colour.cx, colour.cy, colour.width, colour.height)
        if number == 0 and problem is not None:
            warnings.append(f"[colour_camera]: the principal point ({colour.cx:g}, {colour.cy:g}) is far from the centre "
                            f"of the {colour.width}x{colour.height} colour images: intrinsics for another resolution?")
    for _, job in list(jobs)[1:FIRST_FRAMES]:  # a few frames more: one frame may show only a wall
        try:
            medians.append(median_raw_depth(read_depth(job.depth_path)))
        except InputError:
            continue
    hint = depth_scale_hint(medians, config.camera.depth_scale)
    if hint is not None and jobs:
        warnings.append(f"{jobs[0][1].depth_path.parent}: {hint}")
    return warnings


def _warn(warnings: list[str], messages: SequenceType[str]) -> None:
    for message in messages:
        warnings.append(message)
        log.warning(message)

"""The ``cvat2mask`` job: CVAT export(s) + RGB-D sequence -> refined plane masks and a report.

:func:`run_cvat2mask` reads the inputs, places the annotation parts in the sequence, gives every
track its global plane (:mod:`annotate_rgbd.stitch`), plans one :class:`FrameJob` per depth frame
that gets a mask, runs them (:func:`run_frame_job`: read depth, segment, write the PNG) and writes
the tables and the report.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Sequence as SequenceType

import numpy as np

from .config import Config
from .cvat import read_cvat
from .errors import InputError, OutputError
from .execute import JOURNAL, HelperPool, previous_results, run_jobs, start_helpers
from .frame_job import OVERLAY_DIR, FrameJob, SizeMismatch, run_frame_job
from .palette import plane_colours
from .parts import Part, frame_owners, place_parts
from .sequence import Sequence, associate, camera_problem, read_depth, read_sequence
from .report import report_json, write_tables
from .stitch import PartTracks, TrackPlane, assign_planes, label_conflicts, part_pair_iou
from .writer import prepare_output, write_json

log = logging.getLogger("annotate_rgbd")

#: Why a depth frame gets no mask, as written to the report.
OUTSIDE_ANNOTATION = "outside_annotated_range"
NO_RGB_FRAME = "no_rgb_frame_within_max_time_diff"
RGB_NOT_ANNOTATED = "rgb_frame_not_in_annotation"
UNREADABLE_DEPTH = "unreadable_depth"

#: At most this many shared frames of two parts are segmented to match their tracks.
MAX_MATCH_FRAMES = 10


@dataclass
class RunPlan:
    """Everything decided before any mask is made: what each depth frame gets, and from where.

    Parameters
    ----------
    sequence : Sequence
    parts : list of Part
        The annotation parts in sequence order.
    tracks : list of TrackPlane
        The global plane of every track.
    colours : ndarray of uint8, shape (n_planes, 3)
        Plane colours (row ``k - 1`` for plane id ``k``).
    frames : list of dict
        One report entry per depth frame, in depth order.
    jobs : list of (int, FrameJob)
        The frames that get a mask: index into ``frames`` and the job.
    warnings, notes : list of str
    """

    sequence: Sequence
    parts: list[Part]
    tracks: list[TrackPlane]
    colours: np.ndarray
    frames: list[dict]
    jobs: list[tuple[int, FrameJob]]
    warnings: list[str]
    notes: list[str]

    @property
    def n_planes(self) -> int:
        """Number of global planes."""
        return len(self.colours)


@dataclass
class RunReport:
    """A finished run: its plan, with every frame's entry filled in, and the ``counts`` of
    frames ``made``, ``reused`` from an earlier run and ``failed``."""

    plan: RunPlan
    counts: dict[str, int]

    @property
    def frames(self) -> list[dict]:
        """One report entry per depth frame."""
        return self.plan.frames

    @property
    def tracks(self) -> list[TrackPlane]:
        """The global plane of every track."""
        return self.plan.tracks

    @property
    def n_planes(self) -> int:
        """Number of global planes."""
        return self.plan.n_planes

    @property
    def warnings(self) -> list[str]:
        """Warnings of the run, one line each."""
        return self.plan.warnings

    @property
    def notes(self) -> list[str]:
        """What the exports held that was not used."""
        return self.plan.notes

    @property
    def written(self) -> int:
        """Number of masks written."""
        return sum(1 for f in self.frames if f["status"] == "written")


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

    Parameters are those of :func:`run_cvat2mask`.

    Returns
    -------
    RunPlan

    Raises
    ------
    InputError
        A fatal problem with an input.
    """
    out_dir = Path(out_dir)
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
    for line in missing:
        _warn(warnings, line)
    owners = frame_owners(parts)
    nearest, time_diff, matched = associate(sequence.depth.timestamps, sequence.rgb.timestamps, config.sequence.max_time_diff)
    depth_of_rgb = _depth_for_rgb(nearest, time_diff, matched)

    pair_iou = [
        part_pair_iou(sequence, depth_of_rgb, a, b, config, MAX_MATCH_FRAMES) for a, b in zip(parts, parts[1:])
    ]
    tracks = assign_planes(
        [PartTracks.of(p) for p in parts], pair_iou, config.matches, config.stitch.min_iou, "configuration"
    )
    present = {track.label for a in annotations for track in a.tracks}
    for label in sorted(set(config.annotation.labels) - present):
        _warn(warnings, f"no shape in the exports has the label {label!r} (--label / [annotation] labels)")
    for line in label_conflicts(tracks):
        _warn(warnings, line)
    plane_of = {(t.part, t.track): t.plane for t in tracks}
    colours = plane_colours(max((t.plane for t in tracks), default=0))

    first, last = min(owners), max(owners)
    frames: list[dict] = []
    jobs: list[tuple[int, FrameJob]] = []
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
        if rgb < first or rgb > last:
            entry["reason"] = OUTSIDE_ANNOTATION
        elif not matched[d]:
            entry["reason"] = NO_RGB_FRAME
            _warn(warnings, f"{sequence.root / depth_file}: no RGB frame within {config.sequence.max_time_diff} s; skipped")
        elif rgb not in owners:
            entry["reason"] = RGB_NOT_ANNOTATED
        else:
            part = parts[owners[rgb]]
            frame = part.frame_of_rgb[rgb]
            entry.update(part=part.name, cvat_frame=frame)
            shapes = tuple(
                (plane_of[(part.name, track.track_id)], track.shapes[frame])
                for track in part.annotation.tracks
                if frame in track.shapes
            )
            job = FrameJob(
                depth_path=sequence.root / depth_file,
                mask_path=out_dir / "masks" / Path(depth_file).name,
                shapes=shapes,
                image_size=part.annotation.image_size.get(frame),
                part_path=part.annotation.path,
                raw_mask_path=out_dir / "masks_raw" / Path(depth_file).name if raw_masks else None,
                overlay_path=out_dir / OVERLAY_DIR / Path(depth_file).name if overlays else None,
                rgb_path=sequence.root / sequence.rgb.files[rgb],
            )
            jobs.append((d, job))
    _check_camera(jobs, config, warnings)
    return RunPlan(sequence, parts, tracks, colours, frames, jobs, warnings, notes)


def _check_camera(jobs: list[tuple[int, FrameJob]], config: Config, warnings: list[str]) -> None:
    """Warn when the camera's principal point does not fit the first masked depth frame."""
    if not jobs:
        return
    depth_path = jobs[0][1].depth_path
    try:
        height, width = read_depth(depth_path).shape
    except InputError:
        return  # reported with its frame
    problem = camera_problem(config.camera.cx, config.camera.cy, width, height)
    if problem is not None:
        _warn(warnings, f"{depth_path}: {problem}")


def run_cvat2mask(
    sequence_dir: str | Path,
    annotation_paths: SequenceType[str | Path],
    out_dir: str | Path,
    config: Config,
    offsets: Mapping[str, int] | None = None,
    workers: int = 1,
    force: bool = False,
    raw_masks: bool = False,
    overlays: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> RunReport:
    """Run the whole job: ``masks/``, ``planes.csv``, ``tracks.csv`` and ``report.json`` in ``out_dir``.

    A re-run in the same ``out_dir`` redoes only the frames whose inputs changed
    (:mod:`annotate_rgbd.execute`); masks of frames that no longer get one are removed.

    Parameters
    ----------
    sequence_dir : str or Path
        TUM / ICL-NUIM sequence folder.
    annotation_paths : sequence of str or Path
        CVAT exports: one, or several annotation parts of the sequence.
    out_dir : str or Path
        Output folder (created if missing).
    config : Config
    offsets : mapping of str to int, optional
        Explicit part offsets by file name (``--part FILE:OFFSET``); they take precedence over
        the configuration's ``[[parts]]``.
    workers : int
        Processes that make masks in parallel (1: in this process).
    force : bool
        Redo every frame, even those whose inputs are unchanged.
    raw_masks : bool
        Also write ``masks_raw/``: the labeller's shapes as drawn, before any depth check.
    overlays : bool
        Also write ``overlays/``: the review overlays (:mod:`annotate_rgbd.overlay`).
    progress : callable, optional
        Called as ``progress(done, total)`` after each frame that gets a mask.

    Returns
    -------
    RunReport

    Raises
    ------
    InputError
        A fatal problem with an input (missing files, malformed export, parts that cannot be
        placed, sizes that do not match): nothing sensible can be produced.
    """
    helpers = start_helpers(workers)
    try:
        plan = plan_run(sequence_dir, annotation_paths, out_dir, config, offsets, raw_masks, overlays)
        scene = SceneRun(Path(sequence_dir).name, plan, Path(out_dir), config, progress)
        execute_scenes([scene], helpers, force=force)
    finally:
        if helpers is not None:
            helpers.shutdown(cancel_futures=True)
    if scene.error is not None:
        raise scene.error
    return finish_scene(scene)


@dataclass
class SceneRun:
    """One scene's plan on its way through :func:`execute_scenes` and :func:`finish_scene`.

    Parameters
    ----------
    name : str
        For progress and summaries.
    plan : RunPlan
    out_dir : Path
    config : Config
    progress : callable, optional
        ``progress(done, total)`` after each of the scene's frames.
    counts : dict
        Filled in: frames ``made``, ``reused`` (unchanged since an earlier run) and ``failed``.
    error : InputError, optional
        Set when a fatal problem stopped the scene (its other frames are then not made).
    """

    name: str
    plan: RunPlan
    out_dir: Path
    config: Config
    progress: Callable[[int, int], None] | None = None
    counts: dict[str, int] = field(default_factory=lambda: {"made": 0, "reused": 0, "failed": 0})
    error: InputError | None = None


def execute_scenes(
    scenes: SequenceType[SceneRun], helpers: HelperPool | None = None, force: bool = False
) -> None:
    """Make the masks of several scenes with one pool of workers, reusing unchanged masks.

    Fills in every frame's report entry. Each finished frame is appended to its scene's journal
    at once, so that an interrupted run loses no finished work. A fatal problem in one scene
    (a depth image of the wrong size) stops that scene only.

    Parameters
    ----------
    scenes : sequence of SceneRun
    helpers : HelperPool, optional
        Helper processes (:func:`annotate_rgbd.execute.start_helpers`) working beside this one.
    force : bool
        Redo every frame, even those unchanged since an earlier run.
    """
    tasks, owners = [], []
    for scene in scenes:
        try:
            prepare_output(scene.out_dir)
        except OutputError as exc:
            scene.error = exc  # this scene only: the others may write elsewhere
            continue
        previous = {} if force else previous_results(scene.out_dir)
        for index, job in scene.plan.jobs:
            recorded = previous.get(job.mask_path.name)
            tasks.append((job, scene.config, scene.plan.colours, recorded[0] if recorded else None))
            owners.append((scene, index, recorded[1] if recorded else None))
    for scene in scenes:
        _step(scene)
    journals = {
        id(scene): open(scene.out_dir / JOURNAL, "a", encoding="utf-8") for scene in scenes if scene.error is None
    }
    try:
        for k, result in run_jobs(tasks, run_frame_job, helpers):
            scene, index, recorded_entries = owners[k]
            if scene.error is not None:
                continue
            job, entry = tasks[k][0], scene.plan.frames[index]
            if isinstance(result, (SizeMismatch, OutputError)):
                scene.error = result
            elif isinstance(result, InputError):
                entry.update(status="failed", reason=UNREADABLE_DEPTH, error=str(result))
                scene.counts["failed"] += 1
            elif result.pop("reused", False):
                _finish(entry, job, {**result, **recorded_entries})
                scene.counts["reused"] += 1
            else:
                _finish(entry, job, result)
                scene.counts["made"] += 1
                made = {"kept": result["kept"], "dropped": result["dropped"]}
                record = {"mask": job.mask_path.name, "fingerprint": result["fingerprint"], "result": made}
                try:
                    journals[id(scene)].write(json.dumps(record) + "\n")
                    journals[id(scene)].flush()
                except OSError as exc:
                    scene.error = OutputError(scene.out_dir / JOURNAL, f"cannot write output: {exc.strerror or exc}")
            _step(scene)
    finally:
        for journal in journals.values():
            journal.close()
    for scene in scenes:
        # In frame order, whatever order the workers finished in.
        for entry in scene.plan.frames:
            if entry["status"] == "failed":
                _warn(scene.plan.warnings, f"{entry['error']}; skipped")


def finish_scene(scene: SceneRun) -> RunReport:
    """Write a scene's tables and report, remove stale masks and the journal."""
    plan = scene.plan
    report = RunReport(plan, scene.counts)
    write_tables(scene.out_dir, plan.tracks, plan.colours)
    write_json(scene.out_dir / "report.json", report_json(report, scene.config))
    remove_stale_outputs(scene.out_dir, plan)
    (scene.out_dir / JOURNAL).unlink(missing_ok=True)
    return report


def _step(scene: SceneRun) -> None:
    """Report the scene's progress: frames done (made, reused or failed) of its jobs."""
    if scene.progress:
        scene.progress(sum(scene.counts.values()), len(scene.plan.jobs))


def _finish(entry: dict, job: FrameJob, result: dict) -> None:
    entry.update(result)
    entry.update(status="written", mask=f"masks/{job.mask_path.name}")


def remove_stale_outputs(out_dir: Path, plan: RunPlan) -> None:
    """Delete what this run did not write: masks of frames now skipped or failed, raw masks and
    overlays that were not asked for, a review page and contact sheet of an earlier run, and
    temporary files."""
    written = {Path(f["mask"]).name for f in plan.frames if f["status"] == "written"}
    raw_written = written if any(job.raw_mask_path for _, job in plan.jobs) else set()
    overlays_written = written if any(job.overlay_path for _, job in plan.jobs) else set()
    for folder, keep in (("masks", written), ("masks_raw", raw_written), (OVERLAY_DIR, overlays_written)):
        for path in (out_dir / folder).glob("*"):
            temporary = path.name.startswith(".") and path.name.endswith(".tmp")
            if temporary or (path.suffix == ".png" and path.name not in keep):
                path.unlink(missing_ok=True)
        if not keep and (out_dir / folder).is_dir() and not any((out_dir / folder).iterdir()):
            (out_dir / folder).rmdir()
    # They show the masks of an earlier run (cvat2mask --overlays and review write them anew).
    for name in ("review.html", "contact_sheet.png"):
        (out_dir / name).unlink(missing_ok=True)


def _depth_for_rgb(nearest: np.ndarray, time_diff: np.ndarray, matched: np.ndarray) -> dict[int, int]:
    """RGB index -> the depth frame closest to it in time, among the matched ones."""
    best: dict[int, int] = {}
    for d in np.flatnonzero(matched).tolist():
        rgb = int(nearest[d])
        if rgb not in best or abs(time_diff[d]) < abs(time_diff[best[rgb]]):
            best[rgb] = d
    return best


def _warn(warnings: list[str], message: str) -> None:
    warnings.append(message)
    log.warning(message)



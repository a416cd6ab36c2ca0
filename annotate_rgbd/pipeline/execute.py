"""Making the masks of one or more planned scenes: frame jobs shared between this process and
helper processes (:mod:`annotate_rgbd.pool`), unchanged masks reused (:mod:`annotate_rgbd.pipeline.resume`),
every outcome recorded in the scene's frame records and journal as it arrives.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

from annotate_rgbd.config.settings import Config
from annotate_rgbd.errors import InputError, OutputError
from annotate_rgbd.io.outdir import MASKS, REPORT, OutputFolder
from annotate_rgbd.logs import counted, group_errors, group_problems, scene_warnings
from annotate_rgbd.pool import (
    STALL_TIMEOUT, HelperPool, JobTimeout, default_workers, prepare_helpers, reuse_freed_memory, run_jobs, start_helpers,
)
from annotate_rgbd.report.records import FAILED, TIMED_OUT, UNREADABLE_DEPTH, FrameRecord, MaskRecord, summarize
from annotate_rgbd.report.stats import drop_hint, dropped_words
from .resume import Journal, Previous, previous_results

if TYPE_CHECKING:  # the plan's modules import OpenCV, which this module leaves to the helpers' server
    from .plan import RunPlan

__all__ = ["FRAME_JOB_MODULE", "FrameCounts", "SceneResult", "SceneRun", "default_workers", "execute_scenes",
           "prepare_process", "start_frame_helpers"]

log = logging.getLogger("annotate_rgbd")

#: What helper processes import before their first frame job (OpenCV, numpy, the segmentation).
FRAME_JOB_MODULE = "annotate_rgbd.pipeline.frame_job"


def prepare_process(workers: int) -> None:
    """What the command line does first, before its heavy imports: start the server that frame
    helpers are forked from (:func:`annotate_rgbd.pool.prepare_helpers`) and keep freed image
    buffers for reuse (:func:`annotate_rgbd.pool.reuse_freed_memory`)."""
    prepare_helpers(workers, [FRAME_JOB_MODULE])
    reuse_freed_memory()


def start_frame_helpers(workers: int) -> HelperPool | None:
    """Start the ``workers - 1`` helper processes for frame jobs, in the background (None when
    ``workers`` <= 1); see :func:`annotate_rgbd.pool.start_helpers`."""
    return start_helpers(workers, [FRAME_JOB_MODULE])


@dataclass
class FrameCounts:
    """Frames of a scene ``made``, ``reused`` from an earlier run and ``failed``."""

    made: int = 0
    reused: int = 0
    failed: int = 0

    @property
    def done(self) -> int:
        """Frames finished, whatever the outcome."""
        return self.made + self.reused + self.failed


def failure_lines(frames: Sequence[FrameRecord], root: Path) -> list[str]:
    """One line per problem of the failed depth frames: the frame and why, or the frames that
    share the problem (:func:`annotate_rgbd.logs.group_problems`: 8-bit depth is said once).

    Parameters
    ----------
    frames : sequence of FrameRecord
    root : Path
        The sequence folder: a failed frame's error starts with its path there.
    """
    paths = ((str(root / f.depth), f) for f in frames if f.status == FAILED)
    return group_problems((path, (f.error or f.reason).removeprefix(f"{path}: ")) for path, f in paths)


@dataclass
class SceneResult:
    """How one scene of ``cvat2mask`` or ``batch`` ended: a plain record, no open resources.

    Parameters
    ----------
    name : str
        The scene's name (the sequence folder's for ``cvat2mask``).
    out : Path
        Its output folder.
    error : str, optional
        Why the scene failed as a whole (then nothing below is filled in); ``exception`` is
        the error itself.
    frames : list of FrameRecord
        One record per depth frame.
    tracks : list
        The global plane of every track (:class:`annotate_rgbd.annotation.stitch.TrackPlane`).
    n_planes : int
    counts : FrameCounts
    warnings, notes : list of str
    config : Config, optional
    review_page : Path, optional
        ``review.html``, written with overlays.
    propagation : object, optional
        With camera poses: what they gave the run (:class:`annotate_rgbd.pipeline.propagation.Propagation`).
    sequence : Path, optional
        The sequence folder (the failed frames' messages start with their path in it).
    """

    name: str
    out: Path
    error: str | None = None
    exception: Exception | None = field(default=None, repr=False)
    frames: list[FrameRecord] = field(default_factory=list)
    tracks: list = field(default_factory=list)
    n_planes: int = 0
    counts: FrameCounts = field(default_factory=FrameCounts)
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    config: Config | None = None
    review_page: Path | None = None
    propagation: object | None = None
    sequence: Path | None = None

    @property
    def written(self) -> int:
        """Number of masks written."""
        return sum(1 for f in self.frames if f.written)

    def failures(self) -> list[str]:
        """One line per problem of the failed depth frames (:func:`failure_lines`)."""
        return failure_lines(self.frames, self.sequence or Path())

    @property
    def failed_frames(self) -> list[str]:
        """Depth frames that failed, with the reason (:meth:`failures`)."""
        return self.failures()

    def summary(self) -> str:
        """``cvat2mask``'s summary line: masks written (made, unchanged), the annotation's planes
        (and how many reach a mask when not all do), frames skipped, planes dropped by reason,
        frames failed and warnings.

        Example: ``19 masks in out/masks (19 made, 0 unchanged), 10 planes (8 in the masks), 1
        frame skipped, 29 of 146 planes drawn on frames dropped (too far 19, no depth 10)``.
        """
        counts = summarize(self.frames)
        planes = len({track.plane for track in self.tracks})
        # An export of a longer sequence, or planes dropped on every frame: not all in a mask.
        shown = counted(planes, "plane") + (f" ({counts.distinct_planes} in the masks)"
                                            if counts.distinct_planes < planes else "")
        reasons = dropped_words(counts.dropped_by_reason)
        line = (f"{counted(self.written, 'mask')} in {self.out / MASKS} ({self.counts.made} made, "
                f"{self.counts.reused} unchanged), {shown}, {counted(counts.skipped, 'frame')} skipped, "
                f"{counts.planes_dropped} of {counts.planes_kept + counts.planes_dropped} planes drawn on frames dropped"
                + (f" ({reasons})" if reasons else ""))
        if counts.frames_failed:
            line += f", {counted(counts.frames_failed, 'frame')} failed"
        if self.warnings:
            line += f", {counted(len(self.warnings), 'warning')} (see {self.out / REPORT})"
        return line

    def drop_hint(self) -> str | None:
        """Advice on the run as a whole when most of its planes were dropped for one reason
        (:func:`annotate_rgbd.report.stats.drop_hint`), else None."""
        config = self.config or Config()
        return drop_hint(summarize(self.frames), config.camera.depth_scale, config.filter)


@dataclass
class SceneRun:
    """One scene on its way through :func:`execute_scenes` (and
    :func:`annotate_rgbd.pipeline.finish.finish_scene`): its plan, whose frame records get filled in,
    and how its frames ended.

    Parameters
    ----------
    name : str
        For progress and summaries.
    plan : RunPlan
    out_dir : Path
    config : Config
    progress : callable, optional
        ``progress(done, total)`` after each of the scene's frames.
    counts : FrameCounts
        Filled in.
    error : InputError, optional
        Set when a fatal problem stopped the scene (its other frames are then not made).
    previous : Previous
        What earlier runs in ``out_dir`` recorded (read when the scene starts).
    review_page : Path, optional
        ``review.html``, written by :func:`annotate_rgbd.pipeline.finish.finish_scene` with overlays.
    rgb_problems : list of InputError
        RGB images that could not be read for an overlay (drawn on grey instead), in the order
        the frames finished.
    """

    name: str
    plan: RunPlan
    out_dir: Path
    config: Config
    progress: Callable[[int, int], None] | None = None
    counts: FrameCounts = field(default_factory=FrameCounts)
    error: InputError | None = None
    previous: Previous = field(default_factory=Previous)
    review_page: Path | None = None
    folder: OutputFolder | None = field(default=None, repr=False)
    rgb_problems: list[InputError] = field(default_factory=list)

    def open(self, force: bool) -> None:
        """Take the output folder for this run (:class:`annotate_rgbd.io.outdir.OutputFolder`:
        created, no links where the run writes, locked, not another command's), read what
        earlier runs recorded there (unless ``force``), and record every file this run may
        write before it writes any.

        Raises
        ------
        OutputError
        """
        folder = OutputFolder(self.out_dir, "cvat2mask")
        folder.open()
        self.folder = folder
        recorded = previous_results(self.out_dir)
        self.previous = Previous(files=recorded.files | folder.expected) if force else recorded
        self.previous.files |= folder.expected
        folder.expect({name for _, job in self.plan.jobs for name in job.output_names})

    def release(self) -> None:
        """Release the output folder (idempotent)."""
        if self.folder is not None:
            self.folder.release()
            self.folder = None

    @property
    def frames(self) -> list[FrameRecord]:
        """One record per depth frame."""
        return self.plan.frames

    @property
    def tracks(self) -> list:
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
        return sum(1 for f in self.frames if f.written)

    def failures(self) -> list[str]:
        """One line per problem of the failed depth frames (:func:`failure_lines`)."""
        return failure_lines(self.frames, self.plan.sequence.root)

    def result(self) -> SceneResult:
        """The finished scene as a plain record."""
        return SceneResult(self.name, self.out_dir, None, None, self.frames, self.tracks, self.n_planes, self.counts,
                           self.warnings, self.notes, self.config, self.review_page, self.plan.propagation,
                           sequence=self.plan.sequence.root)

    def _step(self) -> None:
        if self.progress:
            self.progress(self.counts.done, len(self.plan.jobs))


def execute_scenes(
    scenes: Sequence[SceneRun], helpers: HelperPool | None = None, force: bool = False,
    job_timeout: float = STALL_TIMEOUT, scene_names: bool = True,
) -> None:
    """Make the masks of several scenes with one pool of workers, reusing unchanged masks.

    Fills in every frame's record. Each finished frame is appended to its scene's journal
    at once, so that an interrupted run loses no finished work. A fatal problem in one scene
    (a depth image of the wrong size, an output that cannot be written) stops that scene only.

    Parameters
    ----------
    scenes : sequence of SceneRun
    helpers : HelperPool, optional
        Helper processes (:func:`start_frame_helpers`) working beside this one.
    force : bool
        Redo every frame, even those unchanged since an earlier run.
    job_timeout : float
        Seconds without any frame finished by a helper after which the helpers are taken to hang
        and are replaced (:func:`annotate_rgbd.pool.run_jobs`); a frame that hangs twice fails.
    scene_names : bool
        Start the failed frames' warnings with the scene's name.
    """
    # Not at the top: OpenCV would slow the command line's start (see prepare_process).
    from .frame_job import FrameTask, SizeMismatch, run_frame_job

    tasks: list[FrameTask] = []
    owners: list[tuple[SceneRun, int, MaskRecord | None]] = []
    for scene in scenes:
        try:
            scene.open(force)
        except OutputError as exc:
            scene.error = exc  # this scene only: the others may write elsewhere
            continue
        for index, job in scene.plan.jobs:
            recorded = scene.previous.masks.get(job.mask_path.name)
            tasks.append(FrameTask(job, scene.config, scene.plan.colours, recorded))
            owners.append((scene, index, recorded))
    for scene in scenes:
        scene._step()
    journals = {}
    for scene in scenes:
        if scene.error is None:
            try:
                journals[id(scene)] = Journal(scene.out_dir)
            except OutputError as exc:
                scene.error = exc
    try:
        for outcome in run_jobs(tasks, run_frame_job, helpers, job_timeout):
            scene, index, recorded = owners[outcome.index]
            if scene.error is not None:
                continue
            job, frame = tasks[outcome.index].job, scene.plan.frames[index]
            mask = f"masks/{job.mask_path.name}"
            if isinstance(outcome.error, (SizeMismatch, OutputError)):
                scene.error = outcome.error
            elif isinstance(outcome.error, JobTimeout):
                frame.fail(TIMED_OUT, f"{job.depth_path}: {outcome.error}")
                scene.counts.failed += 1
            elif outcome.error is not None:
                frame.fail(UNREADABLE_DEPTH, str(outcome.error))
                scene.counts.failed += 1
            elif outcome.value.reused:
                frame.write(recorded.only(job.output_names), mask)
                scene.counts.reused += 1
            else:
                frame.write(outcome.value.made, mask)
                scene.counts.made += 1
                if outcome.value.rgb_problem is not None:
                    scene.rgb_problems.append(outcome.value.rgb_problem)
                try:
                    journals[id(scene)].record(job.mask_path.name, outcome.value.made)
                except OutputError as exc:
                    scene.error = exc
            scene._step()
    finally:
        for journal in journals.values():
            journal.close()
    for scene in scenes:
        if scene.error is None and scene.plan.jobs and scene.counts.failed == len(scene.plan.jobs):
            # A problem every frame shares (8-bit depth): one line, and no run without a mask.
            scene.error = InputError(None, f"no depth frame can be used: {scene.failures()[0]}")
            continue
        # In frame order, whatever order the workers finished in; a problem many frames share once.
        with scene_warnings(scene.name if scene_names else None):
            for line in scene.failures():
                message = f"{line}; failed (no mask)"
                scene.plan.warnings.append(message)
                log.warning(message)
            for line in group_errors(scene.rgb_problems):
                scene.plan.warnings.append(line)
                log.warning(line)

"""Relabel whole scenes in one command: the scenes of a manifest (:mod:`annotate_rgbd.manifest`),
one pool of workers.

Scenes are planned one after the other (a scene whose inputs are broken fails alone), then
the frames of all scenes are made by this process and one pool of helper processes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from annotate_rgbd.config.settings import load_config
from annotate_rgbd.errors import InputError
from .execute import STALL_TIMEOUT, SceneRun, execute_scenes, start_frame_helpers
from annotate_rgbd.logs import scene_warnings
from .manifest import SceneSpec
from .scene import finish_scene
from .plan import plan_run
from annotate_rgbd.report.records import summarize


@dataclass
class SceneOutcome:
    """How one scene of a batch ended."""

    name: str
    out: Path
    run: SceneRun | None = None
    error: str | None = None

    @property
    def failed_frames(self) -> list[str]:
        """Depth frames that failed, with the reason."""
        return [] if self.run is None else self.run.failures()


def run_batch(
    scenes: list[SceneSpec],
    workers: int,
    force: bool = False,
    progress_for: Callable[[str], Callable[[int, int], None]] | None = None,
    job_timeout: float = STALL_TIMEOUT,
) -> list[SceneOutcome]:
    """Relabel every scene; a scene with broken input fails alone.

    Parameters
    ----------
    scenes : list of SceneSpec
    workers : int
        Worker processes shared by all scenes.
    force : bool
        Redo every frame, even those unchanged since the last run.
    progress_for : callable, optional
        ``progress_for(scene name)`` returns that scene's ``progress(done, total)`` callback.
    job_timeout : float
        Seconds without a frame finished by the helpers before they are taken to hang
        (:func:`annotate_rgbd.execute.execute_scenes`).

    Returns
    -------
    list of SceneOutcome
        One per scene, in manifest order.
    """
    outcomes = [SceneOutcome(spec.name, spec.out) for spec in scenes]
    runs: list[tuple[SceneOutcome, SceneRun]] = []
    helpers = start_frame_helpers(workers)  # they start while the scenes are planned
    try:
        for spec, outcome in zip(scenes, outcomes):
            try:
                with scene_warnings(spec.name):
                    config = load_config(spec.config, spec.overrides)
                    plan = plan_run(spec.sequence, spec.annotations, spec.out, config, spec.offsets, spec.raw_masks,
                                    spec.overlays, poses=spec.poses, instance_ids=spec.instance_ids)
            except InputError as exc:
                outcome.error = str(exc)
                continue
            progress = progress_for(spec.name) if progress_for else None
            runs.append((outcome, SceneRun(spec.name, plan, spec.out, config, progress)))
        execute_scenes([run for _, run in runs], helpers, force=force, job_timeout=job_timeout)
        if helpers is not None:
            helpers.shutdown(cancel_futures=True)
            helpers = None
        for outcome, run in runs:
            if run.error is not None:
                outcome.error = str(run.error)
                continue
            try:
                with scene_warnings(outcome.name):
                    finish_scene(run)
                outcome.run = run
            except InputError as exc:
                outcome.error = str(exc)
    finally:
        if helpers is not None:
            helpers.shutdown(cancel_futures=True)
        for _, run in runs:
            run.release()
    return outcomes


def summary_lines(outcomes: list[SceneOutcome]) -> list[str]:
    """A per-scene summary: frames written, unchanged, failed; planes kept and dropped."""
    lines = []
    for outcome in outcomes:
        if outcome.error is not None:
            lines.append(f"{outcome.name}: FAILED: {outcome.error}")
            continue
        counts, summary = outcome.run.counts, summarize(outcome.run.frames)
        lines.append(
            f"{outcome.name}: {summary.masks_written} masks ({counts.made} made, {counts.reused} unchanged), "
            f"{summary.skipped} skipped, {counts.failed} failed; {summary.planes_kept} planes kept, "
            f"{summary.planes_dropped} dropped"
        )
        if outcome.run.review_page is not None:
            lines.append(f"  review page: {outcome.run.review_page}")
        lines.extend(f"  failed: {line}" for line in outcome.failed_frames)
    return lines

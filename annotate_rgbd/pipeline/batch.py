"""Relabel whole scenes in one command: the scenes of a manifest (:mod:`annotate_rgbd.pipeline.manifest`),
one pool of workers.

Scenes are planned one after the other (a scene whose inputs are broken fails alone), then
the frames of all scenes are made by this process and one pool of helper processes.
"""

from __future__ import annotations

from typing import Callable

from annotate_rgbd.config.layout import load_run_config
from annotate_rgbd.config.settings import Config
from annotate_rgbd.errors import InputError
from annotate_rgbd.logs import collect_warnings, manifest_words, scene_warnings
from annotate_rgbd.report.records import summarize
from .execute import STALL_TIMEOUT, SceneResult, SceneRun, execute_scenes, start_frame_helpers
from .manifest import SceneSpec
from .plan import plan_run
from .finish import finish_scene

#: How one scene of a batch ended (the name batch callers know it by).
SceneOutcome = SceneResult


def run_batch(
    scenes: list[SceneSpec],
    workers: int,
    force: bool = False,
    progress_for: Callable[[str], Callable[[int, int], None]] | None = None,
    job_timeout: float = STALL_TIMEOUT,
    scene_names: bool = True,
) -> list[SceneResult]:
    """Relabel every scene; a scene with broken input fails alone.

    Parameters
    ----------
    scenes : list of SceneSpec
        A scene's ``config`` is a preset name or TOML file (with its ``overrides``), None (the
        defaults and the cameras the sequence's layout states:
        :func:`~annotate_rgbd.config.layout.load_run_config`), or a
        :class:`~annotate_rgbd.config.settings.Config` already loaded.
    workers : int
        Worker processes shared by all scenes.
    force : bool
        Redo every frame, even those unchanged since the last run.
    progress_for : callable, optional
        ``progress_for(scene name)`` returns that scene's ``progress(done, total)`` callback.
    job_timeout : float
        Seconds without a frame finished by the helpers before they are taken to hang
        (:func:`annotate_rgbd.pipeline.execute.execute_scenes`), > 0 (``inf``: never; the command
        line asks for at least 1).
    scene_names : bool
        Start warnings with the scene's name (``cvat2mask``, one scene, does not).

    Returns
    -------
    list of SceneResult
        One per scene, in manifest order.
    """
    if not job_timeout > 0:  # NaN too: its comparisons are all false, so a hang would never be noticed
        raise InputError(None, f"--job-timeout must be a number of seconds > 0 (inf: wait for ever), not {job_timeout:g}")
    outcomes: list[SceneResult] = [SceneResult(spec.name, spec.out) for spec in scenes]
    runs: list[tuple[int, SceneRun]] = []
    named = (lambda name: scene_warnings(name)) if scene_names else (lambda name: scene_warnings(None))
    helpers = start_frame_helpers(workers)  # they start while the scenes are planned
    try:
        for position, spec in enumerate(scenes):
            try:
                with named(spec.name):
                    with collect_warnings() as loading:
                        config = (spec.config if isinstance(spec.config, Config)
                                  else load_run_config(spec.sequence, spec.config, spec.overrides, spec.overrides_from))
                    plan = plan_run(spec.sequence, spec.annotations, spec.out, config, spec.offsets, spec.raw_masks,
                                    spec.overlays, poses=spec.poses, instance_ids=spec.instance_ids, helpers=helpers)
                    plan.warnings[:0] = [*spec.warnings, *loading]  # printed already; the report keeps them too
            except InputError as exc:
                outcomes[position] = SceneResult(spec.name, spec.out, str(exc), exc)
                continue
            progress = progress_for(spec.name) if progress_for else None
            runs.append((position, SceneRun(spec.name, plan, spec.out, config, progress)))
        execute_scenes([run for _, run in runs], helpers, force=force, job_timeout=job_timeout,
                       scene_names=scene_names)
        if helpers is not None:
            helpers.shutdown(cancel_futures=True)
            helpers = None
        for position, run in runs:
            if run.error is not None:
                outcomes[position] = SceneResult(run.name, run.out_dir, str(run.error), run.error)
                continue
            try:
                with named(run.name):
                    finish_scene(run)
                outcomes[position] = run.result()
            except InputError as exc:
                outcomes[position] = SceneResult(run.name, run.out_dir, str(exc), exc)
    finally:
        if helpers is not None:
            helpers.shutdown(cancel_futures=True)
        for _, run in runs:
            run.release()
    return outcomes


def summary_lines(outcomes: list[SceneResult]) -> list[str]:
    """A per-scene summary: frames written, unchanged, failed; planes kept and dropped (a scene's
    error with its advice in the manifest's words, :func:`annotate_rgbd.logs.manifest_words`)."""
    lines = []
    for outcome in outcomes:
        if outcome.error is not None:
            lines.append(f"{outcome.name}: FAILED: {manifest_words(outcome.error)}")
            continue
        counts, summary = outcome.counts, summarize(outcome.frames)
        lines.append(
            f"{outcome.name}: {summary.masks_written} masks ({counts.made} made, {counts.reused} unchanged), "
            f"{summary.skipped} skipped, {counts.failed} failed; {summary.planes_kept} planes kept, "
            f"{summary.planes_dropped} dropped"
        )
        if outcome.review_page is not None:
            lines.append(f"  review page: {outcome.review_page}")
        lines.extend(f"  failed: {line}" for line in outcome.failed_frames)
    return lines

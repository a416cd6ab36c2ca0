"""The ``cvat2mask`` job: CVAT export(s) + RGB-D sequence -> refined plane masks and a report.

:func:`run_cvat2mask` plans the run (:mod:`annotate_rgbd.plan`: inputs read, parts placed,
tracks given their global planes, one frame job per depth frame that gets a mask), makes the
masks (:mod:`annotate_rgbd.execute`) and finishes the output folder (:func:`finish_scene`:
tables, report, stale files removed).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Callable, Mapping, Sequence as SequenceType

from annotate_rgbd.config.settings import Config
from .execute import STALL_TIMEOUT, SceneRun, execute_scenes, start_frame_helpers
from annotate_rgbd.io.outdir import remove_review_files, remove_stale_files
from .plan import plan_run
from .tables import run_record, write_tables
from .resume import REPORT, remove_journal
from annotate_rgbd.io.writer import write_json

log = logging.getLogger("annotate_rgbd")


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
    job_timeout: float = STALL_TIMEOUT,
    poses: str | Path | None = None,
    instance_ids: bool = False,
) -> SceneRun:
    """Run the whole job: ``masks/``, ``planes.csv``, ``tracks.csv`` and ``report.json`` in ``out_dir``.

    A re-run in the same ``out_dir`` redoes only the frames whose inputs changed
    (:mod:`annotate_rgbd.resume`); masks of frames that no longer get one are removed.

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
        Also write ``overlays/``: the review overlays (:mod:`annotate_rgbd.overlay`), then
        ``review.html`` and ``contact_sheet.png`` (``review_page`` of the returned run).
    progress : callable, optional
        Called as ``progress(done, total)`` after each frame that gets a mask.
    job_timeout : float
        Seconds without a frame finished by the helper processes before they are taken to hang
        and replaced (:func:`annotate_rgbd.pool.run_jobs`).
    poses : str or Path, optional
        A camera trajectory (TUM format) that carries the keyframe shapes to every frame
        (:mod:`annotate_rgbd.propagate`); default: the configuration's ``sequence.poses``.
    instance_ids : bool
        Also write ``masks_id/``: single-channel masks whose pixel values are the plane ids of
        ``planes.csv`` (8-bit for up to 255 planes, else 16-bit; 0 = no plane).

    Returns
    -------
    SceneRun
        The finished run: its frame records (``frames``), planes, counts and warnings.

    Raises
    ------
    InputError
        A fatal problem with an input (missing files, malformed export, parts that cannot be
        placed, sizes that do not match): nothing sensible can be produced.
    """
    helpers = start_frame_helpers(workers)
    scene = None
    try:
        plan = plan_run(sequence_dir, annotation_paths, out_dir, config, offsets, raw_masks, overlays, poses,
                        instance_ids)
        scene = SceneRun(Path(sequence_dir).name, plan, Path(out_dir), config, progress)
        execute_scenes([scene], helpers, force=force, job_timeout=job_timeout)
        if helpers is not None:
            helpers.shutdown(cancel_futures=True)
            helpers = None
        if scene.error is not None:
            raise scene.error
        finish_scene(scene)
    finally:
        if helpers is not None:
            helpers.shutdown(cancel_futures=True)
        if scene is not None:
            scene.release()
    return scene


def finish_scene(scene: SceneRun) -> None:
    """Remove stale outputs, write a scene's tables and report, then remove the journal; with
    overlays (drawn by the frames' jobs) also the review page and contact sheet."""
    plan = scene.plan
    remove_stale_outputs(scene)
    write_tables(scene.out_dir, plan.tracks, plan.colours)
    write_json(scene.out_dir / REPORT, run_record(plan, scene.config).to_json())
    remove_journal(scene.out_dir)
    if any(job.overlay_path is not None for _, job in plan.jobs):
        from annotate_rgbd.review.review import review_run  # only with overlays (SciPy is slow to import)

        scene.review_page = review_run(scene.out_dir, overlays=False).page


def remove_stale_outputs(scene: SceneRun) -> None:
    """Delete the files an earlier run wrote into the scene's folder that this run did not:
    masks of frames now skipped or failed, raw masks and overlays not asked for, the review
    page and contact sheet of an earlier run (they show its masks), and temporary files. Files
    annotate-rgbd did not write are left alone, with a warning."""
    keep = {path for f in scene.frames if f.written for path, _ in f.result.outputs}
    keep |= {f.mask for f in scene.frames if f.written}  # records of earlier versions list no outputs
    cleanup = remove_stale_files(scene.out_dir, scene.previous.files, keep)
    cleanup.foreign += remove_review_files(scene.out_dir)
    for line in cleanup.removals():
        log.info(line)
    for line in cleanup.warnings():
        scene.plan.warnings.append(line)
        log.warning(line)

"""Finishing a scene's output folder once its frames are made: stale files removed, tables,
drawn shapes and report written, the journal removed, what the run left recorded."""

from __future__ import annotations

import logging
from pathlib import Path

from annotate_rgbd.io.cleanup import (
    ReviewRecord, read_review_record, remove_review_files, remove_stale_files, shown_digest,
)
from annotate_rgbd.io.outdir import OVERLAYS, REPORT
from annotate_rgbd.io.writer import write_json
from annotate_rgbd.report.run_folder import write_drawn_shapes
from .execute import SceneRun
from .resume import remove_journal
from .tables import run_record, write_tables

log = logging.getLogger("annotate_rgbd")


def finish_scene(scene: SceneRun) -> None:
    """Write a scene's tables, remove stale outputs, write its drawn shapes and report, then
    remove the journal and record what the run left; with overlays (drawn by the frames' jobs)
    also the review page and contact sheet."""
    plan = scene.plan
    write_tables(scene.out_dir, plan.tracks, plan.colours)  # first: a kept review must still show them
    keep = remove_stale_outputs(scene)
    write_drawn_shapes(scene.out_dir, ((plan.frames[i].mask, job.shapes, job.carried) for i, job in plan.jobs
                                       if plan.frames[i].written))
    record = run_record(plan, scene.config)
    write_json(scene.out_dir / REPORT, record.to_json())
    remove_journal(scene.out_dir)
    scene.folder.settle(keep)
    if any(job.overlay_path is not None for _, job in plan.jobs):
        from annotate_rgbd.review.review import write_review  # only with overlays (SciPy is slow to import)

        scene.review_page = write_review(scene.folder, record, overlays=False).page


def remove_stale_outputs(scene: SceneRun) -> set[str]:
    """Delete the files an earlier run wrote into the scene's folder that this run did not:
    masks of frames now skipped or failed, raw masks and overlays not asked for, the review
    page and contact sheet of an earlier run (they show its masks), and temporary files. Files
    annotate-rgbd did not write are left alone, with a warning. Returns the per-frame files
    the run keeps (relative paths).

    A review that ``review`` made stays, page, sheet and the overlays it drew, while it still
    shows this output (:func:`review_still_shown`)."""
    keep = {path for f in scene.frames if f.written for path, _ in f.result.outputs}
    keep |= {f.mask for f in scene.frames if f.written}  # records of earlier versions list no outputs
    review = read_review_record(scene.out_dir)
    kept_review = review_still_shown(scene, review)
    if kept_review:
        keep |= {f"{OVERLAYS}/{name}" for name in review.overlays}
    drawn_by_review = () if kept_review else [f"{OVERLAYS}/{name}" for name in review.overlays]
    cleanup = remove_stale_files(scene.out_dir, scene.previous.files, keep, drawn_by_review)
    if kept_review:
        kept = [name for name in review.files if (scene.out_dir / name).is_file()]
        log.info("kept the earlier review (%s): it shows these masks and tables",
                 ", ".join([*kept, f"{len(review.overlays)} overlays"]))
    else:
        remove_review_files(scene.out_dir, cleanup)
        if any(job.overlay_path is not None for _, job in scene.plan.jobs):
            cleanup.review.clear()  # this run writes the page and sheet again (finish_scene): nothing to say
    for line in cleanup.removals():
        log.info(line)
    for line in cleanup.warnings():
        scene.plan.warnings.append(line)
        log.warning(line)
    return keep


def review_still_shown(scene: SceneRun, review: ReviewRecord) -> bool:
    """Whether the review ``review`` made of the folder still shows the run's output: it drew
    the overlay of every frame with a mask, all of them are still there (as annotate-rgbd
    recorded writing them), and the masks and tables are byte for byte those it showed
    (:func:`~annotate_rgbd.io.cleanup.shown_digest`; a run resumed from its journal, or one
    whose frames failed, is judged by its masks, not by what it made)."""
    if not review.overlays or review.shows is None:
        return False
    masks = [f.mask for f in scene.frames if f.written]
    drawn = {f"{OVERLAYS}/{name}" for name in review.overlays}
    if drawn != {f"{OVERLAYS}/{Path(mask).name}" for mask in masks} or not drawn <= set(scene.previous.files):
        return False
    if not all((scene.out_dir / path).is_file() for path in drawn):
        return False
    return shown_digest(scene.out_dir, masks) == review.shows

"""Finishing a scene's output folder once its frames are made: stale files removed, tables,
drawn shapes and report written, the journal removed, what the run left recorded."""

from __future__ import annotations

import logging

from annotate_rgbd.io.cleanup import remove_review_files, remove_stale_files
from annotate_rgbd.io.outdir import REPORT
from annotate_rgbd.io.writer import write_json
from annotate_rgbd.report.run_folder import write_drawn_shapes
from .execute import SceneRun
from .resume import remove_journal
from .tables import run_record, write_tables

log = logging.getLogger("annotate_rgbd")


def finish_scene(scene: SceneRun) -> None:
    """Remove stale outputs, write a scene's tables, drawn shapes and report, then remove the
    journal and record what the run left; with overlays (drawn by the frames' jobs) also the
    review page and contact sheet."""
    plan = scene.plan
    keep = remove_stale_outputs(scene)
    write_tables(scene.out_dir, plan.tracks, plan.colours)
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
    the run keeps (relative paths)."""
    keep = {path for f in scene.frames if f.written for path, _ in f.result.outputs}
    keep |= {f.mask for f in scene.frames if f.written}  # records of earlier versions list no outputs
    cleanup = remove_stale_files(scene.out_dir, scene.previous.files, keep)
    remove_review_files(scene.out_dir, cleanup)
    for line in cleanup.removals():
        log.info(line)
    for line in cleanup.warnings():
        scene.plan.warnings.append(line)
        log.warning(line)
    return keep

"""Finishing a scene's output folder once its frames are made: stale files removed, tables,
drawn shapes and report written, the journal removed, what the run left recorded."""

from __future__ import annotations

import logging

from annotate_rgbd.io.cleanup import read_review_record, remove_review_files, remove_stale_files
from annotate_rgbd.io.outdir import MASKS, OVERLAYS, REPORT
from annotate_rgbd.io.writer import write_json
from annotate_rgbd.report.run_folder import write_drawn_shapes
from .execute import SceneRun
from .resume import remove_journal
from .tables import TABLES, run_record, write_tables

log = logging.getLogger("annotate_rgbd")


def finish_scene(scene: SceneRun) -> None:
    """Write a scene's tables, remove stale outputs, write its drawn shapes and report, then
    remove the journal and record what the run left; with overlays (drawn by the frames' jobs)
    also the review page and contact sheet."""
    plan = scene.plan
    tables_before = _tables(scene)
    write_tables(scene.out_dir, plan.tracks, plan.colours)
    keep = remove_stale_outputs(scene, keep_review=_tables(scene) == tables_before and unchanged(scene))
    write_drawn_shapes(scene.out_dir, ((plan.frames[i].mask, job.shapes, job.carried) for i, job in plan.jobs
                                       if plan.frames[i].written))
    record = run_record(plan, scene.config)
    write_json(scene.out_dir / REPORT, record.to_json())
    remove_journal(scene.out_dir)
    scene.folder.settle(keep)
    if any(job.overlay_path is not None for _, job in plan.jobs):
        from annotate_rgbd.review.review import write_review  # only with overlays (SciPy is slow to import)

        scene.review_page = write_review(scene.folder, record, overlays=False).page


def remove_stale_outputs(scene: SceneRun, keep_review: bool = False) -> set[str]:
    """Delete the files an earlier run wrote into the scene's folder that this run did not:
    masks of frames now skipped or failed, raw masks and overlays not asked for, the review
    page and contact sheet of an earlier run (they show its masks), and temporary files. Files
    annotate-rgbd did not write are left alone, with a warning. Returns the per-frame files
    the run keeps (relative paths).

    With ``keep_review`` (the run changed no mask and no table) a review that ``review`` made
    stays, page, sheet and the overlays it drew: they still show this output. A page that
    shows the earlier run's own ``--overlays`` goes, with those overlays when not asked for
    again (which of them a run drew and which ``review`` did, only the review's record says)."""
    keep = {path for f in scene.frames if f.written for path, _ in f.result.outputs}
    keep |= {f.mask for f in scene.frames if f.written}  # records of earlier versions list no outputs
    drawn = read_review_record(scene.out_dir).overlays if keep_review else ()
    keep |= {f"{OVERLAYS}/{name}" for name in drawn if (scene.out_dir / OVERLAYS / name).is_file()}
    cleanup = remove_stale_files(scene.out_dir, scene.previous.files, keep)
    if not drawn:
        remove_review_files(scene.out_dir, cleanup)
    for line in cleanup.removals():
        log.info(line)
    for line in cleanup.warnings():
        scene.plan.warnings.append(line)
        log.warning(line)
    return keep


def _tables(scene: SceneRun) -> tuple[bytes | None, ...]:
    """The bytes of the scene's tables (None where there is none)."""
    return tuple((scene.out_dir / name).read_bytes() if (scene.out_dir / name).is_file() else None
                 for name in TABLES)


def unchanged(scene: SceneRun) -> bool:
    """Whether the run left the masks as the earlier run had them: every frame reused, none
    failed, and the same frames masked."""
    before = {path for path in scene.previous.files if path.startswith(f"{MASKS}/")}
    now = {f.mask for f in scene.frames if f.written}
    return scene.counts.made == 0 and scene.counts.failed == 0 and bool(before) and before == now

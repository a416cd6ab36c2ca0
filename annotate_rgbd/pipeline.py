"""The ``cvat2mask`` job: CVAT export(s) + RGB-D sequence -> refined plane masks and a report.

:func:`run_cvat2mask` plans the run (:mod:`annotate_rgbd.plan`: inputs read, parts placed,
tracks given their global planes, one frame job per depth frame that gets a mask), makes the
masks (:mod:`annotate_rgbd.execute`) and finishes the output folder (:func:`finish_scene`:
tables, report, stale files removed).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Mapping, Sequence as SequenceType

from .config import Config
from .execute import SceneRun, execute_scenes, start_frame_helpers
from .frame_job import OVERLAY_DIR
from .plan import RunPlan, plan_run
from .report import run_record, write_tables
from .resume import REPORT, remove_journal
from .writer import write_json


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
        Also write ``overlays/``: the review overlays (:mod:`annotate_rgbd.overlay`).
    progress : callable, optional
        Called as ``progress(done, total)`` after each frame that gets a mask.

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
    try:
        plan = plan_run(sequence_dir, annotation_paths, out_dir, config, offsets, raw_masks, overlays)
        scene = SceneRun(Path(sequence_dir).name, plan, Path(out_dir), config, progress)
        execute_scenes([scene], helpers, force=force)
    finally:
        if helpers is not None:
            helpers.shutdown(cancel_futures=True)
    if scene.error is not None:
        raise scene.error
    finish_scene(scene)
    return scene


def finish_scene(scene: SceneRun) -> None:
    """Write a scene's tables and report, remove stale outputs and the journal."""
    plan = scene.plan
    write_tables(scene.out_dir, plan.tracks, plan.colours)
    write_json(scene.out_dir / REPORT, run_record(plan, scene.config).to_json())
    remove_stale_outputs(scene.out_dir, plan)
    remove_journal(scene.out_dir)


def remove_stale_outputs(out_dir: Path, plan: RunPlan) -> None:
    """Delete what this run did not write: masks of frames now skipped or failed, raw masks and
    overlays that were not asked for, a review page and contact sheet of an earlier run, and
    temporary files."""
    written = {Path(f.mask).name for f in plan.frames if f.written}
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

"""Review a finished ``cvat2mask`` run: overlays, the review page and a contact sheet.

:func:`review_run` reads ``OUT_DIR/report.json``, rebuilds the run's plan from the inputs and
the configuration recorded there, segments every written frame again (the result is the same:
RANSAC is seeded) to get what the labeller drew next to what was kept, and writes

* ``overlays/<mask name>``: one overlay per mask (:func:`annotate_rgbd.overlay.render_overlay`);
* ``review.html``: the offline review page (:mod:`annotate_rgbd.review_page`);
* ``contact_sheet.png``: a grid of overlay thumbnails spread over the sequence.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from annotate_rgbd.config.settings import Config, config_from_dict
from annotate_rgbd.errors import InputError
from annotate_rgbd.pipeline.frame_job import OVERLAY_DIR, FrameJob, segment_job
from annotate_rgbd.io.outdir import REVIEW_RECORD, check_output_names, file_digest, read_bounded, read_review_record
from .overlay import contact_sheet, overlay_for_frame
from annotate_rgbd.pipeline.plan import RunPlan, plan_run
from annotate_rgbd.pool import run_jobs, start_helpers
from annotate_rgbd.report.records import FrameRecord, RecordError, RunRecord
from annotate_rgbd.pipeline.resume import MAX_RECORDS_BYTES, REPORT as REPORT_NAME
from .page import render_review_page
from annotate_rgbd.io.sequence import read_rgb
from annotate_rgbd.io.writer import write_bytes_atomic, write_png

log = logging.getLogger("annotate_rgbd")

PAGE_NAME = "review.html"
SHEET_NAME = "contact_sheet.png"
#: Thumbnails on the contact sheet, evenly spread over the written frames.
SHEET_FRAMES = 12
#: How parts were placed whose recorded offset must be passed again to place them the same way.
OFFSET_SOURCES = ("explicit", "file name")


@dataclass
class ReviewOutput:
    """What :func:`review_run` wrote.

    Parameters
    ----------
    overlays : list of Path
        The overlay images written.
    page, sheet : Path or None
        ``review.html`` and ``contact_sheet.png``, where written.
    warnings : list of str
        Frames that did not segment as the report says (the inputs or the tool changed since
        the run).
    """

    overlays: list[Path] = field(default_factory=list)
    page: Path | None = None
    sheet: Path | None = None
    warnings: list[str] = field(default_factory=list)


def read_report(out_dir: str | Path) -> RunRecord:
    """Read ``report.json`` of a finished run.

    Raises
    ------
    InputError
        No report (the folder is not the output of a finished run) or not a report.
    """
    path = Path(out_dir) / REPORT_NAME
    try:
        report = json.loads(read_bounded(path, MAX_RECORDS_BYTES).decode("utf-8"))
    except FileNotFoundError:
        raise InputError(path, "no report: not the output folder of a finished cvat2mask run") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(path, f"cannot read the report: {exc.strerror if isinstance(exc, OSError) else exc}") from None
    except RecursionError:
        raise InputError(path, "cannot read the report: nested too deeply") from None
    if not isinstance(report, dict) or not {"inputs", "config", "frames", "planes"} <= report.keys():
        raise InputError(path, "not a cvat2mask report (inputs, config, frames or planes missing)")
    try:
        return RunRecord.from_json(report)
    except RecordError as exc:
        raise InputError(path, f"not a cvat2mask report: {exc}") from None


def replan(report: RunRecord, out_dir: str | Path, config: Config) -> RunPlan:
    """Rebuild the plan of a finished run from its report.

    Parameters
    ----------
    report : RunRecord
        The run's ``report.json``.
    out_dir : str or Path
        The run's output folder.
    config : Config
        The run's configuration (``config_from_dict(report.config)``).

    Returns
    -------
    RunPlan

    Raises
    ------
    InputError
        An input is gone or unreadable, or the inputs no longer give the run's frames and planes.
    """
    offsets = {p.name: p.offset for p in report.parts if p.placed_by in OFFSET_SOURCES}
    poses = (report.propagation or {}).get("poses")  # the run's trajectory, however it was given
    plan = plan_run(report.sequence, [p.file for p in report.parts], out_dir, config, offsets, poses=poses)
    if [f.depth for f in plan.frames] != [f.depth for f in report.frames] or plan.n_planes != len(report.planes):
        raise InputError(
            Path(out_dir) / REPORT_NAME,
            "the sequence or the annotation changed since this run: its frames or planes differ; run cvat2mask again",
        )
    return plan


def review_run(
    out_dir: str | Path,
    overlays: bool = True,
    page: bool = True,
    sheet: bool = True,
    progress: Callable[[int, int], None] | None = None,
    workers: int = 1,
) -> ReviewOutput:
    """Write the review files of a finished run.

    Parameters
    ----------
    out_dir : str or Path
        The output folder of a finished ``cvat2mask`` run.
    overlays : bool
        Segment every written frame again and write ``overlays/``.
    page : bool
        Write ``review.html``.
    sheet : bool
        Write ``contact_sheet.png`` from the overlays in ``overlays/`` (not for a run without
        masks).
    progress : callable, optional
        Called as ``progress(done, total)`` after each overlay.
    workers : int
        Processes that write overlays, this one included.

    Returns
    -------
    ReviewOutput

    Raises
    ------
    InputError
        No finished run in ``out_dir``, inputs gone or changed, or (for the sheet) no overlays.
    """
    out_dir = Path(out_dir)
    report = read_report(out_dir)
    check_output_names(out_dir)
    output = ReviewOutput()
    written = [f for f in report.frames if f.written]
    if overlays and written:
        config = config_from_dict(report.config, origin=out_dir / REPORT_NAME)
        plan = replan(report, out_dir, config)
        jobs = {job.mask_path.name: job for _, job in plan.jobs}
        tasks = []
        for frame in written:
            path = _overlay_path(out_dir, frame)
            job = jobs.get(path.name)
            if job is None:
                raise InputError(out_dir / REPORT_NAME, f"{frame.depth}: no longer gets a mask from the inputs; run cvat2mask again")
            tasks.append(OverlayTask(job, config, plan.sequence.root / frame.rgb, plan.colours, path))
        with start_helpers(workers, [__name__]) or nullcontext() as helpers:
            for done, outcome in enumerate(run_jobs(tasks, write_overlay, helpers), start=1):
                if outcome.error is not None:
                    raise outcome.error
                _check_records(written[outcome.index], outcome.value, output.warnings)
                if progress:
                    progress(done, len(written))
        output.overlays = [task.path for task in tasks]
    available = [f for f in written if _overlay_path(out_dir, f).is_file()]
    if page:
        output.page = out_dir / PAGE_NAME
        relative = {f.mask: f"{OVERLAY_DIR}/{_overlay_path(out_dir, f).name}" for f in available}
        html = render_review_page(report, relative, title=out_dir.resolve().name)
        write_bytes_atomic(output.page, html.encode("utf-8"))
    if sheet and written:
        if not available:
            raise InputError(out_dir / OVERLAY_DIR, "no overlays for the contact sheet: run review with overlays")
        picks = np.unique(np.linspace(0, len(available) - 1, min(len(available), SHEET_FRAMES)).round().astype(int))
        frames = [available[i] for i in picks]
        images = [read_rgb(_overlay_path(out_dir, f)) for f in frames]
        output.sheet = out_dir / SHEET_NAME
        write_png(output.sheet, contact_sheet(images, [Path(f.depth).stem for f in frames]))
    # So that a later cvat2mask run removes these files, and only these (annotate_rgbd.outdir).
    written_files = {p.name: file_digest(p) for p in (output.page, output.sheet) if p is not None}
    record = {**read_review_record(out_dir), **written_files}
    write_bytes_atomic(out_dir / REVIEW_RECORD, json.dumps(record, indent=1).encode("utf-8"))
    return output


@dataclass(frozen=True)
class OverlayTask:
    """One overlay to write: the frame's job as the run planned it, and where to write."""

    job: FrameJob
    config: Config
    rgb: Path
    colours: np.ndarray
    path: Path


def write_overlay(task: OverlayTask) -> list[tuple]:
    """Segment the task's frame again and write its overlay (run in a helper process).

    Returns
    -------
    list of tuple
        The frame's plane records as ``(plane, pixels, inliers, reason)``, sorted, to compare
        with the report.
    """
    result = segment_job(task.job, task.config)
    write_png(task.path, overlay_for_frame(task.rgb, result, task.colours))
    return _plane_summary([*result.kept, *result.dropped])


def _plane_summary(planes) -> list[tuple]:
    return sorted((r.plane, r.pixels, r.inliers, r.reason) for r in planes)


def _overlay_path(out_dir: Path, frame: FrameRecord) -> Path:
    return out_dir / OVERLAY_DIR / Path(frame.mask).name


def _check_records(frame: FrameRecord, planes: list[tuple], warnings: list[str]) -> None:
    """Warn when a frame no longer segments as the report says (its overlay would mislead)."""
    if planes != _plane_summary([*frame.kept, *frame.dropped]):
        message = (
            f"{frame.depth}: segments differently from report.json (inputs or annotate-rgbd changed "
            "since the run?); the overlay shows what a run would make now"
        )
        warnings.append(message)
        log.warning(message)

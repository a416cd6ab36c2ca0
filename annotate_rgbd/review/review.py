"""Review a finished ``cvat2mask`` run, or ``propose``'s proposals before they go to CVAT:
overlays, the review page and a contact sheet.

:func:`review_run` reads the run's own records (:mod:`annotate_rgbd.report.run_folder`:
``report.json``, the masks, the shapes each frame drew) and the RGB frames, never runs a stage
again, and writes

* ``overlays/<mask name>``: one overlay per mask (:func:`annotate_rgbd.review.overlay.render_overlay`);
* ``review.html``: the offline review page (:mod:`annotate_rgbd.review.page`);
* ``contact_sheet.png``: a grid of overlay thumbnails spread over the sequence.

It holds the run's folder like any command that writes there
(:class:`annotate_rgbd.io.outdir.OutputFolder`), so that it never draws a run half-way through.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from annotate_rgbd.config.settings import config_from_dict
from annotate_rgbd.errors import InputError
from annotate_rgbd.geometry.camera import Camera, depth_to_metres
from annotate_rgbd.geometry.registration import ColourCamera
from annotate_rgbd.io.cleanup import ReviewRecord, read_review_record, shown_digest
from annotate_rgbd.io.outdir import OVERLAYS, REVIEW_RECORD, OutputFolder, file_digest
from annotate_rgbd.io.sequence import read_depth, read_image, read_rgb
from annotate_rgbd.io.writer import write_bytes_atomic, write_png
from annotate_rgbd.logs import group_errors
from annotate_rgbd.pool import run_jobs, start_helpers
from annotate_rgbd.report.records import FrameRecord, RunRecord
from annotate_rgbd.segment.plane_record import PlaneRecord
from annotate_rgbd.report.run_folder import colour_table, mask_plane_ids, read_drawn_shapes, read_report
from annotate_rgbd.segment.frame import FrameResult
from annotate_rgbd.segment.rasterize import carried_shapes, draw_on_depth_grid, rasterize_frame
from .overlay import contact_sheet, overlay_for_frame
from .page import render_review_page

log = logging.getLogger("annotate_rgbd")

PAGE_NAME = "review.html"
SHEET_NAME = "contact_sheet.png"
#: Thumbnails on the contact sheet, evenly spread over the written frames.
SHEET_FRAMES = 12


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
        Problems that did not stop the review (RGB images that could not be read: their
        overlays drawn on grey), one line each, also logged.
    """

    overlays: list[Path] = field(default_factory=list)
    page: Path | None = None
    sheet: Path | None = None
    warnings: list[str] = field(default_factory=list)


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
        The output folder of a finished ``cvat2mask`` or ``propose`` run (its proposals as
        :func:`annotate_rgbd.report.proposals.proposals_record` reads them).
    overlays : bool
        Write ``overlays/`` (one per written mask).
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
        No finished run in ``out_dir``, its records unreadable, or (for the sheet) no overlays
        (an unreadable RGB frame costs its overlay's colour only: drawn on grey, with a warning in
        ``ReviewOutput.warnings``); OutputError when the folder is busy or cannot be written.
    """
    out_dir = Path(out_dir)
    report = read_report(out_dir, proposals=True)
    with OutputFolder(out_dir, None) as folder:
        return write_review(folder, report, overlays, page, sheet, progress, workers)


def write_review(
    folder: OutputFolder,
    report: RunRecord,
    overlays: bool = True,
    page: bool = True,
    sheet: bool = True,
    progress: Callable[[int, int], None] | None = None,
    workers: int = 1,
) -> ReviewOutput:
    """:func:`review_run` in a folder this process already holds (``cvat2mask --overlays``
    calls it with the run's folder before letting it go)."""
    out_dir = folder.path
    output = ReviewOutput()
    written = [f for f in report.frames if f.written]
    if overlays and written:
        shapes = read_drawn_shapes(out_dir, {f.mask for f in written}, report.command)
        keys, values = colour_table(report)
        colours = plane_colour_rows(report)
        registration = None
        if "colour_camera" in report.config:  # shapes drawn on a colour grid of its own
            config = config_from_dict(report.config, out_dir / "report.json")
            registration = (config.camera, config.colour_camera)
        tasks = [
            OverlayTask(Path(report.sequence) / f.rgb, out_dir / f.mask, tuple(shapes[f.mask].shapes),
                        tuple(f.kept), tuple(f.dropped), keys, values, colours, _overlay_path(out_dir, f),
                        Path(report.sequence) / f.depth if registration else None, registration,
                        tuple(shapes[f.mask].carried))
            for f in written
        ]
        folder.expect(f"{OVERLAYS}/{task.path.name}" for task in tasks)
        rgb_problems = []
        with start_helpers(workers, [__name__]) or nullcontext() as helpers:
            for done, outcome in enumerate(run_jobs(tasks, write_overlay, helpers), start=1):
                if outcome.error is not None:
                    raise outcome.error
                if outcome.value is not None:
                    rgb_problems.append(outcome.value)
                if progress:
                    progress(done, len(written))
        output.overlays = [task.path for task in tasks]
        output.warnings = group_errors(rgb_problems)
        for line in output.warnings:
            log.warning("%s", line)
    available = [f for f in written if _overlay_path(out_dir, f).is_file()]
    if sheet and written and not available:  # before the page is written: a refusal leaves nothing half done
        raise InputError(out_dir / OVERLAYS, "no overlays for the contact sheet: run review with overlays "
                                             "(or --no-sheet)")
    if page:
        output.page = out_dir / PAGE_NAME
        relative = {f.mask: f"{OVERLAYS}/{_overlay_path(out_dir, f).name}" for f in available}
        html = render_review_page(report, relative, title=out_dir.resolve().name)
        write_bytes_atomic(output.page, html.encode("utf-8"))
    if sheet and written:
        picks = np.unique(np.linspace(0, len(available) - 1, min(len(available), SHEET_FRAMES)).round().astype(int))
        frames = [available[i] for i in picks]
        images = (read_rgb(_overlay_path(out_dir, f)) for f in frames)  # one full image in memory at a time
        output.sheet = out_dir / SHEET_NAME
        write_png(output.sheet, contact_sheet(images, [Path(f.depth).stem for f in frames]))
    # So that a later cvat2mask run removes these files, and only these (annotate_rgbd.io.outdir).
    written_files = {p.name: file_digest(p) for p in (output.page, output.sheet) if p is not None}
    earlier = read_review_record(out_dir)
    # Overlays drawn by an earlier review stay its own when this call draws none (a run removes
    # the record whenever its masks change, so they show these masks).
    drawn = tuple(sorted(p.name for p in output.overlays)) if output.overlays else earlier.overlays
    record = ReviewRecord({**earlier.files, **written_files}, drawn, shown_digest(out_dir, [f.mask for f in written]))
    write_bytes_atomic(out_dir / REVIEW_RECORD, json.dumps(record.to_json(), indent=1).encode("utf-8"))
    return output


def plane_colour_rows(report: RunRecord) -> np.ndarray:
    """The run's plane colours as an ``(n_planes, 3)`` RGB array, row ``k - 1`` for plane ``k``."""
    colours = np.zeros((max(report.n_planes, max((p.plane for p in report.planes), default=0)), 3), np.uint8)
    for plane in report.planes:
        value = int(plane.colour.lstrip("#"), 16)
        colours[plane.plane - 1] = (value >> 16, (value >> 8) & 255, value & 255)
    return colours


@dataclass(frozen=True)
class OverlayTask:
    """One overlay to draw: the frame's RGB image, mask and drawn shapes, its plane records and
    the run's colours, and where to write it."""

    rgb: Path
    mask: Path
    shapes: tuple
    kept: tuple[PlaneRecord, ...]
    dropped: tuple[PlaneRecord, ...]
    keys: np.ndarray
    values: np.ndarray
    colours: np.ndarray
    path: Path
    depth: Path | None = None
    registration: tuple[Camera, ColourCamera] | None = None
    carried: tuple = ()


def write_overlay(task: OverlayTask) -> InputError | None:
    """Draw one frame's overlay from the run's records and write it (run in a helper process).
    With a colour camera of its own (``registration``: the depth camera and the colour camera)
    the shapes are taken to the depth grid through the frame's depth, as the frame's job did.
    Returns why the RGB image could not be used (the overlay is then drawn on grey), or None."""
    labels = mask_plane_ids(read_image(task.mask, cv2.IMREAD_COLOR), task.keys, task.values, task.mask)
    grid = None
    if task.registration is None:
        shapes, _ = carried_shapes(task.shapes, task.carried, *labels.shape)
        drawn = rasterize_frame(shapes, *labels.shape)
    else:
        camera, colour = task.registration
        shapes, _ = carried_shapes(task.shapes, task.carried, colour.height, colour.width)
        depth_m = depth_to_metres(read_depth(task.depth), camera.depth_scale)
        drawn, grid = draw_on_depth_grid(shapes, depth_m, camera, colour)
    result = FrameResult(labels=labels, drawn=drawn, kept=list(task.kept), dropped=list(task.dropped),
                         colour_grid=grid)
    overlay, rgb_problem = overlay_for_frame(task.rgb, result, task.colours)
    write_png(task.path, overlay)
    return rgb_problem


def _overlay_path(out_dir: Path, frame: FrameRecord) -> Path:
    return out_dir / OVERLAYS / Path(frame.mask).name

"""``export-cvat``: a finished ``cvat2mask`` run's refined masks as a "CVAT for video 1.1" export,
for a correction round in CVAT.

One polygon track per plane, with the run's plane id as CVAT track id and as its ``plane_id``
attribute (which CVAT keeps where the label declares it, and ``cvat2mask`` gives back as the plane's id
and colour: :mod:`annotate_rgbd.annotation.stitch`) and the plane's label;
every written frame is a keyframe (frame number = RGB index, as ``cvat2mask`` reads a video
export); a plane absent on a written frame is ``outside`` there. Polygons are the masks' outer
outlines, every piece of a plane joined into one simple polygon within a tolerance and a vertex
budget (:func:`annotate_rgbd.cvat.from_masks.outline_planes`),
drawn in the order that puts the plane whose pixels fill an overlap on top
(:func:`annotate_rgbd.cvat.from_masks.draw_order`), as ``propose`` draws its detections, so that
``cvat2mask`` reads the file back to nearly the same masks.

With a ``[colour_camera]`` the polygons lie on its colour images, which the labeller opens in
CVAT: each is traced on the depth grid and taken to the colour image through its plane
(:func:`annotate_rgbd.propose.output.colour_image_polygons`), and the export's image size is
theirs.
"""

from __future__ import annotations

import logging
import os
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from annotate_rgbd.annotation.model import PLANE_ID, Shape
from annotate_rgbd.config.propose import EXPORT_MAX_VERTICES, EXPORT_TOLERANCE_PX
from annotate_rgbd.cvat.from_masks import draw_order, piece_outlines
from annotate_rgbd.errors import InputError, OutputError
from annotate_rgbd.io.outdir import TOP_LEVEL_NAMES, check_output_file, reading
from annotate_rgbd.io.writer import is_stream
from annotate_rgbd.logs import group_problems
from annotate_rgbd.pool import run_jobs, start_helpers
from annotate_rgbd.propose.output import TrackShapes, write_polygon_tracks
from annotate_rgbd.propose.output import colour_image_polygons
from annotate_rgbd.segment.rasterize import shape_mask
from annotate_rgbd.io.sequence import read_image
from annotate_rgbd.report.records import FrameRecord, RunRecord
from annotate_rgbd.config.settings import Config, config_from_dict
from annotate_rgbd.report.run_folder import colour_table, mask_plane_ids, read_report

log = logging.getLogger("annotate_rgbd")


def export_cvat(run_dir: str | Path, xml_path: str | Path, tolerance_px: float = EXPORT_TOLERANCE_PX,
                max_vertices: int = EXPORT_MAX_VERTICES, workers: int = 1,
                progress: Callable[[int, int], None] | None = None) -> int:
    """Write a run's masks as polygon tracks.

    Parameters
    ----------
    run_dir : str or Path
        Output folder of a finished ``cvat2mask`` run (``report.json``, ``masks/``).
    xml_path : str or Path
        The CVAT XML file to write.
    tolerance_px : float
        Largest distance of a polygon from the traced outline of its mask, pixels
        (:data:`annotate_rgbd.config.propose.EXPORT_TOLERANCE_PX`).
    max_vertices : int
        Vertex budget of each polygon (0: none); polygons are simple either way
        (:func:`annotate_rgbd.cvat.from_masks.outline_planes`).
    workers : int
        Processes that trace the frames' outlines, this one included.
    progress : callable, optional
        ``progress(done, total)`` after each frame.

    Returns
    -------
    int
        Tracks written.

    Raises
    ------
    InputError
        No report, a mask missing or unreadable, a mask colour that is no plane of the run.
    """
    for option, problem in (("--max-vertices", vertex_budget_problem(max_vertices)),
                            ("--tolerance", tolerance_problem(tolerance_px))):
        if problem:
            raise InputError(None, f"{option} {problem}")
    run_dir = Path(run_dir)
    with reading(run_dir):
        report = read_report(run_dir)
        check_target(run_dir, Path(xml_path), [Path(part.file) for part in report.parts])
        return _export(run_dir, report, Path(xml_path), tolerance_px, max_vertices, workers, progress)


def tolerance_problem(tolerance_px: float) -> str | None:
    """Why a value is no outline tolerance, in words after the option's name; None when it is
    one (a finite distance in pixels, at least 0)."""
    if np.isfinite(tolerance_px) and tolerance_px >= 0:
        return None
    return f"must be a finite distance in pixels >= 0, not {tolerance_px:g}"


def vertex_budget_problem(max_vertices: int) -> str | None:
    """Why a value is no vertex budget, in words after the option's name; None when it is one
    (0, no budget, or at least the 3 vertices of a polygon)."""
    if max_vertices == 0 or max_vertices >= 3:
        return None
    return f"must be 0 (no budget) or at least a polygon's 3 vertices, not {max_vertices}"


@dataclass(frozen=True)
class FramePolygonsJob:
    """One frame of the export: its mask, its record and how to trace it
    (:func:`frame_polygons`, run in a helper process)."""

    mask: Path
    frame: FrameRecord
    keys: np.ndarray
    values: np.ndarray
    config: Config
    tolerance_px: float
    max_vertices: int


def frame_polygons(job: FramePolygonsJob) -> tuple[tuple[int, int], list[tuple[int, np.ndarray, int]]]:
    """A frame's polygons: the mask's size and, per plane on it, ``(plane id, polygon in CVAT
    coordinates of the image the labeller draws on, z_order)``."""
    ids = mask_plane_ids(read_image(job.mask, cv2.IMREAD_COLOR), job.keys, job.values, job.mask)
    present = np.unique(ids[ids > 0])
    if present.size == 0:
        return ids.shape, []
    compact = np.searchsorted(present, ids) + 1
    compact[ids == 0] = 0
    outlines = piece_outlines(compact, job.tolerance_px, max_vertices=job.max_vertices)
    frame = job.frame
    distance = {p.plane: p.mean_distance for p in frame.result.kept} if frame.result else {}
    order = [k for k in range(1, len(present) + 1) if k in outlines]
    windows = [shape_mask(Shape("polygon", outlines[k]), *ids.shape) for k in order]
    far = np.array([np.nan if distance.get(int(present[k - 1])) is None else distance[int(present[k - 1])]
                    for k in order], dtype=np.float64)
    z_order = draw_order(np.searchsorted(order, compact) + 1, windows, far) if order else []
    order, z_order, outlines = on_colour_image(outlines, order, z_order, present, frame, job.config)
    return ids.shape, [(int(present[k - 1]), outlines[k], int(z)) for k, z in zip(order, np.asarray(z_order).tolist())]


def _export(run_dir: Path, report: RunRecord, xml_path: Path, tolerance_px: float, max_vertices: int,
            workers: int = 1, progress: Callable[[int, int], None] | None = None) -> int:
    labels_of = {p.plane: p.label for p in report.planes}
    config = config_from_dict(report.config, run_dir / "report.json")  # [colour_camera]: polygons on its images
    keys, values = colour_table(report)
    jobs = [FramePolygonsJob(run_dir / f.mask, f, keys, values, config, tolerance_px, max_vertices)
            for f in _keyframes(report)]
    traced: list = [None] * len(jobs)
    with start_helpers(workers, [__name__]) or nullcontext() as helpers:
        for done, outcome in enumerate(run_jobs(jobs, frame_polygons, helpers), start=1):
            if outcome.error is not None:
                raise outcome.error
            traced[outcome.index] = outcome.value
            if progress:
                progress(done, len(jobs))
    tracks: dict[int, TrackShapes] = {}
    sampled: list[int] = []
    size = None
    other_size: list[tuple[str, str]] = []
    for job, (shape, polygons) in zip(jobs, traced):
        if size is not None and shape != size:  # the export's frames have one size, the first mask's
            other_size.append((str(job.mask), f"mask is {shape[1]} x {shape[0]} pixels, not {size[1]} x {size[0]} "
                                              "as the first; left out of the export"))
            continue
        size = shape
        sampled.append(job.frame.rgb_index)
        for plane, polygon, z in polygons:
            entry = tracks.setdefault(plane, TrackShapes(plane, labels_of.get(plane, "plane"),
                                                         attributes={PLANE_ID: str(plane)}))
            entry.shapes[job.frame.rgb_index] = Shape("polygon", polygon, z_order=z)
    if size is None:
        raise InputError(run_dir / "report.json", "the run wrote no mask: nothing to export")
    for line in group_problems(other_size):
        log.warning("%s", line)
    last = max([p.last_rgb for p in report.parts] + sampled)
    if config.colour_camera is not None:  # the polygons lie on the colour images
        size = (config.colour_camera.height, config.colour_camera.width)
    write_polygon_tracks([tracks[t] for t in sorted(tracks)], Path(xml_path), n_frames=last + 1,
                         sampled_frames=sampled, width=size[1], height=size[0])
    return len(tracks)


def check_target(run_dir: Path, xml_path: Path, annotations: Sequence[Path] = ()) -> None:
    """Refuse to write the export into a folder that does not exist, over a file of the run it
    is made from (its report, tables, masks: the run would be lost), over one of the
    ``annotations`` the run read (the labeller's work, which the run's report names and a
    re-run needs) or an existing file of the same name as one (the run's report holds absolute
    paths: a project moved or copied elsewhere), over a file of any other annotate-rgbd output
    folder (another run's ``proposals.xml``: its report would no longer describe it), or over an
    existing file that is not CVAT XML (:func:`looks_like_cvat_xml`: the run's trajectory, camera
    file or frame list named by mistake).

    Raises
    ------
    OutputError
    """
    if is_stream(xml_path):
        return
    if xml_path.is_file():
        elsewhere = f"write the export elsewhere (e.g. {xml_path.stem}-refined.xml)"
        for annotation in annotations:
            if annotation.exists() and os.path.samefile(xml_path, annotation):
                raise OutputError(xml_path, f"is an annotation export the run was made from: the labeller's shapes "
                                            f"would be lost; {elsewhere}")
            if xml_path.name == annotation.name:  # the run or its annotations moved since (another machine)
                raise OutputError(xml_path, f"has the name of an annotation export the run was made from ({annotation}):"
                                            f" it may be the labeller's shapes; {elsewhere}")
    try:
        inside = xml_path.resolve().relative_to(run_dir.resolve()).parts
    except ValueError:
        inside = ()
    if inside and inside[0] in TOP_LEVEL_NAMES:
        raise OutputError(xml_path, f"is {'/'.join(inside)} of the run being exported; write the export elsewhere")
    check_output_file(xml_path, "round2.xml", "the export", "XML file", ours=(looks_like_cvat_xml, "a CVAT XML file"))


def looks_like_cvat_xml(head: bytes) -> bool:
    """Whether the first bytes of a file are those of a CVAT XML file (an export this command or
    CVAT wrote): markup that opens an ``<annotations`` element within them (after an XML
    declaration and comments). A trajectory, a camera file or a frame list named as the export by
    mistake is not.
    """
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    return text.startswith(b"<") and b"<annotations" in text


def _keyframes(report: RunRecord) -> list:
    """The written frames, one per RGB frame (the depth frame nearest to it in time)."""
    chosen: dict[int, object] = {}
    for frame in report.frames:
        if frame.status != "written" or not frame.mask:
            continue
        held = chosen.get(frame.rgb_index)
        if held is None or abs(frame.time_offset) < abs(held.time_offset):
            chosen[frame.rgb_index] = frame
    return [chosen[k] for k in sorted(chosen)]


def on_colour_image(outlines: dict, order: list, z_order, present: np.ndarray, frame,
                    config: Config) -> tuple[list, list, dict]:
    """A frame's outlines (traced on the depth grid) on the images the labeller draws on.

    Parameters
    ----------
    outlines : dict of int to ndarray, shape (V, 2)
        Compact label -> polygon, CVAT coordinates of the depth image.
    order : list of int
        The compact labels drawn, with their ``z_order`` (sequence of int).
    present : ndarray of int
        Plane id of each compact label (``present[k - 1]``).
    frame : FrameRecord
        The frame's record: its kept planes' equations and distances.
    config : Config
        The run's: without ``colour_camera`` everything is returned as it is.

    Returns
    -------
    order, z_order : list of int
        Without the labels whose polygon lies outside the colour image.
    outlines : dict of int to ndarray, shape (V, 2)
        On the colour image, clipped to it
        (:func:`annotate_rgbd.propose.output.colour_image_polygons`, through each plane's equation).
    """
    if config.colour_camera is None:
        return order, z_order, outlines
    kept = {p.plane: p for p in frame.result.kept} if frame.result else {}
    records = [kept.get(int(present[k - 1])) for k in order]
    mapped = colour_image_polygons(
        [outlines[k] for k in order],
        [None if r is None or r.equation is None else np.asarray(r.equation, dtype=np.float64) for r in records],
        [None if r is None else r.mean_distance for r in records], config)
    inside = [i for i, polygon in enumerate(mapped) if polygon is not None]
    return ([order[i] for i in inside], [int(np.asarray(z_order)[i]) for i in inside],
            {order[i]: mapped[i] for i in inside})

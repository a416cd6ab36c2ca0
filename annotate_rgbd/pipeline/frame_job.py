"""One depth frame's job: read the depth image, segment it, write its mask (and extras).

Kept apart from :mod:`annotate_rgbd.pipeline` so that worker processes import only what a frame
needs (OpenCV, numpy), not the CVAT reader or the planning: a worker starts faster.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.config.settings import Config
from annotate_rgbd.errors import InputError
from annotate_rgbd.geometry.registration import ColourCamera
from annotate_rgbd.io.outdir import data_digest, file_digest
from annotate_rgbd.report.palette import colourize, id_image
from annotate_rgbd.report.records import MaskRecord
from .resume import fingerprint
from annotate_rgbd.segment.frame import FrameResult, segment_frame
from annotate_rgbd.io.sequence import read_bytes, read_depth
from annotate_rgbd.io.writer import write_png

#: Folder of the review overlays in a run's output folder.
OVERLAY_DIR = "overlays"


@dataclass(frozen=True)
class FrameJob:
    """Everything needed to produce one mask, independent of every other frame.

    Parameters
    ----------
    depth_path : Path
        The depth image.
    mask_path : Path
        Where the colour mask goes.
    shapes : tuple of (int, Shape)
        ``(plane id, shape)`` of the owning part's tracks on the frame, in track order.
    image_size : (int, int) or None
        (width, height) of the annotated image, where the export states it.
    part_path : str
        The export the shapes come from (for messages).
    raw_mask_path : Path or None
        Where the unrefined mask goes (the labeller's shapes as drawn), if wanted.
    overlay_path : Path or None
        Where the review overlay goes, if wanted.
    id_mask_path : Path or None
        Where the instance-id mask goes (plane ids as pixel values), if wanted.
    rgb_path : Path or None
        The RGB image the overlay is drawn on.
    propagated : frozenset of int, optional
        With camera poses: the planes whose shapes the poses carried here from keyframes on
        other frames (:mod:`annotate_rgbd.propagate.carry`); every plane record says whether it is
        one of them. None without poses.
    expected_planes : tuple of (int, (float, float, float, float))
        Where the poses put each of those planes in this depth frame's camera frame (metres):
        refinement looks for it behind what RANSAC finds (:func:`annotate_rgbd.segment.ransac.fit_plane`).
    carried : tuple of (int, int, int, tuple of (int, ndarray), tuple of ndarray)
        ``(position, plane id, z_order, layers, beyond)`` of each plane the poses carried here:
        what its keyframes say it covers and excludes, and what lies past their views
        (:func:`annotate_rgbd.propagate.carry.carried_layers`), drawn among ``shapes`` before the
        one at ``position``.
    """

    depth_path: Path
    mask_path: Path
    shapes: tuple[tuple[int, Shape], ...]
    image_size: tuple[int, int] | None
    part_path: str
    raw_mask_path: Path | None = None
    overlay_path: Path | None = None
    rgb_path: Path | None = None
    id_mask_path: Path | None = None
    propagated: frozenset[int] | None = None
    expected_planes: tuple[tuple[int, tuple[float, float, float, float]], ...] = ()
    carried: tuple = ()

    @property
    def outputs(self) -> list[Path]:
        """The files this job writes."""
        return [p for p in (self.mask_path, self.raw_mask_path, self.overlay_path, self.id_mask_path) if p is not None]

    @property
    def output_names(self) -> set[str]:
        """The files this job writes, relative to the output folder (``masks/<name>``, ...)."""
        return {relative_output(p) for p in self.outputs}


def relative_output(path: Path) -> str:
    """A per-frame output's path relative to the output folder: ``<folder>/<name>``."""
    return f"{path.parent.name}/{path.name}"


def up_to_date(job: FrameJob, made_from: str, recorded: MaskRecord | None) -> bool:
    """Whether the job's outputs are those recorded for the same inputs: the fingerprint
    matches and every output file still has the recorded bytes (a file rewritten since, by an
    interrupted run with other settings or by hand, is made anew)."""
    if recorded is None or recorded.fingerprint != made_from:
        return False
    digests = dict(recorded.outputs)
    return all(digests.get(relative_output(p)) is not None and file_digest(p) == digests[relative_output(p)]
               for p in job.outputs)


@dataclass(frozen=True)
class FrameTask:
    """A frame job with what it needs to run in any process (one picklable argument).

    Parameters
    ----------
    job : FrameJob
    config : Config
    colours : ndarray of uint8, shape (n_planes, 3)
        The plane palette.
    recorded : MaskRecord or None
        What was recorded when the frame's outputs were last written (None: make them in any
        case).
    """

    job: FrameJob
    config: Config
    colours: np.ndarray
    recorded: MaskRecord | None = None


@dataclass(frozen=True)
class FrameOutcome:
    """What :func:`run_frame_job` did.

    Parameters
    ----------
    fingerprint : str
        Of the frame's inputs (:func:`annotate_rgbd.pipeline.resume.fingerprint`).
    made : MaskRecord or None
        The planes of the mask just made; None when the outputs were up to date and reused
        (their recorded planes stand).
    rgb_problem : InputError, optional
        The frame's RGB image could not be read for its overlay (drawn on grey instead).
    """

    fingerprint: str
    made: MaskRecord | None = None
    rgb_problem: InputError | None = None

    @property
    def reused(self) -> bool:
        """Whether nothing was written (the recorded outputs are up to date)."""
        return self.made is None


def segment_job(job: FrameJob, config: Config, depth_file: np.ndarray | None = None) -> FrameResult:
    """Read the job's depth frame, check its size against the annotation, and segment it.

    Parameters
    ----------
    job : FrameJob
    config : Config
    depth_file : ndarray of uint8, optional
        The depth image file's bytes, when already read.

    Raises
    ------
    InputError
        The depth image is unreadable; :class:`SizeMismatch` when its size differs from the
        annotated image.
    """
    depth_raw = read_depth(job.depth_path, depth_file)
    check_size(job, depth_raw.shape, config.colour_camera)
    expected = {plane: np.array(equation) for plane, equation in job.expected_planes}
    return segment_frame(depth_raw, job.shapes, config, job.propagated or (), expected, job.carried)


def check_size(job: FrameJob, shape: tuple[int, ...], colour: ColourCamera | None = None) -> None:
    """Raise :class:`SizeMismatch` when a depth image of ``shape`` (rows, columns) -- or the
    configured colour camera's images, when there is one -- does not have the size of the images
    the job's annotation part was drawn on."""
    if colour is not None:
        if job.image_size is not None and job.image_size != (colour.width, colour.height):
            raise SizeMismatch(
                job.depth_path,
                f"[colour_camera] images are {colour.width}x{colour.height} but {Path(job.part_path).name} "
                f"annotates {job.image_size[0]}x{job.image_size[1]} images",
            )
        return
    if job.image_size is not None and tuple(shape[:2]) != (job.image_size[1], job.image_size[0]):
        raise SizeMismatch(
            job.depth_path,
            f"depth image is {shape[1]}x{shape[0]} but {Path(job.part_path).name} "
            f"annotates {job.image_size[0]}x{job.image_size[1]} images",
        )


def run_frame_job(task: FrameTask) -> FrameOutcome:
    """Make one frame's mask (and raw mask and overlay, if wanted), unless it is up to date.

    Parameters
    ----------
    task : FrameTask

    Returns
    -------
    FrameOutcome

    Raises
    ------
    InputError
        The depth image is unreadable (the frame is skipped) or its size differs from the
        annotated image (fatal).
    """
    job, colours = task.job, task.colours
    depth_file = read_bytes(job.depth_path)
    made_from = fingerprint(job.shapes, job.image_size, task.config, depth_file, job.propagated, job.expected_planes,
                            job.carried)
    if up_to_date(job, made_from, task.recorded):
        return FrameOutcome(made_from)
    result = segment_job(job, task.config, depth_file)
    if job.propagated is not None:
        result.kept = [replace(r, propagated=r.plane in job.propagated) for r in result.kept]
        result.dropped = [replace(r, propagated=r.plane in job.propagated) for r in result.dropped]
    written, rgb_problem, unfinished = {}, None, set()
    if job.raw_mask_path is not None:
        written[job.raw_mask_path] = write_png(job.raw_mask_path, colourize(result.drawn, colours))
    if job.id_mask_path is not None:
        written[job.id_mask_path] = write_png(job.id_mask_path, id_image(result.labels, len(colours)))
    if job.overlay_path is not None:
        from annotate_rgbd.review.overlay import overlay_for_frame  # only when overlays are wanted (SciPy is slow to import)

        overlay, rgb_problem = overlay_for_frame(job.rgb_path, result, colours)
        written[job.overlay_path] = write_png(job.overlay_path, overlay)
        if rgb_problem is not None:  # recorded without a digest: the next run draws it again
            unfinished.add(job.overlay_path)
    # The mask last: a frame whose mask exists has all its outputs.
    written[job.mask_path] = write_png(job.mask_path, colourize(result.labels, colours))
    outputs = tuple(sorted((relative_output(p), "" if p in unfinished else data_digest(data))
                           for p, data in written.items()))
    return FrameOutcome(made_from, MaskRecord(made_from, tuple(result.kept), tuple(result.dropped), outputs), rgb_problem)


class SizeMismatch(InputError):
    """A depth image does not have the size of the annotated images: fatal for the run."""

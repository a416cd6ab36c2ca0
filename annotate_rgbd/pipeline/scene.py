"""The ``cvat2mask`` job: CVAT export(s) + RGB-D sequence -> refined plane masks and a report.

:func:`run_cvat2mask` plans the run (:mod:`annotate_rgbd.pipeline.plan`: inputs read, parts placed,
tracks given their global planes, one frame job per depth frame that gets a mask), makes the
masks (:mod:`annotate_rgbd.pipeline.execute`) and finishes the output folder
(:func:`annotate_rgbd.pipeline.finish.finish_scene`: tables, report, stale files removed). It is
the one-scene case of :func:`annotate_rgbd.pipeline.batch.run_batch`.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Callable, Mapping, Sequence as SequenceType

from annotate_rgbd.config.settings import Config
from .batch import run_batch
from .execute import STALL_TIMEOUT, SceneResult
from .manifest import SceneSpec

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
    warnings: SequenceType[str] = (),
) -> SceneResult:
    """Run the whole job: ``masks/``, ``planes.csv``, ``tracks.csv`` and ``report.json`` in ``out_dir``.

    A re-run in the same ``out_dir`` redoes only the frames whose inputs changed
    (:mod:`annotate_rgbd.pipeline.resume`); masks of frames that no longer get one are removed.

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
        Also write ``overlays/``: the review overlays (:mod:`annotate_rgbd.review.overlay`), then
        ``review.html`` and ``contact_sheet.png`` (``review_page`` of the returned run).
    progress : callable, optional
        Called as ``progress(done, total)`` after each frame that gets a mask.
    job_timeout : float
        Seconds without a frame finished by the helper processes before they are taken to hang
        and replaced (:func:`annotate_rgbd.pool.run_jobs`).
    poses : str or Path, optional
        A camera trajectory (TUM, KITTI rows, a folder of pose files: :mod:`annotate_rgbd.io.poses`)
        that carries the keyframe shapes to every frame (:mod:`annotate_rgbd.propagate.carry`); default:
        the configuration's ``sequence.poses``, else the sequence layout's own poses (ScanNet, 7-Scenes).
    instance_ids : bool
        Also write ``masks_id/``: single-channel masks whose pixel values are the plane ids of
        ``planes.csv`` (8-bit for up to 255 planes, else 16-bit; 0 = no plane).
    warnings : sequence of str
        Warnings of what came before the run (e.g. loading ``config``:
        :func:`annotate_rgbd.logs.collect_warnings`), for the report's ``warnings``.

    Returns
    -------
    SceneResult
        The finished run: its frame records (``frames``), planes, counts and warnings.

    Raises
    ------
    InputError
        A fatal problem with an input (missing files, malformed export, parts that cannot be
        placed, sizes that do not match): nothing sensible can be produced.
    """
    spec = SceneSpec(Path(sequence_dir).name, Path(sequence_dir), tuple(Path(p) for p in annotation_paths),
                     Path(out_dir), config, dict(offsets or {}), {}, raw_masks, overlays, instance_ids,
                     None if poses is None else Path(poses), tuple(warnings))
    (outcome,) = run_batch([spec], workers, force, (lambda _name: progress) if progress else None, job_timeout,
                           scene_names=False)
    if outcome.exception is not None:
        raise outcome.exception
    return outcome

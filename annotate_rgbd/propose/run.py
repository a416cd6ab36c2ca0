"""``propose``: plane proposals for a whole sequence — frame jobs in parallel, linking in frame
order, then the outputs."""

from __future__ import annotations

import json
import logging
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from annotate_rgbd import __version__
from annotate_rgbd.annotation.model import PLANE_ID, Shape
from annotate_rgbd.config.settings import Config, config_to_dict
from annotate_rgbd.config.masks import FilterConfig
from annotate_rgbd.errors import InputError
from annotate_rgbd.geometry.depth_range import depth_scale_hint, median_raw_depth
from annotate_rgbd.geometry.lift import plane_to_world
from annotate_rgbd.pool import default_workers, run_jobs, start_helpers
from annotate_rgbd.io.poses import load_trajectory, poses_of_frames
from annotate_rgbd.io.association_checks import unmatched_frames
from annotate_rgbd.io.sequence import associate, intrinsics_problems, read_depth, read_sequence
from annotate_rgbd.io.cleanup import read_review_record, remove_review_files, remove_stale_files
from annotate_rgbd.io.outdir import MASKS, OVERLAYS, UNFINISHED, OutputFolder, check_outside_sequence, read_bounded
from annotate_rgbd.io.layouts.tum import TRAJECTORY as TUM_TRAJECTORY
from annotate_rgbd.io.writer import write_bytes_atomic, write_json
from annotate_rgbd.logs import counted, group_problems
from annotate_rgbd.report.run_folder import write_drawn_shapes
from annotate_rgbd.report.stats import dropped_hint
from .detect_job import DetectJob, FrameProposal, FrameTooSmall, keep_planes, propose_frame
from .link import TrackLinker
from .persist import PersistenceFilter
from .output import TrackShapes, equation_text, track_colour, write_colour_mask, write_polygon_tracks
from .output import colour_image_polygons

log = logging.getLogger("annotate_rgbd")

#: What helper processes import before their first job.
DETECT_JOB_MODULE = "annotate_rgbd.propose.detect_job"
PROPOSALS_NAME = "proposals.xml"
MASKS_DIR = MASKS
REPORT_NAME = "report.json"
#: Depth frames whose depth range is checked against the configured scale before any work.
FIRST_FRAMES = 3


@dataclass
class ProposeResult:
    """What :func:`run_propose` did.

    Attributes
    ----------
    frames : int
        Depth frames processed (masks written).
    tracks : int
        Tracks (planes) proposed.
    skipped : list of str
        Depth frames not processed, with why.
    warnings : list of str
        Problems with the whole sequence (a depth scale that does not fit, the warnings of loading
        the configuration given to :func:`run_propose`), one line each.
    failed : list of str
        Frames whose job failed, with the error.
    proposed : int
        Planes proposed, over all frames.
    dropped : dict of str to int
        Planes detected and not proposed, by reason (``report.json``'s per-frame ``dropped``).
    """

    frames: int = 0
    tracks: int = 0
    skipped: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    proposed: int = 0
    dropped: dict[str, int] = field(default_factory=dict)

    def summary(self, out_dir: Path) -> str:
        """The command's summary line: tracks, frames, files, and the planes not proposed by reason."""
        reasons = ", ".join(f"{n} {reason}" for reason, n in sorted(self.dropped.items(), key=lambda r: (-r[1], r[0])))
        return (f"{counted(self.tracks, 'plane track')} on {counted(self.frames, 'frame')}: {out_dir / PROPOSALS_NAME}, "
                f"{out_dir / MASKS_DIR}, {out_dir / REPORT_NAME}; {counted(self.proposed, 'plane')} proposed on frames, "
                f"{sum(self.dropped.values())} not" + (f" ({reasons})" if reasons else ""))

    def drop_hint(self, depth_scale: float, drop_rules: FilterConfig | None = None) -> str | None:
        """:func:`annotate_rgbd.report.stats.dropped_hint` of the detected planes, for a reason
        with a likely cause only (small and flickering detections are dropped by design);
        ``drop_rules``: the run's ``[filter]`` section."""
        return dropped_hint(self.dropped, self.proposed + sum(self.dropped.values()), depth_scale, "detected planes",
                            known_only=True, drop_rules=drop_rules)


def run_propose(
    sequence_dir: str | Path,
    out_dir: str | Path,
    config: Config = Config(),
    poses: str | Path | None = None,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    warnings: Sequence[str] = (),
) -> ProposeResult:
    """Propose planes on a sequence's depth frames and write ``proposals.xml``, ``masks/``,
    ``report.json`` and the record of every mask's polygons (which ``review`` draws) into ``out_dir``.

    Parameters
    ----------
    sequence_dir : str or Path
        A sequence folder in any layout :func:`~annotate_rgbd.io.sequence.read_sequence` knows,
        depth-only folders too (their frames are the depth frames; ``rgb`` is null in the report).
    out_dir : str or Path
    config : Config
        Camera, ``[sequence]`` (RGB association), ``[filter]`` (drop rules), ``[noise]``, and
        ``propose``'s own ``[detect]``, ``[propose]`` (every N-th frame, label...) and ``[link]``.
    poses : str or Path, optional
        A trajectory (TUM, KITTI, a folder of pose files): link tracks by world plane. Default:
        the layout's own poses (ScanNet, 7-Scenes), if any.
    workers : int, optional
        Processes in all (default: every core).
    progress : callable, optional
        ``progress(done, total)`` after each frame.
    warnings : sequence of str
        Warnings of what came before the run (e.g. loading ``config``:
        :func:`annotate_rgbd.logs.collect_warnings`), for the report's ``warnings``.

    Returns
    -------
    ProposeResult

    Raises
    ------
    InputError
        Unreadable sequence or trajectory, no frame to process; OutputError when ``out_dir``
        cannot be written, is busy, holds links where ``propose`` writes, or holds the output
        of ``cvat2mask`` (:class:`annotate_rgbd.io.outdir.OutputFolder`).
    """
    sequence = read_sequence(sequence_dir, need_rgb=False)
    out_dir = Path(out_dir)
    check_outside_sequence(out_dir, sequence)
    workers = workers or default_workers()
    # A refused output folder first (its error the only line); then, before the folder is made, the
    # inputs: no frame to process, or a trajectory that cannot be used, writes nothing.
    OutputFolder(out_dir, "propose").check()
    association = _associate(sequence, config)
    result = ProposeResult(warnings=list(warnings))
    frames = _frames_and_poses(sequence, association, config, poses, result)
    with OutputFolder(out_dir, "propose") as folder:
        helpers = start_helpers(workers, [DETECT_JOB_MODULE])
        try:
            return _run(sequence, association, folder, config, frames, helpers, progress, result)
        finally:
            if helpers is not None:
                helpers.shutdown()


def _associate(sequence, config) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each depth frame's nearest RGB frame, its time difference and whether it is close enough
    (:func:`annotate_rgbd.io.sequence.associate`; a depth-only sequence's frames are their own)."""
    depth_times = sequence.depth.timestamps
    if sequence.rgb is None:  # depth only: the depth frames are the frames
        count = len(depth_times)
        return np.arange(count), np.zeros(count), np.ones(count, bool)
    return associate(depth_times, sequence.rgb.timestamps, config.sequence.max_time_diff)


def _frames_and_poses(sequence, association, config: Config, poses_path, result: ProposeResult):
    """The depth frames to process (``--every``'s picks that have an RGB frame; the others go to
    ``result.skipped``, in one warning), the trajectory and those frames' poses (None without
    one): ``(chosen, poses_path, frame_poses)``. The camera's and the trajectory's warnings go to
    ``result``.

    Raises
    ------
    InputError
        No pick has an RGB frame; an unreadable trajectory, or one that gives no processed frame a
        pose.
    """
    depth_times = sequence.depth.timestamps
    _, time_diff, matched = association
    every = config.propose.every
    chosen = np.arange(0, len(depth_times), every)
    # The picks without an RGB frame: one warning; all of them: an error.
    picked = "" if every == 1 else f"of the {len(chosen)} that --every {every} picks"
    for line in unmatched_frames(sequence.root, sequence.depth.files, time_diff, matched,
                                 config.sequence.max_time_diff, chosen, picked):
        log.warning("%s", line)
    for i in chosen[~matched[chosen]]:
        result.skipped.append(f"{sequence.depth.files[i]}: no RGB frame within {config.sequence.max_time_diff} s")
    chosen = chosen[matched[chosen]]
    for hint in _camera_hints(sequence, chosen, config):
        result.warnings.append(hint)
        log.warning("%s", hint)
    frame_poses = None
    if poses_path is None and sequence.poses is not None:
        poses_path = sequence.poses
        log.info("poses: the %s layout's per-frame camera-to-world poses (%s); give --poses for another trajectory",
                 sequence.layout, poses_path)
    if poses_path is not None:
        # The trajectory's clock offset, when known, as cvat2mask reads it (propose does not estimate it).
        times = depth_times[chosen] + config.propagate.time_offset
        frame_poses = _frame_poses(poses_path, sequence, times, config, result.warnings)
    elif (sequence.root / TUM_TRAJECTORY).is_file():  # the layout's own trajectory, not read unasked
        log.info("%s: a camera trajectory beside the frames; give it as --poses to link each plane across frames "
                 "by its place in the room (without, by image overlap: tracks can join different planes when the "
                 "camera moves far between processed frames)", sequence.root / TUM_TRAJECTORY)
    return chosen, poses_path, frame_poses


def _run(sequence, association, folder: OutputFolder, config, frames_and_poses, helpers, progress,
         result: ProposeResult) -> ProposeResult:
    out_dir = folder.path
    settings = config.propose
    depth_times = sequence.depth.timestamps
    nearest, time_diff, _ = association
    chosen, poses_path, frame_poses = frames_and_poses
    # Two depth frames may share their nearest RGB frame; its CVAT keyframe takes the nearer one.
    key_of_rgb: dict[int, int] = {}
    for position, i in enumerate(chosen.tolist()):
        rgb = int(nearest[i])
        if rgb not in key_of_rgb or abs(time_diff[i]) < abs(time_diff[chosen[key_of_rgb[rgb]]]):
            key_of_rgb[rgb] = position
    ours = folder.expected | _masks_of_report(out_dir)  # what earlier runs here wrote
    folder.expect(f"{MASKS_DIR}/{Path(sequence.depth.files[i]).name}" for i in chosen.tolist())
    # Until the report is written, the folder's masks may be this run's and an earlier one's: the
    # readers refuse it (annotate_rgbd.report.run_folder.check_finished).
    write_bytes_atomic(out_dir / UNFINISHED, b"propose\n")
    (out_dir / MASKS_DIR).mkdir(exist_ok=True)

    jobs = [
        DetectJob(position, sequence.root / sequence.depth.files[i], config.camera, config.detect, settings, config.noise,
                  config.filter, config.ransac, config.refine)
        for position, i in enumerate(chosen.tolist())
    ]
    linker = TrackLinker(config.link, config.noise, config.camera)
    # A track must be found on min_track_frames processed frames (fewer when fewer are processed).
    # ... and be large somewhere: its surface (m2) and its share of the image.
    persistence = PersistenceFilter(min(settings.min_track_frames, len(chosen)), config.link.max_gap,
                                    (settings.min_surface_m2, settings.min_track_share),
                                    ("small_surface", "small_in_view"))
    tracks: dict[int, TrackShapes] = {}
    best: dict[int, tuple[int, np.ndarray, str]] = {}  # track -> (area, equation, frame) for the attribute
    frames: list[dict] = []
    drawn: list[tuple[str, list, list]] = []  # each written mask's polygons (nothing carried), for review
    waiting: dict[int, FrameProposal | InputError] = {}
    size = None
    problems: list[tuple[str, str, str]] = []  # (depth file, problem, outcome): said once per problem
    first_size = None  # the exports hold frames of one size, the first linked frame's

    def emit(decided) -> None:
        """Record and write a frame whose tracks' fates are known (frames come in order)."""
        nonlocal size
        record, item, pose, i = decided.payload
        if isinstance(item, FrameTooSmall):
            frames.append({**record, "status": "skipped", "reason": "frame_size", "error": item.message})
            return
        if isinstance(item, InputError):
            frames.append({**record, "status": "failed", "error": str(item)})
            return
        item = keep_planes(item, decided.keep, decided.reasons)
        ids = decided.ids[decided.keep]
        size = item.labels.shape
        mask_name = Path(sequence.depth.files[i]).name
        write_colour_mask(out_dir / MASKS_DIR / mask_name, item.labels, ids)
        drawn.append((f"{MASKS_DIR}/{mask_name}", [(int(t), Shape("polygon", item.outlines[k], z_order=int(item.z_order[k])))
                                                    for k, t in enumerate(ids.tolist())], []))
        keyframe = key_of_rgb[int(nearest[i])] == decided.position
        frames.append({**record, "status": "written", "mask": f"{MASKS_DIR}/{mask_name}",
                       "cvat_keyframe": keyframe, "planes": _plane_records(item, ids), "dropped": item.dropped})
        _collect(_on_colour_image(item, config) if keyframe else item, ids, int(nearest[i]), keyframe, pose,
                 settings.label, tracks, best)
        result.frames += 1

    following = 0
    for outcome in run_jobs(jobs, propose_frame, helpers):
        waiting[outcome.index] = outcome.value if outcome.error is None else outcome.error
        while following in waiting:  # link in frame order
            item = waiting.pop(following)
            i = int(chosen[following])
            record = {"depth": sequence.depth.files[i], "depth_timestamp": float(depth_times[i]),
                      "rgb": None if sequence.rgb is None else sequence.rgb.files[int(nearest[i])],
                      "rgb_index": int(nearest[i]),
                      "time_offset": float(time_diff[i])}
            pose, found, sizes = None, np.zeros(0, dtype=np.int64), None
            if not isinstance(item, InputError) and first_size is not None and item.labels.shape != first_size:
                item = FrameTooSmall(
                    jobs[following].depth_path,
                    f"depth image is {item.labels.shape[1]} x {item.labels.shape[0]} pixels, not "
                    f"{first_size[1]} x {first_size[0]} as the first processed frame",
                )
            if isinstance(item, FrameTooSmall):
                result.skipped.append(f"{sequence.depth.files[i]}: {item.message}")
                problems.append((str(item.path), item.message, "skipped"))
            elif isinstance(item, InputError):
                result.failed.append(f"{sequence.depth.files[i]}: {item}")
                problems.append((str(item.path or jobs[following].depth_path), item.message, "failed"))
            else:
                if frame_poses is not None and frame_poses.ok[following]:
                    pose = (frame_poses.rotations[following], frame_poses.translations[following])
                first_size = item.labels.shape if first_size is None else first_size
                share = item.areas / float(item.labels.size)
                found, sizes = linker.add(item, float(depth_times[i]), pose), np.column_stack([item.surfaces, share])
            for decided in persistence.add(following, found, (record, item, pose, i), sizes):
                emit(decided)
            following += 1
            if progress is not None:
                progress(following, len(jobs))
    for decided in persistence.finish():
        emit(decided)
    if result.frames == 0:
        lines = group_problems((file, problem) for file, problem, _ in problems)
        more = f" (and {counted(len(lines) - 1, 'other problem')})" if len(lines) > 1 else ""
        raise InputError(None, f"no depth frame can be used: {lines[0]}{more}")
    for line in group_problems((file, f"{problem}; {outcome}") for file, problem, outcome in problems):
        log.warning("%s", line)
    for track, (_, equation, where) in best.items():
        tracks[track].attributes = {PLANE_ID: str(track), "equation": equation_text(equation), "equation_frame": where}
    ordered = [tracks[t] for t in sorted(tracks)]
    height, width = size if size is not None else (0, 0)
    if config.colour_camera is not None:  # the polygons lie on the colour images, which CVAT shows
        width, height = config.colour_camera.width, config.colour_camera.height
    sampled = sorted(rgb for rgb, position in key_of_rgb.items() if frames[position]["status"] == "written")
    if sampled:
        n_frames = len(sequence.depth if sequence.rgb is None else sequence.rgb)
        write_polygon_tracks(ordered, out_dir / PROPOSALS_NAME, n_frames=n_frames,
                             sampled_frames=sampled, width=width, height=height)
    result.tracks = len(ordered)
    written = {f["mask"] for f in frames if f["status"] == "written"}
    drawn_by_review = [f"{OVERLAYS}/{name}" for name in read_review_record(out_dir).overlays]
    cleanup = remove_stale_files(out_dir, ours | folder.expected, written, drawn_by_review)
    remove_review_files(out_dir, cleanup)  # an earlier review shows the earlier proposals
    for line in cleanup.removals():
        log.info(line)
    for line in cleanup.warnings():
        log.warning(line)
    if not sampled:
        (out_dir / PROPOSALS_NAME).unlink(missing_ok=True)  # an earlier run's: it shows none of these frames
    write_drawn_shapes(out_dir, drawn)  # what review draws
    result.proposed = sum(len(f.get("planes", ())) for f in frames)
    result.dropped = dict(Counter(d["reason"] for f in frames for d in f.get("dropped", ())))
    write_json(out_dir / REPORT_NAME, {
        "tool": "annotate-rgbd propose", "version": __version__,
        # Absolute, as cvat2mask's: review and the next step's command read them from anywhere.
        "inputs": {"sequence": str(Path(sequence.root).absolute()),
                   "poses": None if poses_path is None else str(Path(poses_path).absolute()),
                   "every": settings.every, "label": settings.label,
                   "min_area_fraction": config.detect.min_area_fraction,
                   "min_track_frames": settings.min_track_frames, "min_surface_m2": settings.min_surface_m2,
                   "min_track_share": settings.min_track_share},
        "config": config_to_dict(config, leave_out=("evaluate",)),
        "summary": {"frames_processed": result.frames, "frames_skipped": len(result.skipped),
                    "frames_failed": len(result.failed), "tracks": result.tracks,
                    "planes_proposed": result.proposed, "planes_dropped": sum(result.dropped.values()),
                    "polygons": polygon_summary(frames, settings.max_vertices)},
        "tracks": [{"track": t.track, "colour": track_colour(t.track), "label": t.label,
                    "cvat_frames": len(t.shapes), **{k: v for k, v in t.attributes.items() if k != PLANE_ID}}
                   for t in ordered],
        "frames": frames,
        "skipped": result.skipped,
        "warnings": result.warnings,
    })
    (out_dir / UNFINISHED).unlink()
    folder.settle(written)
    return result


def _masks_of_report(out_dir: Path) -> set[str]:
    """The masks an earlier ``propose`` run's report says it wrote (runs made before the
    output folder kept its own record)."""
    try:
        report = json.loads(read_bounded(out_dir / REPORT_NAME, 1 << 30))
        frames = report.get("frames", []) if isinstance(report, dict) else []
        return {f["mask"] for f in frames if isinstance(f, dict) and isinstance(f.get("mask"), str)}
    except (OSError, ValueError, RecursionError, AttributeError):
        return set()


def _camera_hints(sequence, chosen: np.ndarray, config: Config) -> list[str]:
    """Warnings about the camera from the first processed frames: intrinsics that do not fit the
    first readable one, unless it is too small for the detector
    (:func:`annotate_rgbd.io.sequence.intrinsics_problems`), depth units
    (:func:`annotate_rgbd.geometry.depth_range.depth_scale_hint`)."""
    medians, hints, checked = [], [], False
    camera = config.camera
    for i in chosen[:FIRST_FRAMES].tolist():
        path = sequence.root / sequence.depth.files[i]
        try:
            depth = read_depth(path)
        except InputError:
            continue  # reported with its frame
        if not checked and min(depth.shape) >= config.detect.cell_px:  # a smaller frame is skipped, said so
            hints.extend(intrinsics_problems(camera, path, *depth.shape[::-1]))
            checked = True
        medians.append(median_raw_depth(depth))
    hint = depth_scale_hint(medians, camera.depth_scale)
    if hint is not None:
        hints.append(f"{sequence.root / Path(sequence.depth.files[0]).parent}: {hint}")
    return hints


def _frame_poses(path, sequence, times: np.ndarray, config: Config, warnings: list[str]):
    """The poses of the processed depth frames; a warning for an implausible trajectory and for
    frames without a pose (with the two time ranges when they lie outside it).

    Raises
    ------
    InputError
        No processed frame has a pose (the time ranges, and the likely unit or offset, said).
    """
    loaded = load_trajectory(path, sequence.depth.timestamps, sequence.clock)
    for note in loaded.notes:
        log.info("%s", note)
    for line in loaded.warnings:
        warnings.append(line)
        log.warning("%s", line)
    frame_poses, ranges = poses_of_frames(loaded.trajectory, path, times, config.sequence.max_pose_gap, sequence.clock,
                                          "processed depth frame")
    missing = int(np.count_nonzero(~frame_poses.ok))
    if missing:
        verb, pronoun = ("has", "it is") if missing == 1 else ("have", "they are")
        line = (f"{path}: {missing} of {len(times)} processed depth frames {verb} no pose; {pronoun} linked "
                f"without poses (camera-frame planes, image overlap){' (' + ranges + ')' if ranges else ''}")
        warnings.append(line)
        log.warning("%s", line)
    return frame_poses


def _plane_records(item: FrameProposal, ids: np.ndarray) -> list[dict]:
    return [
        {"track": int(ids[k]), "area": int(item.areas[k]), "equation": [float(v) for v in item.planes[k]],
         "mean_distance": float(item.mean_distance[k]), "z_order": int(item.z_order[k]),
         "vertices": len(item.outlines[k]), "polygon_pixels": int(item.polygon_pixels[k]),
         "polygon_iou": round(float(item.polygon_iou[k]), 6), "budget_iou_cost": _finite_or_none(item.budget_iou_cost[k])}
        for k in range(len(ids))
    ]


def _finite_or_none(value: float) -> float | None:
    return round(float(value), 6) if np.isfinite(value) else None


def polygon_summary(frames: list[dict], max_vertices: int) -> dict:
    """The polygons of the CVAT keyframes in numbers: how many, their vertices (median, largest),
    how many the vertex budget stopped, their mean IoU with their planes' pixels and the mean IoU
    the budget cost the polygons it stopped."""
    planes = [p for f in frames if f.get("status") == "written" and f.get("cvat_keyframe") for p in f["planes"]]
    vertices = [p["vertices"] for p in planes]
    limited = [p["budget_iou_cost"] for p in planes if p["budget_iou_cost"] is not None]
    return {"polygons": len(planes), "max_vertices": max_vertices,
            "median_vertices": float(np.median(vertices)) if planes else None,
            "largest_vertices": max(vertices, default=None),
            "at_budget": len(limited),
            "mean_polygon_iou": round(float(np.mean([p["polygon_iou"] for p in planes])), 6) if planes else None,
            "mean_budget_iou_cost": round(float(np.mean(limited)), 6) if limited else 0.0}


def _collect(item: FrameProposal, ids, rgb: int, keyframe: bool, pose, label: str, tracks, best) -> None:
    """Add a frame's polygons (when it is the CVAT keyframe of its RGB frame) and remember each
    track's largest detection, whose plane becomes the track's equation attribute."""
    for k, track in enumerate(ids.tolist()):
        entry = tracks.setdefault(track, TrackShapes(track, label))
        if keyframe and item.outlines[k] is not None:  # None: outside the colour image
            entry.shapes[rgb] = Shape("polygon", item.outlines[k], z_order=int(item.z_order[k]))
        area = int(item.areas[k])
        if track not in best or area > best[track][0]:
            if pose is not None:
                best[track] = (area, plane_to_world(item.planes[k], *pose), "world")
            else:
                best[track] = (area, item.planes[k], f"camera of RGB frame {rgb}")


def _on_colour_image(item: FrameProposal, config: Config) -> FrameProposal:
    """The proposal with its polygons on the image the labeller draws on: the colour image of
    ``[colour_camera]`` (None for a polygon outside it), as traced without one
    (:func:`annotate_rgbd.propose.output.colour_image_polygons`)."""
    if config.colour_camera is None:
        return item
    return replace(item, outlines=colour_image_polygons(item.outlines, item.planes, item.mean_distance, config))

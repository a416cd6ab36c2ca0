"""``propose``: plane proposals for a whole sequence — frame jobs in parallel, linking in frame
order, then the outputs."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from annotate_rgbd import __version__
from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.config.settings import Config, config_to_dict
from annotate_rgbd.errors import InputError
from annotate_rgbd.geometry.lift import plane_to_world
from annotate_rgbd.pool import default_workers, run_jobs, start_helpers
from annotate_rgbd.io.poses import poses_at, read_trajectory
from annotate_rgbd.io.sequence import associate, read_sequence
from annotate_rgbd.io.writer import prepare_output, write_json
from .detect_job import DetectJob, FrameProposal, keep_planes, propose_frame
from .link import TrackLinker
from .persist import PersistenceFilter
from .output import TrackShapes, equation_text, track_colour, write_colour_mask, write_polygon_tracks
from .settings import ProposeConfig

log = logging.getLogger("annotate_rgbd")

#: What helper processes import before their first job.
DETECT_JOB_MODULE = "annotate_rgbd.propose.detect_job"
PROPOSALS_NAME = "proposals.xml"
MASKS_DIR = "masks"
REPORT_NAME = "report.json"


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
    failed : list of str
        Frames whose job failed, with the error.
    """

    frames: int = 0
    tracks: int = 0
    skipped: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)


def run_propose(
    sequence_dir: str | Path,
    out_dir: str | Path,
    config: Config = Config(),
    settings: ProposeConfig = ProposeConfig(),
    poses: str | Path | None = None,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ProposeResult:
    """Propose planes on a sequence's depth frames and write ``proposals.xml``, ``masks/`` and
    ``report.json`` into ``out_dir``.

    Parameters
    ----------
    sequence_dir : str or Path
        TUM / ICL-NUIM sequence folder.
    out_dir : str or Path
    config : Config
        Camera, ``[sequence]`` (RGB association), ``[filter]`` (drop rules), ``[noise]``.
    settings : ProposeConfig
    poses : str or Path, optional
        TUM trajectory: link tracks by world plane.
    workers : int, optional
        Processes in all (default: every core).
    progress : callable, optional
        ``progress(done, total)`` after each frame.

    Returns
    -------
    ProposeResult

    Raises
    ------
    InputError
        Unreadable sequence or trajectory, no frame to process; OutputError when ``out_dir``
        cannot be written.
    """
    sequence = read_sequence(sequence_dir)
    out_dir = Path(out_dir)
    workers = workers or default_workers()
    helpers = start_helpers(workers, [DETECT_JOB_MODULE])
    try:
        return _run(sequence, out_dir, config, settings, poses, helpers, progress)
    finally:
        if helpers is not None:
            helpers.shutdown()


def _run(sequence, out_dir, config, settings, poses_path, helpers, progress) -> ProposeResult:
    result = ProposeResult()
    depth_times = sequence.depth.timestamps
    nearest, time_diff, matched = associate(depth_times, sequence.rgb.timestamps, config.sequence.max_time_diff)
    chosen = np.arange(0, len(depth_times), settings.every)
    for i in chosen[~matched[chosen]]:
        result.skipped.append(f"{sequence.depth.files[i]}: no RGB frame within {config.sequence.max_time_diff} s")
        log.warning("%s: no RGB frame within %g s; skipped", sequence.depth.files[i], config.sequence.max_time_diff)
    chosen = chosen[matched[chosen]]
    if len(chosen) == 0:
        raise InputError(sequence.root, "no depth frame has an RGB frame within max_time_diff: nothing to propose")
    frame_poses = None
    if poses_path is not None:
        frame_poses = poses_at(read_trajectory(poses_path), depth_times[chosen])
        if not frame_poses.ok.any():
            raise InputError(poses_path, "no processed depth frame lies within the trajectory")
    # Two depth frames may share their nearest RGB frame; its CVAT keyframe takes the nearer one.
    key_of_rgb: dict[int, int] = {}
    for position, i in enumerate(chosen.tolist()):
        rgb = int(nearest[i])
        if rgb not in key_of_rgb or abs(time_diff[i]) < abs(time_diff[chosen[key_of_rgb[rgb]]]):
            key_of_rgb[rgb] = position
    prepare_output(out_dir)
    (out_dir / MASKS_DIR).mkdir(exist_ok=True)

    jobs = [
        DetectJob(position, sequence.root / sequence.depth.files[i], config.camera, settings, config.noise, config.filter)
        for position, i in enumerate(chosen.tolist())
    ]
    linker = TrackLinker(settings.link, config.noise, config.camera)
    # A track must be found on min_track_frames processed frames (fewer when fewer are processed).
    persistence = PersistenceFilter(min(settings.min_track_frames, len(chosen)), settings.link.max_gap,
                                    settings.min_surface_m2)
    tracks: dict[int, TrackShapes] = {}
    best: dict[int, tuple[int, np.ndarray, str]] = {}  # track -> (area, equation, frame) for the attribute
    frames: list[dict] = []
    waiting: dict[int, FrameProposal | InputError] = {}
    size = None

    def emit(decided) -> None:
        """Write a frame whose tracks' fates are known (frames come in order)."""
        nonlocal size
        record, item, pose, i = decided.payload
        if isinstance(item, InputError):
            frames.append({**record, "status": "failed", "error": str(item)})
            return
        item = keep_planes(item, decided.keep, decided.reasons)
        ids = decided.ids[decided.keep]
        size = item.labels.shape
        mask_name = Path(sequence.depth.files[i]).name
        write_colour_mask(out_dir / MASKS_DIR / mask_name, item.labels, ids)
        keyframe = key_of_rgb[int(nearest[i])] == decided.position
        frames.append({**record, "status": "written", "mask": f"{MASKS_DIR}/{mask_name}",
                       "cvat_keyframe": keyframe, "planes": _plane_records(item, ids), "dropped": item.dropped})
        _collect(item, ids, int(nearest[i]), keyframe, pose, settings.label, tracks, best)
        result.frames += 1

    following = 0
    for outcome in run_jobs(jobs, propose_frame, helpers):
        waiting[outcome.index] = outcome.value if outcome.error is None else outcome.error
        while following in waiting:  # link in frame order
            item = waiting.pop(following)
            i = int(chosen[following])
            record = {"depth": sequence.depth.files[i], "depth_timestamp": float(depth_times[i]),
                      "rgb": sequence.rgb.files[int(nearest[i])], "rgb_index": int(nearest[i]),
                      "time_offset": float(time_diff[i])}
            pose, found, sizes = None, np.zeros(0, dtype=np.int64), None
            if isinstance(item, InputError):
                result.failed.append(f"{sequence.depth.files[i]}: {item}")
                log.warning("%s", item)
            else:
                if frame_poses is not None and frame_poses.ok[following]:
                    pose = (frame_poses.rotations[following], frame_poses.translations[following])
                found, sizes = linker.add(item, float(depth_times[i]), pose), item.surfaces
            for decided in persistence.add(following, found, (record, item, pose, i), sizes):
                emit(decided)
            following += 1
            if progress is not None:
                progress(following, len(jobs))
    for decided in persistence.finish():
        emit(decided)
    for track, (_, equation, where) in best.items():
        tracks[track].attributes = {"equation": equation_text(equation), "equation_frame": where}
    ordered = [tracks[t] for t in sorted(tracks)]
    height, width = size if size is not None else (0, 0)
    sampled = sorted(rgb for rgb, position in key_of_rgb.items() if frames[position]["status"] == "written")
    if sampled:
        write_polygon_tracks(ordered, out_dir / PROPOSALS_NAME, n_frames=len(sequence.rgb),
                             sampled_frames=sampled, width=width, height=height)
    result.tracks = len(ordered)
    write_json(out_dir / REPORT_NAME, {
        "tool": "annotate-rgbd propose", "version": __version__,
        "inputs": {"sequence": str(sequence.root), "poses": None if poses_path is None else str(poses_path),
                   "every": settings.every, "label": settings.label,
                   "min_area_fraction": settings.detector.min_area_fraction,
                   "min_track_frames": settings.min_track_frames, "min_surface_m2": settings.min_surface_m2},
        "config": config_to_dict(config),
        "summary": {"frames_processed": result.frames, "frames_skipped": len(result.skipped),
                    "frames_failed": len(result.failed), "tracks": result.tracks,
                    "planes_proposed": sum(len(f.get("planes", ())) for f in frames),
                    "planes_dropped": sum(len(f.get("dropped", ())) for f in frames)},
        "tracks": [{"track": t.track, "colour": track_colour(t.track), "label": t.label,
                    "cvat_frames": len(t.shapes), **t.attributes} for t in ordered],
        "frames": frames,
        "skipped": result.skipped,
    })
    return result


def _plane_records(item: FrameProposal, ids: np.ndarray) -> list[dict]:
    return [
        {"track": int(ids[k]), "area": int(item.areas[k]), "equation": [float(v) for v in item.planes[k]],
         "mean_distance": float(item.mean_distance[k]), "z_order": int(item.z_order[k])}
        for k in range(len(ids))
    ]


def _collect(item: FrameProposal, ids, rgb: int, keyframe: bool, pose, label: str, tracks, best) -> None:
    """Add a frame's polygons (when it is the CVAT keyframe of its RGB frame) and remember each
    track's largest detection, whose plane becomes the track's equation attribute."""
    for k, track in enumerate(ids.tolist()):
        entry = tracks.setdefault(track, TrackShapes(track, label))
        if keyframe:
            entry.shapes[rgb] = Shape("polygon", item.outlines[k], z_order=int(item.z_order[k]))
        area = int(item.areas[k])
        if track not in best or area > best[track][0]:
            if pose is not None:
                best[track] = (area, plane_to_world(item.planes[k], *pose), "world")
            else:
                best[track] = (area, item.planes[k], f"camera of RGB frame {rgb}")

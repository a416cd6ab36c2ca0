"""Planning propagation: what the camera poses give a run, before any mask is made.

:func:`plan_propagation` reads the trajectory, fits every track's keyframe planes on their depth
frames (:mod:`annotate_rgbd.propagate.keyframes`), estimates the trajectory's time offset from
them (:mod:`annotate_rgbd.propagate.timing`), gives every depth frame its pose, aligns the poses
to the keyframes' depth (:mod:`annotate_rgbd.propagate.align`) and lifts the keyframes onto
their planes (:mod:`annotate_rgbd.propagate.lift`); :func:`propagation_warnings`
says what the run should be warned of. :func:`annotate_rgbd.pipeline.plan.plan_run` calls both,
and its frame planning carries the lifted keyframes to every frame.
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence as SequenceType

import numpy as np

from annotate_rgbd.config.settings import Config
from annotate_rgbd.annotation.parts import Part
from annotate_rgbd.io.layouts.model import SECONDS
from annotate_rgbd.io.rotations import matrix_quaternions
from annotate_rgbd.io.poses import FramePoses, Trajectory, load_trajectory, missing_poses_text, poses_at, poses_of_frames
from annotate_rgbd.propagate.align import Alignment, align_frames
from annotate_rgbd.propagate.keyframes import NO_DEPTH_FRAME, fit_keyframes, keyframe_depths, time_samples
from annotate_rgbd.propagate.lift import TrackLift, lift_tracks
from annotate_rgbd.propagate.timing import TimeOffset, estimate_time_offset
from annotate_rgbd.pool import HelperPool
from annotate_rgbd.io.sequence import Sequence
from annotate_rgbd.annotation.stitch import TrackPlane

log = logging.getLogger("annotate_rgbd")

#: The end of the warnings about frames whose poses the alignment did not correct.
CHECK_POSES = ("the trajectory's poses are kept there; check the trajectory and the masks of those frames "
               "(report.json: propagation.alignment.{listed})")


@dataclass
class Propagation:
    """What the camera poses give a run (:mod:`annotate_rgbd.propagate.carry`).

    Parameters
    ----------
    path : str
        The trajectory (a file, or a folder of pose files).
    lifts : dict of (str, int) to TrackLift
        (part, track id) -> its keyframes lifted onto their planes.
    depth_poses : FramePoses
        The pose of every depth frame (``ok`` False where the trajectory has none).
    trajectory : Trajectory, optional
        The poses read, on the sequence's clock.
    clock : str
        What the sequence's timestamps count.
    depth_times : ndarray, optional
        The depth frames' timestamps (for the time ranges of frames without a pose).
    warnings : list of str
        What reading the trajectory found implausible.
    time_offset : float
        Seconds added to the depth timestamps to read the trajectory (configured plus estimated).
    estimate : TimeOffset, optional
        What the estimate of the offset found.
    alignment : Alignment
        What aligning the frames' poses to the keyframes' depth did.
    """

    path: str
    lifts: dict[tuple[str, int], TrackLift]
    depth_poses: FramePoses
    trajectory: Trajectory | None = None
    clock: str = "seconds"
    depth_times: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)
    time_offset: float = 0.0
    estimate: TimeOffset | None = None
    alignment: Alignment = field(default_factory=Alignment)

    def camera_pose(self, frame: int) -> tuple[float, ...] | None:
        """Depth frame ``frame``'s pose as a TUM trajectory line holds it, ``(tx, ty, tz, qx, qy,
        qz, qw)`` (camera to world), or None where it has none (the report's ``camera_pose``)."""
        if not self.depth_poses.ok[frame]:
            return None
        quaternion = matrix_quaternions(self.depth_poses.rotations[frame][None])[0]
        return tuple(float(v) for v in (*self.depth_poses.translations[frame], *quaternion))

    def to_json(self) -> dict:
        """The report's ``propagation`` section."""
        return {
            "poses": self.path,
            "time_offset_s": round(self.time_offset, 4),
            "time_offset_estimate": self.estimate.to_json() if self.estimate is not None else None,
            "alignment": self.alignment.to_json(self.depth_times),
            "frames_with_pose": int(np.count_nonzero(self.depth_poses.ok)),
            "tracks": [lift.to_json() for lift in self.lifts.values()],
            "inconsistent_tracks": [f"{lift.part}:{lift.track}" for lift in self.lifts.values() if not lift.consistent],
        }



def plan_propagation(
    path: Path, sequence: Sequence, parts: SequenceType[Part], tracks: SequenceType[TrackPlane],
    depth_of_rgb: dict[int, int], config: Config, helpers: HelperPool | None = None,
) -> Propagation:
    """Read the trajectory, fit every track's keyframe planes (reads the depth frames nearest
    the keyframes), estimate the trajectory's time offset from them
    (:func:`annotate_rgbd.propagate.timing.estimate_time_offset`), give every depth frame its
    pose, align the poses to the keyframes' depth
    (:func:`annotate_rgbd.propagate.align.align_frames`: reads every depth frame with a pose)
    and lift the keyframes. ``helpers`` (helper processes) fit keyframe frames and align frames
    too."""
    loaded = load_trajectory(path, sequence.depth.timestamps, sequence.clock)
    for note in loaded.notes:
        log.info(note)
    trajectory = loaded.trajectory
    gap = config.sequence.max_pose_gap
    # One that gives no depth frame a pose is another recording's (or in another time unit):
    # refused, with the two time ranges, as propose and export refuse it.
    poses_of_frames(trajectory, path, np.asarray(sequence.depth.timestamps, dtype=np.float64)
                    + config.propagate.time_offset, gap, sequence.clock, "depth frame")
    plane_of = {(t.part, t.track): t.plane for t in tracks}
    wanted = [
        (p.name, p.annotation.tracks, [plane_of[(p.name, t.track_id)] for t in p.annotation.tracks], p.rgb_of_frame)
        for p in parts
    ]
    depth_files = [sequence.root / f for f in sequence.depth.files]
    fitted = fit_keyframes(wanted, depth_of_rgb, depth_files, config, helpers)
    settings = config.propagate
    times = np.asarray(sequence.depth.timestamps, dtype=np.float64) + settings.time_offset
    offset = TimeOffset()
    if settings.time_offset_search > 0:
        offset = estimate_time_offset(trajectory, time_samples(fitted, times, config), settings.time_offset_search,
                                      settings.time_offset_step, gap, settings.same_surface_offset,
                                      config.inlier_band().model.sigma)
    depth_poses = poses_at(trajectory, times + offset.offset, gap)
    depth_poses, alignment = align_frames(depth_poses, keyframe_depths(fitted), depth_files, config, helpers)
    lifts = lift_tracks(fitted, depth_poses, config)
    return Propagation(str(Path(path).absolute()), {(lift.part, lift.track): lift for lift in lifts}, depth_poses,
                       trajectory, sequence.clock, sequence.depth.timestamps, loaded.warnings,
                       settings.time_offset + offset.offset, offset, alignment)


def propagation_warnings(propagation: Propagation) -> list[str]:
    """What reading the trajectory found implausible, a warning per track whose lifted keyframes
    disagree, one for frames without a pose (with the time ranges when frames lie outside the
    trajectory) and one when no keyframe could be lifted at all."""
    lines = list(propagation.warnings)
    lines += [
        f"{lift.part} track {lift.track} (plane {lift.plane}): "
        f"{_keyframes_lie(lift.substantial)} off the plane its other keyframes agree on (up to {lift.angle:.1f} degrees, {100 * lift.offset:.1f} cm): "
        "a shape over another surface or clutter, two surfaces under one track, or poses that are off; "
        f"{'it was' if len(lift.substantial) == 1 else 'they were'} lifted onto the agreed plane"
        for lift in propagation.lifts.values() if not lift.consistent
    ]
    beyond = propagation.alignment.beyond
    if beyond:
        frame, shift, turn = max(beyond, key=lambda b: (b[1], b[2]))
        settings = "propagate.align_max_shift / align_max_turn"
        frames = f"{len(beyond)} depth frames' poses disagree" if len(beyond) > 1 else "1 depth frame's pose disagrees"
        lines.append(f"{propagation.path}: {frames} with the keyframes' depth by more than {settings} (the most, "
                     f"{100 * shift:.1f} cm and {turn:.1f} degrees, at {_frame_time(propagation, frame)}): "
                     + CHECK_POSES.format(listed="beyond_limits"))
    apart = propagation.alignment.apart
    if apart:
        frame, share = min(apart, key=lambda a: a[1])
        frames = (f"{len(apart)} depth frames do not meet their" if len(apart) > 1 else
                  "1 depth frame does not meet its")
        met = f"{100 * share:.0f} %" if share >= 0.01 else "under 1 %"
        lines.append(f"{propagation.path}: {frames} keyframes' depth (the worst at {_frame_time(propagation, frame)}: "
                     f"of its points that land on their surfaces, {met} lie within reach of them): a pose off by more than "
                     "a few centimetres across the surfaces (a trajectory jump), or a view no keyframe had; "
                     + CHECK_POSES.format(listed="apart_from_keyframes"))
    missing = int(np.count_nonzero(~propagation.depth_poses.ok))
    if missing:
        frames = f"{missing} depth frame{'s have' if missing > 1 else ' has'}"
        whose = "their" if missing > 1 else "its"
        line = f"{propagation.path}: {frames} no pose; {whose} shapes are interpolated in 2-D"
        if propagation.trajectory is not None:
            ranges = missing_poses_text(propagation.trajectory, propagation.depth_times,
                                        propagation.depth_poses.reasons, propagation.clock)
            line += f" ({ranges})" if ranges else ""
        lines.append(line)
    failed = [(lift, frame, reason) for lift in propagation.lifts.values() for frame, reason in lift.failed]
    unmatched = [(lift, frame) for lift, frame, reason in failed if reason == NO_DEPTH_FRAME]
    lifted = sum(len(lift.keyframes) for lift in propagation.lifts.values())
    if unmatched and lifted:
        lift, frame = unmatched[0]
        lines.append(f"{len(unmatched)} of {len(unmatched) + lifted} keyframes (like {lift.part} track {lift.track} "
                     f"frame {frame}) lie on RGB frames no depth frame is matched to (each depth frame takes the RGB "
                     "frame nearest to it in time, within sequence.max_time_diff): the poses carry the others' shapes, "
                     "not theirs (report.json: propagation, each track's keyframes_failed)")
    if failed and not lifted:
        reasons = Counter(reason for _, _, reason in failed)
        lift, frame, reason = next(f for f in failed if f[2] == reasons.most_common(1)[0][0])
        lines.append(f"{propagation.path}: none of the {len(failed)} keyframes could be lifted onto its plane "
                     f"({reasons[reason]} like {lift.part} track {lift.track} frame {frame}: {reason}); "
                     "every shape is interpolated in 2-D")
    return lines


def _frame_time(propagation: Propagation, frame: int) -> str:
    """A depth frame by its timestamp (by its index when the timestamps are unknown)."""
    if propagation.depth_times is None:
        return f"depth frame {frame}"
    time = float(propagation.depth_times[frame])
    return f"depth frame {time:.6f}" if propagation.clock == SECONDS else f"depth frame {time:.0f}"


def _keyframes_lie(frames) -> str:
    """``keyframe 6 lies`` / ``keyframes 6, 9 lie``."""
    frames = list(frames)
    return f"keyframe {frames[0]} lies" if len(frames) == 1 else f"keyframes {', '.join(map(str, frames))} lie"

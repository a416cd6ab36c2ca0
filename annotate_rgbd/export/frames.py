"""A finished run as the plane-GT exports see it: its written frames, each with its mask's plane
ids, the equations of its kept planes and, when the camera trajectory is known, its pose.

The plane equations are those refinement kept (``report.json``: per frame and kept plane,
``equation`` = ``(a, b, c, d)``, ``a x + b y + c z + d = 0`` in the depth camera's frame, metres,
unit normal pointing towards the camera, so ``d > 0`` is the camera's distance to the plane).
Poses are camera-to-world (``X_world = R X_camera + t``): those the run made its masks with
(each frame's ``camera_pose`` in ``report.json``), or, given another trajectory or for a report
without them, read from the trajectory at each depth frame's timestamp as ``cvat2mask`` reads it.
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from annotate_rgbd.errors import InputError
from annotate_rgbd.geometry.lift import plane_to_world
from annotate_rgbd.io.poses import DEFAULT_MAX_POSE_GAP, OUTSIDE_TRAJECTORY, POSE_GAP, poses_of_frames, read_trajectory
from annotate_rgbd.io.sequence import read_image
from annotate_rgbd.report.records import RunRecord
from annotate_rgbd.report.run_folder import NO_CAMERA_POSE, camera_poses, colour_table, mask_plane_ids, read_report
from annotate_rgbd.segment.plane_record import PlaneRecord

log = logging.getLogger("annotate_rgbd")


@dataclass(frozen=True)
class ExportFrame:
    """One written frame of a run.

    Parameters
    ----------
    name : str
        The depth file's name without its suffix (``1305031102.160407``, ``0``): the name of
        the frame's files in every export.
    depth, rgb : str
        The depth and RGB files, relative to the sequence folder.
    timestamp : float
        The depth frame's timestamp, seconds.
    mask : Path
        The colour mask.
    planes : tuple of PlaneRecord
        The planes kept in the mask, with their camera-frame equations.
    pose : (ndarray (3, 3), ndarray (3,)) or None
        Camera-to-world rotation and camera centre (m); None without a trajectory, or where the
        trajectory has no pose for the frame.
    """

    name: str
    depth: str
    rgb: str
    timestamp: float
    mask: Path
    planes: tuple[PlaneRecord, ...]
    pose: tuple[np.ndarray, np.ndarray] | None = None

    def world_planes(self) -> dict[int, np.ndarray]:
        """Plane id -> its equation in the world frame (empty without a pose): unit normal
        ``R n`` (towards the camera that saw it), offset ``d - (R n) . t``."""
        if self.pose is None:
            return {}
        return {p.plane: plane_to_world(np.array(p.equation), *self.pose) for p in self.planes if p.equation}


def equation_convention(fx: float = 1.0, fy: float = 1.0) -> str:
    """The plane-equation convention as every export states it (``export.json``, every frame's file).

    The camera frame's axes follow the depth camera's intrinsics: ``x = (col - cx) z / fx`` and
    ``y = (row - cy) z / fy``, so a negative ``fy`` (ICL-NUIM's) makes y point up, a negative
    ``fx`` x point left.

    Parameters
    ----------
    fx, fy : float
        The depth camera's focal lengths (px); only their signs matter.

    Returns
    -------
    str
    """
    axes = f"x {'right' if fx > 0 else 'left'}, y {'down' if fy > 0 else 'up'}, z forward"
    signs = "" if fx > 0 and fy > 0 else f", as the camera's focal lengths fx = {fx:g}, fy = {fy:g} give"
    return (
        "plane equation (a, b, c, d): a x + b y + c z + d = 0, metres, (a, b, c) a unit normal; camera frame = the "
        f"depth camera's ({axes}{signs}), normal towards the camera, so d > 0 is the camera's distance to "
        "the plane; world frame = the camera trajectory's, normal R n and offset d - (R n) . t for the "
        "camera-to-world pose (R, t)"
    )


@dataclass
class ExportRun:
    """The written frames of a run and where its plane ids come from.

    Parameters
    ----------
    run_dir : Path
    report : RunRecord
    frames : list of ExportFrame
        The written frames, in sequence order.
    trajectory : str or None
        The trajectory the poses come from (with ``poses_from`` ``run``, the one the run read to
        make them; this export did not read it); None: none.
    time_offset : float
        Seconds added to the frames' timestamps to read the trajectory (:func:`trajectory_offset`).
    poses_from : str or None
        ``run``: the poses the run made its masks with (the report's ``camera_pose``);
        ``trajectory``: read from ``trajectory``; None: no poses.
    """

    run_dir: Path
    report: RunRecord
    frames: list[ExportFrame]
    trajectory: str | None = None
    time_offset: float = 0.0
    poses_from: str | None = None

    @property
    def equation_convention(self) -> str:
        """The plane-equation convention of this run's camera (:func:`equation_convention`)."""
        camera = self.report.config.get("camera", {})
        return equation_convention(float(camera.get("fx", 1.0)), float(camera.get("fy", 1.0)))

    @property
    def labels(self) -> dict[int, str]:
        """Plane id -> its CVAT label (``planes.csv``)."""
        return {p.plane: p.label for p in self.report.planes}

    def plane_ids(self, frame: ExportFrame) -> np.ndarray:
        """The plane id of every pixel of the frame's mask (0: no plane), int64 (H, W).

        Raises
        ------
        InputError
            The mask is missing, unreadable, or holds a colour that is no plane of the run.
        """
        return mask_plane_ids(read_image(frame.mask, cv2.IMREAD_COLOR), *colour_table(self.report), frame.mask)


#: Why a frame of a run has no pose (its report's ``pose``), in words.
NO_POSE_WORDS = {POSE_GAP: "in a gap of the trajectory", OUTSIDE_TRAJECTORY: "outside the trajectory",
                 NO_CAMERA_POSE: "without a camera_pose in the report"}


def read_run(run_dir: str | Path, poses: str | Path | None = None, world: bool = True) -> ExportRun:
    """Read a finished run for an export.

    Parameters
    ----------
    run_dir : str or Path
        Output folder of a finished ``cvat2mask`` run.
    poses : str or Path, optional
        A camera trajectory (TUM format, camera to world); default: the poses the run made its
        masks with (each frame's ``camera_pose`` in ``report.json``: the trajectory's, aligned to
        the keyframes' depth), or for a report without them (an earlier version's), the
        trajectory the run used (``propagation.poses``), if any.
    world : bool
        Whether the export holds world-frame planes; without, no trajectory is read and no frame
        has a pose.

    Returns
    -------
    ExportRun

    Raises
    ------
    InputError
        No report, a bad trajectory, the run's trajectory is gone, or no written frame has a pose
        in the trajectory (a warning when some have none).
    """
    run_dir = Path(run_dir)
    report = read_report(run_dir)
    trajectory = (str(poses) if poses is not None else (report.propagation or {}).get("poses")) if world else None
    written = [f for f in report.frames if f.written and f.mask]
    frame_poses, offset = None, 0.0
    own = world and poses is None and any(f.camera_pose is not None for f in written)
    if own:  # the poses the masks were made with: no trajectory to read (it may be gone)
        frame_poses = camera_poses(written)
        offset = trajectory_offset(report, trajectory)
        missing = int(np.count_nonzero(~frame_poses.ok))
        if missing:
            why = ", ".join(f"{count} {NO_POSE_WORDS.get(reason, reason)}"
                            for reason, count in sorted(Counter(frame_poses.reasons[~frame_poses.ok].tolist()).items()))
            log.warning("%s: %d of %d written frames have no pose in the run (%s): their planes have no world "
                        "coordinates", run_dir / "report.json", missing, len(written), why)
    elif trajectory:
        if poses is None and not Path(trajectory).exists():  # a file, or a folder of pose files (ScanNet, 7-Scenes)
            raise InputError(run_dir / "report.json", f"the run's trajectory {trajectory} is gone: give it with --poses")
        gap = report.config.get("sequence", {}).get("max_pose_gap", DEFAULT_MAX_POSE_GAP)
        samples = read_trajectory(trajectory)
        offset = trajectory_offset(report, trajectory)
        times = np.array([f.depth_timestamp for f in written], dtype=np.float64) + offset
        # Refused when no frame gets a pose: the export would hold no world-frame plane at all.
        frame_poses, ranges = poses_of_frames(samples, trajectory, times, gap, samples.clock, "written frame")
        missing = int(np.count_nonzero(~frame_poses.ok))
        if missing and offset and ranges:  # the times read are not the frames' own: say so
            ranges += f"; times are the frames' timestamps {offset:+g} s, the run's clock offset"
        if missing:
            log.warning("%s: %d of %d written frames have no pose: their planes have no world coordinates%s",
                        trajectory, missing, len(written), f" ({ranges})" if ranges else "")
    frames = []
    for i, f in enumerate(written):
        pose = None
        if frame_poses is not None and frame_poses.ok[i]:
            pose = (frame_poses.rotations[i], frame_poses.translations[i])
        frames.append(ExportFrame(Path(f.depth).stem, f.depth, f.rgb, f.depth_timestamp, run_dir / f.mask, f.kept, pose))
    source = "run" if own else "trajectory" if trajectory else None
    return ExportRun(run_dir, report, frames, trajectory or None, offset, source)


def trajectory_offset(report: RunRecord, trajectory: str) -> float:
    """Seconds to add to the frames' timestamps to read ``trajectory`` as the run read it: the
    run's own offset (``propagate.time_offset`` and what it estimated, ``time_offset_s`` of the
    report's ``propagation``) for the run's own trajectory, else the configured
    ``propagate.time_offset`` (an estimate holds for the trajectory it was made on only; a
    warning says so when the run's own offset differs: the file may be a copy of the run's)."""
    propagation = report.propagation or {}
    own = propagation.get("poses")
    run_offset = _seconds(propagation.get("time_offset_s"))
    if own is not None and Path(own).absolute() == Path(trajectory).absolute() and run_offset is not None:
        return run_offset
    configured = _seconds(report.config.get("propagate", {}).get("time_offset", 0.0))
    configured = 0.0 if configured is None else configured
    if own is not None and run_offset is not None and abs(run_offset - configured) > 1e-3:
        advice = ("; to export with the poses the run made its masks with, leave out --poses"
                  if any(f.camera_pose is not None for f in report.frames) else "")
        log.warning("%s: read at the configured propagate.time_offset (%g s), not at the %g s the run estimated for "
                    "its own trajectory %s%s", trajectory, configured, run_offset, own, advice)
    return configured


def _seconds(value) -> float | None:
    """A report's number of seconds, or None where it holds none (or not a finite one)."""
    return float(value) if isinstance(value, (int, float)) and np.isfinite(value) else None

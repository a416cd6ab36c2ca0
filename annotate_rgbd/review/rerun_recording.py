"""A finished run as a Rerun recording (``review --rerun FILE.rrd``): the labels in 3-D.

`Rerun <https://rerun.io>`_ is the viewer the robotics community uses for RGB-D data; its Python
SDK (``rerun-sdk``, an optional extra: ``pip install 'annotate-rgbd[viewer]'``) ships the viewer
too (``rerun FILE.rrd``). :func:`write_recording` reads the run's own records (``report.json``,
the masks, the camera of the run's configuration, the trajectory the run used), never segments a
frame again, and logs every written frame on the ``frame`` timeline (the depth frame's index in
the report) under these entities:

* ``world``: the plane class table (an ``AnnotationContext``: class ``k`` is plane ``k`` with the
  run's colour, ``planes.csv``; class 0 is no plane), static. ``world`` is the trajectory's world
  frame when the run had camera poses, else the depth camera's frame (then it is RDF: x right, y
  down, z forward);
* ``world/camera``: the depth camera's pose (``Transform3D``, camera to world) per frame, with
  poses only; ``world/camera/image``: its intrinsics (``Pinhole``, so the viewer draws the frustum
  and the images in 3-D), with the frame's ``rgb`` (JPEG), ``depth`` (the raw depth image, its
  ``meter`` the camera's ``depth_scale``) and ``planes`` (the mask's plane ids, a
  ``SegmentationImage`` coloured through the class table);
* ``world/camera/colour`` (a run whose colour images have a grid of their own): the colour camera
  in the depth camera's frame (``Transform3D`` of the inverse extrinsic, ``Pinhole``) with the
  ``rgb`` image, instead of ``world/camera/image/rgb``;
* ``world/points``: the labelled pixels' 3-D points (every ``step``-th pixel of every
  ``step``-th row, valid depth and a plane only) in ``world``, their class the plane id;
* ``world/trajectory``: with poses, the camera centres of every depth frame that has a pose, as
  one line strip (static).

With poses, a written frame the trajectory has no pose for (a gap, or outside it) is left out,
with one warning. The recording is written to a temporary file beside ``FILE.rrd`` and renamed
when complete: an interrupted or failed run leaves no partial file.
"""

from __future__ import annotations

import logging
import os
import secrets
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from annotate_rgbd.config.settings import config_from_dict
from annotate_rgbd.errors import InputError, OutputError
from annotate_rgbd.geometry.camera import Camera, backproject, depth_to_metres
from annotate_rgbd.geometry.registration import ColourCamera
from annotate_rgbd.io.outdir import REPORT, reading
from annotate_rgbd.io.poses import DEFAULT_MAX_POSE_GAP, FramePoses, load_trajectory, poses_at
from annotate_rgbd.io.sequence import read_depth, read_image, read_sequence
from annotate_rgbd.report.records import RunRecord
from annotate_rgbd.report.run_folder import camera_poses, colour_table, mask_plane_ids, read_report

log = logging.getLogger("annotate_rgbd")

#: The SDK versions this module is written and tested against (pyproject's ``viewer`` extra).
RERUN_MIN_VERSION = (0, 41)
#: How to get the SDK, for the error when it is missing.
INSTALL_HINT = "pip install 'annotate-rgbd[viewer]'"
#: The recording's application id (the viewer groups recordings by it).
APPLICATION_ID = "annotate-rgbd"
#: The timeline every frame is logged on: the depth frame's index in ``report.json``.
TIMELINE = "frame"
#: Default pixel step of the 3-D points: every 4th pixel of every 4th row (1/16 of the pixels).
DEFAULT_POINT_STEP = 4
#: JPEG quality of the RGB images (about 60 KB for a 640 x 480 frame instead of 900 KB raw).
JPEG_QUALITY = 90

WORLD, CAMERA, IMAGE = "world", "world/camera", "world/camera/image"
COLOUR, POINTS, TRAJECTORY = "world/camera/colour", "world/points", "world/trajectory"


@dataclass(frozen=True)
class RecordingSummary:
    """What :func:`write_recording` wrote.

    Parameters
    ----------
    path : Path
        The recording.
    frames : int
        Frames logged (written frames, every ``every``-th).
    points : int
        3-D points logged, over all frames.
    world : bool
        Whether the points and cameras are in the trajectory's world frame (else the camera's).
    left_out : int
        Frames to record left out: the trajectory has no pose for them.
    size : int
        The file's size, bytes.
    """

    path: Path
    frames: int
    points: int
    world: bool
    left_out: int
    size: int


def import_rerun() -> Any:
    """The ``rerun`` module, or one clear error saying how to install it.

    Raises
    ------
    InputError
        The SDK is not installed, or older than :data:`RERUN_MIN_VERSION`.
    """
    try:
        import rerun
    except ImportError:
        raise InputError(None, f"--rerun needs the Rerun SDK (rerun-sdk 0.41), an optional extra: {INSTALL_HINT}"
                         ) from None
    version = str(getattr(rerun, "__version__", "0"))
    try:
        found = tuple(int(part) for part in version.split(".")[:2])
    except ValueError:
        found = (0, 0)
    if found < RERUN_MIN_VERSION:
        raise InputError(None, f"--rerun needs rerun-sdk >= {'.'.join(map(str, RERUN_MIN_VERSION))}, "
                               f"found {version}: {INSTALL_HINT}")
    return rerun


def labelled_points(labels: np.ndarray, depth_m: np.ndarray, camera: Camera, step: int = DEFAULT_POINT_STEP,
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The 3-D points of a frame's labelled pixels, on a sparse pixel grid.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Plane id per pixel (0: no plane).
    depth_m : ndarray of float, shape (H, W)
        Depth in metres, NaN where invalid (:func:`~annotate_rgbd.geometry.camera.depth_to_metres`).
    camera : Camera
        The depth camera's intrinsics.
    step : int
        Every ``step``-th pixel of every ``step``-th row, from pixel (0, 0).

    Returns
    -------
    points : ndarray of float32, shape (N, 3)
        Camera-frame coordinates, metres, in row-major pixel order.
    planes : ndarray of uint16, shape (N,)
        The plane id of each point.
    """
    if step < 1:
        raise ValueError(f"step must be a positive number of pixels, not {step!r}")
    sub_labels = labels[::step, ::step]
    sub_depth = depth_m[::step, ::step]
    rows, cols = np.nonzero((sub_labels > 0) & np.isfinite(sub_depth))
    points = backproject(cols * step, rows * step, sub_depth[rows, cols], camera)
    return points.astype(np.float32), sub_labels[rows, cols].astype(np.uint16)


def to_world(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Camera-frame points in the world frame: ``R @ X + t`` per point.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
    rotation : ndarray, shape (3, 3)
        Camera-to-world rotation.
    translation : ndarray, shape (3,)
        The camera centre in the world, metres.

    Returns
    -------
    ndarray of float32, shape (N, 3)
    """
    return (np.asarray(points, np.float64) @ np.asarray(rotation).T + np.asarray(translation)).astype(np.float32)


def plane_classes(report: RunRecord) -> list[tuple[int, str, tuple[int, int, int, int]]]:
    """The class table: ``(id, label, RGBA colour)`` for no plane (0, transparent) and every
    plane of the run (its ``planes.csv`` colour, labelled ``plane k: <CVAT label>``)."""
    classes = [(0, "no plane", (0, 0, 0, 0))]
    for plane in sorted(report.planes, key=lambda p: p.plane):
        value = int(plane.colour.lstrip("#"), 16)
        label = f"plane {plane.plane}" + (f": {plane.label}" if plane.label else "")
        classes.append((plane.plane, label, (value >> 16, (value >> 8) & 255, value & 255, 255)))
    return classes


def run_poses(report: RunRecord) -> FramePoses | None:
    """The camera pose of every depth frame of the run (``report.frames``): the poses the run
    made its masks with (each frame's ``camera_pose``: the trajectory's, aligned to the keyframes'
    depth), or for a report without them (an earlier version's), the trajectory the run used,
    read as ``cvat2mask`` read it (frame-numbered poses matched to the depth frames in order, the
    trajectory's time offset the run applied, its ``max_pose_gap``); None when the run had no
    poses, or (with one warning) when its trajectory is gone."""
    if any(f.camera_pose is not None for f in report.frames):
        return camera_poses(report.frames)
    trajectory = (report.propagation or {}).get("poses")
    if not trajectory:
        return None
    if not Path(trajectory).exists():
        log.warning("the run's trajectory %s is gone: the recording is in the camera frame", trajectory)
        return None
    clock = read_sequence(report.sequence, need_rgb=False).clock
    times = np.array([f.depth_timestamp for f in report.frames], dtype=np.float64)
    loaded = load_trajectory(trajectory, times, clock)  # its warnings: cvat2mask gave them already
    gap = report.config.get("sequence", {}).get("max_pose_gap", DEFAULT_MAX_POSE_GAP)
    offset = report.propagation.get("time_offset_s") or 0.0  # configured and estimated, seconds
    return poses_at(loaded.trajectory, times + offset, gap)


def check_recording(path: str | Path, step: int = 1, every: int = 1) -> None:
    """What :func:`write_recording` checks before any work, for a caller to check before its
    own (``review --rerun`` writes the overlays first).

    Raises
    ------
    InputError
        A point step or frame step below 1.
    OutputError
        ``path`` does not end in ``.rrd``, is a folder, or its folder does not exist or cannot
        be written.
    """
    path = Path(path)
    if step < 1 or every < 1:
        raise InputError(None, f"the point step and the frame step must be at least 1, not {step} and {every}")
    if path.suffix.lower() != ".rrd":
        raise OutputError(path, "a Rerun recording's name ends in .rrd (the viewer opens .rrd files)")
    if path.is_dir():
        raise OutputError(path, "is a folder: give the recording's file name (FILE.rrd)")
    if not path.parent.is_dir():
        raise OutputError(path, "cannot write the recording: its folder does not exist")
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise OutputError(path, "cannot write the recording: its folder is not writable")


def write_recording(
    out_dir: str | Path,
    path: str | Path,
    step: int = DEFAULT_POINT_STEP,
    every: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> RecordingSummary:
    """Write a finished run as a Rerun recording (the entities are listed in the module's
    description).

    Parameters
    ----------
    out_dir : str or Path
        The output folder of a finished ``cvat2mask`` run.
    path : str or Path
        The recording to write, ``.rrd``; replaced when complete.
    step : int
        Pixel step of the 3-D points (:func:`labelled_points`).
    every : int
        Log every ``every``-th written frame, from the first (``1``: all of them).
    progress : callable, optional
        Called as ``progress(done, total)`` after each frame.

    Returns
    -------
    RecordingSummary

    Raises
    ------
    InputError
        The SDK is missing, no finished run in ``out_dir``, a mask, image or the trajectory
        unreadable; OutputError when ``path`` cannot be written (nothing is left then).
    """
    rr = import_rerun()
    out_dir, path = Path(out_dir), Path(path)
    check_recording(path, step, every)
    with reading(out_dir):
        report = read_report(out_dir)
        picked = [k for k, f in enumerate(report.frames) if f.written][::every]
        poses = run_poses(report)
        keep = picked if poses is None else [k for k in picked if poses.ok[k]]
        if len(keep) < len(picked):
            log.warning("%d of %d frames to record have no camera pose (a gap in the trajectory, or outside it): "
                        "left out of the recording", len(picked) - len(keep), len(picked))
        config = config_from_dict(report.config, out_dir / REPORT)
        tmp = path.parent / f".{path.name}.{secrets.token_hex(4)}.tmp"
        stream = rr.RecordingStream(APPLICATION_ID)
        done = False
        points = 0
        try:
            try:
                stream.save(tmp)
            except Exception as exc:  # the SDK's own error types: the file cannot be created
                raise OutputError(path, f"cannot write the recording: {exc}") from None
            stream.set_log_time_enabled(False)
            log_static(rr, stream, report, config.camera, config.colour_camera, poses, frames_shape(out_dir, report))
            keys, values = colour_table(report)
            for done_frames, k in enumerate(keep, start=1):
                pose = None if poses is None else (poses.rotations[k], poses.translations[k])
                points += log_frame(rr, stream, out_dir, report, k, config.camera, config.colour_camera,
                                    keys, values, pose, step)
                if progress:
                    progress(done_frames, len(keep))
            stream.flush()
            stream.disconnect()
            if not tmp.is_file():
                raise OutputError(path, "cannot write the recording: the Rerun SDK wrote no file")
            os.replace(tmp, path)
            done = True
        except OSError as exc:
            raise OutputError(path, f"cannot write the recording: {exc.strerror or exc}") from None
        finally:
            if not done:
                stream.disconnect()
                tmp.unlink(missing_ok=True)
    return RecordingSummary(path, len(keep), points, poses is not None, len(picked) - len(keep),
                            path.stat().st_size)


def frames_shape(out_dir: Path, report: RunRecord) -> tuple[int, int] | None:
    """``(height, width)`` of the run's masks (the depth grid), from the first one; None without."""
    first = next((f for f in report.frames if f.written), None)
    return None if first is None else read_image(out_dir / first.mask, cv2.IMREAD_COLOR).shape[:2]


def log_static(rr: Any, stream: Any, report: RunRecord, camera: Camera, colour: ColourCamera | None,
               poses: FramePoses | None, shape: tuple[int, int] | None) -> None:
    """Log what holds for every frame: the class table, the world's axes (camera frame only),
    the cameras' intrinsics and the trajectory."""
    classes = [rr.AnnotationInfo(id=k, label=label, color=rgba) for k, label, rgba in plane_classes(report)]
    stream.log(WORLD, rr.AnnotationContext(classes), static=True)
    if poses is None:
        stream.log(WORLD, rr.ViewCoordinates.RDF, static=True)
    if shape is not None:
        stream.log(IMAGE, pinhole(rr, camera.fx, camera.fy, camera.cx, camera.cy, shape[1], shape[0]), static=True)
    if colour is not None:
        inverse = np.linalg.inv(colour.extrinsic)  # colour camera -> depth camera
        stream.log(COLOUR, rr.Transform3D(translation=inverse[:3, 3], mat3x3=inverse[:3, :3]), static=True)
        stream.log(COLOUR, pinhole(rr, colour.fx, colour.fy, colour.cx, colour.cy, colour.width, colour.height),
                   static=True)
    if poses is not None:
        centres = poses.translations[poses.ok]  # every depth frame with a pose, written or not
        if len(centres) > 1:
            stream.log(TRAJECTORY, rr.LineStrips3D([centres.astype(np.float32)]), static=True)


def pinhole(rr: Any, fx: float, fy: float, cx: float, cy: float, width: int, height: int) -> Any:
    """A Rerun ``Pinhole`` with OpenCV's camera axes (RDF). The intrinsics are the run's as they
    are: the viewer back-projects pixel ``(col, row)`` of a depth image along
    ``((col - cx) / fx, (row - cy) / fy, 1)``, pixel centres at integers as here."""
    matrix = [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]
    return rr.Pinhole(image_from_camera=matrix, resolution=[width, height], camera_xyz=rr.ViewCoordinates.RDF)


def log_frame(rr: Any, stream: Any, out_dir: Path, report: RunRecord, index: int, camera: Camera,
              colour: ColourCamera | None, keys: np.ndarray, values: np.ndarray,
              pose: tuple[np.ndarray, np.ndarray] | None, step: int) -> int:
    """Log the written frame ``report.frames[index]`` at ``index`` on the timeline (pose,
    images, plane ids, 3-D points); returns its point count."""
    frame = report.frames[index]
    stream.set_time(TIMELINE, sequence=index)
    sequence = Path(report.sequence)
    mask_path = out_dir / frame.mask
    labels = mask_plane_ids(read_image(mask_path, cv2.IMREAD_COLOR), keys, values, mask_path)
    depth = read_depth(sequence / frame.depth)
    if depth.shape != labels.shape:
        raise InputError(sequence / frame.depth, f"depth image of {depth.shape[1]}x{depth.shape[0]} pixels, but "
                         f"its mask {frame.mask} has {labels.shape[1]}x{labels.shape[0]}: the sequence changed "
                         "since the run")
    if pose is not None:
        stream.log(CAMERA, rr.Transform3D(translation=pose[1], mat3x3=pose[0]))
    _, jpeg = cv2.imencode(".jpg", read_image(sequence / frame.rgb, cv2.IMREAD_COLOR),
                            [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    rgb = rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg")
    stream.log(f"{COLOUR}/rgb" if colour is not None else f"{IMAGE}/rgb", rgb)
    stream.log(f"{IMAGE}/depth", rr.DepthImage(depth, meter=camera.depth_scale))
    dtype = np.uint8 if labels.max(initial=0) <= 255 else np.uint16
    stream.log(f"{IMAGE}/planes", rr.SegmentationImage(labels.astype(dtype)))
    points, planes = labelled_points(labels, depth_to_metres(depth, camera.depth_scale), camera, step)
    if pose is not None:
        points = to_world(points, *pose)
    stream.log(POINTS, rr.Points3D(points, class_ids=planes, radii=rr.Radius.ui_points(2.0)))
    return len(points)

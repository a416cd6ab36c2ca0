"""A whole synthetic sequence on disk: TUM RGB-D layout, plane ground truth and the annotation."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from annotate_rgbd.annotation.model import Annotation, Shape, Track
from annotate_rgbd.geometry.camera import Camera
from .frame import render_frame
from .ground_truth import depth_statistics, plane_record
from .pose_error import perturb_poses
from .scene import Pose, Scene, room_scene, room_trajectory

#: Second seed word of the generator of the trajectory's error (frames use ``[seed, i]``, i <
#: n_frames): any value beyond a frame count keeps the two streams apart.
TRAJECTORY_STREAM = 2**31 - 1


def _timestamps(
    n_frames: int, fps: float, rng: np.random.Generator, start: float
) -> tuple[np.ndarray, np.ndarray]:
    """RGB times on an ``fps`` clock with +-0.5 ms jitter, each depth frame 5-11 ms after its
    RGB frame. At 30 Hz a depth frame is then at least 21 ms from every other RGB frame, so
    one whose RGB frame is dropped has no RGB frame within 0.02 s."""
    rgb = start + np.arange(n_frames) / fps + rng.uniform(-0.0005, 0.0005, n_frames)
    depth = rgb + rng.uniform(0.005, 0.011, n_frames)
    return np.round(rgb, 6), np.round(depth, 6)


def _write_list(path: Path, kind: str, folder: str, names: Sequence[str], seed: int) -> None:
    lines = [f"# {kind}", f"# file: 'synthetic room, seed {seed}'", "# timestamp filename"]
    lines += [f"{name[:-4]} {folder}/{name}" for name in names]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _write_png(path: Path, image: np.ndarray) -> None:
    """Write an image as PNG at zlib level 6 (``(H, W, 3)`` arrays are taken as RGB).

    Not :func:`annotate_rgbd.io.writer.write_png`: that one encodes with OpenCV's default settings,
    which give other bytes (on the committed sample RGB images 54 % larger, depth images 3 %
    smaller), so every committed sample image would change; and it writes atomically with an
    ``fsync`` per file, which a throw-away render does not need.
    """
    if image.ndim == 3:
        image = image[:, :, ::-1]  # OpenCV writes BGR
    if not cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, 6]):
        raise OSError(f"cannot write {path}")


def make_sequence(
    out_dir: str | Path,
    *,
    n_frames: int,
    width: int,
    height: int,
    camera: Camera,
    seed: int,
    scene: Scene | None = None,
    poses: Sequence[Pose] | None = None,
    fps: float = 30.0,
    dropped_rgb_frames: Sequence[int] | None = None,
    start_time: float = 1700000000.0,
    ground_truth_dir: str | Path | None = None,
    polygon_jitter_px: float = 0.0,
    object_index_dir: str | Path | None = None,
    write_trajectory: bool = False,
    trajectory_noise: tuple[float, float] | None = None,
    trajectory_time_offset: float = 0.0,
) -> Annotation:
    """Render a synthetic sequence in TUM RGB-D layout with plane ground truth.

    Writes ``rgb/<t>.png``, ``depth/<t>.png``, ``rgb.txt``, ``depth.txt`` into ``out_dir`` and
    into the ground-truth folder ``<depth file name>`` (16-bit: ``track_id + 1`` of the plane
    per pixel, 0 for clutter, background, missing depth and planes not annotated in that frame;
    dropped planes keep their value) and ``planes.json`` (every track with its label, expected
    fate "kept" or "dropped" with a reason "too_far" / "invalid_depth", its statistics, and
    every depth frame with its RGB file and annotation frame, if any). The expected fate is a
    whole-sequence oracle that differs from the pipeline's per-frame rules in the ways listed
    in :mod:`annotate_rgbd.synthetic.ground_truth`.

    Parameters
    ----------
    out_dir : str or Path
        Created if needed; existing files of the same names are overwritten.
    n_frames : int
        Rendered frames (depth frames); RGB has ``n_frames - len(dropped_rgb_frames)``.
    width, height : int
        Image size.
    camera : Camera
        Intrinsics and depth scale for rendering and for the depth PNGs.
    seed : int
        Seed of every random choice (noise, holes, timestamps, track ids).
    scene : Scene, optional
        Default :func:`room_scene`.
    poses : sequence of Pose, optional
        One per frame; default :func:`room_trajectory`.
    fps : float
        RGB frame rate, at most 30 Hz (see ``dropped_rgb_frames``).
    dropped_rgb_frames : sequence of int, optional
        Frames whose RGB image is missing, so that their depth frame has no RGB frame within
        0.02 s. Default: the middle frame; ``()`` for none.
    start_time : float
        Timestamp of the first RGB frame, seconds.
    ground_truth_dir : str or Path, optional
        Where the ground truth goes; default ``out_dir / "ground_truth"``.
    polygon_jitter_px : float
        Labeller's error: every polygon vertex moves by up to this many pixels per axis (see
        :func:`render_frame <annotate_rgbd.synthetic.frame.render_frame>`); 0: exact outlines.
    write_trajectory : bool
        Also write ``groundtruth.txt``: the exact camera pose of every frame in TUM format
        (``timestamp tx ty tz qx qy qz qw``, camera to world), at the RGB and the depth
        frames' timestamps (both images of a frame are rendered at one pose), as TUM RGB-D ships
        a trajectory with its sequences.
    trajectory_noise : (float, float), optional
        Make the written trajectory as inexact as real published poses: every frame's pose moved
        and turned by Gaussian errors of these median sizes (metres, degrees; real Kinect
        trajectories: about 0.004 and 0.2), drawn by
        :func:`~annotate_rgbd.synthetic.pose_error.perturb_poses` from a generator of its own
        (the rendered images do not change). Both samples of a frame carry its error.
    trajectory_time_offset : float
        The trajectory's clock runs this many seconds ahead of the camera's: the pose of the
        frame captured at ``t`` is written at ``t + trajectory_time_offset`` (TUM's motion
        capture: about -0.02 s on freiburg1), so that a reader interpolating the trajectory at a
        frame's timestamp gets the pose of a moment before or after it.
    object_index_dir : str or Path, optional
        When given, also write there per depth frame ``<depth file name>``: 16-bit, the index
        + 1 of the scene object seen at each pixel whatever its depth (planes 1..P in
        ``scene.planes`` order, then clutter), 0 where nothing is hit. For benchmarks that
        tell clutter from planes and find the planes' true borders.

    Returns
    -------
    Annotation
        CVAT video annotation: frames are RGB indices, one track per plane annotated in at
        least one frame, tracks in ascending id order.
    """
    out_dir = Path(out_dir)
    scene = room_scene() if scene is None else scene
    poses = room_trajectory(n_frames) if poses is None else list(poses)
    if len(poses) != n_frames:
        raise ValueError(f"{len(poses)} poses for {n_frames} frames")
    if not 0 < fps <= 30:
        raise ValueError(f"fps must be in (0, 30], got {fps}")
    dropped = {n_frames // 2} if dropped_rgb_frames is None else set(dropped_rgb_frames)
    rng = np.random.default_rng(seed)
    track_ids = rng.permutation(len(scene.planes))
    rgb_times, depth_times = _timestamps(n_frames, fps, rng, start_time)
    gt_dir = out_dir / "ground_truth" if ground_truth_dir is None else Path(ground_truth_dir)
    object_dir = None if object_index_dir is None else Path(object_index_dir)
    for folder in (out_dir / "rgb", out_dir / "depth", gt_dir, object_dir):
        if folder is not None:
            folder.mkdir(parents=True, exist_ok=True)

    n_planes = len(scene.planes)
    shapes: dict[int, dict[int, Shape]] = {k: {} for k in range(n_planes)}
    stats = np.zeros((3, n_planes))
    rgb_names, depth_names, frame_records = [], [], []
    gt_value = np.append(track_ids + 1, 0).astype(np.uint16)  # plane index -1 -> 0
    for i, pose in enumerate(poses):
        frame = render_frame(scene, pose, camera, width, height, np.random.default_rng([seed, i]),
                             polygon_jitter_px=polygon_jitter_px)
        depth_name = f"{depth_times[i]:.6f}.png"
        depth_names.append(depth_name)
        _write_png(out_dir / "depth" / depth_name, frame.depth_raw)
        _write_png(gt_dir / depth_name, gt_value[frame.plane_index])
        if object_dir is not None:
            _write_png(object_dir / depth_name, (frame.visible + 1).astype(np.uint16))
        record = {"depth": f"depth/{depth_name}", "ground_truth": depth_name,
                  "rgb": None, "annotation_frame": None}
        if i not in dropped:
            rgb_name = f"{rgb_times[i]:.6f}.png"
            _write_png(out_dir / "rgb" / rgb_name, frame.rgb)
            record.update(rgb=f"rgb/{rgb_name}", annotation_frame=len(rgb_names))
            for k, polygon in frame.polygons.items():
                shapes[k][len(rgb_names)] = Shape("polygon", polygon, z_order=scene.planes[k].z_order)
            rgb_names.append(rgb_name)
        frame_records.append(record)
        stats += depth_statistics(frame, n_planes, camera.depth_scale)

    _write_list(out_dir / "rgb.txt", "color images", "rgb", rgb_names, seed)
    _write_list(out_dir / "depth.txt", "depth maps", "depth", depth_names, seed)
    if write_trajectory:
        # Frame i's RGB and depth images are both rendered at pose i, so the trajectory holds
        # pose i at both their timestamps: it is exact wherever a frame was captured (unless
        # made inexact on purpose).
        written = poses
        if trajectory_noise is not None:
            written = perturb_poses(poses, np.random.default_rng([seed, TRAJECTORY_STREAM]), *trajectory_noise)
        shift = float(trajectory_time_offset)
        samples = sorted({**{float(t) + shift: p for t, p in zip(rgb_times, written)},
                          **{float(t) + shift: p for t, p in zip(depth_times, written)}}.items())
        write_tum_trajectory(out_dir / "groundtruth.txt", [t for t, _ in samples], [p for _, p in samples])
    order = [k for k in np.argsort(track_ids) if shapes[k]]
    description = {
        "description": "Synthetic room rendered by annotate_rgbd.synthetic.make_sequence. "
        "Ground-truth PNGs hold track_id + 1 of the plane seen at each pixel with valid depth, "
        "0 elsewhere; planes expected to be dropped keep their value. Frame paths: rgb and "
        "depth relative to the sequence folder, ground_truth relative to this file's folder.",
        "seed": seed,
        "width": width,
        "height": height,
        "depth_scale": camera.depth_scale,
        "planes": [
            plane_record(int(track_ids[k]), scene.planes[k].label, len(shapes[k]), *stats[:, k])
            for k in order
        ],
        "frames": frame_records,
    }
    (gt_dir / "planes.json").write_text(json.dumps(description, indent=1) + "\n", encoding="utf-8")

    tracks = [Track(int(track_ids[k]), scene.planes[k].label, shapes[k]) for k in order]
    frames = list(range(len(rgb_names)))
    return Annotation(
        path=str(out_dir), format="video", tracks=tracks, frames=frames,
        image_size={f: (width, height) for f in frames},
    )


def write_tum_trajectory(path: Path, timestamps: Sequence[float], poses: Sequence[Pose]) -> None:
    """Write camera poses as a TUM trajectory file (what :func:`annotate_rgbd.io.poses.read_trajectory` reads).

    Parameters
    ----------
    path : Path
    timestamps : sequence of float
        Seconds, one per pose, increasing.
    poses : sequence of Pose
        Camera-to-world poses (the camera's x right, y down, z forward, as TUM's optical frame).
    """
    from scipy.spatial.transform import Rotation

    quaternions = Rotation.from_matrix(np.array([p.rotation for p in poses])).as_quat()  # x, y, z, w
    lines = ["# ground-truth trajectory of a rendered sequence (annotate_rgbd.synthetic)",
             "# timestamp tx ty tz qx qy qz qw"]
    for time, pose, q in zip(timestamps, poses, quaternions):
        lines.append(f"{time:.6f} " + " ".join(f"{v:.9f}" for v in (*pose.position, *q)))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")

"""Rendered sequences written in ScanNet's and 7-Scenes' layouts, as their own tools write them.

The frames come from :func:`annotate_rgbd.synthetic.render_frame` (exact plane ground truth,
exact camera poses); the files follow ScanNet's ``SensReader`` export (``color/<i>.jpg``,
``depth/<i>.png`` in millimetres, ``pose/<i>.txt`` printed with ``%f``, ``-inf`` where tracking
was lost, ``intrinsic/*.txt`` as 4 x 4 matrices) and the 7-Scenes download
(``frame-000000.color.png``, ``.depth.png`` in millimetres with 65535 for no depth, ``.pose.txt``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from annotate_rgbd.annotation.model import Annotation, Shape, Track
from annotate_rgbd.cvat import write_cvat_video
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.synthetic import Frame, Pose, render_frame, room_scene, room_trajectory


@dataclass
class Rendered:
    """A rendered walk: its frames, poses, the scene and the keyframes-only CVAT export."""

    frames: list[Frame]
    poses: list[Pose]
    labels: list[str]
    annotation: Annotation


def render_walk(n_frames: int, width: int, height: int, camera: Camera, seed: int = 5) -> Rendered:
    """Frames of the room walk and a CVAT video annotation of every plane on every frame."""
    scene = room_scene()
    poses = room_trajectory(n_frames)
    frames = [render_frame(scene, pose, camera, width, height, np.random.default_rng([seed, i]))
              for i, pose in enumerate(poses)]
    shapes: dict[int, dict[int, Shape]] = {}
    for i, frame in enumerate(frames):
        for k, polygon in frame.polygons.items():
            shapes.setdefault(k, {})[i] = Shape("polygon", polygon, z_order=scene.planes[k].z_order)
    tracks = [Track(k, scene.planes[k].label, shapes[k]) for k in sorted(shapes)]
    annotation = Annotation(path="rendered", format="video", tracks=tracks, frames=list(range(n_frames)),
                            image_size={i: (width, height) for i in range(n_frames)})
    return Rendered(frames, poses, [p.label for p in scene.planes], annotation)


def write_keyframes(rendered: Rendered, path: Path, step: int) -> Path:
    width, height = rendered.annotation.image_size[0]
    write_cvat_video(rendered.annotation, path, width=width, height=height, keyframe_step=step, keyframes_only=True)
    return path


def pose_matrix(pose: Pose) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, :3] = pose.rotation
    matrix[:3, 3] = pose.position
    return matrix


def _save_matrix(path: Path, matrix: np.ndarray) -> None:
    with open(path, "w") as handle:  # as SensReader's save_mat_to_file: one row a line, "%f"
        for row in matrix:
            np.savetxt(handle, row[np.newaxis], fmt="%f")


def _intrinsic(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[fx, 0, cx, 0], [0, fy, cy, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=np.float64)


def write_scannet(root: Path, rendered: Rendered, camera: Camera, lost: tuple[int, ...] = (),
                  extrinsic_depth: np.ndarray | None = None) -> Path:
    """A ScanNet export of the rendered frames; ``lost``: frames whose pose is all ``-inf``."""
    for name in ("color", "depth", "pose", "intrinsic"):
        (root / name).mkdir(parents=True, exist_ok=True)
    for i, (frame, pose) in enumerate(zip(rendered.frames, rendered.poses)):
        cv2.imwrite(str(root / "color" / f"{i}.jpg"), frame.rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
        cv2.imwrite(str(root / "depth" / f"{i}.png"), frame.depth_raw)
        _save_matrix(root / "pose" / f"{i}.txt", np.full((4, 4), -np.inf) if i in lost else pose_matrix(pose))
    k = _intrinsic(camera.fx, camera.fy, camera.cx, camera.cy)
    _save_matrix(root / "intrinsic" / "intrinsic_depth.txt", k)
    _save_matrix(root / "intrinsic" / "intrinsic_color.txt", k)
    _save_matrix(root / "intrinsic" / "extrinsic_color.txt", np.eye(4))
    _save_matrix(root / "intrinsic" / "extrinsic_depth.txt", np.eye(4) if extrinsic_depth is None else extrinsic_depth)
    return root


def write_seven_scenes(root: Path, rendered: Rendered) -> Path:
    """A 7-Scenes sequence folder of the rendered frames: missing depth written as 65535."""
    root.mkdir(parents=True, exist_ok=True)
    for i, (frame, pose) in enumerate(zip(rendered.frames, rendered.poses)):
        name = f"frame-{i:06d}"
        cv2.imwrite(str(root / f"{name}.color.png"), frame.rgb[:, :, ::-1])
        cv2.imwrite(str(root / f"{name}.depth.png"), np.where(frame.depth_raw == 0, 65535, frame.depth_raw).astype(np.uint16))
        np.savetxt(root / f"{name}.pose.txt", pose_matrix(pose), fmt="%.8e", delimiter="\t")
    return root

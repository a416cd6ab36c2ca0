"""Plane parameters of a run for plane-GT consumers: per frame, and one per plane of a scene.

Conventions (also written into every export's ``export.json``):

- Our equation: ``a x + b y + c z + d = 0``, metres, ``(a, b, c)`` a unit normal. In the camera
  frame (x right, y down, z forward, the depth camera's) the normal points towards the camera,
  so ``d > 0`` is the camera's distance to the plane. In the world frame (the trajectory's) the
  same plane: normal ``R n``, offset ``d - (R n) . t`` for the camera-to-world pose ``(R, t)``.
  The axes follow the intrinsics' signs: with a negative ``fy`` (ICL-NUIM) y points up
  (:func:`annotate_rgbd.export.frames.equation_convention`).
- PlaneRCNN (``planes.npy``): one 3-vector per plane, ``normal * offset`` with the plane's
  points ``X`` satisfying ``normal . X = offset``: the foot of the perpendicular from the
  origin, ``-d n`` for our ``(n, d)``; its norm is the plane's distance to the origin. A plane
  through the origin has no such vector (``0``; PlaneRCNN's loader skips it).
- PlaneRecNet (COCO ``plane_paras``): ``(nx, ny, nz, offset)`` with ``normal . X = offset``,
  camera frame, the normal pointing away from the camera so that ``offset > 0`` is the
  distance: ``(-a, -b, -c, d)`` for our ``(a, b, c, d)``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from annotate_rgbd.io.writer import write_json
from .frames import ExportRun

def foot_vector(equation: np.ndarray) -> np.ndarray:
    """PlaneRCNN's plane vector: ``normal * offset`` with ``normal . X = offset``.

    Parameters
    ----------
    equation : ndarray, shape (..., 4)
        ``(a, b, c, d)`` with a unit normal.

    Returns
    -------
    ndarray, shape (..., 3)
        ``-d (a, b, c)``: the point of the plane nearest the origin.
    """
    equation = np.asarray(equation, dtype=np.float64)
    return -equation[..., 3:4] * equation[..., :3]


def plane_paras(equation: np.ndarray) -> list[float]:
    """PlaneRecNet's ``plane_paras`` ``(nx, ny, nz, offset)`` (camera frame, normal away from the
    camera, ``offset > 0``) of a camera-frame equation ``(a, b, c, d)`` with ``d > 0``."""
    a, b, c, d = (float(v) for v in equation)
    return [-a, -b, -c, d]


def scene_planes(run: ExportRun) -> dict[int, np.ndarray]:
    """One world-frame equation per plane of the run: the mean of its per-frame world planes,
    weighted by the frame's inliers.

    Each frame's plane is taken to the world with that frame's pose; normals are turned to
    agree with the plane's largest view before averaging; the mean normal is renormalised and
    the offset is the weighted mean offset. Frames without a pose do not count.

    Parameters
    ----------
    run : ExportRun

    Returns
    -------
    dict of int to ndarray, shape (4,)
        Plane id -> ``(a, b, c, d)`` in the world frame, for every plane kept on a frame with a
        pose.
    """
    gathered: dict[int, list[tuple[np.ndarray, float]]] = {}
    for frame in run.frames:
        world = frame.world_planes()
        for record in frame.planes:
            if record.plane in world:
                gathered.setdefault(record.plane, []).append((world[record.plane], float(record.inliers or 0)))
    planes = {}
    for plane, views in sorted(gathered.items()):
        equations = np.array([e for e, _ in views])
        weights = np.array([w for _, w in views]) + 1e-12
        largest = equations[int(np.argmax(weights))]
        equations *= np.where(equations[:, :3] @ largest[:3] < 0, -1.0, 1.0)[:, None]
        mean = (equations * weights[:, None]).sum(axis=0) / weights.sum()
        planes[plane] = mean / np.linalg.norm(mean[:3])
    return planes


def write_frame_planes(run: ExportRun, out: Path) -> list[Path]:
    """``frames/<frame>.json`` per written frame: every kept plane's equation in the camera frame and,
    with a pose, in the world frame, with its plane id (``planes.csv``) and label.

    Parameters
    ----------
    run : ExportRun
    out : Path
        The export folder.

    Returns
    -------
    list of Path
        The files written.
    """
    written = []
    labels = run.labels
    for frame in run.frames:
        world = frame.world_planes()
        entry = {
            "frame": frame.name,
            "depth": frame.depth,
            "rgb": frame.rgb,
            "depth_timestamp": frame.timestamp,
            "camera_to_world": None if frame.pose is None else _matrix(*frame.pose),
            "convention": run.equation_convention,
            "planes": [
                {
                    "plane": p.plane,
                    "label": labels.get(p.plane, ""),
                    "pixels": (p.inliers or 0) + (p.grown or 0),
                    "camera": list(p.equation),
                    "world": None if p.plane not in world else [round(float(v), 9) for v in world[p.plane]],
                }
                for p in frame.planes if p.equation is not None
            ],
        }
        path = out / "frames" / f"{frame.name}.json"
        write_json(path, entry)
        written.append(path)
    return written


def _matrix(rotation: np.ndarray, translation: np.ndarray) -> list[list[float]]:
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = rotation, translation
    return [[round(float(v), 9) for v in row] for row in matrix]

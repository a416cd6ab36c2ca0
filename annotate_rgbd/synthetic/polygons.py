"""The polygon a labeller draws for a plane: its outline projected into the image and clipped
to it, running straight over clutter and nearer planes."""

from __future__ import annotations

import numpy as np

from annotate_rgbd.geometry.camera import Camera, project
from .scene import NEAR, Plane, Pose


def _clip_polygon(points: np.ndarray, axis: int, limit: float, keep_above: bool) -> np.ndarray:
    """Sutherland-Hodgman: keep the part of a closed polygon with ``points[:, axis] >= limit``
    (or ``<=`` when not ``keep_above``)."""
    if len(points) == 0:
        return points
    sign = 1.0 if keep_above else -1.0
    inside = sign * (points[:, axis] - limit) >= 0
    out = []
    for i in range(len(points)):
        j = (i + 1) % len(points)
        if inside[i]:
            out.append(points[i])
        if inside[i] != inside[j]:
            f = (limit - points[i, axis]) / (points[j, axis] - points[i, axis])
            crossing = points[i] + f * (points[j] - points[i])
            crossing[axis] = limit  # exactly on the border, not 1e-14 outside
            out.append(crossing)
    return np.asarray(out).reshape(-1, points.shape[1])


def plane_polygon(
    plane: Plane, pose: Pose, camera: Camera, width: int, height: int
) -> np.ndarray | None:
    """The polygon a labeller draws for ``plane``: its outline clipped against the near plane,
    projected and clipped to the image.

    Parameters
    ----------
    plane : Plane
    pose : Pose
    camera : Camera
    width, height : int
        Image size.

    Returns
    -------
    ndarray of float64, shape (N, 2), or None
        Vertices in CVAT image coordinates (top-left image corner at (0, 0), so a pixel centre
        sits at ``(col + 0.5, row + 0.5)``); None when nothing of it is in the image.
    """
    points = _clip_polygon(pose.to_camera(plane.outline()), 2, NEAR, keep_above=True)
    if len(points) < 3:
        return None
    polygon = project(points, camera) + 0.5
    polygon = _clip_polygon(polygon, 0, 0.0, keep_above=True)
    polygon = _clip_polygon(polygon, 0, float(width), keep_above=False)
    polygon = _clip_polygon(polygon, 1, 0.0, keep_above=True)
    polygon = _clip_polygon(polygon, 1, float(height), keep_above=False)
    if len(polygon) < 3:
        return None
    x, y = polygon[:, 0], polygon[:, 1]
    area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    return polygon if area > 0 else None


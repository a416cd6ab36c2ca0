"""Geometry of pose-guided propagation: keyframe polygon -> 3-D world polygon -> other frames.

A polygon drawn on a keyframe is lifted onto the plane fitted to its depth (each vertex's ray
meets the plane), moved to world coordinates with the keyframe's pose, and projected into any
other frame with that frame's pose, after clipping it against the near plane (a polygon that
reaches behind the camera has no finite image there).

Conventions:

- Polygons are in CVAT image coordinates, as :class:`annotate_rgbd.annotation.model.Shape` holds them
  and :mod:`annotate_rgbd.segment.rasterize` fills them: the top-left image corner is (0, 0), so the centre
  of pixel ``(col, row)`` is ``(col + 0.5, row + 0.5)``. The camera model
  (:mod:`annotate_rgbd.geometry.camera`) puts pixel centres at integers, hence the half-pixel shifts here.
- Poses are camera-to-world, ``X_world = R @ X_camera + t`` (TUM trajectories,
  :mod:`annotate_rgbd.io.poses`); camera frame x right, y down (or up when fy < 0), z forward.
- A plane ``(a, b, c, d)`` holds the points with ``a x + b y + c z + d = 0``; the plane fits of
  :mod:`annotate_rgbd.segment.refine` have a unit normal and ``d >= 0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Camera, backproject, project

#: Default near plane for :func:`project_polygon`, metres: nearer than any depth sensor measures
#: (Kinect and RealSense start at about 0.3-0.5 m), far enough that a vertex just in front of the
#: camera does not project thousands of pixels away.
NEAR = 0.05

#: A vertex's ray counts as parallel to the plane when the cosine of the angle between the ray
#: and the plane's normal is below this (numerically parallel; any steeper ray meets the plane).
PARALLEL_COSINE = 1e-9

RAY_PARALLEL = "ray_parallel_to_plane"
BEHIND_CAMERA = "plane_behind_camera"


@dataclass(frozen=True)
class LiftedPolygon:
    """A keyframe polygon lifted onto its plane, from :func:`lift_polygon`.

    Parameters
    ----------
    world : ndarray of float64, shape (V, 3)
        Vertices in world coordinates, metres; NaN for vertices that failed.
    valid : ndarray of bool, shape (V,)
        Whether each vertex's ray meets the plane in front of the camera.
    reason : str
        ``""`` when every vertex is valid, else why the first failing one failed:
        :data:`RAY_PARALLEL` or :data:`BEHIND_CAMERA`.
    """

    world: np.ndarray
    valid: np.ndarray
    reason: str

    @property
    def ok(self) -> bool:
        """Whether every vertex was lifted."""
        return not self.reason


def pixel_rays(points_px: np.ndarray, camera: Camera) -> np.ndarray:
    """Camera-frame rays ``(x / z, y / z, 1)`` through points in CVAT image coordinates.

    Parameters
    ----------
    points_px : ndarray, shape (V, 2)
        ``(x, y)`` in CVAT image coordinates (pixel centres at half-integers).
    camera : Camera

    Returns
    -------
    ndarray of float64, shape (V, 3)
    """
    points_px = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
    # The camera model puts pixel centres at integers: its point at depth 1 is the ray.
    return backproject(points_px[:, 0] - 0.5, points_px[:, 1] - 0.5, np.ones(len(points_px)), camera)


def lift_polygon(
    points_px: np.ndarray,
    equation: np.ndarray,
    camera: Camera,
    rotation: np.ndarray,
    translation: np.ndarray,
) -> LiftedPolygon:
    """Intersect a polygon's vertex rays with a camera-frame plane, in world coordinates.

    Parameters
    ----------
    points_px : ndarray, shape (V, 2)
        Polygon in CVAT image coordinates on the keyframe.
    equation : ndarray, shape (4,)
        The plane in the keyframe's camera frame (any scale).
    camera : Camera
        Intrinsics.
    rotation : ndarray, shape (3, 3)
        Keyframe camera-to-world rotation.
    translation : ndarray, shape (3,)
        Keyframe camera centre in world coordinates, metres.

    Returns
    -------
    LiftedPolygon
        The world vertices, with the vertices whose ray is parallel to the plane or meets it
        behind (or at) the camera marked invalid.
    """
    equation = np.asarray(equation, dtype=np.float64)
    normal, offset = equation[:3], equation[3]
    rays = pixel_rays(points_px, camera)
    along = rays @ normal  # n . r
    parallel = np.abs(along) <= PARALLEL_COSINE * np.linalg.norm(rays, axis=1) * np.linalg.norm(normal)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(parallel, np.nan, -offset / along)  # the ray's z where it meets the plane
    behind = ~parallel & ~(depth > 0)
    valid = ~(parallel | behind)
    camera_points = rays * np.where(valid, depth, np.nan)[:, None]
    world = camera_points @ np.asarray(rotation, dtype=np.float64).T + np.asarray(translation, dtype=np.float64)
    reason = ""
    if not valid.all():
        first = int(np.argmin(valid))
        reason = RAY_PARALLEL if parallel[first] else BEHIND_CAMERA
    return LiftedPolygon(world, valid, reason)


def world_to_camera(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """World points -> camera-frame points for a camera-to-world pose.

    Parameters
    ----------
    points : ndarray, shape (V, 3)
    rotation : ndarray, shape (3, 3)
    translation : ndarray, shape (3,)

    Returns
    -------
    ndarray of float64, shape (V, 3)
        ``R^T (X - t)`` per point.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return (points - np.asarray(translation, dtype=np.float64)) @ np.asarray(rotation, dtype=np.float64)


def clip_near(points: np.ndarray, near: float = NEAR) -> np.ndarray:
    """The part of a closed polygon with ``z >= near`` (Sutherland-Hodgman against one plane).

    Parameters
    ----------
    points : ndarray, shape (V, 3)
        Camera-frame polygon (planar or not), vertices in order.
    near : float
        The near plane's z, metres.

    Returns
    -------
    ndarray of float64, shape (K, 3)
        The clipped polygon; vertices made by the clip lie exactly on ``z = near``. Empty when
        the polygon lies wholly in front of the plane (``z < near``).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    inside = points[:, 2] >= near
    if inside.all():
        return points.copy()
    following = np.roll(points, -1, axis=0)
    crosses = inside != np.roll(inside, -1)
    with np.errstate(divide="ignore", invalid="ignore"):  # edges that do not cross: unused
        f = (near - points[:, 2]) / (following[:, 2] - points[:, 2])
        crossing = points + f[:, None] * (following - points)
    crossing[:, 2] = near  # exactly on the plane, not a rounding error off it
    # Each edge i -> i+1 emits its start when that is inside, then its crossing if it has one.
    candidates = np.stack([points, crossing], axis=1)  # (V, 2, 3)
    keep = np.stack([inside, crosses], axis=1)
    return candidates[keep]


def project_polygon(
    world: np.ndarray,
    camera: Camera,
    rotation: np.ndarray,
    translation: np.ndarray,
    near: float = NEAR,
) -> np.ndarray:
    """Image of a world polygon in a frame: to the camera frame, clip at ``near``, project.

    Parameters
    ----------
    world : ndarray, shape (V, 3)
        Polygon in world coordinates, metres.
    camera : Camera
        Intrinsics (fy may be negative).
    rotation : ndarray, shape (3, 3)
        The frame's camera-to-world rotation.
    translation : ndarray, shape (3,)
        The frame's camera centre in world coordinates.
    near : float
        Near plane, metres (> 0).

    Returns
    -------
    ndarray of float64, shape (K, 2)
        Polygon in CVAT image coordinates, not clipped to the image; fewer than 3 vertices
        (possibly none) when nothing of it lies in front of the near plane.
    """
    if not near > 0:
        raise ValueError(f"near must be positive, not {near!r}")
    clipped = clip_near(world_to_camera(world, rotation, translation), near)
    if len(clipped) == 0:
        return np.empty((0, 2))
    return project(clipped, camera) + 0.5


def project_polygons(
    polygons: list[np.ndarray],
    camera: Camera,
    rotation: np.ndarray,
    translation: np.ndarray,
    near: float = NEAR,
) -> list[np.ndarray]:
    """:func:`project_polygon` for many polygons at once (one transform and one projection for
    all their vertices; only polygons that reach in front of ``near`` are clipped one by one).

    Returns
    -------
    list of ndarray of float64, shape (K, 2)
        One per polygon, as :func:`project_polygon` gives it.
    """
    if not near > 0:
        raise ValueError(f"near must be positive, not {near!r}")
    if not polygons:
        return []
    sizes = [len(p) for p in polygons]
    camera_points = world_to_camera(np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in polygons]),
                                    rotation, translation)
    ends = np.cumsum(sizes)
    behind = np.add.reduceat(camera_points[:, 2] < near, np.r_[0, ends[:-1]]) if camera_points.size else np.zeros(0)
    projected = project(np.where(camera_points[:, 2:3] < near, np.array([0.0, 0.0, 1.0]), camera_points), camera) + 0.5
    result = []
    for i, (start, end) in enumerate(zip(np.r_[0, ends[:-1]], ends)):
        if sizes[i] == 0:
            result.append(np.empty((0, 2)))
        elif behind[i]:
            clipped = clip_near(camera_points[start:end], near)
            result.append(project(clipped, camera) + 0.5 if len(clipped) else np.empty((0, 2)))
        else:
            result.append(projected[start:end])
    return result


def plane_to_world(equation: np.ndarray, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """A camera-frame plane in world coordinates.

    Parameters
    ----------
    equation : ndarray, shape (4,) or (K, 4)
        ``(a, b, c, d)`` in the camera frame (or K such planes).
    rotation, translation : ndarray, shapes (3, 3) and (3,)
        Camera-to-world pose.

    Returns
    -------
    ndarray of float64, shape of ``equation``
        The same plane in the world frame, same scale: normal ``R n``, offset ``d - (R n) . t``.
    """
    equation = np.asarray(equation, dtype=np.float64)
    normal = equation[..., :3] @ np.asarray(rotation, dtype=np.float64).T
    offset = equation[..., 3] - normal @ np.asarray(translation, dtype=np.float64)
    return np.concatenate([normal, np.asarray(offset)[..., None]], axis=-1)


def plane_to_camera(equation: np.ndarray, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """A world plane in a camera's frame (inverse of :func:`plane_to_world`).

    Parameters
    ----------
    equation : ndarray, shape (4,)
        ``(a, b, c, d)`` in the world frame.
    rotation, translation : ndarray, shapes (3, 3) and (3,)
        Camera-to-world pose.

    Returns
    -------
    ndarray of float64, shape (4,)
        Normal ``R^T n``, offset ``d + n . t``.
    """
    equation = np.asarray(equation, dtype=np.float64)
    normal = equation[:3]
    return np.append(
        np.asarray(rotation, dtype=np.float64).T @ normal,
        equation[3] + normal @ np.asarray(translation, dtype=np.float64),
    )


def plane_agreement(
    first: np.ndarray, second: np.ndarray, at: np.ndarray | None = None
) -> tuple[float, float]:
    """How far apart two planes are: the angle between their normals and their offset at a point.

    Orientation does not matter: ``(n, d)`` and ``(-n, -d)`` are the same plane.

    Parameters
    ----------
    first : ndarray, shape (4,)
        A plane (e.g. the world plane lifted from a keyframe of a track), any scale.
    second : ndarray, shape (4,) or (K, 4)
        A plane in the same frame, or K of them (each compared with ``first``).
    at : ndarray, shape (3,) or (K, 3), optional
        Where to compare the offsets: the difference of the two planes' signed distances from
        this point (one per plane of ``second``). Give a point of the surface (e.g. the lifted
        polygon's centroid): for planes that are not quite parallel the gap between them grows
        with the distance from where they cross, so the origin (the default) can be metres
        away from the surface.

    Returns
    -------
    angle : float, or ndarray of float64 of shape (K,)
        Angle between the normals, degrees, in [0, 90].
    offset : float, or ndarray of float64 of shape (K,)
        Difference of the signed distances of ``at`` from the two planes, metres (for parallel
        planes, the distance between them).
    """
    first = np.asarray(first, dtype=np.float64)
    second = np.asarray(second, dtype=np.float64)
    first = first / np.linalg.norm(first[:3])
    second = second / np.linalg.norm(second[..., :3], axis=-1, keepdims=True)
    second = second * np.where(second[..., :3] @ first[:3] < 0, -1.0, 1.0)[..., None]
    # atan2 of cross and dot keeps tiny angles accurate (arccos of a dot near 1 does not).
    cross = np.linalg.norm(np.cross(first[:3], second[..., :3]), axis=-1)
    angle = np.degrees(np.arctan2(cross, second[..., :3] @ first[:3]))
    point = np.zeros(3) if at is None else np.asarray(at, dtype=np.float64)
    offset = np.abs((point @ first[:3] + first[3]) - (np.sum(point * second[..., :3], axis=-1) + second[..., 3]))
    if second.ndim == 1:
        return float(angle), float(offset)
    return angle, offset

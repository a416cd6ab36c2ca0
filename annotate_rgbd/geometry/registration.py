"""Colour and depth on different pixel grids: where each depth pixel lies in the colour image.

A labeller draws on the colour image; masks live on the depth grid. TUM RGB-D and ICL-NUIM
register depth to colour (one grid: nothing to do here). Other sensors do not: ScanNet's colour
images are 1296 x 968 with their own intrinsics, Kinect v2, Azure Kinect and unaligned
RealSense streams have their own intrinsics and a depth-to-colour extrinsic. Each depth pixel is
back-projected with the depth camera, moved into the colour camera's frame by the extrinsic and
projected with the colour intrinsics; it takes the label of the colour pixel it lands on
(:func:`colour_pixel_grid`, :func:`sample_labels`). ``propose`` and ``export-cvat`` go the other
way, a polygon traced on the depth grid onto the colour image the labeller draws on
(:func:`polygon_on_colour_image`).

Conventions
-----------
- The extrinsic maps depth-camera coordinates to colour-camera coordinates (metres):
  ``X_colour = R @ X_depth + t``. Both camera frames are x right, y down, z forward (OpenCV).
- Pixel centres at integer coordinates, as in :mod:`annotate_rgbd.geometry.camera`.
- A pixel without depth has no 3-D point: it is placed at the frame's median valid depth (its
  label then only counts towards its plane's share of pixels without depth, the ``invalid_depth``
  drop rule; refinement never keeps a pixel without depth).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import cv2
import numpy as np

from .camera import Camera, ray_grid

#: Largest colour image side accepted (pixels): beyond any RGB-D sensor, and a bound on the
#: label image a frame rasterises.
MAX_COLOUR_SIDE = 20000
#: Largest deviation of ``R^T R`` from the identity for ``R`` to count as a rotation (calibration
#: files print 6 to 9 digits).
ROTATION_TOLERANCE = 1e-4
#: Keys of a ``[colour_camera]`` section.
INTRINSIC_KEYS = ("fx", "fy", "cx", "cy")
SIZE_KEYS = ("width", "height")
EXTRINSIC_KEYS = ("extrinsic", "rotation", "translation")


@dataclass(frozen=True)
class ColourCamera:
    """The colour camera, when its pixel grid is not the depth camera's.

    Parameters
    ----------
    fx, fy, cx, cy : float
        Pinhole intrinsics of the colour images, pixels (centres at integers).
    width, height : int
        Size of the colour images (the images the labeller drew on).
    rotation : tuple of 3 tuples of 3 float
        ``R`` of the depth-to-colour extrinsic, ``X_colour = R @ X_depth + t``.
    translation : tuple of 3 float
        ``t`` of the extrinsic, metres.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    rotation: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def intrinsics(self) -> Camera:
        """The colour intrinsics as a :class:`Camera` (its ``depth_scale`` is unused: 1)."""
        return Camera(fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy, depth_scale=1.0)

    @property
    def extrinsic(self) -> np.ndarray:
        """The 4 x 4 depth-to-colour transform."""
        matrix = np.eye(4)
        matrix[:3, :3] = self.rotation
        matrix[:3, 3] = self.translation
        return matrix

    def to_mapping(self) -> dict[str, Any]:
        """The ``[colour_camera]`` section as plain values (the extrinsic as a 4 x 4 list)."""
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy, "width": self.width,
                "height": self.height, "extrinsic": self.extrinsic.tolist()}


def colour_camera_from_mapping(values: Mapping[str, Any]) -> ColourCamera:
    """Build a :class:`ColourCamera` from a ``[colour_camera]`` section.

    ``fx``, ``fy``, ``cx``, ``cy``, ``width`` and ``height`` are required; the extrinsic is
    either ``extrinsic`` (4 x 4, last row ``0 0 0 1``) or ``rotation`` (3 x 3) with
    ``translation`` (3, metres); neither: the cameras share their centre and axes (only the
    intrinsics and the size differ).

    Parameters
    ----------
    values : mapping of str to value

    Returns
    -------
    ColourCamera

    Raises
    ------
    ValueError
        One line naming the key: unknown or missing key, a value of the wrong type or shape, not
        finite, ``fx`` or ``fy`` 0, a size out of range, a rotation that is not one.
    """
    known = INTRINSIC_KEYS + SIZE_KEYS + EXTRINSIC_KEYS
    for key in values:
        if key not in known:
            raise ValueError(f"unknown key 'colour_camera.{key}' (known in [colour_camera]: {', '.join(known)})")
    for key in INTRINSIC_KEYS + SIZE_KEYS:
        if key not in values:
            raise ValueError(f"'colour_camera.{key}' is missing ([colour_camera] needs {', '.join(INTRINSIC_KEYS + SIZE_KEYS)})")
    intrinsics = {key: _number(key, values[key]) for key in INTRINSIC_KEYS}
    for key in ("fx", "fy"):
        if intrinsics[key] == 0:
            raise ValueError(f"'colour_camera.{key}' must not be 0")
    size = {}
    for key in SIZE_KEYS:
        value = values[key]
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_COLOUR_SIDE:
            raise ValueError(f"'colour_camera.{key}' must be an integer in [1, {MAX_COLOUR_SIDE}], got {value!r}")
        size[key] = value
    if "extrinsic" in values and ("rotation" in values or "translation" in values):
        raise ValueError("give 'colour_camera.extrinsic' or 'rotation' and 'translation', not both")
    if "extrinsic" in values:
        matrix = _matrix("extrinsic", values["extrinsic"], 4)
        if not np.allclose(matrix[3], (0.0, 0.0, 0.0, 1.0), atol=1e-9):
            raise ValueError("'colour_camera.extrinsic' must end with the row [0, 0, 0, 1]")
        rotation, translation = matrix[:3, :3], matrix[:3, 3]
    else:
        rotation = _matrix("rotation", values["rotation"], 3) if "rotation" in values else np.eye(3)
        translation = _vector("translation", values["translation"]) if "translation" in values else np.zeros(3)
    if not np.allclose(rotation.T @ rotation, np.eye(3), atol=ROTATION_TOLERANCE) or np.linalg.det(rotation) <= 0:
        raise ValueError("the rotation of 'colour_camera' is not a rotation (R^T R must be the identity, det R = 1)")
    return ColourCamera(
        **intrinsics, **size,
        rotation=tuple(tuple(float(v) for v in row) for row in rotation),
        translation=tuple(float(v) for v in translation),
    )


def colour_pixel_grid(depth_m: np.ndarray, depth_camera: Camera, colour: ColourCamera) -> tuple[np.ndarray, np.ndarray]:
    """Where every depth pixel lies in the colour image.

    Parameters
    ----------
    depth_m : ndarray of float, shape (H, W)
        Depth in metres, NaN where invalid.
    depth_camera : Camera
        Intrinsics of the depth camera.
    colour : ColourCamera

    Returns
    -------
    map_x, map_y : ndarray of float32, shape (H, W)
        Colour image coordinates (column, row; pixel centres at integers) of each depth pixel's
        point. Pixels without depth are placed at the frame's median valid depth (at infinity
        when the frame has none: only the rotation moves them); a point at or behind the colour
        camera's centre plane gets ``-1`` (off the image).
    """
    height, width = depth_m.shape
    valid = np.isfinite(depth_m)
    fill = _typical_depth(depth_m, valid)
    translation = np.asarray(colour.translation, dtype=np.float32)
    if fill is None:  # no depth at all: every pixel at infinity, where only the rotation counts
        z, translation = np.ones((height, width), dtype=np.float32), np.zeros(3, dtype=np.float32)
    else:
        z = np.where(valid, depth_m, np.float32(fill)).astype(np.float32, copy=False)
    ray_x, ray_y = (ray.astype(np.float32) for ray in ray_grid(depth_camera, height, width))
    rotation = np.asarray(colour.rotation, dtype=np.float32)
    # X_colour = R @ (z * ray) + t, one component at a time, in place (float32: 0.001 px at
    # 10,000 px); then the colour pinhole projection.
    x, y, zc = ((row[0] * ray_x)[None, :] + (row[1] * ray_y)[:, None] + row[2] for row in rotation)
    for component, t in zip((x, y, zc), translation):
        component *= z
        component += t
    behind = zc <= 0
    with np.errstate(divide="ignore", invalid="ignore"):
        np.divide(np.float32(1.0), zc, out=zc)
    for component, focal, centre in ((x, colour.fx, colour.cx), (y, colour.fy, colour.cy)):
        component *= zc
        component *= np.float32(focal)
        component += np.float32(centre)
        component[behind] = -1.0
    return x, y


#: Pixels without depth are placed at the median depth of every SAMPLE_STEP-th row and column.
SAMPLE_STEP = 4


def _typical_depth(depth_m: np.ndarray, valid: np.ndarray) -> float | None:
    """The median valid depth of a sparse grid of the frame (of all of it when the grid has
    none); None without any valid depth."""
    sample = depth_m[::SAMPLE_STEP, ::SAMPLE_STEP]
    sample = sample[np.isfinite(sample)]
    if sample.size == 0:
        sample = depth_m[valid]
    return float(np.median(sample)) if sample.size else None


def sample_labels(colour_labels: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """The label of the colour pixel nearest each depth pixel's position (0 off the image).

    Parameters
    ----------
    colour_labels : ndarray of int, shape (Hc, Wc)
        A label image on the colour grid.
    map_x, map_y : ndarray of float32, shape (H, W)
        :func:`colour_pixel_grid`.

    Returns
    -------
    ndarray, shape (H, W), dtype of ``colour_labels``
    """
    if colour_labels.dtype in (np.uint8, np.uint16):  # OpenCV's nearest-neighbour remap (ties round up)
        return cv2.remap(colour_labels, map_x, map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    rows_c, cols_c = colour_labels.shape
    cols = np.floor(map_x + np.float32(0.5))
    rows = np.floor(map_y + np.float32(0.5))
    inside = (cols >= 0) & (cols <= cols_c - 1) & (rows >= 0) & (rows <= rows_c - 1)
    labels = np.zeros(map_x.shape, dtype=colour_labels.dtype)
    labels[inside] = colour_labels[rows[inside].astype(np.intp), cols[inside].astype(np.intp)]
    return labels


def polygon_on_colour_image(points: np.ndarray, plane: np.ndarray, depth_camera: Camera, colour: ColourCamera,
                            fallback_depth: float) -> np.ndarray:
    """A polygon drawn on the depth image, as it lies on the colour image: the way back from
    the depth grid to the image the labeller draws on (``propose``, ``export-cvat``).

    The polygon outlines a planar region, so each vertex is taken where its viewing ray meets
    the plane (the points of one plane map between the two images by a homography: straight
    edges stay straight), moved into the colour camera by the extrinsic and projected. A vertex
    whose ray meets the plane nowhere in front of the camera (a ray along the plane) is taken at
    ``fallback_depth``. A depth pixel whose centre lies inside the polygon then lands inside the
    mapped polygon (:func:`colour_pixel_grid`, :func:`sample_labels`) wherever its measured depth
    lies on the plane.

    Parameters
    ----------
    points : ndarray of float, shape (V, 2)
        Vertices ``(x, y)`` in CVAT coordinates of the depth image (pixel ``(col, row)`` has its
        centre at ``(col + 0.5, row + 0.5)``).
    plane : ndarray of float, shape (4,)
        ``(a, b, c, d)``: ``a x + b y + c z + d = 0`` in the depth camera's frame, metres.
    depth_camera : Camera
    colour : ColourCamera
    fallback_depth : float
        Depth (m along the depth camera's axis) of a vertex whose ray misses the plane.

    Returns
    -------
    ndarray of float64, shape (V, 2)
        The vertices in CVAT coordinates of the colour image.
    """
    points = np.asarray(points, dtype=np.float64)
    a, b, c, d = (float(v) for v in plane)
    ray_x = (points[:, 0] - 0.5 - depth_camera.cx) / depth_camera.fx
    ray_y = (points[:, 1] - 0.5 - depth_camera.cy) / depth_camera.fy
    with np.errstate(divide="ignore", invalid="ignore"):
        z = -d / (a * ray_x + b * ray_y + c)
    z = np.where(np.isfinite(z) & (z > 0), z, fallback_depth)
    camera_points = np.stack([ray_x * z, ray_y * z, z], axis=1)
    moved = camera_points @ np.asarray(colour.rotation, dtype=np.float64).T + np.asarray(colour.translation)
    zc = np.maximum(moved[:, 2], 1e-6)  # a vertex at or behind the colour camera: far off its image
    return np.stack([colour.fx * moved[:, 0] / zc + colour.cx + 0.5, colour.fy * moved[:, 1] / zc + colour.cy + 0.5],
                    axis=1)


def clip_to_image(points: np.ndarray, width: int, height: int) -> np.ndarray:
    """A polygon clipped to the image ``[0, width] x [0, height]`` (CVAT coordinates), as CVAT
    keeps its shapes (it would move a vertex beyond the image onto its edge, bending the edges
    that meet there). Sutherland-Hodgman, one image edge at a time.

    Parameters
    ----------
    points : ndarray of float, shape (V, 2)
    width, height : int

    Returns
    -------
    ndarray of float64, shape (V', 2)
        The part inside the image; fewer than 3 vertices when the polygon lies outside it.
    """
    points = np.asarray(points, dtype=np.float64)
    for axis, limit, keep_above in ((0, 0.0, True), (0, float(width), False), (1, 0.0, True), (1, float(height), False)):
        if len(points) == 0:
            break
        sign = 1.0 if keep_above else -1.0
        inside = sign * (points[:, axis] - limit) >= 0
        if inside.all():
            continue
        following = np.roll(points, -1, axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):  # edges along the image edge: never used
            share = (limit - points[:, axis]) / (following[:, axis] - points[:, axis])
            crossing = points + share[:, None] * (following - points)
        crossing[:, axis] = limit  # exactly on the edge
        # Each vertex gives itself when inside, then the crossing of its edge when that edge
        # crosses the image edge.
        candidates = np.stack([points, crossing], axis=1).reshape(-1, 2)
        keep = np.stack([inside, inside != np.roll(inside, -1)], axis=1).reshape(-1)
        points = candidates[keep]
    return points


def colour_pose(rotation: np.ndarray, translation: np.ndarray, colour: ColourCamera) -> tuple[np.ndarray, np.ndarray]:
    """The colour camera's camera-to-world pose from the depth camera's.

    Parameters
    ----------
    rotation : ndarray, shape (3, 3)
        Depth camera-to-world rotation.
    translation : ndarray, shape (3,)
        Depth camera centre in world coordinates, metres.
    colour : ColourCamera

    Returns
    -------
    (ndarray (3, 3), ndarray (3,))
        ``X_world = R_wd R^T (X_colour - t) + t_wd``.
    """
    r_cd = np.asarray(colour.rotation, dtype=np.float64)
    r_wc = np.asarray(rotation, dtype=np.float64) @ r_cd.T
    return r_wc, np.asarray(translation, dtype=np.float64) - r_wc @ np.asarray(colour.translation, dtype=np.float64)


def _number(key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"'colour_camera.{key}' must be a finite number, got {value!r}")
    return float(value)


def _matrix(key: str, value: Any, size: int) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or len(value) != size or not all(
        isinstance(row, (list, tuple)) and len(row) == size for row in value
    ):
        raise ValueError(f"'colour_camera.{key}' must be a {size} x {size} list of rows, e.g. [[1, 0, 0], ...]")
    return np.array([[_number(key, v) for v in row] for row in value], dtype=np.float64)


def _vector(key: str, value: Any) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ValueError(f"'colour_camera.{key}' must be a list of 3 numbers (metres)")
    return np.array([_number(key, v) for v in value], dtype=np.float64)

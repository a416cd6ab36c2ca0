"""Synthetic RGB-D room scenes with exact plane ground truth, for tests, benchmarks and samples.

A scene is a set of planar rectangles (walls, floor, a table top, cabinet faces, ...) and
non-planar clutter (spheres, cylinders). Every frame is ray-cast analytically with numpy, all
pixels at once, from a pose on a smooth camera trajectory. The depth gets Kinect-like noise and
holes, the RGB image flat-shaded colours with a mild texture, and every plane the polygon a
labeller would draw: its outline projected into the image, running straight over clutter and
nearer planes, with a ``z_order`` that puts nearer planes on top.

:func:`make_sequence` writes all of it as a TUM RGB-D sequence plus ground truth and returns the
annotation as the format-neutral model (:mod:`annotate_rgbd.annotation`).

World frame: metres, z up. Camera frame: x right, y down, z forward (the pinhole model of
:mod:`annotate_rgbd.camera`). A frame's RGB and depth images are rendered from the same pose
(registered, like TUM's depth images); only their timestamps differ.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from .annotation import Annotation, Shape, Track
from .camera import Camera, project

#: Kinect range: no depth nearer than this or farther than ``MAX_DEPTH`` (metres).
MIN_DEPTH = 0.4
MAX_DEPTH = 5.0
#: Rays start this far in front of the camera; polygons are clipped against this plane.
NEAR = 0.01
#: EVOPS filter rules used to state the expected fate of each plane in ``planes.json``.
MAX_MEAN_DISTANCE = 3.5
MAX_INVALID_RATIO = 0.8


@dataclass(frozen=True)
class Plane:
    """A planar rectangle: ``centre + a * edge_u + b * edge_v`` for ``a, b`` in [-0.5, 0.5].

    Parameters
    ----------
    label : str
        The CVAT label a labeller gives it ("floor", "wall_left", ...).
    centre, edge_u, edge_v : tuple of float
        Centre and the two (orthogonal) full edge vectors in world coordinates, metres. For
        walls ``edge_v`` points up, so ``b = -0.5`` is the lower edge.
    colour : tuple of int
        Base RGB colour.
    z_order : int
        Drawing order of its polygon: higher is drawn on top. It must put a plane above every
        plane it can occlude, as a labeller does (table over floor, cabinet over wall).
    openings : tuple of (a0, a1, b0, b1)
        Rectangular holes in ``(a, b)`` coordinates (a doorway, a window frame). An opening that
        reaches the lower edge (a door) is cut out of the drawn outline; other openings stay
        inside it, as when a labeller draws the window as its own polygon on top of the wall.
    valid_fraction : float
        Share of its pixels where the sensor returns depth (glass: about 0.1).
    texture : {"plain", "plaster", "tiles", "wood", "glass"}
        Mild shading pattern of its RGB colour.
    """

    label: str
    centre: tuple[float, float, float]
    edge_u: tuple[float, float, float]
    edge_v: tuple[float, float, float]
    colour: tuple[int, int, int]
    z_order: int = 0
    openings: tuple[tuple[float, float, float, float], ...] = ()
    valid_fraction: float = 1.0
    texture: str = "plain"

    def outline(self) -> np.ndarray:
        """The outline a labeller draws, as world points, shape (N, 3)."""
        lower = [(-0.5, -0.5)]
        for a0, a1, b0, b1 in sorted(self.openings):
            if b0 <= -0.5:
                lower += [(a0, -0.5), (a0, b1), (a1, b1), (a1, -0.5)]
        ab = np.array(lower + [(0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)])
        return (
            np.asarray(self.centre)
            + ab[:, :1] * np.asarray(self.edge_u)
            + ab[:, 1:] * np.asarray(self.edge_v)
        )


@dataclass(frozen=True)
class Sphere:
    """A ball of clutter.

    Parameters
    ----------
    centre : tuple of float
        World coordinates, metres.
    radius : float
        Metres.
    colour : tuple of int
        RGB.
    """

    centre: tuple[float, float, float]
    radius: float
    colour: tuple[int, int, int]


@dataclass(frozen=True)
class Cylinder:
    """A closed cylinder of clutter from ``base`` along the unit ``axis`` for ``height``.

    Parameters
    ----------
    base : tuple of float
        Centre of the bottom disc, world coordinates, metres.
    axis : tuple of float
        Unit direction from the bottom to the top disc.
    height, radius : float
        Metres.
    colour : tuple of int
        RGB.
    """

    base: tuple[float, float, float]
    axis: tuple[float, float, float]
    height: float
    radius: float
    colour: tuple[int, int, int]


Clutter = Sphere | Cylinder


@dataclass(frozen=True)
class Scene:
    """Planes and clutter. Object index ``k`` in rendered images is ``planes[k]`` for
    ``k < len(planes)``, else ``clutter[k - len(planes)]``; -1 is background (nothing hit).

    Parameters
    ----------
    planes : tuple of Plane
    clutter : tuple of Sphere or Cylinder
    light : tuple of float
        Direction towards the light in world coordinates (need not be unit length).
    """

    planes: tuple[Plane, ...]
    clutter: tuple[Clutter, ...] = ()
    light: tuple[float, float, float] = (-0.3, -0.6, 1.0)


@dataclass(frozen=True)
class Pose:
    """Camera pose in the world.

    Parameters
    ----------
    rotation : ndarray, shape (3, 3)
        Camera-to-world rotation: its columns are the camera's x (right), y (down) and
        z (forward) axes in world coordinates.
    position : ndarray, shape (3,)
        Camera centre in world coordinates.
    """

    rotation: np.ndarray
    position: np.ndarray

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> camera-frame points (N, 3)."""
        return (np.asarray(points, dtype=np.float64) - self.position) @ self.rotation

    def direction_to_camera(self, vectors: np.ndarray) -> np.ndarray:
        """World directions (N, 3) -> camera-frame directions (N, 3)."""
        return np.asarray(vectors, dtype=np.float64) @ self.rotation


@dataclass
class Render:
    """One noise-free rendered frame.

    Parameters
    ----------
    depth : ndarray of float32, shape (H, W)
        z depth in metres of the nearest surface; 0 where nothing is hit.
    object_index : ndarray of int16, shape (H, W)
        Index of the visible object (see :class:`Scene`), -1 for background.
    rgb : ndarray of uint8, shape (H, W, 3)
    """

    depth: np.ndarray
    object_index: np.ndarray
    rgb: np.ndarray


def room_scene() -> Scene:
    """A small office: floor, three walls, a doorway onto a corridor, a window, a table with
    clutter and a cabinet.

    The corridor wall behind the doorway is about 4.5 m from the camera (mean distance above
    3.5 m), the window is glass (about 90 % of its pixels have no depth); every other plane
    stays within about 3 m, where Kinect noise is below 1.5 cm.

    Returns
    -------
    Scene
    """
    up = (0.0, 0.0, 1.0)
    planes = (
        # x from -1.6 to 2.8 so that rays through the doorway land on it, y from -1.0 to 4.2.
        Plane("floor", (0.6, 1.6, 0.0), (4.4, 0.0, 0.0), (0.0, 5.2, 0.0), (150, 120, 90), 0,
              texture="tiles"),
        Plane("wall_corridor", (0.6, 4.2, 1.3), (4.4, 0.0, 0.0), (0.0, 0.0, 2.6), (120, 150, 170), 0,
              texture="plaster"),
        Plane("wall_back", (0.0, 2.2, 1.3), (3.2, 0.0, 0.0), (0.0, 0.0, 2.6), (205, 200, 185), 1,
              # Doorway: x 0.2..1.1 m, floor to 2.0 m.
              openings=((0.2 / 3.2, 1.1 / 3.2, -0.5, 0.7 / 2.6),), texture="plaster"),
        Plane("wall_left", (-1.6, 0.6, 1.3), (0.0, 3.2, 0.0), (0.0, 0.0, 2.6), (185, 195, 205), 1,
              # Window: y 0.9..1.9 m, z 1.0..2.1 m.
              openings=((0.3 / 3.2, 1.3 / 3.2, -0.3 / 2.6, 0.8 / 2.6),), texture="plaster"),
        Plane("wall_right", (1.6, 0.6, 1.3), (0.0, -3.2, 0.0), (0.0, 0.0, 2.6), (200, 185, 190), 1,
              texture="plaster"),
        # The glass, flush with the window opening of wall_left.
        Plane("window", (-1.6, 1.4, 1.55), (0.0, 1.0, 0.0), (0.0, 0.0, 1.1), (170, 210, 235), 2,
              valid_fraction=0.1, texture="glass"),
        Plane("cabinet_front", (-1.1, 1.75, 0.5), (0.8, 0.0, 0.0), (0.0, 0.0, 1.0), (110, 80, 60), 3,
              texture="wood"),
        Plane("cabinet_top", (-1.1, 1.975, 1.0), (0.8, 0.0, 0.0), (0.0, 0.45, 0.0), (125, 92, 70), 3,
              texture="wood"),
        Plane("cabinet_side", (-0.7, 1.975, 0.5), (0.0, 0.45, 0.0), (0.0, 0.0, 1.0), (100, 72, 55), 3,
              texture="wood"),
        Plane("table_top", (0.1, 1.05, 0.74), (1.2, 0.0, 0.0), (0.0, 0.7, 0.0), (190, 150, 100), 4,
              texture="wood"),
    )
    legs = tuple(
        Cylinder((0.1 + dx, 1.05 + dy, 0.0), up, 0.73, 0.025, (70, 70, 75))
        for dx in (-0.54, 0.54)
        for dy in (-0.29, 0.29)
    )
    # Balls rest on the table at a point, so that few of their pixels come within a RANSAC
    # threshold of it (the share grows as the radius shrinks).
    clutter = legs + (
        Sphere((-0.2, 0.95, 0.74 + 0.12), 0.12, (200, 60, 50)),
        Sphere((0.42, 1.2, 0.74 + 0.1), 0.1, (60, 110, 190)),
        Cylinder((1.05, 0.9, 0.0), up, 0.55, 0.14, (90, 150, 140)),
    )
    return Scene(planes, clutter)


def look_at(position: np.ndarray, target: np.ndarray) -> Pose:
    """The pose of a camera at ``position`` looking at ``target``, with no roll (world z up).

    Parameters
    ----------
    position, target : array_like, shape (3,)
        World coordinates.

    Returns
    -------
    Pose
    """
    position = np.asarray(position, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - position
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, (0.0, 0.0, 1.0))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return Pose(np.stack([right, down, forward], axis=1), position)


def room_trajectory(n_frames: int) -> list[Pose]:
    """A smooth hand-held pan across :func:`room_scene`, from the window corner to the doorway.

    The path is the same for any ``n_frames``; more frames sample it more densely.

    Parameters
    ----------
    n_frames : int

    Returns
    -------
    list of Pose
    """
    s = np.linspace(0.0, 1.0, n_frames)
    ease = (1.0 - np.cos(np.pi * s)) / 2.0
    positions = np.stack(
        [
            0.5 - 0.6 * ease,
            -0.45 + 0.15 * np.sin(np.pi * s),
            1.5 - 0.08 * ease + 0.02 * np.sin(3 * np.pi * s),
        ],
        axis=1,
    )
    targets = np.stack(
        [-1.0 + 1.9 * ease, 1.7 + 0.3 * ease, 0.75 + 0.1 * np.sin(np.pi * s)], axis=1
    )
    return [look_at(p, t) for p, t in zip(positions, targets)]


def _ray_grid(camera: Camera, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-column x/z and per-row y/z of the pixel-centre rays (rays are ``(x, y, 1)``)."""
    cols = ((np.arange(width) - camera.cx) / camera.fx).astype(np.float32)
    rows = ((np.arange(height) - camera.cy) / camera.fy).astype(np.float32)
    return cols, rows


def _dot(vector: np.ndarray, cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``ray . vector`` for every pixel of the window spanned by ``rows`` x ``cols``, float32."""
    v = np.asarray(vector, dtype=np.float32)
    return v[0] * cols[None, :] + (v[1] * rows + v[2])[:, None]


def _window(points: np.ndarray, camera: Camera, width: int, height: int) -> tuple[int, int, int, int] | None:
    """Pixel window ``(row0, row1, col0, col1)`` that holds the projection of the convex hull of
    camera-frame ``points``: the whole image if any point is behind the near plane, None if the
    hull projects outside the image."""
    if len(points) == 0:
        return None
    if np.any(points[:, 2] <= NEAR):
        return 0, height, 0, width
    uv = project(points, camera)
    (c0, r0), (c1, r1) = np.floor(uv.min(axis=0)) - 1, np.ceil(uv.max(axis=0)) + 2
    c0, c1 = int(max(c0, 0)), int(min(c1, width))
    r0, r1 = int(max(r0, 0)), int(min(r1, height))
    return (r0, r1, c0, c1) if c0 < c1 and r0 < r1 else None


def _box_corners(low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The 8 corners of the axis-aligned box from ``low`` to ``high``, shape (8, 3)."""
    pick = np.array(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")).reshape(3, -1).T
    return np.where(pick == 0, low, high)


def _extent(item: Plane | Clutter, pose: Pose, camera: Camera, width: int, height: int) -> np.ndarray:
    """Camera-frame points whose convex hull holds ``item``, or for a plane the image polygon
    lifted to z = 1 (so that it projects onto itself)."""
    if isinstance(item, Plane):
        polygon = plane_polygon(item, pose, camera, width, height)
        if polygon is None:
            return np.empty((0, 3))
        return np.column_stack(
            [(polygon[:, 0] - 0.5 - camera.cx) / camera.fx, (polygon[:, 1] - 0.5 - camera.cy) / camera.fy,
             np.ones(len(polygon))]
        )
    if isinstance(item, Sphere):
        centre = pose.to_camera(np.asarray([item.centre]))[0]
        return _box_corners(centre - item.radius, centre + item.radius)
    ends = pose.to_camera(np.asarray([item.base, np.add(item.base, np.multiply(item.height, item.axis))]))
    return _box_corners(ends.min(axis=0) - item.radius, ends.max(axis=0) + item.radius)


def _cast_plane(plane: Plane, pose: Pose, cols, rows, ray_norm2, light):
    """Depth of the ray hits on the plane's rectangle minus openings, where they hit, and the
    brightness there."""
    centre = pose.to_camera(np.asarray([plane.centre]))[0]
    edge_u, edge_v = pose.direction_to_camera(np.asarray([plane.edge_u, plane.edge_v]))
    normal = np.cross(edge_u, edge_v)
    offset = normal @ centre
    # With t = offset / (normal . ray), the plane coordinate a = (t * ray - centre) . edge_u /
    # |edge_u|^2 is (ray . pa) / (ray . normal) for a fixed vector pa; likewise b.
    pa = (offset * edge_u - (edge_u @ centre) * normal) / (edge_u @ edge_u)
    pb = (offset * edge_v - (edge_v @ centre) * normal) / (edge_v @ edge_v)
    with np.errstate(divide="ignore"):
        inverse = np.reciprocal(_dot(normal, cols, rows))
    t = inverse * np.float32(offset)
    a = _dot(pa, cols, rows)
    a *= inverse
    b = _dot(pb, cols, rows)
    b *= inverse
    with np.errstate(invalid="ignore"):
        hit = (t > NEAR) & (np.abs(a) <= 0.5) & (np.abs(b) <= 0.5)
    for a0, a1, b0, b1 in plane.openings:
        hit &= ~((a > a0) & (a < a1) & (b > b0) & (b < b1))
    facing = -np.sign(offset) * normal / np.linalg.norm(normal)
    lambert = 0.6 + 0.4 * max(float(facing @ light), 0.0)
    a *= np.float32(np.linalg.norm(edge_u))
    b *= np.float32(np.linalg.norm(edge_v))
    return t, hit, lambert * _plane_texture(plane.texture, a, b)


def _cast_sphere(sphere: Sphere, pose: Pose, cols, rows, ray_norm2, light):
    centre = pose.to_camera(np.asarray([sphere.centre]))[0]
    dc = _dot(centre, cols, rows)
    disc = dc * dc - ray_norm2 * np.float32(centre @ centre - sphere.radius**2)
    with np.errstate(invalid="ignore"):
        t = (dc - np.sqrt(disc)) / ray_norm2
    # Lambert with the outward normal (t * ray - centre) / radius.
    cosine = (t * _dot(light, cols, rows) - np.float32(centre @ light)) / np.float32(sphere.radius)
    shade = 0.45 + 0.55 * np.clip(np.nan_to_num(cosine), 0.0, 1.0)
    with np.errstate(invalid="ignore"):
        return t, (disc >= 0) & (t > NEAR), shade


def _cast_cylinder(cyl: Cylinder, pose: Pose, cols, rows, ray_norm2, light):
    base = pose.to_camera(np.asarray([cyl.base]))[0]
    axis = pose.direction_to_camera(np.asarray([cyl.axis]))[0]
    offset = -base  # camera centre relative to the base
    offset_perp = offset - (offset @ axis) * axis
    da = _dot(axis, cols, rows)
    with np.errstate(divide="ignore", invalid="ignore"):
        # Side: |perp(t * ray + offset)|^2 = r^2, within the height.
        quad_a = ray_norm2 - da * da
        quad_b = _dot(offset_perp, cols, rows)
        disc = quad_b * quad_b - quad_a * np.float32(offset_perp @ offset_perp - cyl.radius**2)
        t = (-quad_b - np.sqrt(disc)) / quad_a
        along = np.float32(offset @ axis) + t * da
        t = np.where((disc >= 0) & (t > NEAR) & (along >= 0) & (along <= cyl.height), t, np.inf)
        # Lambert with the outward normal (t * ray - base - along * axis) / radius.
        cosine = (t * _dot(light, cols, rows) - np.float32(base @ light)
                  - along * np.float32(axis @ light)) / np.float32(cyl.radius)
        shade = 0.45 + 0.55 * np.clip(np.nan_to_num(cosine), 0.0, 1.0)
        # Caps: the discs at along = 0 (normal -axis) and along = height (normal +axis).
        for cap_height, sign in ((0.0, -1.0), (cyl.height, 1.0)):
            centre = base + cap_height * axis
            t_cap = np.float32(centre @ axis) / da
            dist2 = t_cap * t_cap * ray_norm2 - 2 * t_cap * _dot(centre, cols, rows) + np.float32(
                centre @ centre
            )
            on_cap = (t_cap > NEAR) & (dist2 <= cyl.radius**2) & (t_cap < t)
            t = np.where(on_cap, t_cap, t)
            shade[on_cap] = 0.45 + 0.55 * max(sign * float(axis @ light), 0.0)
    return t.astype(np.float32), np.isfinite(t), shade


def _plane_texture(kind: str, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Brightness factor around 1 from metric plane coordinates ``u``, ``v``."""
    if kind == "tiles":  # 0.5 m tiles in two shades with dark grout lines
        fu, fv = u * np.float32(2.0), v * np.float32(2.0)
        ku, kv = np.floor(fu), np.floor(fv)
        grout = (np.abs(fu - ku - 0.5) > 0.46) | (np.abs(fv - kv - 0.5) > 0.46)
        shade = np.where(((ku + kv).astype(np.int32) & 1) == 1, np.float32(1.02), np.float32(0.95))
        shade[grout] = 0.75
        return shade
    if kind == "wood":
        return 1.0 + 0.06 * np.sin(40.0 * v + 3.0 * np.sin(4.0 * u))
    if kind == "plaster":
        return 1.0 + 0.03 * np.sin(3.1 * u) * np.sin(2.3 * v)
    if kind == "glass":
        return 0.85 + 0.25 * (v + 0.55)
    return np.ones_like(u)


def render(scene: Scene, pose: Pose, camera: Camera, width: int, height: int) -> Render:
    """Ray-cast one noise-free frame.

    Each object is cast only in the image window that can hold it, nearest hit wins.

    Parameters
    ----------
    scene : Scene
    pose : Pose
    camera : Camera
        Intrinsics; pixel ``(col, row)`` looks along ``((col - cx) / fx, (row - cy) / fy, 1)``.
    width, height : int
        Image size in pixels.

    Returns
    -------
    Render
    """
    cols, rows = _ray_grid(camera, width, height)
    ray_norm2 = (cols * cols)[None, :] + (rows * rows + 1.0)[:, None]
    light = pose.direction_to_camera(np.asarray([scene.light]))[0]
    light /= np.linalg.norm(light)
    depth = np.full((height, width), np.inf, dtype=np.float32)
    index = np.full((height, width), -1, dtype=np.int16)
    shade = np.ones((height, width), dtype=np.float32)
    items = list(scene.planes) + list(scene.clutter)
    casters = {Plane: _cast_plane, Sphere: _cast_sphere, Cylinder: _cast_cylinder}
    for k, item in enumerate(items):
        window = _window(_extent(item, pose, camera, width, height), camera, width, height)
        if window is None:
            continue
        r0, r1, c0, c1 = window
        t, closer, brightness = casters[type(item)](
            item, pose, cols[c0:c1], rows[r0:r1], ray_norm2[r0:r1, c0:c1], light
        )
        with np.errstate(invalid="ignore"):
            closer &= t < depth[r0:r1, c0:c1]
        np.copyto(depth[r0:r1, c0:c1], t, where=closer)
        np.copyto(index[r0:r1, c0:c1], k, where=closer)
        np.copyto(shade[r0:r1, c0:c1], brightness, where=closer)
    colours = np.array([item.colour for item in items] + [(40, 40, 45)], dtype=np.float32)
    rgb = np.take(colours, index, axis=0) * shade[:, :, None]
    depth[index < 0] = 0.0
    return Render(depth, index, np.clip(rgb + 0.5, 0, 255).astype(np.uint8))


def kinect_noise_sigma(depth: np.ndarray) -> np.ndarray:
    """Axial noise standard deviation of a Kinect at ``depth`` metres (Nguyen et al. 2012).

    Parameters
    ----------
    depth : ndarray
        Metres.

    Returns
    -------
    ndarray
        ``0.0012 + 0.0019 * (depth - 0.4) ** 2`` metres.
    """
    return 0.0012 + 0.0019 * (depth - 0.4) ** 2


def sensor_depth(
    depth: np.ndarray,
    valid_probability: np.ndarray,
    rng: np.random.Generator,
    *,
    depth_scale: float,
    hole_rate: float = 8.0,
) -> np.ndarray:
    """Turn a clean depth image into what a Kinect-like sensor records.

    Adds axial Gaussian noise (:func:`kinect_noise_sigma`), drops pixels at random where
    ``valid_probability`` is below 1 (glass), drops about half of the pixels next to depth
    discontinuities, punches small elliptic holes, removes depth outside
    [``MIN_DEPTH``, ``MAX_DEPTH``] and quantises.

    Parameters
    ----------
    depth : ndarray of float, shape (H, W)
        Clean z depth in metres, 0 where nothing is seen.
    valid_probability : ndarray of float, shape (H, W)
        Chance that a pixel returns depth at all.
    rng : numpy.random.Generator
    depth_scale : float
        Raw units per metre.
    hole_rate : float
        Mean number of holes per 640 x 480 pixels.

    Returns
    -------
    ndarray of uint16, shape (H, W)
        Raw depth, 0 = missing.
    """
    height, width = depth.shape
    noisy = depth + rng.standard_normal(depth.shape, dtype=np.float32) * kinect_noise_sigma(depth)
    valid = (depth >= MIN_DEPTH) & (noisy >= MIN_DEPTH) & (noisy <= MAX_DEPTH)
    valid &= rng.random(depth.shape, dtype=np.float32) < valid_probability

    # Discontinuities: a jump of more than 5 % between 4-neighbours, dilated by one pixel.
    jump_x = np.abs(np.diff(depth, axis=1)) > 0.05 * np.minimum(depth[:, 1:], depth[:, :-1]) + 1e-6
    jump_y = np.abs(np.diff(depth, axis=0)) > 0.05 * np.minimum(depth[1:], depth[:-1]) + 1e-6
    edge = np.zeros(depth.shape, dtype=bool)
    edge[:, 1:] |= jump_x
    edge[:, :-1] |= jump_x
    edge[1:] |= jump_y
    edge[:-1] |= jump_y
    grown = edge.copy()
    grown[1:] |= edge[:-1]
    grown[:-1] |= edge[1:]
    grown[:, 1:] |= edge[:, :-1]
    grown[:, :-1] |= edge[:, 1:]
    edge_rows, edge_cols = np.nonzero(grown)
    dropped = rng.random(edge_rows.size) < 0.5
    valid[edge_rows[dropped], edge_cols[dropped]] = False

    # Small elliptic holes, sized relative to a 640-pixel-wide image.
    scale = width / 640.0
    n_holes = rng.poisson(hole_rate * width * height / (640 * 480))
    centres = rng.random((n_holes, 2)) * (width, height)
    radii = rng.uniform(1.5, 6.0, (n_holes, 2)) * scale + 0.5
    angles = rng.uniform(0.0, 180.0, n_holes)
    holes = np.zeros(depth.shape, dtype=np.uint8)
    for (x, y), (rx, ry), angle in zip(centres, radii, angles):
        # cv2 draws with 4 fractional bits: integer coordinates in units of 1/16 pixel.
        cv2.ellipse(holes, (int(x * 16), int(y * 16)), (int(rx * 16), int(ry * 16)), angle, 0, 360,
                    1, -1, cv2.LINE_8, 4)
    valid &= holes == 0

    raw = np.rint(noisy * np.float32(depth_scale))  # float32 resolves ~0.002 raw units at 5 m
    raw[~valid] = 0
    return np.clip(raw, 0, 65535).astype(np.uint16)


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


@dataclass
class Frame:
    """One synthetic frame as a sensor and a labeller would produce it.

    Parameters
    ----------
    rgb : ndarray of uint8, shape (H, W, 3)
    depth_raw : ndarray of uint16, shape (H, W)
        Noisy, quantised depth (0 = missing).
    plane_index : ndarray of int16, shape (H, W)
        Ground truth: index into ``scene.planes`` of the plane seen at the pixel where it has
        valid depth and is annotated in this frame, else -1 (clutter, background, holes).
    visible : ndarray of int16, shape (H, W)
        The noise-free object index (see :class:`Scene`), whatever the depth.
    polygons : dict of int to ndarray
        Plane index -> polygon (CVAT image coordinates) for every annotated plane.
    """

    rgb: np.ndarray
    depth_raw: np.ndarray
    plane_index: np.ndarray
    visible: np.ndarray
    polygons: dict[int, np.ndarray] = field(default_factory=dict)


def render_frame(
    scene: Scene,
    pose: Pose,
    camera: Camera,
    width: int,
    height: int,
    rng: np.random.Generator,
    *,
    min_plane_fraction: float = 0.002,
) -> Frame:
    """Render one frame with sensor noise, ground truth and the labeller's polygons.

    Parameters
    ----------
    scene : Scene
    pose : Pose
    camera : Camera
    width, height : int
    rng : numpy.random.Generator
        Source of the depth noise and holes.
    min_plane_fraction : float
        A plane is annotated when at least this share of the image shows it (a labeller skips
        slivers).

    Returns
    -------
    Frame
    """
    clean = render(scene, pose, camera, width, height)
    n_planes = len(scene.planes)
    valid_fraction = np.array([p.valid_fraction for p in scene.planes] + [1.0] * len(scene.clutter)
                              + [0.0], dtype=np.float32)
    depth_raw = sensor_depth(clean.depth, valid_fraction[clean.object_index], rng,
                             depth_scale=camera.depth_scale)
    counts = np.bincount(clean.object_index.ravel() + 1, minlength=n_planes + 1)[1 : n_planes + 1]
    polygons = {}
    for k in np.flatnonzero(counts >= min_plane_fraction * width * height):
        polygon = plane_polygon(scene.planes[k], pose, camera, width, height)
        if polygon is not None:
            polygons[int(k)] = polygon
    annotated = np.zeros(len(scene.planes) + len(scene.clutter) + 1, dtype=bool)
    annotated[list(polygons)] = True
    plane_index = np.where(annotated[clean.object_index] & (depth_raw > 0), clean.object_index, -1)
    return Frame(clean.rgb, depth_raw, plane_index.astype(np.int16), clean.object_index, polygons)


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
    if image.ndim == 3:
        image = image[:, :, ::-1]  # OpenCV writes BGR
    if not cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, 6]):
        raise OSError(f"cannot write {path}")


def _depth_statistics(frame: Frame, n_planes: int, depth_scale: float) -> np.ndarray:
    """Per plane annotated in ``frame``: visible pixels, those without depth, and the sum of
    the depth of the others in metres; shape (3, n_planes)."""
    seen = frame.visible.ravel()
    on = np.isin(seen, list(frame.polygons))
    has_depth = frame.depth_raw.ravel() > 0
    metres = frame.depth_raw.ravel() / depth_scale
    return np.stack([
        np.bincount(seen[on], minlength=n_planes)[:n_planes],
        np.bincount(seen[on & ~has_depth], minlength=n_planes)[:n_planes],
        np.bincount(seen[on & has_depth], weights=metres[on & has_depth], minlength=n_planes)[:n_planes],
    ]).astype(np.float64)


def _plane_record(
    track_id: int, label: str, n_frames: int, visible: float, invalid: float, depth_sum: float
) -> dict:
    """The ``planes.json`` entry of one plane, with its expected fate under the EVOPS rules."""
    invalid_ratio = invalid / visible
    mean_depth = depth_sum / (visible - invalid) if visible > invalid else float("nan")
    reason = None
    if invalid_ratio > MAX_INVALID_RATIO:
        reason = "invalid_depth"
    elif mean_depth > MAX_MEAN_DISTANCE:
        reason = "too_far"
    return {
        "track_id": track_id,
        "gt_value": track_id + 1,
        "label": label,
        "expected": "kept" if reason is None else "dropped",
        "reason": reason,
        "annotated_frames": n_frames,
        "visible_pixels": int(visible),
        "invalid_ratio": round(invalid_ratio, 4),
        "mean_depth_m": round(mean_depth, 4) if np.isfinite(mean_depth) else None,
    }


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
) -> Annotation:
    """Render a synthetic sequence in TUM RGB-D layout with plane ground truth.

    Writes ``rgb/<t>.png``, ``depth/<t>.png``, ``rgb.txt``, ``depth.txt`` into ``out_dir`` and
    into the ground-truth folder ``<depth file name>`` (16-bit: ``track_id + 1`` of the plane per pixel, 0 for
    clutter, background, missing depth and planes not annotated in that frame; dropped planes
    keep their value) and ``planes.json`` (every track with its label, expected
    fate "kept" or "dropped" with a reason "too_far" / "invalid_depth", its statistics, and
    every depth frame with its RGB file and annotation frame, if any).

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
    for folder in (out_dir / "rgb", out_dir / "depth", gt_dir):
        folder.mkdir(parents=True, exist_ok=True)

    n_planes = len(scene.planes)
    shapes: dict[int, dict[int, Shape]] = {k: {} for k in range(n_planes)}
    stats = np.zeros((3, n_planes))
    rgb_names, depth_names, frame_records = [], [], []
    gt_value = np.append(track_ids + 1, 0).astype(np.uint16)  # plane index -1 -> 0
    for i, pose in enumerate(poses):
        frame = render_frame(scene, pose, camera, width, height, np.random.default_rng([seed, i]))
        depth_name = f"{depth_times[i]:.6f}.png"
        depth_names.append(depth_name)
        _write_png(out_dir / "depth" / depth_name, frame.depth_raw)
        _write_png(gt_dir / depth_name, gt_value[frame.plane_index])
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
        stats += _depth_statistics(frame, n_planes, camera.depth_scale)

    _write_list(out_dir / "rgb.txt", "color images", "rgb", rgb_names, seed)
    _write_list(out_dir / "depth.txt", "depth maps", "depth", depth_names, seed)
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
            _plane_record(int(track_ids[k]), scene.planes[k].label, len(shapes[k]), *stats[:, k])
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

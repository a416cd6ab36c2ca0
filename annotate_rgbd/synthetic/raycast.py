"""Ray casting: one noise-free frame (z depth, visible object, flat-shaded RGB) of a scene.

Every object is intersected analytically with the rays of all pixels at once (numpy, float32),
only in the image window that can hold it; the nearest hit wins. RGB is the object's colour,
Lambert-shaded and, on planes, mildly textured.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from annotate_rgbd.geometry.camera import Camera, project, ray_grid
from annotate_rgbd.geometry.lift import pixel_rays
from .polygons import plane_polygon
from .scene import NEAR, Box, Clutter, Cylinder, Plane, Pose, Scene, Sphere


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
        return pixel_rays(polygon, camera)
    if isinstance(item, Sphere):
        centre = pose.to_camera(np.asarray([item.centre]))[0]
        return _box_corners(centre - item.radius, centre + item.radius)
    if isinstance(item, Box):
        return pose.to_camera(item.corners())
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


def box_hits(
    centre: np.ndarray, edges: np.ndarray, cols: np.ndarray, rows: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the pixel rays ``(x, y, 1)`` from the camera centre enter an oriented box (slab method).

    Parameters
    ----------
    centre : ndarray, shape (3,)
        Box centre in the camera frame, metres.
    edges : ndarray, shape (3, 3)
        The three full, mutually orthogonal edge vectors (rows) in the camera frame.
    cols, rows : ndarray of float32, shapes (W,) and (H,)
        The x/z and y/z of the pixel rays of a window.

    Returns
    -------
    t : ndarray of float32, shape (H, W)
        z depth where the ray enters the box (meaningless where not ``hit``).
    hit : ndarray of bool, shape (H, W)
        The ray enters the box farther than ``NEAR``.
    face : ndarray of intp, shape (H, W)
        Index of the edge whose pair of faces the ray enters through.
    """
    # Along edge i the box is the slab |(t * ray - centre) . e_i| <= |e_i|^2 / 2, i.e. t * (ray . e_i)
    # between centre . e_i -+ |e_i|^2 / 2: an interval of t per edge; the ray is in the box where
    # the three intervals overlap.
    near = np.empty((3, rows.size, cols.size), dtype=np.float32)
    far = np.empty_like(near)
    with np.errstate(divide="ignore", invalid="ignore"):
        for i, edge in enumerate(edges):
            inverse = np.reciprocal(_dot(edge, cols, rows))
            middle, half = float(edge @ centre), 0.5 * float(edge @ edge)
            low, high = inverse * np.float32(middle - half), inverse * np.float32(middle + half)
            np.minimum(low, high, out=near[i])
            np.maximum(low, high, out=far[i])
        face = np.argmax(near, axis=0)
        t = np.take_along_axis(near, face[None], axis=0)[0]
        hit = (t <= far.min(axis=0)) & (t > NEAR) & np.isfinite(t)
    return t, hit, face


def _cast_box(box: Box, pose: Pose, cols, rows, ray_norm2, light):
    centre = pose.to_camera(np.asarray([box.centre]))[0]
    edges = pose.direction_to_camera(np.asarray([box.edge_u, box.edge_v, box.edge_w]))
    t, hit, face = box_hits(centre, edges, cols, rows)
    # Lambert with the outward normal of the entry face: -sign(ray . e_i) e_i / |e_i|.
    facing = np.stack([np.sign(_dot(edge, cols, rows)) for edge in edges])
    facing = -np.take_along_axis(facing, face[None], axis=0)[0]
    cosine = facing * (edges @ light / np.linalg.norm(edges, axis=1)).astype(np.float32)[face]
    return t, hit, 0.45 + 0.55 * np.clip(cosine, 0.0, 1.0)


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


def _paint_decals(base: np.ndarray, seen: np.ndarray, plane: Plane, pose: Pose, camera: Camera) -> None:
    """Give the pixels of ``plane`` (``seen``) that fall on one of its decals the decal's colour.

    Parameters
    ----------
    base : ndarray of float32, shape (H, W, 3)
        Unshaded colour of every pixel, changed in place.
    seen : ndarray of bool, shape (H, W)
        Where the plane is the visible object.
    plane : Plane
    pose : Pose
    camera : Camera
    """
    rows, cols = np.nonzero(seen)
    if rows.size == 0:
        return
    rays = np.column_stack([(cols - camera.cx) / camera.fx, (rows - camera.cy) / camera.fy, np.ones(rows.size)])
    centre = pose.to_camera(np.asarray([plane.centre]))[0]
    edge_u, edge_v = pose.direction_to_camera(np.asarray([plane.edge_u, plane.edge_v]))
    normal = np.cross(edge_u, edge_v)
    points = rays * ((normal @ centre) / (rays @ normal))[:, None]
    a = (points - centre) @ edge_u / (edge_u @ edge_u)
    b = (points - centre) @ edge_v / (edge_v @ edge_v)
    for a0, a1, b0, b1, colour in plane.decals:
        on = (a > a0) & (a < a1) & (b > b0) & (b < b1)
        base[rows[on], cols[on]] = colour


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
    cols, rows = (ray.astype(np.float32) for ray in ray_grid(camera, height, width))
    ray_norm2 = (cols * cols)[None, :] + (rows * rows + 1.0)[:, None]
    light = pose.direction_to_camera(np.asarray([scene.light]))[0]
    light /= np.linalg.norm(light)
    depth = np.full((height, width), np.inf, dtype=np.float32)
    index = np.full((height, width), -1, dtype=np.int16)
    shade = np.ones((height, width), dtype=np.float32)
    items = list(scene.planes) + list(scene.clutter)
    casters = {Plane: _cast_plane, Sphere: _cast_sphere, Cylinder: _cast_cylinder, Box: _cast_box}
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
    base = np.take(colours, index, axis=0)
    for k, plane in enumerate(scene.planes):
        if plane.decals:
            _paint_decals(base, index == k, plane, pose, camera)
    rgb = base * shade[:, :, None]
    depth[index < 0] = 0.0
    return Render(depth, index, np.clip(rgb + 0.5, 0, 255).astype(np.uint8))


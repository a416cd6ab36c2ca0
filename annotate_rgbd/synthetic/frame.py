"""One synthetic frame as a sensor and a labeller produce it: RGB, noisy depth, the
per-pixel plane ground truth and the polygons."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from annotate_rgbd.geometry.camera import Camera
from .polygons import plane_polygon
from .raycast import render
from .scene import Pose, Scene
from .sensor import sensor_depth


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
    polygon_jitter_px: float = 0.0,
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
    polygon_jitter_px : float
        A careless labeller: every polygon vertex moves by an offset drawn from ``rng``
        (after the depth noise), uniform in [-jitter, jitter] pixels per axis, then is clamped
        to the image as CVAT does. 0 (default) leaves the polygons exact and draws nothing.
        The ground truth does not change.

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
    if polygon_jitter_px > 0:
        polygons = jitter_polygons(polygons, polygon_jitter_px, width, height, rng)
    annotated = np.zeros(len(scene.planes) + len(scene.clutter) + 1, dtype=bool)
    annotated[list(polygons)] = True
    plane_index = np.where(annotated[clean.object_index] & (depth_raw > 0), clean.object_index, -1)
    return Frame(clean.rgb, depth_raw, plane_index.astype(np.int16), clean.object_index, polygons)



def jitter_polygons(
    polygons: dict[int, np.ndarray], jitter_px: float, width: int, height: int, rng: np.random.Generator
) -> dict[int, np.ndarray]:
    """Move every vertex by a random offset, as a labeller draws a few pixels off the real edge.

    Parameters
    ----------
    polygons : dict of int to ndarray, shape (N, 2)
        Plane index -> vertices in CVAT image coordinates; jittered in ascending key order.
    jitter_px : float
        Largest offset per axis, pixels; offsets are uniform in [-jitter_px, jitter_px].
    width, height : int
        Image size: the moved vertices are clamped to [0, width] x [0, height].
    rng : numpy.random.Generator

    Returns
    -------
    dict of int to ndarray
        New arrays; the input is left alone.
    """
    moved = {}
    for k in sorted(polygons):
        points = polygons[k] + rng.uniform(-jitter_px, jitter_px, polygons[k].shape)
        moved[k] = np.clip(points, 0.0, (float(width), float(height)))
    return moved

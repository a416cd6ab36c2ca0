"""One synthetic frame as a sensor and a labeller produce it: RGB, noisy depth, the
per-pixel plane ground truth and the polygons."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import Camera
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


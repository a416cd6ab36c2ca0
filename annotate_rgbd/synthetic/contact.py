"""The room with clutter in contact with its planes, and a walk through it from 3 m to 0.8 m.

:func:`contact_scene` adds to :func:`room_scene <annotate_rgbd.synthetic.scene.room_scene>` the
objects that lie on or against planes, 1 to 3 cm proud of them: books, a notebook and a closed
laptop flat on the table, a doormat on the floor, a carton on the floor against the right
wall, a whiteboard and a framed picture hung on the walls, a bin touching the cabinet front.
Their pixels are clutter in the ground truth (never plane), yet they lie inside the polygons a
labeller draws for those planes, within a few centimetres of them: what a fixed inlier band of
2 cm keeps near the camera, where the Kinect noise is a few millimetres.

How much of them any depth test can reject depends on the distance: an object ``h`` metres
proud of a plane stands ``h / sigma(z)`` noise deviations off it (:func:`kinect_noise_sigma
<annotate_rgbd.synthetic.sensor.kinect_noise_sigma>`). A 2 cm picture is 8 sigma off the wall
at 1 m but 3 sigma at 2 m; :func:`contact_trajectory` therefore sees the small objects mostly
from nearby (the labeller walks up to the table and the wall), and the far planes mostly from
afar, so that the plane pixels cover 0.8 to 3 m.
"""

from __future__ import annotations

import numpy as np

from .scene import Box, Cylinder, Pose, Scene, look_at, room_scene

#: Height of the room's table top (metres), on which the flat objects lie.
TABLE_TOP = 0.74


def _flat(x: float, y: float, z0: float, size_x: float, size_y: float, thickness: float, angle_deg: float,
          colour: tuple[int, int, int]) -> Box:
    """A box lying flat on the horizontal plane at height ``z0``, turned by ``angle_deg`` about z."""
    a = np.radians(angle_deg)
    u = (size_x * np.cos(a), size_x * np.sin(a), 0.0)
    v = (-size_y * np.sin(a), size_y * np.cos(a), 0.0)
    return Box((x, y, z0 + thickness / 2), u, v, (0.0, 0.0, thickness), colour)


def contact_scene() -> Scene:
    """:func:`room_scene` plus clutter in contact with its planes (see the module notes).

    The objects, each touching its plane (metres; the last figure is how far it stands off it):

    - laptop, book, notebook on table_top: 0.33 x 0.23, 0.02; 0.24 x 0.17, 0.03; 0.21 x 0.30, 0.012
    - doormat on the floor before the doorway: 0.60 x 0.40, 0.015
    - carton on the floor against wall_right: 0.35 x 0.50, 0.30 high
    - whiteboard on wall_back: 0.90 x 0.60, 0.015
    - framed picture on wall_right: 0.50 x 0.40, 0.02
    - bin (a cylinder, radius 0.13, 0.35 high) touching cabinet_front

    Returns
    -------
    Scene
        The room's planes (same indices) and its clutter followed by these objects.
    """
    room = room_scene()
    contact = (
        _flat(0.2, 0.86, TABLE_TOP, 0.33, 0.23, 0.02, 8.0, (60, 62, 70)),  # laptop
        _flat(0.0, 1.25, TABLE_TOP, 0.24, 0.17, 0.03, -20.0, (150, 40, 45)),  # book
        _flat(0.52, 0.88, TABLE_TOP, 0.21, 0.30, 0.012, 3.0, (230, 225, 200)),  # notebook
        _flat(0.75, 1.8, 0.0, 0.6, 0.4, 0.015, 0.0, (95, 90, 80)),  # doormat, before the doorway
        # Carton on the floor, its back against wall_right (x = 1.6).
        Box((1.6 - 0.175, 1.7, 0.15), (0.35, 0.0, 0.0), (0.0, 0.5, 0.0), (0.0, 0.0, 0.3), (175, 140, 95)),
        # Whiteboard on wall_back (y = 2.2, seen from -y), 1.5 cm proud.
        Box((-0.6, 2.2 - 0.0075, 1.5), (0.9, 0.0, 0.0), (0.0, 0.015, 0.0), (0.0, 0.0, 0.6), (240, 240, 236)),
        # Framed picture on wall_right (x = 1.6, seen from -x), 2 cm proud.
        Box((1.6 - 0.01, 1.1, 1.3), (0.02, 0.0, 0.0), (0.0, 0.5, 0.0), (0.0, 0.0, 0.4), (70, 100, 60)),
        # Bin touching cabinet_front (y = 1.75, seen from -y).
        Cylinder((-1.0, 1.75 - 0.13, 0.0), (0.0, 0.0, 1.0), 0.35, 0.13, (80, 80, 150)),
    )
    return Scene(room.planes, room.clutter + contact, room.light)


def contact_trajectory(n_frames: int) -> list[Pose]:
    """A smooth walk through :func:`contact_scene` from about 3 m to 0.8 m off its planes.

    The labeller starts on the near side looking across the room at the back wall (planes at
    2-3 m), walks up to the table looking down at the objects on it (0.8-1.2 m), then turns to
    the whiteboard and cabinet and last to the right wall with the carton and the picture. The
    path is the same for any ``n_frames``; more frames sample it more densely.

    Parameters
    ----------
    n_frames : int

    Returns
    -------
    list of Pose
    """
    s = np.linspace(0.0, 1.0, n_frames)
    # Key poses (camera position, look-at target), eased from one to the next.
    keys = np.array([
        [(0.7, -0.1, 1.6), (-0.8, 2.2, 0.8)],   # far: across the room
        [(0.3, 0.15, 1.45), (0.1, 1.05, 0.74)],  # above the table's front edge
        [(-0.3, 0.9, 1.5), (-0.6, 2.2, 1.3)],    # beside the table: whiteboard
        [(-0.2, 1.0, 1.45), (-1.1, 1.75, 0.6)],  # cabinet and bin
        [(0.6, 0.9, 1.4), (1.6, 1.3, 0.8)],      # right wall: picture and carton
    ])
    segment = np.minimum((s * (len(keys) - 1)).astype(int), len(keys) - 2)
    local = s * (len(keys) - 1) - segment
    ease = ((1.0 - np.cos(np.pi * local)) / 2.0)[:, None]
    position = keys[segment, 0] + ease * (keys[segment + 1, 0] - keys[segment, 0])
    target = keys[segment, 1] + ease * (keys[segment + 1, 1] - keys[segment, 1])
    # A little hand-held sway.
    position = position + 0.02 * np.stack([np.sin(5 * np.pi * s), np.sin(7 * np.pi * s), np.sin(3 * np.pi * s)], 1)
    return [look_at(p, t) for p, t in zip(position, target)]

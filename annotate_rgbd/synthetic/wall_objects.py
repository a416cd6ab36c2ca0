"""The contact room with the near-coplanar things real walls carry.

:func:`wall_objects_scene` adds to :func:`contact_scene <annotate_rgbd.synthetic.contact.contact_scene>`
what real scenes are full of and the rendered room had not: posters, a framed picture, a light
switch, a shallow rack a few centimetres proud of a wall, a shelf with books, on the two walls
that :func:`contact_trajectory <annotate_rgbd.synthetic.contact.contact_trajectory>` looks at
from 1-1.5 m. Objects that stand off a wall are clutter in the ground truth (never the wall):
a depth test sees them at ``h / sigma(z)`` noise deviations (a 1 cm switch is 5 sigma off the
wall at 1 m, 2 sigma at 1.5 m). Posters are decals of the wall (:class:`Plane.decals
<annotate_rgbd.synthetic.scene.Plane>`): paper has no depth, so they are wall in the ground
truth, and only their colour edge tells them apart.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .contact import contact_scene
from .scene import Box, Plane, Scene

def wall_rectangle(plane: Plane, corner_a, corner_b) -> tuple[float, float, float, float]:
    """The ``(a0, a1, b0, b1)`` plane coordinates of the rectangle spanned by two world points
    on ``plane`` (opposite corners), as :attr:`Plane.openings` and :attr:`Plane.decals` take them.

    Parameters
    ----------
    plane : Plane
    corner_a, corner_b : array_like, shape (3,)
        World points on the plane, metres.

    Returns
    -------
    tuple of float
        ``a0 < a1``, ``b0 < b1``.
    """
    centre = np.asarray(plane.centre, dtype=np.float64)
    u, v = np.asarray(plane.edge_u, dtype=np.float64), np.asarray(plane.edge_v, dtype=np.float64)
    ab = [((np.asarray(p, dtype=np.float64) - centre) @ u / (u @ u), (np.asarray(p, dtype=np.float64) - centre) @ v / (v @ v))
          for p in (corner_a, corner_b)]
    (a0, b0), (a1, b1) = ab
    return float(min(a0, a1)), float(max(a0, a1)), float(min(b0, b1)), float(max(b0, b1))


def _on_back_wall(x0: float, x1: float, z0: float, z1: float, proud: float, colour) -> Box:
    """A box against wall_back (y = 2.2, seen from -y) over ``x0..x1``, ``z0..z1``, ``proud`` deep."""
    return Box(((x0 + x1) / 2, 2.2 - proud / 2, (z0 + z1) / 2), (x1 - x0, 0.0, 0.0), (0.0, proud, 0.0),
               (0.0, 0.0, z1 - z0), colour)


def _on_right_wall(y0: float, y1: float, z0: float, z1: float, proud: float, colour) -> Box:
    """A box against wall_right (x = 1.6, seen from -x) over ``y0..y1``, ``z0..z1``, ``proud`` deep."""
    return Box((1.6 - proud / 2, (y0 + y1) / 2, (z0 + z1) / 2), (proud, 0.0, 0.0), (0.0, y1 - y0, 0.0),
               (0.0, 0.0, z1 - z0), colour)


def wall_objects_scene() -> Scene:
    """:func:`contact_scene` plus near-coplanar wall objects (see the module notes).

    On wall_back (y = 2.2; the whiteboard of the contact scene at x -1.05..-0.15, z 1.2..1.8):

    - a poster (decal) at x -1.40..-1.10, z 1.05..1.55, above the cabinet;
    - a shallow rack (pin board with a ledge) 4 cm proud at x -0.60..-0.20, z 0.78..1.12;
    - a framed picture 2.5 cm proud at x -0.10..0.15, z 1.25..1.55, beside the doorway;
    - a light switch 1 cm proud at x 0.06..0.14, z 1.02..1.10.

    On wall_right (x = 1.6; the contact scene's picture at y 0.85..1.35, carton at y 1.45..1.95):

    - a poster (decal) at y 1.45..1.95, z 0.70..1.30, above the carton;
    - a shelf board 20 cm deep, 2 cm thick, y 0.75..1.25, top at z 0.70 (under the picture), with
      five books standing on it against the wall (17 cm deep, 20-24 cm high).

    Returns
    -------
    Scene
        The contact scene's planes (same indices, wall_back and wall_right with their decals) and
        its clutter followed by these objects.
    """
    contact = contact_scene()
    planes = list(contact.planes)
    labels = [p.label for p in planes]
    back, right = labels.index("wall_back"), labels.index("wall_right")
    planes[back] = replace(planes[back], decals=(
        (*wall_rectangle(planes[back], (-1.40, 2.2, 1.05), (-1.10, 2.2, 1.55)), (200, 60, 70)),))
    planes[right] = replace(planes[right], decals=(
        (*wall_rectangle(planes[right], (1.6, 1.45, 0.70), (1.6, 1.95, 1.30)), (40, 90, 160)),))
    objects = [
        _on_back_wall(-0.60, -0.20, 0.78, 1.12, 0.04, (160, 120, 80)),  # rack
        _on_back_wall(-0.10, 0.15, 1.25, 1.55, 0.025, (60, 50, 40)),  # framed picture
        _on_back_wall(0.06, 0.14, 1.02, 1.10, 0.01, (235, 235, 230)),  # light switch
        _on_right_wall(0.75, 1.25, 0.68, 0.70, 0.20, (180, 170, 150)),  # shelf board
    ]
    # Books on the shelf: (thickness, height, colour), packed from y = 0.80 with 5 mm gaps.
    y = 0.80
    for thickness, height, colour in ((0.04, 0.22, (150, 40, 40)), (0.03, 0.24, (40, 80, 140)),
                                      (0.05, 0.20, (60, 120, 60)), (0.035, 0.23, (200, 170, 60)),
                                      (0.045, 0.21, (90, 60, 110))):
        objects.append(_on_right_wall(y, y + thickness, 0.70, 0.70 + height, 0.17, colour))
        y += thickness + 0.005
    return Scene(tuple(planes), contact.clutter + tuple(objects), contact.light)

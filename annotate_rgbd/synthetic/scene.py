"""What a synthetic sequence shows: planes, clutter, the camera's poses, and the default room.

A scene is a set of planar rectangles (walls, floor, a table top, cabinet faces, ...) and
clutter (spheres, cylinders, boxes). World frame: metres, z up. Camera frame: x right,
y down, z forward (the pinhole model of :mod:`annotate_rgbd.geometry.camera`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Rays start this far in front of the camera (metres); polygons are clipped against this plane.
NEAR = 0.01


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
    decals : tuple of (a0, a1, b0, b1, colour)
        Rectangles of the plane in ``(a, b)`` coordinates painted in another RGB colour, with no
        depth of their own: a poster or a sheet of paper flat on a wall, part of the plane for
        the depth and the ground truth, a colour edge for the RGB image.
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
    decals: tuple[tuple[float, float, float, float, tuple[int, int, int]], ...] = ()

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


@dataclass(frozen=True)
class Box:
    """An oriented box of clutter: ``centre + a * edge_u + b * edge_v + c * edge_w`` for
    ``a, b, c`` in [-0.5, 0.5] (a book, a laptop, a carton, a picture frame).

    Parameters
    ----------
    centre : tuple of float
        World coordinates, metres.
    edge_u, edge_v, edge_w : tuple of float
        The three full edge vectors, mutually orthogonal, metres.
    colour : tuple of int
        RGB.
    """

    centre: tuple[float, float, float]
    edge_u: tuple[float, float, float]
    edge_v: tuple[float, float, float]
    edge_w: tuple[float, float, float]
    colour: tuple[int, int, int]

    def corners(self) -> np.ndarray:
        """The 8 corners as world points, shape (8, 3)."""
        signs = np.array(np.meshgrid([-0.5, 0.5], [-0.5, 0.5], [-0.5, 0.5], indexing="ij")).reshape(3, -1).T
        return np.asarray(self.centre) + signs @ np.array([self.edge_u, self.edge_v, self.edge_w], dtype=np.float64)


Clutter = Sphere | Cylinder | Box


@dataclass(frozen=True)
class Scene:
    """Planes and clutter. Object index ``k`` in rendered images is ``planes[k]`` for
    ``k < len(planes)``, else ``clutter[k - len(planes)]``; -1 is background (nothing hit).

    Parameters
    ----------
    planes : tuple of Plane
    clutter : tuple of Sphere, Cylinder or Box
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


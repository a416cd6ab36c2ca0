"""Synthetic RGB-D room scenes with exact plane ground truth, for tests, benchmarks and samples.

A scene is a set of planar rectangles (walls, floor, a table top, cabinet faces, ...) and
clutter (spheres, cylinders, oriented boxes). Every frame is ray-cast analytically with numpy, all
pixels at once, from a pose on a smooth camera trajectory. The depth gets Kinect-like noise and
holes, the RGB image flat-shaded colours with a mild texture, and every plane the polygon a
labeller would draw: its outline projected into the image, running straight over clutter and
nearer planes, with a ``z_order`` that puts nearer planes on top.

:func:`make_sequence` writes all of it as a TUM RGB-D sequence plus ground truth and returns the
annotation as the format-neutral model (:mod:`annotate_rgbd.annotation.model`).

World frame: metres, z up. Camera frame: x right, y down, z forward (the pinhole model of
:mod:`annotate_rgbd.geometry.camera`). A frame's RGB and depth images are rendered from the same pose
(registered, like TUM's depth images); only their timestamps differ.

Modules
-------
scene
    Scene description (planes, clutter, poses), the default room and its camera path.
contact
    The room with clutter in contact with its planes and a walk from 3 m to 0.8 m.
wall_objects
    The contact room with near-coplanar wall objects: posters, a picture, a switch, a rack, a
    shelf with books.
pose_error
    Trajectory error as real published poses carry it (per-pose noise; the clock offset is
    applied by ``make_sequence``).
raycast
    Ray casting of one noise-free frame: z depth, visible object, shaded RGB.
sensor
    The depth sensor model: Kinect noise, missing depth, range limits, quantisation.
polygons
    The polygon a labeller draws for a plane.
frame
    One frame as sensor and labeller produce it (:func:`render_frame`), optionally with the
    labeller's polygon error.
ground_truth
    Per-plane statistics and expected fate in ``planes.json`` (an oracle for the tests).
sequence
    :func:`make_sequence`: a whole sequence on disk in TUM layout, with ground truth.
"""

from .contact import contact_scene, contact_trajectory
from .frame import Frame, jitter_polygons, render_frame
from .ground_truth import MAX_INVALID_RATIO, MAX_MEAN_DISTANCE
from .polygons import plane_polygon
from .pose_error import perturb_poses
from .raycast import Render, render
from .scene import NEAR, Box, Clutter, Cylinder, Plane, Pose, Scene, Sphere, look_at, room_scene, room_trajectory
from .sensor import MAX_DEPTH, MIN_DEPTH, kinect_noise_sigma, sensor_depth
from .sequence import make_sequence, write_tum_trajectory
from .wall_objects import wall_objects_scene

__all__ = [
    "MAX_DEPTH",
    "MAX_INVALID_RATIO",
    "MAX_MEAN_DISTANCE",
    "MIN_DEPTH",
    "NEAR",
    "Box",
    "Clutter",
    "Cylinder",
    "Frame",
    "Plane",
    "Pose",
    "Render",
    "Scene",
    "Sphere",
    "contact_scene",
    "contact_trajectory",
    "kinect_noise_sigma",
    "jitter_polygons",
    "look_at",
    "make_sequence",
    "perturb_poses",
    "plane_polygon",
    "render",
    "render_frame",
    "room_scene",
    "room_trajectory",
    "sensor_depth",
    "wall_objects_scene",
    "write_tum_trajectory",
]

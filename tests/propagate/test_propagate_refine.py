"""Refinement of shapes that camera poses carried from keyframes: the plane the poses expect
decides which surface behind RANSAC's plane is the one, and the plane goes on, over pixels on
it, past every keyframe's view."""

import numpy as np
import pytest

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.config.settings import Config, RansacConfig, load_config
from annotate_rgbd.segment.grow import grow_connected
from annotate_rgbd.geometry.noise import SENSOR_MODELS, NoiseSettings
from annotate_rgbd.segment.ransac import fit_plane
from annotate_rgbd.pipeline.resume import fingerprint
from annotate_rgbd.segment.frame import segment_frame

from builders import floor_under_carton, through

KINECT = NoiseSettings(SENSOR_MODELS["kinect_v1"])
CAMERA = Camera(fx=150.0, fy=150.0, cx=79.5, cy=59.5, depth_scale=5000.0)
SHAPE = (120, 160)


# --- the expected plane ----------------------------------------------------------------------

def test_the_expected_plane_decides_which_surface_behind_is_the_one():
    points, floor_y, top_y = floor_under_carton(np.random.default_rng(4))
    floor = np.array([0.0, -1.0, 0.0, floor_y])
    # Poses say the shape is the floor: it is found behind the carton top.
    fit = fit_plane(points, RansacConfig(max_points=0), KINECT, look_behind=False, expected=floor)
    assert through(fit.equation, floor_y)
    # Poses say it is the carton's top (a table top, say, whose projected shape ran past its
    # edge onto the floor): the floor behind is not taken.
    top = np.array([0.0, -1.0, 0.0, top_y])
    fit = fit_plane(points, RansacConfig(max_points=0), KINECT, look_behind=False, expected=top)
    assert through(fit.equation, top_y)
    # Within the tolerance of poses: 4 cm and 3 degrees off still is the floor; 8 cm is not.
    tilt = np.radians(3)
    near = np.array([0.0, -np.cos(tilt), np.sin(tilt), np.cos(tilt) * (floor_y - 0.04) - np.sin(tilt) * 2.25])
    assert through(fit_plane(points, RansacConfig(max_points=0), KINECT, look_behind=False, expected=near).equation,
                   floor_y)
    far = np.array([0.0, -1.0, 0.0, floor_y + 0.08])
    assert through(fit_plane(points, RansacConfig(max_points=0), KINECT, look_behind=False, expected=far).equation,
                   top_y)


def test_the_fingerprint_holds_the_propagated_planes_and_where_the_poses_put_them():
    shapes = [(1, Shape("polygon", np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])))]
    config = Config()
    depth = b"depth"
    plain = fingerprint(shapes, (320, 240), config, depth)
    assert fingerprint(shapes, (320, 240), config, depth, frozenset(), ()) == plain
    carried = fingerprint(shapes, (320, 240), config, depth, frozenset({1}), ((1, (0.0, -1.0, 0.0, 1.5)),))
    assert carried != plain
    assert fingerprint(shapes, (320, 240), config, depth, frozenset({1}), ()) not in (plain, carried)
    moved = fingerprint(shapes, (320, 240), config, depth, frozenset({1}), ((1, (0.0, -1.0, 0.0, 1.5001)),))
    assert moved != carried


# --- growing past the keyframes' view --------------------------------------------------------

def floor_depth(rng=None, height=1.0):
    """Depth (m) of a floor ``height`` m below the camera on the lower image half (rows >= 70);
    NaN above. With ``rng``, Kinect noise."""
    rows = np.mgrid[: SHAPE[0], : SHAPE[1]][0]
    ray_y = (rows - CAMERA.cy) / CAMERA.fy
    with np.errstate(divide="ignore"):
        depth = np.where(rows >= 70, height / ray_y, np.nan)
    if rng is not None:
        depth = depth + rng.standard_normal(SHAPE) * (0.0012 + 0.0019 * (np.nan_to_num(depth) - 0.4) ** 2)
    return depth


def grow(labels, drawn, claimed, depth, height=1.0):
    """:func:`grow_connected` of the floor ``height`` m below the camera as plane 1."""
    floor = np.array([0.0, -1.0, 0.0, height])  # normal towards the camera
    return grow_connected(labels, drawn, claimed, depth, {1: floor}, CAMERA,
                          NoiseSettings(SENSOR_MODELS["kinect_v1"], 3.0, 0.002, 0.1))


def test_a_carried_plane_takes_the_pixels_on_it_that_connect_to_it():
    depth = floor_depth(np.random.default_rng(1))
    labels = np.zeros(SHAPE, np.uint8)
    labels[70:, :60] = 1  # what the keyframes' outlines covered
    drawn = labels.copy()
    # A wall standing on the floor cuts off the far right: on-plane pixels there do not connect.
    depth[70:, 120:124] = 0.8
    grown_labels, grown = grow(labels, drawn, np.zeros(SHAPE, bool), depth)
    on_floor = np.isfinite(depth) & (np.arange(SHAPE[1])[None, :] < 120)
    taken = (grown_labels == 1) & (labels == 0)
    assert grown[1] == taken.sum()
    assert taken[70:, 60:118].mean() > 0.97  # the free floor, but for noise beyond the band
    assert not taken[:, 120:].any() and not taken[~on_floor].any()


def test_claimed_pixels_a_surface_on_the_plane_and_its_own_left_out_pixels_are_not_taken():
    depth = floor_depth(height=0.5)
    labels = np.zeros(SHAPE, np.uint8)
    labels[70:, :60] = 1
    drawn = labels.copy()
    claimed = np.zeros(SHAPE, bool)
    claimed[70:90, 60:160] = True  # a shape a labeller drew on this frame (its plane left them)
    rows = np.mgrid[: SHAPE[0], : SHAPE[1]][0]
    mat = (rows >= 100) & (np.arange(SHAPE[1])[None, :] >= 100)
    depth[mat] = 0.493 / ((rows[mat] - CAMERA.cy) / CAMERA.fy)  # a mat 7 mm proud: within the band
    left_out = np.zeros(SHAPE, bool)
    left_out[75:80, 10:20] = True
    labels[left_out] = 0  # refinement left these out of the plane's own shape
    grown_labels, _ = grow(labels, drawn, claimed, depth, height=0.5)
    taken = (grown_labels == 1) & (labels == 0)
    assert not taken[claimed].any() and not taken[left_out].any()
    core = mat.copy()
    core[100:103, :] = False
    core[:, 100:103] = False  # the mat's rim, where windows are half on the floor
    assert not taken[core].any()
    assert taken[90:, 60:97].mean() > 0.99


def test_a_free_pixel_on_two_growing_planes_equally_goes_to_the_lower_id():
    depth = floor_depth(height=0.5)
    floor = np.array([0.0, -1.0, 0.0, 0.5])
    labels = np.zeros(SHAPE, np.uint8)
    labels[70:, :40] = 2
    labels[70:, 120:] = 1  # the same floor under two ids; the free floor between touches both
    noise = NoiseSettings(SENSOR_MODELS["kinect_v1"], 3.0, 0.002, 0.1)
    grown_labels, grown = grow_connected(labels, labels.copy(), np.zeros(SHAPE, bool), depth,
                                         {2: floor, 1: floor.copy()}, CAMERA, noise)
    assert (grown_labels[70:, 40:120] == 1).all()
    assert grown == {1: 80 * (SHAPE[0] - 70), 2: 0}


def test_only_planes_carried_by_poses_grow_past_their_shapes():
    depth = floor_depth(height=0.5)
    raw = np.nan_to_num(depth * CAMERA.depth_scale).round().astype(np.uint16)
    shape = Shape("polygon", np.array([[0.0, 70.0], [60.0, 70.0], [60.0, 120.0], [0.0, 120.0]]))
    config = load_config(None, {"camera.fx": CAMERA.fx, "camera.fy": CAMERA.fy, "camera.cx": CAMERA.cx,
                                "camera.cy": CAMERA.cy})
    drawn = segment_frame(raw, [(1, shape)], config)
    carried = segment_frame(raw, [(1, shape)], config, propagated={1}, expected={1: np.array([0.0, -1, 0, 0.5])})
    beyond = np.zeros(SHAPE, bool)
    beyond[70:, 70:] = True  # past the shape and its grow_pixels band
    assert not drawn.labels[beyond].any()
    assert carried.labels[beyond].mean() > 0.99
    assert carried.kept[0].grown == int(((carried.labels == 1) & (carried.drawn != 1)).sum())
    # grow_pixels = 0 turns growing off, this too.
    off = load_config(None, {"camera.fx": CAMERA.fx, "camera.fy": CAMERA.fy, "camera.cx": CAMERA.cx,
                             "camera.cy": CAMERA.cy, "refine.grow_pixels": 0})
    assert not segment_frame(raw, [(1, shape)], off, propagated={1}).labels[beyond].any()


def test_a_carried_shape_whose_ransac_plane_holds_few_points_gets_an_exhaustive_search(monkeypatch):
    # RANSAC stops early once its plane likely is the best given the share it holds; with two
    # surfaces of about half each that can be a plane leaning between them. Stand-in RANSAC: the
    # early stop returns a leaning plane, the exhaustive search the wall's own.
    from annotate_rgbd.segment import ransac

    # The early stop returns a recess 10 cm deep in the wall (nothing lies behind it to look for),
    # the exhaustive search the wall.
    rng = np.random.default_rng(7)
    wall = np.column_stack([rng.uniform(-1, 1, 600), rng.uniform(-1, 1, 600), np.full(600, 2.0)])
    recess = np.column_stack([rng.uniform(-0.5, 0.5, 400), rng.uniform(-0.5, 0.5, 400), np.full(400, 2.10)])
    points = np.vstack([wall, recess])
    calls = []

    class StandIn:
        """The early stop finds the recess (450 inliers), the rest of the hypotheses the wall (550)."""

        def __init__(self, sample, threshold, iterations, seed):
            self.best_count = 0

        def score(self, probability=ransac.DEFAULT_PROBABILITY):
            calls.append(probability == 1.0)
            self.best_count = 550 if probability == 1.0 else 450

        def best(self):
            return np.array([0.0, 0.0, -1.0, 2.0 if self.best_count == 550 else 2.10]), self.best_count

    monkeypatch.setattr(ransac, "RansacSearch", StandIn)
    expected = np.array([0.0, 0.0, -1.0, 2.0])
    fit = fit_plane(points, RansacConfig(max_points=0), KINECT, look_behind=False, expected=expected)
    assert calls[:2] == [False, True]
    assert abs(fit.equation[3] - 2.0) < 0.001 and abs(fit.equation[2]) > 0.9999
    # Drawn shapes (no expected plane) keep RANSAC's early stop: the recess it stopped on.
    calls.clear()
    fit = fit_plane(points, RansacConfig(max_points=0), KINECT)
    assert True not in calls and abs(fit.equation[3] - 2.10) < 0.001

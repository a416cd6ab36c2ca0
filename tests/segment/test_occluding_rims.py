"""A plane gives up a rim at its own occluding edges, where a depth sensor smears its depth onto
the first pixels of the farther surface beyond the edge (segment.rims.near_surfaces_behind)."""

import numpy as np
import pytest
from scipy import ndimage

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.config.settings import Config, RefineConfig, config_from_dict
from annotate_rgbd.errors import InputError
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.geometry.noise import SENSOR_MODELS, NoiseSettings
from annotate_rgbd.segment.frame import segment_frame
from annotate_rgbd.segment.rims import near_surfaces_behind

KINECT = NoiseSettings(SENSOR_MODELS["kinect_v1"])
CAMERA = Camera(fx=150.0, fy=150.0, cx=79.5, cy=59.5, depth_scale=5000.0)
SHAPE = (120, 160)
CONFIG = {"camera": {"fx": 150.0, "fy": 150.0, "cx": 79.5, "cy": 59.5, "depth_scale": 5000.0},
          "noise": {"model": "kinect_v1"}}
FACING = np.array([0.0, 0.0, -1.0, 1.0])  # the plane z = 1 m, normal towards the camera


def euclidean_rim(surface, own, rim):
    """Independently: the pixels of ``own`` within ``rim`` (Euclidean) of ``surface``."""
    return own & (ndimage.distance_transform_edt(~surface) <= rim)


def board_before_wall(rng, wall=1.8):
    """A board facing the camera 1 m away over the middle of the image, a wall ``wall`` m away
    around it; depth in metres with Kinect-like noise, and the board's pixels."""
    depth = np.full(SHAPE, wall)
    board = np.zeros(SHAPE, bool)
    board[30:90, 40:120] = True
    depth[board] = 1.0
    depth += rng.standard_normal(SHAPE) * (0.0012 + 0.0019 * (depth - 0.4) ** 2)
    return depth.astype(np.float32), board


@pytest.mark.parametrize("rim", [1, 2, 3])
def test_the_rim_is_the_board_within_the_distance_of_the_wall_behind_it(rim):
    depth, board = board_before_wall(np.random.default_rng(rim))
    labels = board.astype(np.uint8)
    got = near_surfaces_behind(labels, depth, {1: FACING}, CAMERA, KINECT, rim)
    assert np.array_equal(got, euclidean_rim(~board, board, rim))
    assert not near_surfaces_behind(labels, depth, {1: FACING}, CAMERA, KINECT, 0).any()


def test_the_wall_loses_nothing_next_to_the_board_in_front_of_it():
    # The wall's shape ends at the board: the board is in front of the wall, not behind.
    depth, board = board_before_wall(np.random.default_rng(4))
    labels = (~board).astype(np.uint8)
    wall = np.array([0.0, 0.0, -1.0, 1.8])
    assert not near_surfaces_behind(labels, depth, {1: wall}, CAMERA, KINECT, 2).any()


def test_planes_meeting_in_a_concave_corner_lose_nothing():
    # A floor 1 m below the camera and a wall 2 m ahead meeting where the floor reaches the
    # wall: each is in front of the other's plane, nothing behind.
    rows, cols = np.mgrid[0:SHAPE[0], 0:SHAPE[1]]
    ray_y = (rows - CAMERA.cy) / CAMERA.fy
    with np.errstate(divide="ignore"):
        floor_z = np.where(ray_y > 0, 1.0 / ray_y, np.inf)
    on_floor = floor_z < 2.0
    depth = np.where(on_floor, floor_z, 2.0).astype(np.float32)
    labels = np.where(on_floor, 1, 2).astype(np.uint8)
    planes = {1: np.array([0.0, -1.0, 0.0, 1.0]), 2: np.array([0.0, 0.0, -1.0, 2.0])}
    assert not near_surfaces_behind(labels, depth, planes, CAMERA, KINECT, 2).any()


def test_specks_and_missing_depth_are_not_surfaces_behind():
    depth = np.full(SHAPE, 1.0, np.float32)
    depth[10, 10] = depth[20, 20:22] = 1.5  # a pixel and two pixels behind
    depth[40:42, 40:42] = 1.5  # 2 x 2: no 3 x 3 square either
    depth[60:80, 60:80] = np.nan  # a hole
    labels = np.ones(SHAPE, np.uint8)
    labels[60:80, 60:80] = 0
    assert not near_surfaces_behind(labels, depth, {1: FACING}, CAMERA, KINECT, 2).any()
    depth[40:43, 40:43] = 1.5  # 3 x 3: a surface
    block = np.zeros(SHAPE, bool)
    block[40:43, 40:43] = True
    got = near_surfaces_behind(labels, depth, {1: FACING}, CAMERA, KINECT, 2)
    assert np.array_equal(got, euclidean_rim(block, labels > 0, 2))


def test_only_what_lies_behind_by_more_than_the_band_counts():
    # A board 5 mm proud of the plane is within the band (about 7 mm at 1 m): not behind.
    depth = np.full(SHAPE, 1.0, np.float32)
    depth[:, 100:] = 1.005
    labels = np.zeros(SHAPE, np.uint8)
    labels[:, :100] = 1
    assert not near_surfaces_behind(labels, depth, {1: FACING}, CAMERA, KINECT, 2).any()
    depth[:, 100:] = 1.05
    assert near_surfaces_behind(labels, depth, {1: FACING}, CAMERA, KINECT, 2)[:, 98:100].all()


def test_a_smeared_edge_is_trimmed_and_the_report_counts_what_is_left():
    # A board before a wall whose depth the sensor smeared 2 px beyond the board's edge; the
    # labeller's polygon runs 2 px past the edge. Without the rim the board keeps the smeared
    # pixels; with a 2 px rim its mask ends at the true edge (within a pixel).
    rng = np.random.default_rng(7)
    depth, board = board_before_wall(rng)
    smeared = ndimage.binary_dilation(board, iterations=2)
    depth[smeared & ~board] = 1.0 + rng.standard_normal(int((smeared & ~board).sum())).astype(np.float32) * 0.0013
    raw = np.round(depth * CAMERA.depth_scale).astype(np.uint16)
    polygon = np.array([[37.5, 27.5], [121.5, 27.5], [121.5, 91.5], [37.5, 91.5]])
    shape = Shape(kind="polygon", points=polygon)
    plain = segment_frame(raw, [(1, shape)], config_from_dict(CONFIG))
    trimmed = segment_frame(raw, [(1, shape)], config_from_dict({**CONFIG, "refine": {"occluding_rim_pixels": 2}}))
    outside = smeared & ~board
    assert (plain.labels[outside] == 1).mean() > 0.9
    assert not (trimmed.labels == 1)[outside].any()
    assert (trimmed.labels[ndimage.binary_erosion(board, iterations=1)] == 1).mean() > 0.99
    record = trimmed.kept[0]
    mask, drawn = trimmed.labels == 1, trimmed.drawn == 1
    assert record.inliers == int((mask & drawn).sum()) and record.grown == int((mask & ~drawn).sum())


def test_occluding_rim_pixels_setting():
    assert Config().refine.occluding_rim_pixels == RefineConfig().occluding_rim_pixels
    assert config_from_dict({"refine": {"occluding_rim_pixels": 3}}).refine.occluding_rim_pixels == 3
    with pytest.raises(InputError, match="occluding_rim_pixels"):
        config_from_dict({"refine": {"occluding_rim_pixels": -1}})

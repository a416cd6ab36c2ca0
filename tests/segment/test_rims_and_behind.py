"""Two ways refinement uses what a labeller's polygon means: it runs over what stands on its
plane (so a large surface *behind* RANSAC's plane is the plane the labeller meant), and what
stands on the plane meets it in a rim that depth cannot separate (so the plane gives it up)."""

import numpy as np
import pytest
from builders import floor_under_carton, through
from scipy import ndimage

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.config.settings import Config, RansacConfig, RefineConfig, config_from_dict
from annotate_rgbd.errors import InputError
from annotate_rgbd.geometry.noise import SENSOR_MODELS, NoiseSettings
from annotate_rgbd.segment.ransac import fit_plane
from annotate_rgbd.segment.refine import refine_planes
from annotate_rgbd.segment.rims import near_surfaces_in_front
from annotate_rgbd.segment.frame import segment_frame

KINECT = NoiseSettings(SENSOR_MODELS["kinect_v1"])
CAMERA = Camera(fx=150.0, fy=150.0, cx=79.5, cy=59.5, depth_scale=5000.0)
SHAPE = (120, 160)


def euclidean_rim(surface, labels, plane, rim):
    """Independently: the plane's pixels within ``rim`` (Euclidean) of the surface."""
    distance = ndimage.distance_transform_edt(~surface)
    return (labels == plane) & (distance <= rim)


# --- near_surfaces_in_front -----------------------------------------------------------------

def test_the_rim_is_every_pixel_of_the_shape_within_the_distance_of_a_surface_in_front():
    labels = np.ones((40, 50), np.uint8)
    in_front = np.zeros(labels.shape, bool)
    in_front[10:20, 15:30] = True  # a book on the plane
    for rim in (1, 2, 3):
        got = near_surfaces_in_front(in_front, labels, rim)
        assert np.array_equal(got, euclidean_rim(in_front, labels, 1, rim)), rim
    assert not near_surfaces_in_front(in_front, labels, 0).any()


def test_specks_of_noise_beyond_the_band_are_not_surfaces():
    labels = np.ones((40, 50), np.uint8)
    in_front = np.zeros(labels.shape, bool)
    in_front[5, 5] = in_front[20, 20:22] = True  # one pixel, two pixels
    in_front[30:32, 30:32] = True  # 2x2: does not fill a 3x3 square either
    assert not near_surfaces_in_front(in_front, labels, 2).any()
    in_front[30:33, 30:33] = True  # 3x3: a surface
    block = np.zeros(labels.shape, bool)
    block[30:33, 30:33] = True
    assert np.array_equal(near_surfaces_in_front(in_front, labels, 2), euclidean_rim(block, labels, 1, 2))


def test_a_surface_in_front_of_one_plane_takes_no_rim_from_another():
    # Plane 1's shape runs two pixels over plane 2 (nearer): those pixels are in front of plane
    # 1, and plane 1 gives up a rim next to them; plane 2's own pixels stay.
    labels = np.ones((40, 50), np.uint8)
    labels[:, 25:] = 2
    in_front = np.zeros(labels.shape, bool)
    in_front[:, 22:25] = True  # plane 1's shape, over plane 2
    in_front[5:10, 40:45] = True  # an object in front of plane 2
    got = near_surfaces_in_front(in_front, labels, 2)
    expected = euclidean_rim(in_front & (labels == 1), labels, 1, 2) | euclidean_rim(
        in_front & (labels == 2), labels, 2, 2)
    assert np.array_equal(got, expected)
    assert not got[:, 25:27].any()  # plane 2's edge next to plane 1's overhang


# --- refinement with rims --------------------------------------------------------------------

def table_with_box(rng, height=0.03):
    """A table facing the camera 1.2 m away with a box ``height`` m proud of it; depth (m), the
    box's pixels, its outline within 2 px."""
    depth = np.full(SHAPE, 1.2, np.float64)
    box = np.zeros(SHAPE, bool)
    box[40:70, 50:100] = True
    depth[box] -= height
    # The box's sides: a pixel's worth of them at the table's height, then rising.
    side = ndimage.binary_dilation(box, iterations=2) & ~box
    depth[side] -= 0.001
    depth += rng.standard_normal(SHAPE) * 0.0012
    return depth.astype(np.float32), box | side


def test_refinement_gives_up_the_rim_around_an_object_on_the_plane():
    depth, box = table_with_box(np.random.default_rng(3))
    labels = np.ones(SHAPE, np.uint8)
    config = RansacConfig()
    plain, _ = refine_planes(labels, depth, np.array([1]), CAMERA, config, KINECT, rim_pixels=0)
    rimmed, _ = refine_planes(labels, depth, np.array([1]), CAMERA, config, KINECT, rim_pixels=2)
    assert plain[box].mean() > 0.1  # the sides at the table's height are inliers
    assert rimmed[box].mean() == 0  # ... and all within 2 px of the box's top
    # What the rim takes is exactly the plane's inliers near the box's top (the surface off
    # the plane), nothing farther.
    top = np.zeros(SHAPE, bool)
    top[40:70, 50:100] = True
    near = euclidean_rim(top, labels, 1, 2)
    assert np.array_equal((plain > 0) & (rimmed == 0), (plain > 0) & near)


def test_rim_pixels_setting():
    assert Config().refine.rim_pixels == 2 == RefineConfig().rim_pixels
    assert config_from_dict({"refine": {"rim_pixels": 0}}).refine.rim_pixels == 0
    with pytest.raises(InputError, match="rim_pixels"):
        config_from_dict({"refine": {"rim_pixels": 51}})


# --- the surface behind RANSAC's plane -------------------------------------------------------

def test_a_floor_mostly_hidden_by_a_carton_is_found_behind_the_carton_top():
    points, floor_y, top_y = floor_under_carton(np.random.default_rng(4))
    fit = fit_plane(points, RansacConfig(max_points=0), KINECT)
    assert through(fit.equation, floor_y) and fit.surface_behind
    # Without looking behind (a shape carried from other frames), RANSAC's larger surface.
    fit = fit_plane(points, RansacConfig(max_points=0), KINECT, look_behind=False)
    assert through(fit.equation, top_y) and not fit.surface_behind
    # Nor with ransac.max_behind = 0; nor when the floor must lie nearer behind than it does (0.3 m).
    for config in (RansacConfig(max_points=0, max_behind=0), RansacConfig(max_points=0, max_behind_depth=0.2)):
        fit = fit_plane(points, config, KINECT)
        assert through(fit.equation, top_y) and not fit.surface_behind


def test_a_plane_whose_points_lie_behind_the_first_is_not_taken():
    # The carton's side is behind the top's plane, but the top is behind the side's plane as
    # well: not the plane the shape was drawn over. Without the floor, the top stays.
    points, _, top_y = floor_under_carton(np.random.default_rng(5), floor_points=0, side_points=500)
    assert through(fit_plane(points, RansacConfig(max_points=0), KINECT).equation, top_y)


def test_a_strip_behind_the_plane_smaller_than_the_share_is_not_taken():
    # A shape running a little past a table's edge onto the floor below: the floor's points are
    # fewer than BEHIND_SHARE of the table's.
    rng = np.random.default_rng(6)
    points, _, top_y = floor_under_carton(rng, floor_points=200, top_points=800, side_points=0)
    assert through(fit_plane(points, RansacConfig(max_points=0), KINECT).equation, top_y)
    points, floor_y, _ = floor_under_carton(rng, floor_points=300, top_points=800, side_points=0)
    assert through(fit_plane(points, RansacConfig(max_points=0), KINECT).equation, floor_y)


def test_what_shows_through_an_opening_or_a_few_stray_points_do_not_replace_the_plane():
    rng = np.random.default_rng(8)
    wall = np.column_stack([rng.uniform(-1, 1, 1000), rng.uniform(-1, 1, 1000), np.full(1000, 2.0)])
    # A doorway in the wall drawn over, the next room's wall 1 m behind: not an object on it.
    room = np.column_stack([rng.uniform(-0.3, 0.3, 400), rng.uniform(-0.3, 0.6, 400), np.full(400, 3.0)])
    fit = fit_plane(np.vstack([wall, room]), RansacConfig(max_points=0), KINECT)
    assert abs(fit.equation[3] - 2.0) < 0.01 and abs(fit.equation[2]) > 0.999
    # 30 cm behind (a carton's height), the same points are the plane the shape was drawn for.
    room[:, 2] = 2.3
    fit = fit_plane(np.vstack([wall[:600], room]), RansacConfig(max_points=0), KINECT)
    assert abs(fit.equation[3] - 2.3) < 0.01
    # A tiny shape: three stray points behind ten on the wall always make a plane of their own.
    for seed in range(20):
        rng = np.random.default_rng(seed)
        few = np.vstack([wall[:10], np.column_stack([rng.uniform(-1, 1, 3), rng.uniform(-1, 1, 3), rng.uniform(2.2, 2.4, 3)])])
        assert abs(fit_plane(few, RansacConfig(max_points=0), KINECT).equation[3] - 2.0) < 0.01, seed


def test_shapes_carried_by_poses_do_not_look_behind():
    # A floor seen at the bottom of the image, with a box standing on it that covers more of
    # the floor's shape than the floor does.
    rows, cols = np.mgrid[: SHAPE[0], : SHAPE[1]]
    ray_y = (rows - CAMERA.cy) / CAMERA.fy
    depth = np.where(ray_y > 0.05, 0.5 / np.maximum(ray_y, 1e-6), 0.0)  # floor 0.5 m below the camera
    box = (rows > 85) & (cols >= 20) & (cols < 140)
    depth[box] = 0.35 / ray_y[box]  # its top 0.15 m above the floor
    raw = np.round(depth * CAMERA.depth_scale).astype(np.uint16)
    shape = Shape("polygon", np.array([[0, 80], [160, 80], [160, 120], [0, 120]], float))
    config = Config(camera=CAMERA)
    drawn = segment_frame(raw, [(1, shape)], config)
    carried = segment_frame(raw, [(1, shape)], config, propagated={1})
    floor = (rows >= 80) & ~box & (ndimage.distance_transform_edt(~box) > 2)  # beyond the box's rim
    assert drawn.labels[floor].mean() > 0.95 and not drawn.labels[box].any()
    assert carried.labels[box].mean() > 0.9 and not carried.labels[floor].any()
    # The report says which plane was found behind what RANSAC took first.
    assert drawn.kept[0].surface_behind is True and carried.kept[0].surface_behind is False
    assert drawn.kept[0].to_json()["surface_behind"] is True
    assert type(drawn.kept[0]).from_json(drawn.kept[0].to_json()) == drawn.kept[0]
    # What poses carry always comes with the plane they expect: the floor is taken from behind
    # when it is that plane, not when the box's top is (a table top's shape run past its edge).
    floor_plane = {1: np.array([0.0, -1.0, 0.0, 0.5])}
    top_plane = {1: np.array([0.0, -1.0, 0.0, 0.35])}
    expect_floor = segment_frame(raw, [(1, shape)], config, propagated={1}, expected=floor_plane)
    expect_top = segment_frame(raw, [(1, shape)], config, propagated={1}, expected=top_plane)
    assert expect_floor.labels[floor].mean() > 0.95 and not expect_floor.labels[box].any()
    assert expect_top.labels[box].mean() > 0.9 and not expect_top.labels[floor].any()


@pytest.mark.parametrize("top", [7, 255, 256, 70_000])
def test_ids_nearby_against_a_brute_force_search(top):
    from annotate_rgbd.segment.rims import ids_nearby

    rng = np.random.default_rng(top)
    ids = np.where(rng.random((30, 40)) < 0.03, rng.integers(1, top + 1, (30, 40)), 0)
    ids[3, 4] = top
    lowest, highest = ids_nearby(ids, 2)
    rows, cols = np.nonzero(ids)
    for r in range(30):
        for c in range(40):
            near = ids[rows, cols][(rows - r) ** 2 + (cols - c) ** 2 <= 4]
            assert highest[r, c] == (near.max() if near.size else 0)
            assert lowest[r, c] == (near.min() if near.size else 0)

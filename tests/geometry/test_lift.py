"""Lifting keyframe polygons onto planes and projecting them into other frames (annotate_rgbd.lift)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from skimage.measure import points_in_poly

from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.geometry.lift import (
    BEHIND_CAMERA,
    RAY_PARALLEL,
    clip_near,
    lift_polygon,
    plane_agreement,
    plane_to_camera,
    plane_to_world,
    project_polygon,
    project_polygons,
)
from annotate_rgbd.segment.rasterize import polygon_window
from annotate_rgbd.synthetic import Plane, Scene, look_at, render

TUM = Camera(fx=517.306408, fy=516.469215, cx=318.643040, cy=255.313989, depth_scale=5000)
ICL = Camera(fx=481.20, fy=-480.00, cx=319.5, cy=239.5, depth_scale=5000)  # y up: fy < 0
WIDTH, HEIGHT = 640, 480


def random_pose(rng) -> tuple[np.ndarray, np.ndarray]:
    return Rotation.random(random_state=rng.integers(1 << 31)).as_matrix(), rng.normal(size=3)


def intrinsics(camera: Camera) -> np.ndarray:
    return np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1]])


def project_by_hand(world: np.ndarray, camera: Camera, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Pinhole projection with the 3x4 matrix K [R^T | -R^T t], shifted to CVAT coordinates."""
    matrix = intrinsics(camera) @ np.hstack([rotation.T, -rotation.T @ translation[:, None]])
    image = np.hstack([world, np.ones((len(world), 1))]) @ matrix.T
    return image[:, :2] / image[:, 2:] + 0.5


def irregular_polygon(rng, n: int, centre=(320.0, 240.0), radius=(40.0, 200.0)) -> np.ndarray:
    angles = np.sort(rng.uniform(0, 2 * np.pi, n))
    radii = rng.uniform(*radius, n)
    return np.c_[centre[0] + radii * np.cos(angles), centre[1] + radii * np.sin(angles)]


def shoelace(xy: np.ndarray) -> float:
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


# ---------------------------------------------------------------- lifting


@pytest.mark.parametrize("camera", [TUM, ICL], ids=["tum", "icl_negative_fy"])
@pytest.mark.parametrize("seed", range(3))
def test_lift_then_project_with_the_same_pose_returns_the_polygon(camera, seed):
    rng = np.random.default_rng(seed)
    polygon = irregular_polygon(rng, 12)
    # A plane 1-4 m in front, tilted up to ~50 degrees away from facing the camera.
    normal = np.array([0.0, 0.0, -1.0]) + rng.uniform(-0.6, 0.6, 3) * [1, 1, 0]
    normal /= np.linalg.norm(normal)
    equation = np.append(normal, rng.uniform(1.0, 4.0))
    rotation, translation = random_pose(rng)
    lifted = lift_polygon(polygon, 3.0 * equation, camera, rotation, translation)  # any scale
    assert lifted.ok and lifted.valid.all()
    # By hand: back in the camera frame every vertex lies on the plane ...
    in_camera = (lifted.world - translation) @ rotation
    np.testing.assert_allclose(in_camera @ equation[:3] + equation[3], 0, atol=1e-12)
    # ... and projects onto its pixel.
    np.testing.assert_allclose(project_by_hand(lifted.world, camera, rotation, translation), polygon, atol=1e-6)
    np.testing.assert_allclose(project_polygon(lifted.world, camera, rotation, translation), polygon, rtol=0, atol=1e-6)


def test_lift_failures_are_reported_per_vertex():
    camera = Camera(fx=500, fy=500, cx=319.5, cy=239.5, depth_scale=5000)
    floor = np.array([0.0, 1.0, 0.0, -1.5])  # y = 1.5 m: the floor under a level camera (y down)
    # CVAT y = cy + 0.5 is the horizon row: its rays are parallel to the floor; above it the rays
    # meet the floor's plane behind the camera.
    polygon = np.array([[100.0, 400.0], [500.0, 400.0], [500.0, 240.0], [100.0, 100.0]])
    lifted = lift_polygon(polygon, floor, camera, np.eye(3), np.zeros(3))
    assert lifted.valid.tolist() == [True, True, False, False]
    assert lifted.reason == RAY_PARALLEL and not lifted.ok
    assert np.isnan(lifted.world[2:]).all()
    # Row 400 looks down at (400 - 240) / 500 = 0.32: the floor 1.5 m down is 1.5 / 0.32 m ahead.
    np.testing.assert_allclose(lifted.world[0], [(99.5 - 319.5) / 500 * 1.5 / 0.32, 1.5, 1.5 / 0.32])
    lifted = lift_polygon(polygon[[0, 3, 2]], floor, camera, np.eye(3), np.zeros(3))
    assert lifted.reason == BEHIND_CAMERA and lifted.valid.tolist() == [True, False, False]
    through_camera = lift_polygon(polygon, [0.0, 0.0, 1.0, 0.0], camera, np.eye(3), np.zeros(3))
    assert through_camera.reason == BEHIND_CAMERA and not through_camera.valid.any()


# ---------------------------------------------------------------- propagation against a rendered plane

# A 1.2 m x 0.8 m panel on a wall (world z up), and two views of it from 1.5 m and 2 m away.
PANEL = Plane("panel", centre=(0.0, 2.0, 1.2), edge_u=(1.2, 0.3, 0.0), edge_v=(0.0, 0.0, 0.8), colour=(200, 50, 50))
VIEW_A = look_at((-0.4, 0.6, 1.4), (0.0, 2.0, 1.2))
VIEW_B = look_at((0.7, 0.2, 1.0), (0.1, 2.0, 1.3))


def render_panel(view, camera):
    return render(Scene(planes=(PANEL,)), view, camera, WIDTH, HEIGHT)


def plane_from_depth(depth: np.ndarray, mask: np.ndarray, camera: Camera) -> np.ndarray:
    """Least-squares plane through the rendered pixels, back-projected by hand."""
    rows, cols = np.nonzero(mask)
    z = depth[rows, cols].astype(np.float64)
    points = np.c_[(cols - camera.cx) / camera.fx * z, (rows - camera.cy) / camera.fy * z, z]
    centroid = points.mean(axis=0)
    normal = np.linalg.svd(points - centroid, full_matrices=False)[2][-1]
    return np.append(normal, -normal @ centroid)


@pytest.mark.parametrize("camera", [TUM, ICL], ids=["tum", "icl_negative_fy"])
def test_propagated_polygon_matches_the_rendered_plane(camera):
    outline = PANEL.outline()
    drawn = project_by_hand(outline, camera, VIEW_A.rotation, VIEW_A.position)  # the labeller's polygon on A
    assert (drawn.min(axis=0) > 0).all() and (drawn.max(axis=0) < [WIDTH, HEIGHT]).all()
    rendered_a = render_panel(VIEW_A, camera)
    equation = plane_from_depth(rendered_a.depth, rendered_a.object_index == 0, camera)
    lifted = lift_polygon(drawn, equation, camera, VIEW_A.rotation, VIEW_A.position)
    assert lifted.ok
    np.testing.assert_allclose(lifted.world, outline, atol=1e-6)  # float32 depth limits the fit

    propagated = project_polygon(lifted.world, camera, VIEW_B.rotation, VIEW_B.position)
    expected = project_by_hand(outline, camera, VIEW_B.rotation, VIEW_B.position)
    np.testing.assert_allclose(propagated, expected, atol=1e-3)
    # The pixels it covers on B are the pixels where B's rendering sees the panel.
    top, left, inside = polygon_window(propagated, HEIGHT, WIDTH)
    filled = np.zeros((HEIGHT, WIDTH), dtype=bool)
    filled[top : top + inside.shape[0], left : left + inside.shape[1]] = inside
    seen = render_panel(VIEW_B, camera).object_index == 0
    assert seen.sum() > 20000
    assert (filled != seen).sum() <= 10  # a pixel centre within float32 rounding of an edge may flip


def test_exact_plane_propagates_exactly():
    # The plane from the panel's own geometry (no depth): the propagation is exact.
    camera = TUM
    centre = VIEW_A.to_camera(np.asarray([PANEL.centre]))[0]
    normal = np.cross(*VIEW_A.direction_to_camera(np.asarray([PANEL.edge_u, PANEL.edge_v])))
    equation = np.append(normal, -normal @ centre)
    drawn = project_by_hand(PANEL.outline(), camera, VIEW_A.rotation, VIEW_A.position)
    lifted = lift_polygon(drawn, equation, camera, VIEW_A.rotation, VIEW_A.position)
    np.testing.assert_allclose(lifted.world, PANEL.outline(), atol=1e-12)
    np.testing.assert_allclose(
        project_polygon(lifted.world, camera, VIEW_B.rotation, VIEW_B.position),
        project_by_hand(PANEL.outline(), camera, VIEW_B.rotation, VIEW_B.position),
        atol=1e-9,
    )


# ---------------------------------------------------------------- near-plane clipping


def test_clip_puts_new_vertices_exactly_on_the_near_plane():
    # A square in the camera's x-z plane reaching from 1 m behind the camera to 1 m in front.
    square = np.array([[-1.0, 0.3, -1.0], [1.0, 0.3, -1.0], [1.0, 0.3, 1.0], [-1.0, 0.3, 1.0]])
    clipped = clip_near(square, near=0.05)
    # Edge 0 -> 1 is behind; edge 1 -> 2 crosses; 2 and 3 are kept; edge 3 -> 0 crosses.
    np.testing.assert_array_equal(
        clipped, [[1.0, 0.3, 0.05], [1.0, 0.3, 1.0], [-1.0, 0.3, 1.0], [-1.0, 0.3, 0.05]]
    )
    tilted = square @ Rotation.from_euler("y", 17, degrees=True).as_matrix().T + [0.1, 0.0, 0.2]
    clipped = clip_near(tilted, near=0.05)
    made = ~np.isin(clipped[:, 0], tilted[:, 0])
    assert made.sum() == 2 and (clipped[made, 2] == 0.05).all() and (clipped[:, 2] >= 0.05).all()


def test_clip_wholly_in_front_or_behind():
    triangle = np.array([[0.0, 0, 1], [1, 0, 2], [0, 1, 3]])
    np.testing.assert_array_equal(clip_near(triangle, 0.05), triangle)
    assert clip_near(triangle - [0, 0, 3.01], 0.05).shape == (0, 3)
    assert project_polygon(triangle - [0, 0, 3.01], TUM, np.eye(3), np.zeros(3)).shape == (0, 2)
    touching = triangle - [0, 0, 0.75]  # one vertex exactly on the plane z = 0.25 (dyadic)
    np.testing.assert_array_equal(clip_near(touching, 0.25), touching)


@pytest.mark.parametrize("seed", range(4))
def test_clipped_area_matches_a_point_count(seed):
    # Non-convex polygons in a plane y = const, partly behind z = near: the clipped polygon's area
    # equals the area of the polygon's part with z >= near, counted on a fine grid of points.
    rng = np.random.default_rng(seed)
    xz = irregular_polygon(rng, 9, centre=(0.0, rng.uniform(-0.3, 0.3)), radius=(0.2, 1.0))
    near = 0.05
    polygon = np.c_[xz[:, 0], np.full(len(xz), 0.7), xz[:, 1]]
    clipped = clip_near(polygon, near)
    assert (clipped[:, 2] >= near).all()
    step = 0.0025
    gx, gz = np.meshgrid(np.arange(-1.1, 1.1, step) + step / 2, np.arange(-1.5, 1.5, step) + step / 2)
    grid = np.c_[gx.ravel(), gz.ravel()]
    counted = (points_in_poly(grid, xz) & (grid[:, 1] >= near)).sum() * step * step
    assert shoelace(clipped[:, [0, 2]]) == pytest.approx(counted, abs=0.01 + 0.003 * counted)


def test_projection_of_a_polygon_crossing_the_near_plane():
    rng = np.random.default_rng(7)
    rotation, translation = random_pose(rng)
    # Camera-frame quad from 0.5 m behind to 2 m in front, as world points.
    quad = np.array([[-0.5, -0.4, -0.5], [0.5, -0.4, -0.5], [0.5, 0.4, 2.0], [-0.5, 0.4, 2.0]])
    world = quad @ rotation.T + translation
    image = project_polygon(world, ICL, rotation, translation, near=0.1)
    # The clip points of edges 1 -> 2 and 3 -> 0 at z = 0.1, projected by hand; then 2 and 3.
    f = 0.6 / 2.5
    on_near = np.array([[0.5, -0.4 + 0.8 * f, 0.1], [-0.5, -0.4 + 0.8 * f, 0.1]])
    expected = project_by_hand(np.r_[on_near[:1], quad[2:], on_near[1:]], ICL, np.eye(3), np.zeros(3))
    np.testing.assert_allclose(image, expected, atol=1e-9)


def test_many_polygons_project_as_each_one_alone():
    rng = np.random.default_rng(8)
    rotation, translation = random_pose(rng)
    crossing = np.array([[-0.5, -0.4, -0.5], [0.5, -0.4, -0.5], [0.5, 0.4, 2.0], [-0.5, 0.4, 2.0]])
    in_front = np.array([[0.0, 0.0, 1.0], [0.3, 0.0, 1.2], [0.1, 0.4, 1.5]])
    behind = np.array([[0.0, 0.0, -1.0], [0.3, 0.0, -1.2], [0.1, 0.4, -1.5]])
    worlds = [q @ rotation.T + translation for q in (in_front, crossing, behind, in_front[::-1])]
    together = project_polygons(worlds, ICL, rotation, translation, near=0.1)
    assert len(together) == 4 and len(together[2]) == 0
    for world, image in zip(worlds, together):
        np.testing.assert_allclose(image, project_polygon(world, ICL, rotation, translation, near=0.1), atol=1e-9)
    assert project_polygons([], ICL, rotation, translation) == []


# ---------------------------------------------------------------- planes in two frames


def test_plane_to_world_and_back():
    rng = np.random.default_rng(11)
    rotation, translation = random_pose(rng)
    normal = rng.normal(size=3)
    normal /= np.linalg.norm(normal)
    equation = np.append(normal, 1.7)
    # Points of the camera-frame plane, moved to the world by hand, lie on the world plane.
    basis = np.linalg.svd(normal[None])[2][1:]
    points = -1.7 * normal + rng.normal(size=(20, 2)) @ basis
    world = points @ rotation.T + translation
    world_plane = plane_to_world(equation, rotation, translation)
    np.testing.assert_allclose(world @ world_plane[:3] + world_plane[3], 0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(world_plane[:3]), 1.0, atol=1e-15)
    np.testing.assert_allclose(plane_to_camera(world_plane, rotation, translation), equation, atol=1e-12)


def test_plane_agreement():
    rng = np.random.default_rng(5)
    normal = rng.normal(size=3)
    normal /= np.linalg.norm(normal)
    axis = np.cross(normal, rng.normal(size=3))
    axis /= np.linalg.norm(axis)
    for degrees in (1e-5, 0.5, 10.0, 75.0):
        turned = Rotation.from_rotvec(np.radians(degrees) * axis).apply(normal)
        angle, offset = plane_agreement(np.append(normal, 1.0), -2.0 * np.append(turned, 1.0))
        assert angle == pytest.approx(degrees, rel=1e-6)
        assert offset == pytest.approx(0.0, abs=1e-12)  # both pass 1 m from the origin
    # Parallel planes 3 cm apart: 3 cm wherever measured.
    for at in (None, [5.0, -2.0, 1.0]):
        assert plane_agreement([0, 0, 1, -1.0], [0, 0, -2, 2.06], at=at) == pytest.approx((0.0, 0.03))
    # Planes 2 degrees apart crossing at a point 4 m from the origin: no gap there.
    point = np.array([4.0, 0.0, 0.0])
    tilted = Rotation.from_euler("y", 2, degrees=True).apply([1.0, 0, 0])
    first, second = np.array([1.0, 0, 0, -4.0]), np.append(tilted, -tilted @ point)
    angle, at_origin = plane_agreement(first, second)
    assert angle == pytest.approx(2.0) and at_origin == pytest.approx(4 - 4 * np.cos(np.radians(2)))
    assert plane_agreement(first, second, at=point)[1] == pytest.approx(0.0, abs=1e-12)


def test_plane_agreement_and_plane_to_world_take_many_planes_at_once():
    rng = np.random.default_rng(3)
    planes = np.concatenate([rng.normal(size=(5, 3)), rng.uniform(-2, 2, (5, 1))], axis=1)
    points = rng.normal(size=(5, 3))
    first = np.array([0.2, -0.1, 1.0, -1.5])
    angles, offsets = plane_agreement(first, planes, at=points)
    for k in range(5):
        assert (angles[k], offsets[k]) == pytest.approx(plane_agreement(first, planes[k], at=points[k]))
    rotation, translation = np.linalg.qr(rng.normal(size=(3, 3)))[0], rng.normal(size=3)
    together = plane_to_world(planes, rotation, translation)
    np.testing.assert_allclose(together, [plane_to_world(p, rotation, translation) for p in planes])

"""The wall-objects scene (decals, near-coplanar objects) and the trajectory's error (pose noise,
clock offset)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.io.poses import poses_at, read_trajectory
from annotate_rgbd.io.sequence import read_sequence
from annotate_rgbd.synthetic import (
    Scene,
    contact_scene,
    contact_trajectory,
    look_at,
    make_sequence,
    perturb_poses,
    render,
    render_frame,
    wall_objects_scene,
)

WIDTH, HEIGHT = 320, 240
CAMERA = Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, depth_scale=5000.0)
N_CONTACT = len(contact_scene().clutter)
#: The wall objects (clutter index past the contact scene's) -> (their wall, how far they stand off it, m).
OFF_WALL = {0: ("wall_back", 0.04), 1: ("wall_back", 0.025), 2: ("wall_back", 0.01), 3: ("wall_right", 0.2),
            **{k: ("wall_right", 0.17) for k in range(4, 9)}}


def _rays() -> np.ndarray:
    cols, rows = np.meshgrid((np.arange(WIDTH) - CAMERA.cx) / CAMERA.fx, (np.arange(HEIGHT) - CAMERA.cy) / CAMERA.fy)
    return np.dstack([cols, rows, np.ones_like(cols)])


def _off_wall(plane, points: np.ndarray) -> np.ndarray:
    """How far world points stand off the plane on the room's side, metres (computed here)."""
    normal = np.cross(plane.edge_u, plane.edge_v)
    normal = normal / np.linalg.norm(normal)
    side = np.sign((np.array([0.0, 1.0, 1.3]) - np.asarray(plane.centre)) @ normal)
    return (points - np.asarray(plane.centre)) @ normal * side


def test_wall_objects_stand_off_their_wall_by_their_depth_and_touch_it():
    scene = wall_objects_scene()
    planes = {p.label: p for p in scene.planes}
    rays = _rays()
    poses = contact_trajectory(60)
    seen = dict.fromkeys(OFF_WALL, 0)
    for i in range(0, 60, 3):
        clean = render(scene, poses[i], CAMERA, WIDTH, HEIGHT)
        world = (rays * clean.depth[..., None]) @ poses[i].rotation.T + poses[i].position
        for k, (label, depth) in OFF_WALL.items():
            pixels = clean.object_index == len(scene.planes) + N_CONTACT + k
            distance = _off_wall(planes[label], world[pixels])
            assert np.all((distance >= -1e-3) & (distance <= depth + 1e-3))
            seen[k] += int(pixels.sum())
    assert all(count > 50 for count in seen.values()), seen


def test_the_contact_scene_is_kept_whole():
    walls, contact = wall_objects_scene(), contact_scene()
    assert [replace(p, decals=()) for p in walls.planes] == list(contact.planes)
    assert walls.clutter[:N_CONTACT] == contact.clutter


def test_posters_change_the_colour_only_and_exactly_on_their_rectangle():
    scene = wall_objects_scene()
    bare = Scene(tuple(replace(p, decals=()) for p in scene.planes), scene.clutter, scene.light)
    pose = look_at((-0.3, 0.9, 1.5), (-0.6, 2.2, 1.3))  # facing the back wall's poster
    with_posters, without = render(scene, pose, CAMERA, WIDTH, HEIGHT), render(bare, pose, CAMERA, WIDTH, HEIGHT)
    np.testing.assert_array_equal(with_posters.depth, without.depth)
    np.testing.assert_array_equal(with_posters.object_index, without.object_index)
    # The poster, from the world: x -1.40..-1.10, z 1.05..1.55 on the back wall (y = 2.2).
    world = (_rays() * with_posters.depth[..., None]) @ pose.rotation.T + pose.position
    back = [p.label for p in scene.planes].index("wall_back")
    on_wall = with_posters.object_index == back
    inside = on_wall & (world[..., 0] > -1.40) & (world[..., 0] < -1.10) & (world[..., 2] > 1.05) & (world[..., 2] < 1.55)
    changed = np.any(with_posters.rgb != without.rgb, axis=2)
    assert inside.sum() > 500
    # Off by a pixel at most along the poster's edges (float32 rays against float64 here).
    edge = inside ^ changed
    assert edge.sum() <= 0.05 * inside.sum()
    assert not np.any(changed & ~on_wall)
    # Inside, the poster's colour shaded like the wall: the red channel over the blue is the poster's.
    ratio = with_posters.rgb[inside & changed][:, 0] / np.maximum(with_posters.rgb[inside & changed][:, 2], 1)
    assert np.median(ratio) == pytest.approx(200 / 70, rel=0.05)


def test_posters_are_wall_in_the_ground_truth():
    scene = wall_objects_scene()
    pose = look_at((-0.3, 0.9, 1.5), (-0.6, 2.2, 1.3))
    frame = render_frame(scene, pose, CAMERA, WIDTH, HEIGHT, np.random.default_rng(0))
    bare = render_frame(Scene(tuple(replace(p, decals=()) for p in scene.planes), scene.clutter, scene.light), pose,
                        CAMERA, WIDTH, HEIGHT, np.random.default_rng(0))
    np.testing.assert_array_equal(frame.plane_index, bare.plane_index)
    np.testing.assert_array_equal(frame.depth_raw, bare.depth_raw)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(a.T @ b) - 1) / 2, -1.0, 1.0))))


def test_pose_noise_has_the_asked_medians():
    poses = [look_at((0.0, 0.0, 1.0), (1.0, 2.0, 0.5))] * 4000
    noisy = perturb_poses(poses, np.random.default_rng(1), 0.004, 0.2)
    shift = np.array([np.linalg.norm(n.position - p.position) for n, p in zip(noisy, poses)])
    angle = np.array([_angle_deg(n.rotation, p.rotation) for n, p in zip(noisy, poses)])
    assert np.median(shift) == pytest.approx(0.004, rel=0.05)
    assert np.median(angle) == pytest.approx(0.2, rel=0.05)
    assert all(np.allclose(n.rotation.T @ n.rotation, np.eye(3)) for n in noisy[:10])
    assert perturb_poses(poses[:3], np.random.default_rng(1), 0.0, 0.0)[0].position == pytest.approx(poses[0].position)


def test_trajectory_error_leaves_the_images_alone_and_shifts_the_clock(tmp_path):
    poses = contact_trajectory(6)
    common = dict(n_frames=6, width=80, height=60, camera=Camera(fx=65.625, fy=65.625, cx=39.5, cy=29.5,
                  depth_scale=5000.0), seed=5, scene=contact_scene(), poses=poses, dropped_rgb_frames=(),
                  write_trajectory=True)
    make_sequence(tmp_path / "exact", **common)
    make_sequence(tmp_path / "noisy", **common, trajectory_noise=(0.004, 0.2), trajectory_time_offset=-0.02)
    exact, noisy = read_sequence(tmp_path / "exact"), read_sequence(tmp_path / "noisy")
    for name in exact.depth.files + exact.rgb.files:
        assert (tmp_path / "exact" / name).read_bytes() == (tmp_path / "noisy" / name).read_bytes()
    times = exact.depth.timestamps
    at_exact = poses_at(read_trajectory(tmp_path / "exact" / "groundtruth.txt"), times)
    # The noisy trajectory holds frame i's pose at t_i - 0.02 s, each off by a little.
    at_shifted = poses_at(read_trajectory(tmp_path / "noisy" / "groundtruth.txt"), times - 0.02)
    for i, pose in enumerate(poses):
        np.testing.assert_allclose(at_exact.translations[i], pose.position, atol=1e-6)
        shift = np.linalg.norm(at_shifted.translations[i] - pose.position)
        angle = _angle_deg(at_shifted.rotations[i], pose.rotation)
        assert 0 < shift < 0.03 and 0 < angle < 1.5
    # Read at the frames' own times, the noisy trajectory lags: poses of other moments.
    at_frames = poses_at(read_trajectory(tmp_path / "noisy" / "groundtruth.txt"), times[1:-1])
    moved = np.linalg.norm(at_frames.translations - np.array([p.position for p in poses[1:-1]]), axis=1)
    assert np.median(moved) > 0.01

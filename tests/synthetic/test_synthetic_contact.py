"""The renderer's box clutter, the contact scene and its walk, and the labeller's polygon jitter."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.cvat import write_cvat_video
from annotate_rgbd.synthetic import (
    Box,
    Pose,
    Scene,
    contact_scene,
    contact_trajectory,
    jitter_polygons,
    kinect_noise_sigma,
    look_at,
    make_sequence,
    render,
    render_frame,
    room_scene,
    room_trajectory,
)

SAMPLE_DATA = Path(__file__).resolve().parents[2] / "sample_data"
WIDTH, HEIGHT = 160, 120
CAMERA = Camera(fx=131.25, fy=131.25, cx=79.5, cy=59.5, depth_scale=5000.0)
#: Contact objects lying flat on or hung flat against a plane: clutter index in contact_scene ->
#: (the plane's label, how far the object stands off it in metres).
N_ROOM_CLUTTER = len(room_scene().clutter)
FLAT_ON = {0: ("table_top", 0.02), 1: ("table_top", 0.03), 2: ("table_top", 0.012), 3: ("floor", 0.015),
           5: ("wall_back", 0.015), 6: ("wall_right", 0.02)}


def _rays(camera: Camera, width: int, height: int) -> np.ndarray:
    """Pixel-centre rays (x/z, y/z, 1), float64, shape (H, W, 3)."""
    cols, rows = np.meshgrid((np.arange(width) - camera.cx) / camera.fx, (np.arange(height) - camera.cy) / camera.fy)
    return np.dstack([cols, rows, np.ones_like(cols)])


def _box_by_faces(box: Box, pose: Pose, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Entry z depth of every ray into the box, inf where it misses, and the outward normal
    (camera frame) of the face it enters by: each of the six faces intersected as a bounded
    rectangle, in float64, nearest face in front of the camera wins."""
    centre = pose.to_camera(np.asarray([box.centre]))[0]
    edges = pose.direction_to_camera(np.asarray([box.edge_u, box.edge_v, box.edge_w]))
    best = np.full(rays.shape[:2], np.inf)
    normals = np.zeros(rays.shape)
    for i in range(3):
        normal = edges[i] / np.linalg.norm(edges[i])
        others = [edges[j] for j in range(3) if j != i]
        for side in (-0.5, 0.5):
            face_centre = centre + side * edges[i]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (face_centre @ normal) / (rays @ normal)
            local = t[..., None] * rays - face_centre
            inside = np.ones(t.shape, dtype=bool)
            for other in others:
                inside &= np.abs(local @ other) <= 0.5 * (other @ other)
            nearer = inside & (t > 0.01) & (t < best)
            best = np.where(nearer, t, best)
            normals[nearer] = np.sign(side) * normal
    return best, normals


@pytest.mark.parametrize("seed", range(4))
def test_box_depth_equals_a_face_by_face_intersection(seed):
    rng = np.random.default_rng(seed)
    # A box of random size and orientation 1-3 m in front of the camera.
    rotation, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    size = rng.uniform(0.1, 0.8, 3)
    box = Box(tuple(rng.uniform(-0.4, 0.4, 3) + (0.0, 2.0, 1.0)), *(tuple(s * r) for s, r in zip(size, rotation.T)),
              (200, 100, 50))
    pose = look_at((0.0, 0.0, 1.0), (0.0, 2.0, 1.0))
    frame = render(Scene((), (box,)), pose, CAMERA, WIDTH, HEIGHT)
    expected, normals = _box_by_faces(box, pose, _rays(CAMERA, WIDTH, HEIGHT))
    hit, expected_hit = frame.object_index == 0, np.isfinite(expected)
    assert expected_hit.sum() > 300
    # float32 against float64: only rays grazing an edge may disagree on hit or miss.
    assert np.count_nonzero(hit != expected_hit) <= 0.01 * expected_hit.sum()
    both = hit & expected_hit
    np.testing.assert_allclose(frame.depth[both], expected[both], rtol=1e-4)
    # Lambert shading of the entry face: 0.45 + 0.55 cos, as the other clutter.
    light = pose.direction_to_camera(np.asarray([Scene(()).light]))[0]
    shade = 0.45 + 0.55 * np.clip(normals[both] @ (light / np.linalg.norm(light)), 0.0, 1.0)
    np.testing.assert_allclose(frame.rgb[both][:, 0], 200 * shade, atol=1.0)
    assert np.ptp(shade) > 0.1  # at least two faces with different light


def test_box_seen_from_inside_or_behind_is_not_drawn():
    box = Box((0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (255, 0, 0))
    inside = render(Scene((), (box,)), look_at((0.0, 0.0, 1.0), (0.0, 1.0, 1.0)), CAMERA, WIDTH, HEIGHT)
    behind = render(Scene((), (box,)), look_at((0.0, -2.0, 1.0), (0.0, -3.0, 1.0)), CAMERA, WIDTH, HEIGHT)
    assert not (inside.object_index == 0).any() and not (behind.object_index == 0).any()


@pytest.fixture(scope="module")
def contact_frames():
    scene = contact_scene()
    poses = contact_trajectory(12)
    return scene, poses, [render_frame(scene, p, CAMERA, WIDTH, HEIGHT, np.random.default_rng(i)) for i, p in
                          enumerate(poses)]


def _plane_distance(plane, points: np.ndarray) -> np.ndarray:
    """Signed distance of world points to the plane's infinite plane, positive on the room side."""
    normal = np.cross(plane.edge_u, plane.edge_v)
    normal = normal / np.linalg.norm(normal)
    distance = (points - np.asarray(plane.centre)) @ normal
    room_side = np.sign((np.array([0.0, 1.0, 1.3]) - np.asarray(plane.centre)) @ normal)
    return distance * room_side


def test_contact_clutter_is_clutter_in_the_ground_truth_and_lies_within_3_cm_of_its_plane(contact_frames):
    scene, poses, frames = contact_frames
    planes = {p.label: p for p in scene.planes}
    rays = _rays(CAMERA, WIDTH, HEIGHT)
    seen = dict.fromkeys(FLAT_ON, 0)
    for pose, frame in zip(poses, frames):
        clean = render(scene, pose, CAMERA, WIDTH, HEIGHT)
        world = (rays * clean.depth[..., None]) @ pose.rotation.T + pose.position
        for k, (label, height) in FLAT_ON.items():
            pixels = clean.object_index == len(scene.planes) + N_ROOM_CLUTTER + k
            assert np.all(frame.plane_index[pixels] == -1)
            distance = _plane_distance(planes[label], world[pixels])
            # The visible faces: the top (at the height) and the rims (from 0 up to it).
            assert np.all((distance >= -1e-3) & (distance <= height + 1e-3)) and height <= 0.03
            seen[k] += int(pixels.sum())
    assert all(count > 100 for count in seen.values()), seen
    # The carton and the bin stand on the floor: their lowest visible points touch it.
    floor = planes["floor"]
    for k in (4, 7):
        lowest = []
        for pose in poses:
            clean = render(scene, pose, CAMERA, WIDTH, HEIGHT)
            pixels = clean.object_index == len(scene.planes) + N_ROOM_CLUTTER + k
            world = (rays * clean.depth[..., None])[pixels] @ pose.rotation.T + pose.position
            lowest += _plane_distance(floor, world).tolist()
        assert lowest and -1e-3 <= min(lowest) < 0.03


def test_contact_walk_sees_the_planes_from_0_8_to_3_m(contact_frames):
    scene, _, frames = contact_frames
    kept = [k for k, p in enumerate(scene.planes) if p.label not in ("window", "wall_corridor")]
    depth = np.concatenate([f.depth_raw[np.isin(f.plane_index, kept)] / CAMERA.depth_scale for f in frames])
    low, high = np.percentile(depth, [2, 98])
    assert 0.6 < low < 1.0 and 2.5 < high < 3.5
    # Near the ends the fixed 2 cm band is 2 sigma (far) or more than 10 sigma (near).
    assert 0.02 / kinect_noise_sigma(high) < 3 and 0.02 / kinect_noise_sigma(low) > 10


def test_jitter_moves_every_vertex_within_the_bound_seeded_and_leaves_the_rest_alone():
    scene, pose = room_scene(), room_trajectory(5)[2]
    exact = render_frame(scene, pose, CAMERA, WIDTH, HEIGHT, np.random.default_rng(3))
    jittered = render_frame(scene, pose, CAMERA, WIDTH, HEIGHT, np.random.default_rng(3), polygon_jitter_px=2.0)
    again = render_frame(scene, pose, CAMERA, WIDTH, HEIGHT, np.random.default_rng(3), polygon_jitter_px=2.0)
    other = render_frame(scene, pose, CAMERA, WIDTH, HEIGHT, np.random.default_rng(4), polygon_jitter_px=2.0)
    assert exact.polygons.keys() == jittered.polygons.keys() and len(exact.polygons) >= 4
    offsets = np.concatenate([jittered.polygons[k] - exact.polygons[k] for k in exact.polygons])
    assert np.abs(offsets).max() <= 2.0 and np.abs(offsets).max() > 1.5
    # Every coordinate inside the image moved; one on the image border stayed or moved inward.
    original = np.concatenate([exact.polygons[k] for k in exact.polygons])
    on_border = (original == 0) | (original == (WIDTH, HEIGHT))
    assert np.all(offsets[~on_border] != 0) and on_border.sum() < 0.5 * original.size
    assert np.all(np.where(original == 0, offsets >= 0, True) & np.where(original == (WIDTH, HEIGHT), offsets <= 0, True))
    for polygon in jittered.polygons.values():
        assert np.all((polygon >= 0) & (polygon <= (WIDTH, HEIGHT)))
    for k in exact.polygons:
        np.testing.assert_array_equal(again.polygons[k], jittered.polygons[k])
    assert any(not np.array_equal(other.polygons[k], jittered.polygons[k]) for k in exact.polygons)
    # The sensor and the ground truth are what they are, whatever the labeller draws.
    for name in ("rgb", "depth_raw", "plane_index", "visible"):
        np.testing.assert_array_equal(getattr(jittered, name), getattr(exact, name))


def test_jitter_offsets_are_uniform_per_axis():
    polygons = {0: np.full((20000, 2), 50.0)}
    moved = jitter_polygons(polygons, 2.0, 100, 100, np.random.default_rng(0))[0] - 50.0
    assert np.abs(moved).max() <= 2.0
    np.testing.assert_allclose(moved.mean(axis=0), 0.0, atol=0.05)
    np.testing.assert_allclose(moved.std(axis=0), 2.0 / np.sqrt(3), rtol=0.02)
    assert abs(np.corrcoef(moved.T)[0, 1]) < 0.03
    np.testing.assert_array_equal(polygons[0], 50.0)  # the input is left alone


def test_default_arguments_render_the_committed_sample_and_object_images_add_only_files(tmp_path):
    """The default polygon jitter gives the committed sample's bytes (decoded for PNGs), and
    asking for the object images adds them and changes nothing else (``tests/synthetic/test_synthetic.py``
    checks the sample made without any of the new options)."""
    spec = importlib.util.spec_from_file_location("make_sample_data", SAMPLE_DATA / "make_sample_data.py")
    sample = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sample)
    annotation = make_sequence(tmp_path / "sequence", n_frames=sample.N_FRAMES, width=sample.WIDTH, height=sample.HEIGHT,
                  camera=sample.CAMERA, seed=sample.SEED, ground_truth_dir=tmp_path / "ground_truth",
                  object_index_dir=tmp_path / "objects")
    for folder in ("sequence", "ground_truth"):
        committed = sorted(p.relative_to(SAMPLE_DATA / folder) for p in (SAMPLE_DATA / folder).rglob("*") if p.is_file())
        fresh = sorted(p.relative_to(tmp_path / folder) for p in (tmp_path / folder).rglob("*") if p.is_file())
        assert committed == fresh
        for name in committed:
            a, b = SAMPLE_DATA / folder / name, tmp_path / folder / name
            if a.suffix == ".png":
                assert np.array_equal(cv2.imread(str(a), cv2.IMREAD_UNCHANGED), cv2.imread(str(b), cv2.IMREAD_UNCHANGED))
            else:
                assert a.read_bytes() == b.read_bytes(), name
    write_cvat_video(annotation, tmp_path / "annotations.xml", width=sample.WIDTH, height=sample.HEIGHT,
                     keyframe_step=sample.KEYFRAME_STEP)
    assert (tmp_path / "annotations.xml").read_bytes() == (SAMPLE_DATA / "annotations.xml").read_bytes()
    # The object image of a frame is the renderer's object index + 1.
    info = json.loads((tmp_path / "ground_truth" / "planes.json").read_text())
    frame = info["frames"][3]
    objects = cv2.imread(str(tmp_path / "objects" / frame["ground_truth"]), cv2.IMREAD_UNCHANGED)
    clean = render(room_scene(), room_trajectory(sample.N_FRAMES)[3], sample.CAMERA, sample.WIDTH, sample.HEIGHT)
    assert objects.dtype == np.uint16
    np.testing.assert_array_equal(objects.astype(np.int64), clean.object_index + 1)

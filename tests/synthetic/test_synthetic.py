"""The synthetic scene renderer and the committed sample rendered with it."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from skimage.measure import points_in_poly

from annotate_rgbd.geometry.camera import Camera, depth_to_metres
from annotate_rgbd.config.settings import FilterConfig, load_config
from annotate_rgbd.segment.filters import drop_reasons, plane_statistics
from annotate_rgbd.segment.rasterize import rasterize_frame
from annotate_rgbd.synthetic import (
    MAX_DEPTH,
    kinect_noise_sigma,
    make_sequence,
    render,
    render_frame,
    room_scene,
    room_trajectory,
)

SAMPLE_DATA = Path(__file__).resolve().parents[2] / "sample_data"
WIDTH, HEIGHT = 160, 120
CAMERA = Camera(fx=131.25, fy=131.25, cx=79.5, cy=59.5, depth_scale=5000.0)


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> tuple[Path, object]:
    """A small rendered sequence and the annotation make_sequence returned."""
    out = tmp_path_factory.mktemp("synthetic")
    annotation = make_sequence(out, n_frames=9, width=WIDTH, height=HEIGHT, camera=CAMERA, seed=5)
    return out, annotation


def _read_list(path: Path) -> tuple[list[str], list[tuple[float, str]]]:
    lines = path.read_text().splitlines()
    header = [line for line in lines if line.startswith("#")]
    entries = [(float(line.split()[0]), line.split()[1]) for line in lines if not line.startswith("#")]
    return header, entries


def _files(folder: Path) -> dict[str, Path]:
    return {str(p.relative_to(folder)): p for p in sorted(folder.rglob("*")) if p.is_file()}


def _same_content(a: Path, b: Path) -> bool:
    """PNGs compare decoded (zlib builds may differ), everything else byte for byte."""
    if a.suffix == ".png":
        image_a, image_b = cv2.imread(str(a), cv2.IMREAD_UNCHANGED), cv2.imread(str(b), cv2.IMREAD_UNCHANGED)
        return image_a.dtype == image_b.dtype and np.array_equal(image_a, image_b)
    return a.read_bytes() == b.read_bytes()


def _top_polygon(frame, scene) -> np.ndarray:
    """Plane index whose polygon is drawn on top at each pixel centre (-1: none)."""
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH]
    centres = np.column_stack([cols.ravel() + 0.5, rows.ravel() + 0.5])
    top = np.full(HEIGHT * WIDTH, -1)
    for k in sorted(frame.polygons, key=lambda k: scene.planes[k].z_order):
        top[points_in_poly(centres, frame.polygons[k])] = k
    return top.reshape(HEIGHT, WIDTH)


def test_rendering_is_deterministic_and_depends_on_the_seed():
    scene, pose = room_scene(), room_trajectory(5)[2]
    a = render_frame(scene, pose, CAMERA, WIDTH, HEIGHT, np.random.default_rng(1))
    b = render_frame(scene, pose, CAMERA, WIDTH, HEIGHT, np.random.default_rng(1))
    c = render_frame(scene, pose, CAMERA, WIDTH, HEIGHT, np.random.default_rng(2))
    for name in ("rgb", "depth_raw", "plane_index", "visible"):
        assert np.array_equal(getattr(a, name), getattr(b, name))
    assert a.polygons.keys() == b.polygons.keys()
    assert all(np.array_equal(a.polygons[k], b.polygons[k]) for k in a.polygons)
    assert not np.array_equal(a.depth_raw, c.depth_raw)


def test_make_sequence_is_deterministic(sequence, tmp_path):
    out, _ = sequence
    make_sequence(tmp_path, n_frames=9, width=WIDTH, height=HEIGHT, camera=CAMERA, seed=5)
    first, second = _files(out), _files(tmp_path)
    assert first.keys() == second.keys()
    assert all(first[name].read_bytes() == second[name].read_bytes() for name in first)


def test_gt_pixels_lie_in_their_polygon_drawn_on_top():
    scene = room_scene()
    for i, pose in enumerate(room_trajectory(6)):
        frame = render_frame(scene, pose, CAMERA, WIDTH, HEIGHT, np.random.default_rng(i))
        labelled = frame.plane_index >= 0
        assert labelled.sum() > 0.5 * WIDTH * HEIGHT
        agree = _top_polygon(frame, scene)[labelled] == frame.plane_index[labelled]
        assert agree.mean() > 0.998, f"frame {i}: {agree.mean():.4f}"
        for polygon in frame.polygons.values():
            assert polygon[:, 0].min() >= 0 and polygon[:, 0].max() <= WIDTH
            assert polygon[:, 1].min() >= 0 and polygon[:, 1].max() <= HEIGHT


def test_polygons_run_over_clutter_and_nearer_planes():
    scene = room_scene()
    frame = render_frame(scene, room_trajectory(5)[2], CAMERA, WIDTH, HEIGHT, np.random.default_rng(0))
    floor = next(k for k, p in enumerate(scene.planes) if p.label == "floor")
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH]
    centres = np.column_stack([cols.ravel() + 0.5, rows.ravel() + 0.5])
    inside = points_in_poly(centres, frame.polygons[floor]).reshape(HEIGHT, WIDTH)
    covered = frame.visible[inside & (frame.visible != floor)]
    n_planes = len(scene.planes)
    assert (covered >= n_planes).sum() > 50  # table legs, the bin
    assert np.isin(covered, [k for k, p in enumerate(scene.planes) if p.label == "table_top"]).sum() > 50


def test_depth_has_kinect_noise_holes_and_range_limit():
    scene, pose = room_scene(), room_trajectory(5)[2]
    clean = render(scene, pose, CAMERA, WIDTH, HEIGHT)
    frame = render_frame(scene, pose, CAMERA, WIDTH, HEIGHT, np.random.default_rng(3))
    metres = frame.depth_raw / CAMERA.depth_scale
    valid = frame.depth_raw > 0
    error = (metres - clean.depth)[valid]
    assert 0.5 < np.std(error / kinect_noise_sigma(clean.depth[valid])) < 1.5
    assert metres.max() <= MAX_DEPTH
    glass = np.isin(frame.visible, [k for k, p in enumerate(scene.planes) if p.valid_fraction < 1])
    holes = ~valid & (clean.depth > 0) & ~glass
    assert 0.002 < holes.mean() < 0.1
    # Pixels next to a depth jump lose depth far more often than the rest.
    jump = np.zeros(clean.depth.shape, dtype=bool)
    jump[:, 1:] = np.abs(np.diff(clean.depth, axis=1)) > 0.2
    assert (~valid[jump & ~glass]).mean() > 5 * holes.mean()


def test_glass_is_mostly_invalid_and_far_wall_is_far():
    scene = room_scene()
    window = next(k for k, p in enumerate(scene.planes) if p.label == "window")
    corridor = next(k for k, p in enumerate(scene.planes) if p.label == "wall_corridor")
    frame = render_frame(scene, room_trajectory(5)[0], CAMERA, WIDTH, HEIGHT, np.random.default_rng(0))
    seen = frame.visible == window
    assert seen.sum() > 100 and (frame.depth_raw[seen] == 0).mean() > 0.8
    frame = render_frame(scene, room_trajectory(5)[2], CAMERA, WIDTH, HEIGHT, np.random.default_rng(0))
    far = frame.plane_index == corridor
    assert far.sum() > 100 and (frame.depth_raw[far] / CAMERA.depth_scale).mean() > 3.5


def test_planes_json_agrees_with_the_ground_truth_images(sequence):
    out, annotation = sequence
    info = json.loads((out / "ground_truth" / "planes.json").read_text())
    planes = {p["label"]: p for p in info["planes"]}
    assert planes["wall_corridor"]["expected"] == "dropped" and planes["wall_corridor"]["reason"] == "too_far"
    assert planes["window"]["expected"] == "dropped" and planes["window"]["reason"] == "invalid_depth"
    others = {p["expected"] for label, p in planes.items() if label not in ("window", "wall_corridor")}
    assert others == {"kept"}
    # Track ids are shuffled, and the tracks are the planes.
    assert [p["track_id"] for p in info["planes"]] == sorted(p["track_id"] for p in info["planes"])
    assert [t.track_id for t in annotation.tracks] == [p["track_id"] for p in info["planes"]]
    assert [t.label for t in annotation.tracks] == [p["label"] for p in info["planes"]]
    assert [p["label"] for p in info["planes"]] != [p.label for p in room_scene().planes]
    far, glass = [], []
    for record in info["frames"]:
        gt = cv2.imread(str(out / "ground_truth" / record["ground_truth"]), cv2.IMREAD_UNCHANGED)
        depth = cv2.imread(str(out / record["depth"]), cv2.IMREAD_UNCHANGED)
        assert gt.dtype == np.uint16 and gt.shape == (HEIGHT, WIDTH)
        assert np.all(depth[gt > 0] > 0)
        assert set(np.unique(gt)) <= {0} | {p["gt_value"] for p in info["planes"]}
        far.append(depth[gt == planes["wall_corridor"]["gt_value"]])
        glass.append(depth[gt == planes["window"]["gt_value"]])
    assert np.concatenate(far).mean() / CAMERA.depth_scale > 3.5
    assert planes["window"]["invalid_ratio"] > 0.8


def test_planes_json_statistics_are_those_of_the_ground_truth_images(sequence):
    """mean_depth_m is the z depth pooled over every depth frame (the one without RGB too)."""
    out, _ = sequence
    info = json.loads((out / "ground_truth" / "planes.json").read_text())
    images = [(cv2.imread(str(out / "ground_truth" / r["ground_truth"]), cv2.IMREAD_UNCHANGED),
               cv2.imread(str(out / r["depth"]), cv2.IMREAD_UNCHANGED)) for r in info["frames"]]
    assert any(r["rgb"] is None for r in info["frames"])
    for plane in info["planes"]:
        depth = np.concatenate([d[gt == plane["gt_value"]] for gt, d in images]) / CAMERA.depth_scale
        assert plane["mean_depth_m"] == pytest.approx(depth.mean(), abs=6e-5)
        # The ground truth holds the plane's visible pixels that have depth.
        assert depth.size == pytest.approx(plane["visible_pixels"] * (1 - plane["invalid_ratio"]), abs=1e-4 * plane["visible_pixels"] + 1)


def test_expected_fate_is_what_the_per_frame_filter_rules_give(sequence):
    """The whole-sequence oracle and filters.py differ in method (see synthetic/ground_truth.py)
    but must agree on the room: every plane gets its expected fate in every annotated frame."""
    out, annotation = sequence
    info = json.loads((out / "ground_truth" / "planes.json").read_text())
    expected = {p["track_id"] + 1: p["reason"] for p in info["planes"]}
    depth_of_frame = {r["annotation_frame"]: out / r["depth"] for r in info["frames"] if r["rgb"]}
    decisions = 0
    for frame in annotation.frames:
        shapes = [(t.track_id + 1, t.shapes[frame]) for t in annotation.tracks if frame in t.shapes]
        drawn = rasterize_frame(shapes, HEIGHT, WIDTH)
        depth = depth_to_metres(cv2.imread(str(depth_of_frame[frame]), cv2.IMREAD_UNCHANGED), CAMERA.depth_scale)
        stats = plane_statistics(drawn, depth, CAMERA)
        for plane, reason in zip(stats.plane_ids, drop_reasons(stats, FilterConfig())):
            assert reason == expected[plane], f"frame {frame}, track {plane - 1}"
            decisions += 1
    assert decisions == sum(len(t.shapes) for t in annotation.tracks)


def test_annotation_shapes_follow_the_rgb_frames(sequence):
    out, annotation = sequence
    info = json.loads((out / "ground_truth" / "planes.json").read_text())
    _, rgb = _read_list(out / "rgb.txt")
    assert annotation.format == "video" and annotation.frames == list(range(len(rgb)))
    z_orders = {p.label: p.z_order for p in room_scene().planes}
    for track, plane in zip(annotation.tracks, info["planes"], strict=True):
        assert len(track.shapes) == plane["annotated_frames"] > 0
        assert set(track.shapes) <= set(annotation.frames)
        assert all(s.kind == "polygon" and s.z_order == z_orders[track.label] for s in track.shapes.values())
    by_label = {t.label: t for t in annotation.tracks}
    frame = next(iter(by_label["table_top"].shapes))
    assert by_label["table_top"].shapes[frame].z_order > by_label["floor"].shapes[frame].z_order


def test_timestamps_differ_and_one_depth_frame_has_no_rgb(sequence):
    out, _ = sequence
    rgb_header, rgb = _read_list(out / "rgb.txt")
    depth_header, depth = _read_list(out / "depth.txt")
    assert len(rgb_header) == len(depth_header) == 3
    assert len(depth) == len(rgb) + 1
    for t, name in rgb + depth:
        assert (out / name).is_file() and name.endswith(f"{t:.6f}.png")
    rgb_times = np.array([t for t, _ in rgb])
    gaps = np.array([np.abs(rgb_times - t).min() for t, _ in depth])
    assert np.all(gaps > 0)
    assert (gaps >= 0.02).sum() == 1
    assert np.all(gaps[gaps < 0.02] >= 0.005)


def test_sample_data_matches_a_fresh_render(tmp_path):
    script = SAMPLE_DATA / "make_sample_data.py"
    spec = importlib.util.spec_from_file_location("make_sample_data", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.make_sample_data(tmp_path)
    # The script, the README and the review-page screenshot (made by tests/review/test_review.py) are not renders.
    committed = {name: path for name, path in _files(SAMPLE_DATA).items() if path.suffix != ".py" and
                 not name.endswith(".md") and "__pycache__" not in name and name != "review.png"}
    fresh = _files(tmp_path)
    assert committed.keys() == fresh.keys()
    differing = [name for name in fresh if not _same_content(committed[name], fresh[name])]
    assert not differing, f"regenerate with: python sample_data/make_sample_data.py ({differing[:3]})"
    assert sum(p.stat().st_size for p in SAMPLE_DATA.rglob("*") if p.is_file()) < 4_500_000


def test_sample_camera_file_is_a_valid_configuration():
    config = load_config(SAMPLE_DATA / "camera.toml")
    assert config.camera == Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, depth_scale=5000.0)
    # The quick start shows noise-aware refinement: no fixed band, and the noise model is the
    # one the renderer draws the sample's depth noise from.
    assert config.ransac.distance_threshold == 0.0
    assert config.inlier_band() == config.noise
    z = np.linspace(0.4, 5.0, 47)
    np.testing.assert_allclose(config.noise.model.sigma(z), kinect_noise_sigma(z), rtol=1e-12)

"""Colour and depth on different pixel grids: labels drawn on an offset colour camera of another
resolution land on the right depth pixels.

The expected labels are computed independently of annotate_rgbd.geometry.registration: homogeneous
4 x 4 matrices and intrinsic matrices, and scikit-image's point-in-polygon test at the exact
projected point (no rasterisation).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from skimage.measure import points_in_poly
from typer.testing import CliRunner

from annotate_rgbd.annotation.model import Annotation, Shape, Track
from annotate_rgbd.cli import app
from annotate_rgbd.config.settings import Config, config_from_dict, config_to_dict, load_config
from annotate_rgbd.cvat import read_cvat
from annotate_rgbd.cvat.writer import write_cvat_video
from annotate_rgbd.errors import InputError
from annotate_rgbd.geometry.camera import Camera, depth_to_metres
from annotate_rgbd.geometry.registration import (
    clip_to_image, colour_camera_from_mapping, polygon_on_colour_image, sample_labels,
)
from annotate_rgbd.segment.frame import segment_frame
from annotate_rgbd.segment.rasterize import draw_on_depth_grid, rasterize_frame
from annotate_rgbd.synthetic import (
    Pose, plane_polygon, render, render_frame, room_scene, room_trajectory, write_tum_trajectory,
)

DEPTH_CAMERA = Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, depth_scale=5000.0)
DEPTH_SIZE = (320, 240)
COLOUR_SIZE = (424, 300)
#: A wider field of view than the depth camera's, as ScanNet's colour camera has.
COLOUR_K = np.array([[290.0, 0.0, 211.0], [0.0, 288.0, 150.5], [0.0, 0.0, 1.0]])
ANGLE = np.deg2rad(3.0)
#: Depth camera frame -> colour camera frame: 3 degrees about y, 5 cm to the side.
EXTRINSIC = np.array([
    [np.cos(ANGLE), 0.0, np.sin(ANGLE), 0.052],
    [0.0, 1.0, 0.0, -0.011],
    [-np.sin(ANGLE), 0.0, np.cos(ANGLE), 0.004],
    [0.0, 0.0, 0.0, 1.0],
])
COLOUR_TABLE = {"fx": 290.0, "fy": 288.0, "cx": 211.0, "cy": 150.5, "width": COLOUR_SIZE[0],
                "height": COLOUR_SIZE[1], "extrinsic": EXTRINSIC.tolist()}
COLOUR_TOML = (
    "[colour_camera]\nfx = 290.0\nfy = 288.0\ncx = 211.0\ncy = 150.5\nwidth = 424\nheight = 300\n"
    f"extrinsic = {json.dumps(EXTRINSIC.tolist())}\n"
)


def colour_view(depth_pose: Pose) -> tuple[Pose, Camera]:
    """The colour camera's pose (camera to world) and intrinsics for a depth camera pose."""
    depth_to_world = np.eye(4)
    depth_to_world[:3, :3], depth_to_world[:3, 3] = depth_pose.rotation, depth_pose.position
    colour_to_world = depth_to_world @ np.linalg.inv(EXTRINSIC)
    camera = Camera(fx=COLOUR_K[0, 0], fy=COLOUR_K[1, 1], cx=COLOUR_K[0, 2], cy=COLOUR_K[1, 2], depth_scale=5000.0)
    return Pose(colour_to_world[:3, :3], colour_to_world[:3, 3]), camera


def colour_frame(index: int, n_frames: int = 8):
    """Depth rendered from the depth camera, colour image and polygons from the colour camera."""
    scene = room_scene()
    pose = room_trajectory(n_frames)[index]
    depth = render_frame(scene, pose, DEPTH_CAMERA, *DEPTH_SIZE, np.random.default_rng(index))
    view, camera = colour_view(pose)
    seen = render(scene, view, camera, *COLOUR_SIZE)
    counts = np.bincount(seen.object_index.ravel() + 1, minlength=len(scene.planes) + 1)[1 : len(scene.planes) + 1]
    shapes = []
    for k in np.flatnonzero(counts >= 0.002 * COLOUR_SIZE[0] * COLOUR_SIZE[1]):
        polygon = plane_polygon(scene.planes[k], view, camera, *COLOUR_SIZE)
        if polygon is not None:
            shapes.append((int(k) + 1, Shape("polygon", polygon, z_order=scene.planes[k].z_order)))
    return scene, depth, seen, shapes


def in_colour_image(depth_raw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each valid depth pixel (rows, cols) and its point's colour image position (N, 2; pixel
    centres at integers), with homogeneous matrices."""
    rows, cols = np.nonzero(depth_raw > 0)
    z = depth_raw[rows, cols] / DEPTH_CAMERA.depth_scale
    k_depth = np.array([[DEPTH_CAMERA.fx, 0, DEPTH_CAMERA.cx], [0, DEPTH_CAMERA.fy, DEPTH_CAMERA.cy], [0, 0, 1]])
    points = np.linalg.solve(k_depth, np.stack([cols, rows, np.ones_like(cols)]).astype(float)) * z
    colour_points = (EXTRINSIC @ np.vstack([points, np.ones(len(z))]))[:3]
    pixels = COLOUR_K @ colour_points
    return rows, cols, (pixels[:2] / pixels[2]).T


def expected_drawn(depth_raw: np.ndarray, shapes) -> np.ndarray:
    """Independent expectation: each valid depth pixel's point in the colour image, tested against
    the polygons in z-order (later on top at equal z_order)."""
    rows, cols, xy = in_colour_image(depth_raw)
    cvat_xy = xy + 0.5  # CVAT puts pixel centres at +0.5
    labels = np.zeros(depth_raw.shape, dtype=np.int32)
    for plane_id, shape in sorted(shapes, key=lambda item: item[1].z_order):
        inside = points_in_poly(cvat_xy, shape.points)
        labels[rows[inside], cols[inside]] = plane_id
    return labels


def seen_by_both(depth, seen, plane_ids) -> np.ndarray:
    """Ground truth: a depth pixel shows plane k when the depth camera sees k there and the colour
    camera sees the same surface where that point lies in its image (not beyond its view, not
    behind an occluder), for the given planes (ids = scene plane index + 1)."""
    rows, cols, xy = in_colour_image(depth.depth_raw)
    at = np.rint(xy).astype(int)
    inside = (at[:, 0] >= 0) & (at[:, 0] < COLOUR_SIZE[0]) & (at[:, 1] >= 0) & (at[:, 1] < COLOUR_SIZE[1])
    seen_there = np.full(len(rows), -2)
    seen_there[inside] = seen.object_index[at[inside, 1], at[inside, 0]]
    visible = depth.visible[rows, cols]
    same = (seen_there == visible) & np.isin(visible + 1, plane_ids)
    truth = np.zeros(depth.depth_raw.shape, dtype=np.int32)
    truth[rows[same], cols[same]] = visible[same] + 1
    return truth


def edge_distance(points: np.ndarray, polygons) -> np.ndarray:
    """Distance of each point (N, 2) to the nearest edge of any polygon."""
    nearest = np.full(len(points), np.inf)
    for polygon in polygons:
        start, end = polygon, np.roll(polygon, -1, axis=0)
        edge = end - start
        u = np.clip(np.einsum("nek,ek->ne", points[:, None] - start[None], edge) / (edge ** 2).sum(1), 0, 1)
        foot = start[None] + u[..., None] * edge[None]
        nearest = np.minimum(nearest, np.linalg.norm(points[:, None] - foot, axis=2).min(axis=1))
    return nearest


def mean_iou(found: np.ndarray, expected: np.ndarray, ids) -> float:
    ious = [np.count_nonzero((found == i) & (expected == i)) / np.count_nonzero((found == i) | (expected == i))
            for i in ids]
    return float(np.mean(ious))


def test_shapes_land_where_the_depth_pixels_project():
    _, depth, _, shapes = colour_frame(3)
    colour = colour_camera_from_mapping(COLOUR_TABLE)
    depth_m = depth_to_metres(depth.depth_raw, DEPTH_CAMERA.depth_scale)
    drawn, grid = draw_on_depth_grid(shapes, depth_m, DEPTH_CAMERA, colour)
    expected = expected_drawn(depth.depth_raw, shapes)
    valid = depth.depth_raw > 0
    assert grid is not None and grid[0].shape == depth.depth_raw.shape
    assert np.mean(drawn[valid] == expected[valid]) > 0.995
    # Rasterising on the colour grid (the label of the colour pixel nearest the point) moves a
    # label only where the point lies within half a colour pixel's diagonal of an outline.
    rows, cols, xy = in_colour_image(depth.depth_raw)
    differ = drawn[rows, cols] != expected[rows, cols]
    assert 0 < np.count_nonzero(differ)
    assert (edge_distance(xy[differ] + 0.5, [shape.points for _, shape in shapes]) <= np.sqrt(0.5) + 1e-6).all()
    ids = np.unique(expected[expected > 0])
    assert len(ids) >= 4
    assert mean_iou(np.where(valid, drawn, 0), expected, ids) > 0.97
    # The registered assumption (the colour coordinates taken as depth coordinates) is far off.
    registered, none = draw_on_depth_grid(shapes, depth_m, DEPTH_CAMERA, None)
    assert none is None and mean_iou(np.where(valid, registered, 0), expected, ids) < 0.8


@pytest.mark.parametrize("index", [1, 5])
def test_refined_masks_match_the_rendered_ground_truth(index):
    scene, depth, seen, shapes = colour_frame(index)
    config = Config(camera=DEPTH_CAMERA, colour_camera=colour_camera_from_mapping(COLOUR_TABLE))
    result = segment_frame(depth.depth_raw, shapes, config)
    truth = seen_by_both(depth, seen, [plane_id for plane_id, _ in shapes])
    kept = [r.plane for r in result.kept]
    assert {scene.planes[r.plane - 1].label for r in result.dropped} <= {"wall_corridor", "window"}  # far, glass
    assert len(kept) >= 6
    assert mean_iou(result.labels, truth, kept) >= 0.95
    assert not result.labels[depth.depth_raw == 0].any()  # pixels without depth get no label


def test_pixels_without_depth_count_for_the_invalid_depth_rule():
    _, depth, _, shapes = colour_frame(3)
    config = Config(camera=DEPTH_CAMERA, colour_camera=colour_camera_from_mapping(COLOUR_TABLE))
    before = segment_frame(depth.depth_raw, shapes, config)
    largest = max(before.kept, key=lambda r: r.inliers).plane
    holes = depth.depth_raw.copy()
    holes[depth.visible == largest - 1] = 0  # the sensor returns nothing from that plane (glass)
    after = segment_frame(holes, shapes, config)
    dropped = {r.plane: r for r in after.dropped}
    assert dropped[largest].reason == "invalid_depth" and dropped[largest].invalid_ratio > 0.8


def test_colour_camera_configuration(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text(COLOUR_TOML, encoding="utf-8")
    config = load_config(path)
    assert config.colour_camera is not None and config.colour_camera.width == 424
    np.testing.assert_allclose(config.colour_camera.extrinsic, EXTRINSIC)
    # The report's configuration reads back to the same camera; a registered one has no section.
    assert config_from_dict(config_to_dict(config)).colour_camera == config.colour_camera
    assert "colour_camera" not in config_to_dict(Config())
    rotation = EXTRINSIC[:3, :3].tolist()
    path.write_text(COLOUR_TOML.split("extrinsic")[0] + f"rotation = {json.dumps(rotation)}\n"
                    "translation = [0.052, -0.011, 0.004]\n", encoding="utf-8")
    np.testing.assert_allclose(load_config(path).colour_camera.extrinsic, EXTRINSIC)
    bad = {
        "rotation = [[1, 0, 0], [0, 1, 0], [0, 0, 2]]\n": "not a rotation",
        "extrinsic = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]\n": "0, 0, 0, 1",
        "extrinsic = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n": "4 x 4",
        "translation = [0, 0]\n": "3 numbers",
        "skew = 0\n": "unknown key 'colour_camera.skew'",
    }
    base = COLOUR_TOML.split("extrinsic")[0]
    for line, message in bad.items():
        path.write_text(base + line, encoding="utf-8")
        with pytest.raises(InputError, match=message):
            load_config(path)
    path.write_text(base.replace("width = 424\n", ""), encoding="utf-8")
    with pytest.raises(InputError, match="'colour_camera.width' is missing"):
        load_config(path)


def write_sequence(folder: Path, frames=(2, 3, 4), n_frames: int = 8, keyframe_step: int = 1) -> Path:
    """A TUM-layout sequence whose RGB images come from the offset colour camera, with the
    labeller's polygons drawn on them as a CVAT video export (keyframes every ``keyframe_step``
    frames and the last, the API's way) and the depth camera's trajectory."""
    (folder / "rgb").mkdir(parents=True)
    (folder / "depth").mkdir()
    tracks: dict[int, dict[int, Shape]] = {}
    rgb_lines, depth_lines, stamps = [], [], []
    for i, index in enumerate(frames):
        _, depth, seen, shapes = colour_frame(index, n_frames)
        stamp = f"{1700000000 + i / 10:.6f}"
        stamps.append(float(stamp))
        cv2.imwrite(str(folder / "rgb" / f"{stamp}.png"), cv2.cvtColor(seen.rgb, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(folder / "depth" / f"{stamp}.png"), depth.depth_raw)
        rgb_lines.append(f"{stamp} rgb/{stamp}.png")
        depth_lines.append(f"{stamp} depth/{stamp}.png")
        for plane_id, shape in shapes:
            tracks.setdefault(plane_id, {})[i] = shape
    (folder / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (folder / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    write_tum_trajectory(folder / "groundtruth.txt", stamps, [room_trajectory(n_frames)[i] for i in frames])
    scene = room_scene()
    annotation = Annotation(
        path=str(folder), format="video", frames=list(range(len(frames))),
        tracks=[Track(plane_id, scene.planes[plane_id - 1].label, shapes) for plane_id, shapes in sorted(tracks.items())],
        image_size={f: COLOUR_SIZE for f in range(len(frames))},
    )
    xml = folder / "annotations.xml"
    write_cvat_video(annotation, xml, width=COLOUR_SIZE[0], height=COLOUR_SIZE[1], keyframe_step=keyframe_step,
                     keyframes_only=keyframe_step > 1)
    return xml


def test_cvat2mask_with_a_colour_camera(tmp_path):
    xml = write_sequence(tmp_path / "seq")
    camera = (f"[camera]\nfx = {DEPTH_CAMERA.fx}\nfy = {DEPTH_CAMERA.fy}\ncx = {DEPTH_CAMERA.cx}\n"
              f"cy = {DEPTH_CAMERA.cy}\ndepth_scale = 5000.0\n")
    registered = tmp_path / "registered.toml"
    registered.write_text(camera, encoding="utf-8")
    runner = CliRunner()
    result = runner.invoke(app, ["cvat2mask", str(tmp_path / "seq"), str(xml), "--config", str(registered),
                                 "--out", str(tmp_path / "out0"), "-j", "1"])
    assert result.exit_code == 1 and "depth image is 320x240 but annotations.xml annotates 424x300" in result.output
    config = tmp_path / "colour.toml"
    config.write_text(camera + COLOUR_TOML, encoding="utf-8")
    out = tmp_path / "out"
    result = runner.invoke(app, ["cvat2mask", str(tmp_path / "seq"), str(xml), "--config", str(config),
                                 "--out", str(out), "-j", "1", "--overlays"])
    assert result.exit_code == 0, result.output
    report = json.loads((out / "report.json").read_text())
    assert report["config"]["colour_camera"]["width"] == 424
    assert load_config(config).colour_camera == config_from_dict(report["config"]).colour_camera
    masks = sorted((out / "masks").iterdir())
    overlays = sorted((out / "overlays").iterdir())
    assert len(masks) == len(overlays) == 3
    assert cv2.imread(str(masks[0])).shape[:2] == cv2.imread(str(overlays[0])).shape[:2] == (240, 320)
    assert all(f["kept"] for f in report["frames"])
    # review draws them again from the run's records: the same overlays as the frames' jobs drew.
    made = {p.name: p.read_bytes() for p in overlays}
    result = runner.invoke(app, ["review", str(out), "-j", "1"])
    assert result.exit_code == 0, result.output
    assert {p.name: p.read_bytes() for p in (out / "overlays").iterdir()} == made


def test_poses_carry_keyframes_drawn_on_the_colour_camera(tmp_path):
    frames = list(range(20, 27))
    xml = write_sequence(tmp_path / "seq", frames=frames, n_frames=48, keyframe_step=6)
    config = tmp_path / "colour.toml"
    config.write_text(f"[camera]\nfx = {DEPTH_CAMERA.fx}\nfy = {DEPTH_CAMERA.fy}\ncx = {DEPTH_CAMERA.cx}\n"
                      f"cy = {DEPTH_CAMERA.cy}\ndepth_scale = 5000.0\n" + COLOUR_TOML, encoding="utf-8")
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["cvat2mask", str(tmp_path / "seq"), str(xml), "--config", str(config), "--out",
                                      str(out), "-j", "1", "--instance-ids", "--poses",
                                      str(tmp_path / "seq" / "groundtruth.txt")])
    assert result.exit_code == 0, result.output
    report = json.loads((out / "report.json").read_text())
    track_of = {p["plane"]: p["track_id"] for p in report["planes"]}
    ious = []
    for i, frame in enumerate(report["frames"][1:6], start=1):  # between the keyframes 0 and 6
        _, depth, seen, shapes = colour_frame(frames[i], 48)
        ids = cv2.imread(str(out / "masks_id" / Path(frame["depth"]).name), cv2.IMREAD_UNCHANGED)
        as_tracks = np.array([0] + [track_of[p] for p in range(1, len(track_of) + 1)])[ids]
        truth = seen_by_both(depth, seen, [plane_id for plane_id, _ in shapes])
        kept = [track_of[r["plane"]] for r in frame["kept"]]
        assert any(r["propagated"] for r in frame["kept"])
        ious.append(mean_iou(as_tracks, truth, kept))
    assert np.mean(ious) >= 0.95, ious


def test_label_sampling_is_the_nearest_colour_pixel():
    rng = np.random.default_rng(1)
    labels = rng.integers(0, 200, (97, 131))
    map_x = rng.uniform(-3, 134, (50, 60)).astype(np.float32)
    map_y = rng.uniform(-3, 100, (50, 60)).astype(np.float32)
    cols, rows = np.floor(map_x.astype(np.float64) + 0.5).astype(int), np.floor(map_y.astype(np.float64) + 0.5).astype(int)
    inside = (cols >= 0) & (cols < 131) & (rows >= 0) & (rows < 97)
    expected = np.where(inside, labels[rows.clip(0, 96), cols.clip(0, 130)], 0)
    for dtype in (np.uint8, np.uint16, np.int32):  # OpenCV's remap, and numpy for ids past 65535
        np.testing.assert_array_equal(sample_labels(labels.astype(dtype), map_x, map_y), expected)


def save_matrix(path: Path, matrix: np.ndarray) -> None:
    """A 4 x 4 matrix as ScanNet's SensReader writes it: one row a line."""
    path.write_text("".join(" ".join(f"{v:f}" for v in row) + "\n" for row in matrix))


def write_scannet_scene(tmp_path: Path, frames=(2, 3, 4)) -> tuple[Path, Path]:
    """A ScanNet export whose colour images come from the offset colour camera (another size,
    intrinsics and pose), with the labeller's polygons drawn on them as a CVAT video export."""
    root = tmp_path / "scene0000_00"
    for name in ("color", "depth", "pose", "intrinsic"):
        (root / name).mkdir(parents=True)
    tracks: dict[int, dict[int, Shape]] = {}
    for i, index in enumerate(frames):
        _, depth, seen, shapes = colour_frame(index)
        cv2.imwrite(str(root / "color" / f"{i}.jpg"), seen.rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
        cv2.imwrite(str(root / "depth" / f"{i}.png"), np.round(depth.depth_raw / 5.0).astype(np.uint16))  # mm
        pose = room_trajectory(8)[index]
        save_matrix(root / "pose" / f"{i}.txt", np.vstack([np.c_[pose.rotation, pose.position], [0, 0, 0, 1]]))
        for plane_id, shape in shapes:
            tracks.setdefault(plane_id, {})[i] = shape
    k_depth = np.array([[DEPTH_CAMERA.fx, 0, DEPTH_CAMERA.cx, 0], [0, DEPTH_CAMERA.fy, DEPTH_CAMERA.cy, 0],
                        [0, 0, 1, 0], [0, 0, 0, 1]])
    save_matrix(root / "intrinsic" / "intrinsic_depth.txt", k_depth)
    save_matrix(root / "intrinsic" / "intrinsic_color.txt", np.pad(COLOUR_K, (0, 1)) + np.diag([0, 0, 0, 1]))
    # ScanNet's extrinsics map each camera to the colour camera (sensorData.h): depth's is depth -> colour.
    save_matrix(root / "intrinsic" / "extrinsic_color.txt", np.eye(4))
    save_matrix(root / "intrinsic" / "extrinsic_depth.txt", EXTRINSIC)
    scene = room_scene()
    annotation = Annotation(
        path=str(root), format="video", frames=list(range(len(frames))),
        tracks=[Track(p, scene.planes[p - 1].label, shapes) for p, shapes in sorted(tracks.items())],
        image_size={f: COLOUR_SIZE for f in range(len(frames))},
    )
    xml = tmp_path / "annotations.xml"
    write_cvat_video(annotation, xml, width=COLOUR_SIZE[0], height=COLOUR_SIZE[1])
    return root, xml


def test_scannet_layout_with_its_colour_camera(tmp_path):
    """Without --config, the layout's colour camera is used, and the shapes drawn on the colour
    images land on the right depth pixels; a batch scene without a config does the same."""
    frames = (2, 3, 4)
    root, xml = write_scannet_scene(tmp_path, frames)
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["cvat2mask", str(root), str(xml), "--out", str(out), "-j", "1", "--instance-ids"])
    assert result.exit_code == 0, result.output
    assert "colour camera: " in result.output and "424x300" in result.output
    report = json.loads((out / "report.json").read_text())
    np.testing.assert_allclose(report["config"]["colour_camera"]["extrinsic"], EXTRINSIC, atol=1e-6)
    track_of = {p["plane"]: p["track_id"] for p in report["planes"]}
    ious = []
    for index, frame in zip(frames, report["frames"]):
        _, depth, seen, shapes = colour_frame(index)
        ids = cv2.imread(str(out / "masks_id" / Path(frame["mask"]).name), cv2.IMREAD_UNCHANGED)
        as_tracks = np.array([0] + [track_of[p] for p in range(1, len(track_of) + 1)])[ids]
        truth = seen_by_both(depth, seen, [plane_id for plane_id, _ in shapes])
        ious.append(mean_iou(as_tracks, truth, [track_of[r["plane"]] for r in frame["kept"]]))
    assert np.mean(ious) >= 0.95, ious
    # batch reads the layout's cameras too: the same masks as cvat2mask's.
    manifest = tmp_path / "batch.toml"
    manifest.write_text(f'[[scene]]\nsequence = "{root}"\nannotations = ["{xml}"]\nout = "{tmp_path / "batch"}"\n')
    result = CliRunner().invoke(app, ["batch", str(manifest), "-j", "1"])
    assert result.exit_code == 0, result.output
    assert "colour camera: " in result.output
    masks = sorted((out / "masks").iterdir())
    assert [m.read_bytes() for m in masks] == [(tmp_path / "batch" / "masks" / m.name).read_bytes() for m in masks]


def seen_by_colour_camera(depth_raw: np.ndarray) -> np.ndarray:
    """Depth pixels whose point lies on the colour image (the only ones a labeller can draw on)."""
    rows, cols, xy = in_colour_image(depth_raw)
    at = np.floor(xy + 0.5)
    inside = (at[:, 0] >= 0) & (at[:, 0] < COLOUR_SIZE[0]) & (at[:, 1] >= 0) & (at[:, 1] < COLOUR_SIZE[1])
    seen = np.zeros(depth_raw.shape, dtype=bool)
    seen[rows[inside], cols[inside]] = True
    return seen


def colour_ids(path: Path) -> np.ndarray:
    """A colour mask's pixels as one integer per colour (0: black)."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR).astype(np.int64)
    return image[..., 0] + 256 * image[..., 1] + 65536 * image[..., 2]


def matched_iou(found: np.ndarray, expected: np.ndarray) -> list[float]:
    """IoU of each region of ``expected`` with the region of ``found`` that covers most of it
    (plane ids and colours may differ between runs)."""
    ious = []
    for value in np.unique(expected[expected > 0]):
        candidates, counts = np.unique(found[expected == value], return_counts=True)
        best = candidates[np.argmax(counts)]
        ious.append(0.0 if best == 0 else float(np.count_nonzero((found == best) & (expected == value))
                                                 / np.count_nonzero((found == best) | (expected == value))))
    return ious


def test_proposals_and_exports_are_drawn_on_the_colour_images(tmp_path):
    """propose and export-cvat write polygons on the colour images (the labeller's), in an
    export of the colour images' size: cvat2mask reads them back to the masks they were made
    from, on every depth pixel the colour camera sees."""
    frames = (2, 3, 4)
    root, _ = write_scannet_scene(tmp_path, frames)
    runner = CliRunner()
    result = runner.invoke(app, ["propose", str(root), "--out", str(tmp_path / "proposals"), "-j", "1"])
    assert result.exit_code == 0, result.output
    xml = tmp_path / "proposals" / "proposals.xml"
    meta = read_cvat(xml)
    assert all(size == COLOUR_SIZE for size in meta.image_size.values())
    polygons = [shape.points for track in meta.tracks for shape in track.shapes.values()]
    assert polygons and max(p[:, 0].max() for p in polygons) > DEPTH_SIZE[0]  # the colour image's coordinates
    assert all((p >= 0).all() and (p[:, 0] <= COLOUR_SIZE[0]).all() and (p[:, 1] <= COLOUR_SIZE[1]).all()
               for p in polygons)  # clipped to it
    runs = {"proposals": tmp_path / "proposals"}
    for made_from, xml_of in (("proposals", xml), ("run", tmp_path / "round2.xml")):
        if made_from == "run":
            result = runner.invoke(app, ["export-cvat", str(runs["run"]), str(xml_of)])
            assert result.exit_code == 0, result.output
            assert all(size == COLOUR_SIZE for size in read_cvat(xml_of).image_size.values())
        out = tmp_path / f"from_{made_from}"
        result = runner.invoke(app, ["cvat2mask", str(root), str(xml_of), "--out", str(out), "-j", "1"])
        assert result.exit_code == 0, result.output
        runs.setdefault("run", out)
        ious = []
        for i, index in enumerate(frames):
            _, depth, _, _ = colour_frame(index)
            seen = seen_by_colour_camera(depth.depth_raw)
            assert 0.8 < seen.mean() < 1.0  # the colour camera is turned: a strip it does not see
            expected = np.where(seen, colour_ids(runs[made_from] / "masks" / f"{i}.png"), 0)
            ious += matched_iou(np.where(seen, colour_ids(out / "masks" / f"{i}.png"), 0), expected)
        assert len(ious) >= 9 and np.mean(ious) >= 0.95, (made_from, ious)


def test_polygon_vertices_go_to_the_colour_image_through_their_plane():
    colour = colour_camera_from_mapping(COLOUR_TABLE)
    plane = np.array([0.2, -0.1, -0.97, 2.1])  # a x + b y + c z + d = 0, depth camera frame
    plane /= np.linalg.norm(plane[:3])
    points = np.array([[10.5, 20.0], [300.25, 15.75], [160.0, 230.5], [5.0, 200.0]])  # CVAT, depth image
    # Independently: the vertex's ray K^-1 (u - 0.5, v - 0.5, 1) meets the plane at s, then the
    # 4 x 4 extrinsic and the colour intrinsic matrix; CVAT puts pixel centres at +0.5.
    k_depth = np.array([[DEPTH_CAMERA.fx, 0, DEPTH_CAMERA.cx], [0, DEPTH_CAMERA.fy, DEPTH_CAMERA.cy], [0, 0, 1]])
    rays = np.linalg.solve(k_depth, np.vstack([(points - 0.5).T, np.ones(len(points))]))
    on_plane = rays * (-plane[3] / (plane[:3] @ rays))
    in_colour = COLOUR_K @ (EXTRINSIC @ np.vstack([on_plane, np.ones(len(points))]))[:3]
    expected = (in_colour[:2] / in_colour[2]).T + 0.5
    found = polygon_on_colour_image(points, plane, DEPTH_CAMERA, colour, fallback_depth=2.0)
    np.testing.assert_allclose(found, expected, atol=1e-9)
    # A ray along the plane (it never meets it): the vertex is taken at the fallback depth.
    along = np.array([[0.0, 0.0, 1.0, 0.0]])[0]  # the plane z = 0 holds the camera centre
    far = polygon_on_colour_image(points[:1], along, DEPTH_CAMERA, colour, fallback_depth=2.0)
    point = rays[:, :1] * 2.0
    in_colour = COLOUR_K @ (EXTRINSIC @ np.vstack([point, [[1.0]]]))[:3]
    np.testing.assert_allclose(far, (in_colour[:2] / in_colour[2]).T + 0.5, atol=1e-9)


def test_polygons_are_clipped_to_the_image():
    rng = np.random.default_rng(3)
    width, height = 40, 30
    for _ in range(20):
        polygon = rng.uniform(-25, 65, (rng.integers(3, 12), 2))
        clipped = clip_to_image(polygon, width, height)
        # The pixels the clipped polygon covers are the original's within the image (rasterised on
        # a canvas with room around the image).
        pad = 30
        whole = rasterize_frame([(1, Shape("polygon", polygon + pad))], height + 2 * pad, width + 2 * pad)
        expected = whole[pad:pad + height, pad:pad + width]
        if len(clipped) < 3:
            assert not expected.any()
            continue
        assert (clipped >= 0).all() and (clipped[:, 0] <= width).all() and (clipped[:, 1] <= height).all()
        np.testing.assert_array_equal(rasterize_frame([(1, Shape("polygon", clipped))], height, width), expected)
    inside = np.array([[1.0, 1.0], [20.0, 2.0], [10.0, 25.0]])
    np.testing.assert_array_equal(clip_to_image(inside, width, height), inside)

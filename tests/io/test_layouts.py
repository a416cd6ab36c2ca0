"""Sequence layouts: ScanNet, 7-Scenes and depth-only folders read into the one sequence model,
and rendered ScanNet and 7-Scenes sequences through propose, cvat2mask and review as they are."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.errors import InputError
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.io.sequence import FRAME_NUMBERS, SECONDS, read_depth, read_sequence
from annotate_rgbd.synthetic import room_scene
from layout_fixtures import pose_matrix, render_walk, write_keyframes, write_scannet, write_seven_scenes

SCANNET_CAMERA = Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, depth_scale=1000.0)
SEVEN_SCENES_CAMERA = Camera(fx=585.0, fy=585.0, cx=320.0, cy=240.0, depth_scale=1000.0)  # as documented
#: A plane farther than this on average is dropped by design (filter.max_mean_distance).
FAR = 3.5


def touch_png(path: Path, shape=(4, 6), dtype=np.uint16, value=1000) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.full(shape, value, dtype=dtype))


def save_matrix(path: Path, matrix) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, np.asarray(matrix, dtype=np.float64), fmt="%f")


# ---------------------------------------------------------------- the model


def test_scannet_export_is_read_with_its_cameras_and_poses(tmp_path):
    for i in (0, 2, 10):  # as text, 10 would come before 2
        touch_png(tmp_path / "depth" / f"{i}.png")
        touch_png(tmp_path / "color" / f"{i}.jpg", shape=(968, 1296, 3), dtype=np.uint8, value=90)
        save_matrix(tmp_path / "pose" / f"{i}.txt", np.eye(4))
    intrinsic = tmp_path / "intrinsic"
    save_matrix(intrinsic / "intrinsic_depth.txt", [[577.59, 0, 318.9, 0], [0, 578.73, 242.7, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    save_matrix(intrinsic / "intrinsic_color.txt", [[1170.19, 0, 647.75, 0], [0, 1170.19, 483.75, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    # Camera -> the rig's base frame, as ScanNet's sensorData.h says (its Converter writes depth ->
    # colour as the depth extrinsic and the identity as the colour one; here both differ from it).
    colour_pose = pose_matrix_of(angle=0.1, shift=(0.05, 0.0, 0.0))
    depth_pose = pose_matrix_of(angle=-0.05, shift=(0.0, 0.02, 0.0))
    save_matrix(intrinsic / "extrinsic_color.txt", colour_pose)
    save_matrix(intrinsic / "extrinsic_depth.txt", depth_pose)

    sequence = read_sequence(tmp_path)
    assert sequence.layout == "ScanNet" and sequence.clock == FRAME_NUMBERS
    assert sequence.depth.files == ("depth/0.png", "depth/2.png", "depth/10.png")
    assert sequence.rgb.files == ("color/0.jpg", "color/2.jpg", "color/10.jpg")
    np.testing.assert_array_equal(sequence.depth.timestamps, [0, 2, 10])
    camera = sequence.camera
    assert (camera.fx, camera.fy, camera.cx, camera.cy, camera.depth_scale) == (577.59, 578.73, 318.9, 242.7, 1000.0)
    colour = sequence.colour_camera
    assert (colour.fx, colour.fy, colour.cx, colour.cy, colour.width, colour.height) == (1170.19, 1170.19, 647.75, 483.75, 1296, 968)
    # A depth-camera point goes to the base frame (depth's extrinsic), then into the colour camera
    # (the inverse of colour's); checked on a point, not by repeating the formula.
    point = np.array([0.3, -0.2, 1.5, 1.0])
    base = depth_pose @ point
    np.testing.assert_allclose(colour.depth_to_colour @ point, np.linalg.solve(colour_pose, base), atol=1e-5)
    # As ScanNet's Converter writes them (colour: the identity; depth: depth -> colour).
    save_matrix(intrinsic / "extrinsic_color.txt", np.eye(4))
    np.testing.assert_allclose(read_sequence(tmp_path).colour_camera.depth_to_colour, depth_pose, atol=1e-6)
    assert sequence.poses == tmp_path / "pose"


def pose_matrix_of(angle: float, shift) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    matrix = np.eye(4)
    matrix[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    matrix[:3, 3] = shift
    return np.round(matrix, 6)  # as printed with "%f"


def test_seven_scenes_folder_is_read_and_65535_is_no_depth(tmp_path):
    depth = np.array([[0, 65535, 1200], [65534, 800, 65535]], dtype=np.uint16)
    for i in (0, 1):
        cv2.imwrite(str(tmp_path / f"frame-{i:06d}.depth.png"), depth)
        touch_png(tmp_path / f"frame-{i:06d}.color.png", shape=(2, 3, 3), dtype=np.uint8, value=90)
        save_matrix(tmp_path / f"frame-{i:06d}.pose.txt", np.eye(4))
    sequence = read_sequence(tmp_path)
    assert sequence.layout == "7-Scenes" and sequence.clock == FRAME_NUMBERS and sequence.poses == tmp_path
    assert sequence.rgb.files == ("frame-000000.color.png", "frame-000001.color.png")
    assert (sequence.camera.fx, sequence.camera.cx, sequence.camera.cy, sequence.camera.depth_scale) == (585, 320, 240, 1000)
    assert sequence.colour_camera is None  # 7-Scenes is not calibrated: colour is taken as on the depth grid
    expected = depth.copy()
    expected[depth == 65535] = 0
    np.testing.assert_array_equal(read_depth(tmp_path / sequence.depth.files[0]), expected)


@pytest.mark.parametrize("form", ["depth.txt", "depth/", "ScanNet"])
def test_depth_only_folders_are_for_propose(tmp_path, form):
    touch_png(tmp_path / "depth" / "1.png")
    touch_png(tmp_path / "depth" / "2.png")
    if form == "depth.txt":
        (tmp_path / "depth.txt").write_text("# depth\n1.0 depth/1.png\n2.0 depth/2.png\n")
    if form == "ScanNet":
        save_matrix(tmp_path / "intrinsic" / "intrinsic_depth.txt", np.eye(4) * 500)
    sequence = read_sequence(tmp_path, need_rgb=False)
    assert sequence.rgb is None and sequence.depth.files == ("depth/1.png", "depth/2.png")
    assert sequence.clock == (FRAME_NUMBERS if form == "ScanNet" else SECONDS)
    with pytest.raises(InputError) as caught:
        read_sequence(tmp_path)
    message = str(caught.value)
    assert message.startswith(f"{tmp_path}: ") and "no colour images" in message and "propose works on depth alone" in message


def test_a_folder_that_fits_no_layout_names_them_all(tmp_path):
    (tmp_path / "images").mkdir()
    with pytest.raises(InputError) as caught:
        read_sequence(tmp_path)
    message = str(caught.value)
    assert "\n" not in message
    for layout in ("TUM RGB-D", "ICL-NUIM", "ScanNet", "7-Scenes", "depth only"):
        assert layout in message


@pytest.mark.parametrize(
    ("setup", "problem"),
    [
        (lambda p: touch_png(p / "depth" / "frame1.png"), "depth/frame1.png: not a frame of this layout (expected <frame number>.png"),
        (lambda p: (touch_png(p / "depth" / "1.png"), touch_png(p / "depth" / "01.png")), "frame 1 appears twice"),
        (lambda p: (touch_png(p / "depth" / "1.png"), (p / "intrinsic" / "intrinsic_depth.txt").write_text("1 0 0\n0 1\n")),
         "intrinsic_depth.txt: expected a 3x3 or 4x4 matrix, found rows of different lengths"),
        (lambda p: (touch_png(p / "depth" / "1.png"), save_matrix(p / "intrinsic" / "intrinsic_depth.txt", np.zeros((4, 4)))),
         "intrinsic_depth.txt: not an intrinsic matrix: focal length fx 0, fy 0"),
    ],
)
def test_broken_scannet_exports_are_one_line_errors(tmp_path, setup, problem):
    (tmp_path / "intrinsic").mkdir()
    setup(tmp_path)
    with pytest.raises(InputError) as caught:
        read_sequence(tmp_path, need_rgb=False)
    assert problem in str(caught.value) and "\n" not in str(caught.value)


# ---------------------------------------------------------------- rendered sequences, end to end


@pytest.fixture(scope="module")
def scannet(tmp_path_factory) -> dict:
    """A rendered ScanNet export (frame 5's tracking lost) and a keyframe every 5th frame."""
    root = tmp_path_factory.mktemp("scannet")
    rendered = render_walk(16, 320, 240, SCANNET_CAMERA)
    return {"rendered": rendered, "sequence": write_scannet(root / "scene0000_00", rendered, SCANNET_CAMERA, lost=(5,)),
            "keyframes": write_keyframes(rendered, root / "keyframes.xml", step=5), "root": root,
            "mask": lambda i: f"{i}.png"}


@pytest.fixture(scope="module")
def seven_scenes(tmp_path_factory) -> dict:
    """A rendered 7-Scenes sequence at the documented camera and a keyframe every 4th frame."""
    root = tmp_path_factory.mktemp("seven")
    rendered = render_walk(8, 640, 480, SEVEN_SCENES_CAMERA)
    return {"rendered": rendered, "sequence": write_seven_scenes(root / "seq-01", rendered),
            "keyframes": write_keyframes(rendered, root / "keyframes.xml", step=4), "root": root,
            "mask": lambda i: f"frame-{i:06d}.depth.png"}


def mask_ious(out: Path, data: dict, camera: Camera) -> list[float]:
    """IoU of every plane the ground truth shows on >= 2 % of a frame and nearer than FAR on
    average, with the mask's region of that plane's colour (planes.csv: label -> colour)."""
    colour = {row.split(",")[5]: tuple(int(v) for v in row.split(",")[2:5])
              for row in (out / "planes.csv").read_text().splitlines()[1:]}
    ious = []
    for i, frame in enumerate(data["rendered"].frames):
        mask = cv2.cvtColor(cv2.imread(str(out / "masks" / data["mask"](i))), cv2.COLOR_BGR2RGB)
        for k, label in enumerate(data["rendered"].labels):
            truth = frame.plane_index == k
            if truth.sum() < 0.02 * truth.size or np.median(frame.depth_raw[truth]) / camera.depth_scale > FAR:
                continue
            ours = (mask == colour[label]).all(axis=2)
            ious.append((ours & truth).sum() / (ours | truth).sum())
    return ious


@pytest.mark.parametrize(("name", "camera", "frames_without_pose"),
                         [("scannet", SCANNET_CAMERA, 1), ("seven_scenes", SEVEN_SCENES_CAMERA, 0)])
def test_rendered_layouts_run_through_propose_cvat2mask_and_review(request, name, camera, frames_without_pose):
    data = request.getfixturevalue(name)
    sequence, root = data["sequence"], data["root"]
    runner = CliRunner()

    proposed = runner.invoke(app, ["propose", str(sequence), "--out", str(root / "proposals"), "-j", "1"])
    assert proposed.exit_code == 0, proposed.output
    report = json.loads((root / "proposals" / "report.json").read_text())
    assert report["inputs"]["poses"] == str(data["sequence"] if name == "seven_scenes" else sequence / "pose")
    assert report["summary"]["frames_processed"] == len(data["rendered"].frames) and report["tracks"]

    refined = runner.invoke(app, ["cvat2mask", str(sequence), str(data["keyframes"]), "--out", str(root / "out"), "-j", "1"])
    assert refined.exit_code == 0, refined.output
    # No --config: the layout's camera, said in one line; no --poses: the layout's, said too.
    assert sum("info: camera: " in line for line in refined.output.splitlines()) == 1
    assert "info: poses: the " in refined.output
    report = json.loads((root / "out" / "report.json").read_text())
    used = report["config"]["camera"]
    assert (used["fx"], used["fy"], used["cx"], used["cy"], used["depth_scale"]) == (camera.fx, camera.fy, camera.cx, camera.cy, 1000.0)
    assert [f["pose"] for f in report["frames"]].count("ok") == len(data["rendered"].frames) - frames_without_pose
    assert sum(len(t["keyframes_lifted"]) for t in report["propagation"]["tracks"]) > 0
    ious = mask_ious(root / "out", data, camera)
    assert len(ious) >= 30 and np.mean(ious) >= 0.95, (np.mean(ious), min(ious))

    reviewed = runner.invoke(app, ["review", str(root / "out"), "-j", "1"])
    assert reviewed.exit_code == 0, reviewed.output
    assert len(list((root / "out" / "overlays").iterdir())) == len(data["rendered"].frames)

    # The exports take the run's trajectory, the layout's pose files, without --poses.
    exported = runner.invoke(app, ["export", str(root / "out"), "--format", "planercnn", str(root / "planercnn")])
    assert exported.exit_code == 0, exported.output
    record = json.loads((root / "planercnn" / "export.json").read_text())
    assert record["frames_with_pose"] == len(data["rendered"].frames) - frames_without_pose
    planes = np.load(root / "planercnn" / "planes.npy")
    by_label = {p.label: p for p in room_scene().planes}
    kept = {plane["plane"] for f in report["frames"] for plane in f["kept"]}
    for row in (root / "out" / "planes.csv").read_text().splitlines()[1:]:
        plane_id, label = int(row.split(",")[0]), row.split(",")[5]
        if plane_id in kept:  # normal * offset of the rendered plane (normal . X = offset)
            normal = np.cross(by_label[label].edge_u, by_label[label].edge_v)
            normal /= np.linalg.norm(normal)
            assert np.linalg.norm(planes[plane_id - 1] - normal * (normal @ by_label[label].centre)) < 0.03, label

    # A batch scene without a config reads the layout's camera and poses too: cvat2mask's masks.
    manifest = root / "batch.toml"
    manifest.write_text(f'[[scene]]\nsequence = "{sequence}"\nannotations = ["{data["keyframes"]}"]\n'
                        f'out = "{root / "batch"}"\n')
    batch = runner.invoke(app, ["batch", str(manifest), "-j", "1"])
    assert batch.exit_code == 0, batch.output
    assert "info: " in batch.output and "camera: " in batch.output
    masks = sorted((root / "out" / "masks").iterdir())
    assert [m.read_bytes() for m in masks] == [(root / "batch" / "masks" / m.name).read_bytes() for m in masks]


def test_a_config_overrides_the_layout_camera(scannet, tmp_path):
    config = tmp_path / "camera.toml"
    config.write_text("[camera]\nfx = 262.5\nfy = 262.5\ncx = 159.5\ncy = 119.5\ndepth_scale = 1000.0\n")
    result = CliRunner().invoke(app, ["propose", str(scannet["sequence"]), "--out", str(tmp_path / "a"), "-j", "1",
                                      "--config", str(config), "--set", "camera.depth_scale=999"])
    assert result.exit_code == 0, result.output
    assert "info: camera: " not in result.output
    assert json.loads((tmp_path / "a" / "report.json").read_text())["config"]["camera"]["depth_scale"] == 999
    result = CliRunner().invoke(app, ["propose", str(scannet["sequence"]), "--out", str(tmp_path / "b"), "-j", "1",
                                      "--set", "camera.depth_scale=999"])
    camera = json.loads((tmp_path / "b" / "report.json").read_text())["config"]["camera"]
    assert (camera["fx"], camera["depth_scale"]) == (262.5, 999)  # the layout's intrinsics, the option's scale


def test_propose_reads_a_depth_only_folder(scannet, tmp_path):
    folder = tmp_path / "depth_only"
    (folder / "depth").mkdir(parents=True)
    for i in range(4):
        (folder / "depth" / f"{i}.png").write_bytes((scannet["sequence"] / "depth" / f"{i}.png").read_bytes())
    (folder / "depth.txt").write_text("".join(f"{i / 30:.6f} depth/{i}.png\n" for i in range(4)))
    config = tmp_path / "camera.toml"
    config.write_text("[camera]\nfx = 262.5\nfy = 262.5\ncx = 159.5\ncy = 119.5\ndepth_scale = 1000.0\n")
    result = CliRunner().invoke(app, ["propose", str(folder), "--out", str(tmp_path / "out"), "-j", "1", "-c", str(config)])
    assert result.exit_code == 0, result.output
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert [f["rgb"] for f in report["frames"]] == [None] * 4 and [f["rgb_index"] for f in report["frames"]] == [0, 1, 2, 3]
    assert report["summary"]["frames_processed"] == 4 and report["tracks"]
    refused = CliRunner().invoke(app, ["cvat2mask", str(folder), str(scannet["keyframes"]), "--out", str(tmp_path / "x"),
                                       "-c", str(config)])
    assert refused.exit_code == 1 and "no colour images" in refused.output.strip().splitlines()[-1]
    # review draws on the RGB frames: it says why it cannot, not that the report looks damaged.
    review = CliRunner().invoke(app, ["review", str(tmp_path / "out")])
    assert review.exit_code == 1
    assert review.output.strip().splitlines()[-1] == (
        f"error: {tmp_path / 'out' / 'report.json'}: a propose run of a depth-only sequence: review draws on the RGB "
        "frames, and it has none; look at its masks/ (or proposals.xml in CVAT)")
    # Nor does stats suggest cvat2mask, which refuses the folder.
    stats = CliRunner().invoke(app, ["stats", str(tmp_path / "out")])
    assert stats.exit_code == 1 and stats.stderr == (
        f"error: {tmp_path / 'out' / 'report.json'}: this is the output of `propose`, not of a cvat2mask run: a propose "
        "run of a depth-only sequence, which cvat2mask cannot take (it needs the RGB frames annotations are drawn "
        "on): its masks/ hold the proposals\n")

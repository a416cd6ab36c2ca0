"""``review --rerun``: the Rerun recording of a run, read back with the SDK's own reader
(``rerun.chunk.RrdReader``) and checked against the run's files decoded here independently: the
masks through ``planes.csv``, the depth PNGs, the camera of the configuration and the trajectory
file. Tests that need the SDK skip without it (an optional extra)."""

from __future__ import annotations

import csv
import json
import logging
import shutil
import sys
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.config.settings import load_config
from annotate_rgbd.cvat.writer import write_cvat_video
from annotate_rgbd.errors import InputError, OutputError
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.pipeline.scene import run_cvat2mask
from annotate_rgbd.review.rerun_recording import labelled_points, write_recording
from annotate_rgbd.synthetic import make_sequence

CAMERA = Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, depth_scale=5000.0)
SKIP = "the Rerun SDK is an optional extra (pip install '.[viewer]'; bash .ci/setup --tests installs it)"


@pytest.fixture(scope="module")
def rerun_sdk():
    return pytest.importorskip("rerun", reason=SKIP)


@pytest.fixture(scope="module")
def posed(tmp_path_factory) -> Path:
    """A rendered room walk relabelled with its exact trajectory: the run's folder."""
    root = tmp_path_factory.mktemp("rerun_posed")
    annotation = make_sequence(root / "sequence", n_frames=6, width=320, height=240, camera=CAMERA, seed=5,
                               dropped_rgb_frames=(), write_trajectory=True)
    xml = root / "annotations.xml"
    write_cvat_video(annotation, xml, width=320, height=240)
    config = load_config(None, {"camera.fx": CAMERA.fx, "camera.fy": CAMERA.fy, "camera.cx": CAMERA.cx,
                                "camera.cy": CAMERA.cy})
    run_cvat2mask(root / "sequence", [xml], root / "run", config, poses=root / "sequence" / "groundtruth.txt")
    return root / "run"


def read_recording(path: Path) -> dict[str, dict[int | None, dict]]:
    """Entity path -> frame (None: static) -> component -> value, by the SDK's own reader."""
    from rerun.chunk import RrdReader

    found: dict[str, dict[int | None, dict]] = defaultdict(lambda: defaultdict(dict))
    for chunk in RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        names = batch.schema.names
        frames = batch.column("frame").to_pylist() if "frame" in names else [None] * batch.num_rows
        for name in names:
            if ":" in name:  # a component column ("Archetype:field")
                for frame, value in zip(frames, batch.column(name).to_pylist()):
                    found[chunk.entity_path][frame][name] = value
    return found


def _report(run: Path) -> dict:
    return json.loads((run / "report.json").read_text(encoding="utf-8"))


def _plane_ids(mask_path: Path, run: Path) -> np.ndarray:
    """A mask's plane ids, decoded through ``planes.csv`` (not the package's decoder)."""
    with open(run / "planes.csv", newline="") as handle:
        colour = {(int(r["r"]), int(r["g"]), int(r["b"])): int(r["plane_id"]) for r in csv.DictReader(handle)}
    rgb = cv2.cvtColor(cv2.imread(str(mask_path), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    ids = np.zeros(rgb.shape[:2], np.int64)
    for key, plane in colour.items():
        ids[np.all(rgb == key, axis=2)] = plane
    return ids


def _image(entry: dict, archetype: str) -> np.ndarray:
    import rerun

    shape = entry[f"{archetype}:format"][0]
    name = rerun.ChannelDatatype(shape["channel_datatype"]).name  # "U16" is uint16, "F32" float32
    dtype = np.dtype({"U": "uint", "I": "int", "F": "float"}[name[0]] + name[1:])
    buffer = np.frombuffer(bytes(entry[f"{archetype}:buffer"][0]), dtype=dtype)
    return buffer.reshape(shape["height"], shape["width"])


def _pose_matrix(tx, ty, tz, x, y, z, w) -> np.ndarray:
    """4 x 4 camera-to-world of a TUM line's pose (quaternion to matrix written out)."""
    matrix = np.eye(4)
    matrix[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    matrix[:3, 3] = tx, ty, tz
    return matrix


def _trajectory(run: Path) -> dict[float, np.ndarray]:
    """Timestamp -> 4 x 4 camera-to-world, from the TUM file."""
    poses = {}
    for line in Path(_report(run)["propagation"]["poses"]).read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        t, *pose = map(float, line.split())
        poses[t] = _pose_matrix(*pose)
    return poses


def _without_camera_poses(report: dict) -> dict:
    """The report as an earlier version wrote it: no frame holds its camera pose."""
    for frame in report["frames"]:
        frame.pop("camera_pose", None)
    return report


def test_recording_holds_the_runs_frames_labels_depth_and_class_table(rerun_sdk, sample_run, tmp_path):
    run = sample_run[0]
    summary = write_recording(run, tmp_path / "sample.rrd")
    content = read_recording(summary.path)
    report = _report(run)
    written = {k: f for k, f in enumerate(report["frames"]) if f["status"] == "written"}
    image = "/world/camera/image"
    assert set(content) - {"/__properties"} == {"/world", image, f"{image}/rgb", f"{image}/depth",
                                                 f"{image}/planes", "/world/points"}
    assert not summary.world and summary.frames == len(written) == 19
    for entity in (f"{image}/rgb", f"{image}/depth", f"{image}/planes", "/world/points"):
        assert sorted(content[entity]) == sorted(written), entity  # the frame timeline: report indices

    # The class table: every plane of planes.csv with its colour (RGBA, opaque), no plane transparent.
    with open(run / "planes.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    table = content["/world"][None]["AnnotationContext:context"][0]
    colours = {c["class_id"]: c["class_description"]["info"]["color"] for c in table}
    labels = {c["class_id"]: c["class_description"]["info"]["label"] for c in table}
    assert colours == {0: 0, **{int(r["plane_id"]): (int(r["r"]) << 24) | (int(r["g"]) << 16) | (int(r["b"]) << 8)
                                | 255 for r in rows}}
    assert all(labels[int(r["plane_id"])] == f"plane {r['plane_id']}: {r['label']}" for r in rows)
    assert content["/world"][None]["ViewCoordinates:xyz"] == [[3, 2, 5]]  # RDF: the camera frame

    # The camera: the configuration's intrinsics, column-major as Rerun stores a 3 x 3 matrix.
    pinhole = content[image][None]
    assert pinhole["Pinhole:image_from_camera"] == [[262.5, 0, 0, 0, 262.5, 0, 159.5, 119.5, 1]]
    assert pinhole["Pinhole:resolution"] == [[320, 240]]

    sequence = Path(report["inputs"]["sequence"])
    total = 0
    for k, frame in written.items():
        ids = _plane_ids(run / frame["mask"], run)
        assert np.array_equal(_image(content[f"{image}/planes"][k], "SegmentationImage"), ids)
        depth = cv2.imread(str(sequence / frame["depth"]), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(_image(content[f"{image}/depth"][k], "DepthImage"), depth)
        assert content[f"{image}/depth"][k]["DepthImage:meter"] == [5000.0]
        points = content["/world/points"][k]
        # Every 4th pixel of every 4th row with a plane and a depth: its point and its plane.
        rows_, cols = np.nonzero((ids[::4, ::4] > 0) & (depth[::4, ::4] > 0))
        rows_, cols = rows_ * 4, cols * 4
        z = depth[rows_, cols] / 5000.0
        expected = np.stack([(cols - 159.5) * z / 262.5, (rows_ - 119.5) * z / 262.5, z], axis=1)
        assert np.allclose(np.array(points["Points3D:positions"]), expected, atol=1e-5)
        assert points["Points3D:class_ids"] == ids[rows_, cols].tolist()
        total += len(expected)
        rgb = cv2.imdecode(np.frombuffer(bytes(content[f"{image}/rgb"][k]["EncodedImage:blob"][0]), np.uint8),
                           cv2.IMREAD_COLOR)
        original = cv2.imread(str(sequence / frame["rgb"]), cv2.IMREAD_COLOR)
        assert np.abs(rgb.astype(int) - original).mean() < 3  # JPEG
    assert summary.points == total > 1000
    assert summary.size == summary.path.stat().st_size


def test_with_poses_cameras_and_points_are_in_the_world_frame(rerun_sdk, posed, tmp_path):
    summary = write_recording(posed, tmp_path / "posed.rrd", step=2)
    content = read_recording(summary.path)
    report = _report(posed)
    trajectory = _trajectory(posed)
    written = {k: f for k, f in enumerate(report["frames"]) if f["status"] == "written"}
    assert summary.world and summary.frames == len(written) >= 5
    assert sorted(content["/world/camera"]) == sorted(written)
    assert "ViewCoordinates:xyz" not in content["/world"][None]  # the trajectory's own world frame
    sequence = Path(report["inputs"]["sequence"])
    for k, frame in written.items():
        pose = _pose_matrix(*frame["camera_pose"])  # the pose the run made the mask with
        # ... the rendered trajectory's at the frame's own timestamp (exact), aligned to the
        # keyframes' depth: by far less than a centimetre or a degree.
        assert np.abs(pose - trajectory[frame["depth_timestamp"]]).max() < 0.005
        transform = content["/world/camera"][k]
        assert np.allclose(transform["Transform3D:translation"][0], pose[:3, 3], atol=1e-6)
        assert np.allclose(np.array(transform["Transform3D:mat3x3"][0]).reshape(3, 3).T, pose[:3, :3], atol=1e-6)
        ids = _plane_ids(posed / frame["mask"], posed)
        depth = cv2.imread(str(sequence / frame["depth"]), cv2.IMREAD_UNCHANGED)
        rows, cols = np.nonzero((ids[::2, ::2] > 0) & (depth[::2, ::2] > 0))
        rows, cols = rows * 2, cols * 2
        z = depth[rows, cols] / CAMERA.depth_scale
        camera = np.stack([(cols - CAMERA.cx) * z / CAMERA.fx, (rows - CAMERA.cy) * z / CAMERA.fy, z, np.ones_like(z)])
        world = (pose @ camera)[:3].T
        assert np.allclose(np.array(content["/world/points"][k]["Points3D:positions"]), world, atol=1e-4)
    # The whole path: every depth frame's camera centre (all have a pose here), in order.
    strip = np.array(content["/world/trajectory"][None]["LineStrips3D:strips"][0])
    centres = np.array([f["camera_pose"][:3] for f in report["frames"]])
    assert np.allclose(strip, centres, atol=1e-5)


def test_frames_the_trajectory_has_no_pose_for_are_left_out_with_a_warning(rerun_sdk, posed, tmp_path, caplog):
    run = tmp_path / "run"
    shutil.copytree(posed, run)
    report = _without_camera_poses(_report(run))
    samples = [line for line in Path(report["propagation"]["poses"]).read_text().splitlines() if line[:1] != "#"]
    short = tmp_path / "half.txt"
    short.write_text("\n".join(samples[: len(samples) // 2]) + "\n")
    report["propagation"]["poses"] = str(short)
    (run / "report.json").write_text(json.dumps(report))
    with caplog.at_level(logging.WARNING, logger="annotate_rgbd"):
        summary = write_recording(run, tmp_path / "half.rrd")
    written = [k for k, f in enumerate(report["frames"]) if f["status"] == "written"]
    content = read_recording(summary.path)
    logged = sorted(content["/world/points"])
    assert summary.left_out == len(written) - len(logged) > 0 and logged == written[: len(logged)]
    assert [r.getMessage() for r in caplog.records] == [
        f"{summary.left_out} of {len(written)} frames to record have no camera pose (a gap in the trajectory, "
        "or outside it): left out of the recording"]


def test_a_gone_trajectory_gives_a_camera_frame_recording_and_one_warning(rerun_sdk, posed, tmp_path, caplog):
    # A report without the frames' camera poses (an earlier version's) needs its trajectory; one
    # with them (this version's) does not.
    run = tmp_path / "run"
    shutil.copytree(posed, run)
    report = _report(run)
    report["propagation"]["poses"] = str(tmp_path / "moved.txt")
    (run / "report.json").write_text(json.dumps(report))
    with caplog.at_level(logging.WARNING, logger="annotate_rgbd"):
        summary = write_recording(run, tmp_path / "own.rrd")
    assert summary.world and not caplog.records
    cameras = read_recording(summary.path)["/world/camera"]
    for k, frame in enumerate(report["frames"]):
        if frame["status"] == "written":
            assert np.allclose(cameras[k]["Transform3D:translation"][0], frame["camera_pose"][:3], atol=1e-6)
    # The frames' poses are enough: as for export, even without the report's propagation section.
    (run / "report.json").write_text(json.dumps({**report, "propagation": None}))
    assert write_recording(run, tmp_path / "bare.rrd").world
    (run / "report.json").write_text(json.dumps(_without_camera_poses(report)))
    with caplog.at_level(logging.WARNING, logger="annotate_rgbd"):
        summary = write_recording(run, tmp_path / "gone.rrd")
    assert not summary.world and "/world/camera" not in read_recording(summary.path)
    assert [r.getMessage() for r in caplog.records] == [
        f"the run's trajectory {tmp_path / 'moved.txt'} is gone: the recording is in the camera frame"]


def test_point_and_frame_steps(rerun_sdk, sample_run, tmp_path):
    run = sample_run[0]
    every_pixel = write_recording(run, tmp_path / "all.rrd", step=1)
    sparse = write_recording(run, tmp_path / "sparse.rrd", step=8, every=3)
    assert every_pixel.points > 40 * sparse.points and every_pixel.size > sparse.size
    written = [k for k, f in enumerate(_report(run)["frames"]) if f["status"] == "written"]
    assert sorted(read_recording(sparse.path)["/world/points"]) == written[::3]


def test_labelled_points_are_the_sparse_grid_of_labelled_pixels_with_depth():
    labels = np.zeros((6, 8), np.int64)
    labels[:, 4:] = 3
    labels[0, 0] = 2
    depth = np.full((6, 8), 2.0)
    depth[4, 4] = np.nan
    points, planes = labelled_points(labels, depth, Camera(fx=2.0, fy=4.0, cx=1.0, cy=0.0, depth_scale=1.0), step=2)
    # Pixels (row, col) on the grid: (0,0) plane 2, (0,4) (0,6) (2,4) (2,6) (4,6) plane 3; (4,4) has no depth.
    assert planes.tolist() == [2, 3, 3, 3, 3, 3]
    assert np.allclose(points[:, 0], [(c - 1) * 2 / 2 for c in (0, 4, 6, 4, 6, 6)])
    assert np.allclose(points[:, 1], [r * 2 / 4 for r in (0, 0, 0, 2, 2, 4)])
    with pytest.raises(ValueError, match="step"):
        labelled_points(labels, depth, CAMERA, step=0)


def test_the_recording_reads_the_run_and_never_segments(rerun_sdk, sample_run, tmp_path, monkeypatch):
    import annotate_rgbd.segment.frame as frame_stage

    def no_segmenting(*args, **kwargs):
        raise AssertionError("the recording segmented a frame again")

    monkeypatch.setattr(frame_stage, "segment_frame", no_segmenting)
    assert write_recording(sample_run[0], tmp_path / "r.rrd").frames == 19


def test_a_failure_half_way_leaves_no_file_and_the_old_one_untouched(rerun_sdk, sample_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(sample_run[0], run)
    written = [f for f in _report(run)["frames"] if f["status"] == "written"]
    (run / written[-1]["mask"]).write_bytes(b"not a png")
    old = tmp_path / "view.rrd"
    old.write_bytes(b"the previous recording")
    with pytest.raises(InputError, match=Path(written[-1]["mask"]).name):
        write_recording(run, old)
    assert old.read_bytes() == b"the previous recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "view.rrd"]


def test_bad_recording_names(rerun_sdk, sample_run, tmp_path):
    with pytest.raises(OutputError, match=r"ends in \.rrd"):
        write_recording(sample_run[0], tmp_path / "view.png")
    with pytest.raises(OutputError, match="its folder does not exist"):
        write_recording(sample_run[0], tmp_path / "missing" / "view.rrd")
    with pytest.raises(InputError, match="no report"):
        write_recording(tmp_path, tmp_path / "view.rrd")
    assert not list(tmp_path.iterdir())


def test_cli_review_refuses_a_recording_path_before_drawing_the_overlays(rerun_sdk, sample_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(sample_run[0], run)
    before = sorted(p.relative_to(run) for p in run.rglob("*"))
    result = CliRunner().invoke(app, ["review", str(run), "--rerun", str(tmp_path / "missing" / "v.rrd")])
    assert result.exit_code == 1
    assert result.output.strip() == f"error: {tmp_path / 'missing' / 'v.rrd'}: cannot write the recording: its folder does not exist"
    assert sorted(p.relative_to(run) for p in run.rglob("*")) == before  # no overlay, page or sheet


def test_cli_review_rerun(rerun_sdk, sample_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(sample_run[0], run)
    result = CliRunner().invoke(app, ["review", str(run), "--no-overlays", "--no-page", "--no-sheet",
                                      "--rerun", str(tmp_path / "v.rrd"), "--rerun-step", "2"])
    assert result.exit_code == 0, result.output
    size = (tmp_path / "v.rrd").stat().st_size
    assert (f"{tmp_path / 'v.rrd'}: Rerun recording of 19 frames, " in result.stdout
            and f"3-D points in the camera frame, {size / 1e6:.1f} MB (view it: rerun {tmp_path / 'v.rrd'})"
            in result.stdout)


def test_cli_without_the_sdk_says_how_to_install_it_and_writes_nothing(sample_run, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)  # `import rerun` raises ImportError
    run = tmp_path / "run"
    shutil.copytree(sample_run[0], run)
    before = sorted(p.relative_to(run) for p in run.rglob("*"))
    result = CliRunner().invoke(app, ["review", str(run), "--rerun", str(tmp_path / "v.rrd")])
    assert result.exit_code == 1
    assert result.stderr == ("error: --rerun needs the Rerun SDK (rerun-sdk 0.41), an optional extra: "
                             "pip install 'annotate-rgbd[viewer]'\n")
    assert sorted(p.relative_to(run) for p in run.rglob("*")) == before  # no overlays either
    assert not (tmp_path / "v.rrd").exists()


def test_a_colour_camera_of_its_own_holds_the_rgb_images(rerun_sdk, sample_run, tmp_path):
    """With ``[colour_camera]`` the RGB images are the colour camera's, placed by the inverse of
    its extrinsic (depth -> colour) in the depth camera's frame."""
    run = tmp_path / "run"
    shutil.copytree(sample_run[0], run)
    report = _report(run)
    angle = np.deg2rad(3.0)
    extrinsic = np.array([[np.cos(angle), 0, np.sin(angle), 0.052], [0, 1, 0, -0.011],
                          [-np.sin(angle), 0, np.cos(angle), 0.004], [0, 0, 0, 1]])
    report["config"]["colour_camera"] = {"fx": 290.0, "fy": 288.0, "cx": 211.0, "cy": 150.5, "width": 424,
                                         "height": 300, "extrinsic": extrinsic.tolist()}
    (run / "report.json").write_text(json.dumps(report))
    content = read_recording(write_recording(run, tmp_path / "colour.rrd").path)
    colour = content["/world/camera/colour"][None]
    assert np.allclose(colour["Transform3D:translation"][0], -extrinsic[:3, :3].T @ extrinsic[:3, 3])
    assert np.allclose(np.array(colour["Transform3D:mat3x3"][0]).reshape(3, 3).T, extrinsic[:3, :3].T)
    assert colour["Pinhole:image_from_camera"] == [[290, 0, 0, 0, 288, 0, 211, 150.5, 1]]
    assert colour["Pinhole:resolution"] == [[424, 300]]
    written = [k for k, f in enumerate(report["frames"]) if f["status"] == "written"]
    assert sorted(content["/world/camera/colour/rgb"]) == written
    assert "/world/camera/image/rgb" not in content and sorted(content["/world/camera/image/planes"]) == written


def test_the_poses_are_taken_at_the_trajectory_time_offset_the_run_applied(rerun_sdk, posed, tmp_path):
    # A report without the frames' camera poses (an earlier version's): read from the trajectory.
    from annotate_rgbd.io.poses import poses_at, read_trajectory

    run = tmp_path / "run"
    shutil.copytree(posed, run)
    report = _without_camera_poses(_report(run))
    report["propagation"]["time_offset_s"] = 0.0123
    (run / "report.json").write_text(json.dumps(report))
    content = read_recording(write_recording(run, tmp_path / "late.rrd").path)
    written = [k for k, f in enumerate(report["frames"]) if f["status"] == "written"]
    times = np.array([report["frames"][k]["depth_timestamp"] for k in written])
    trajectory = read_trajectory(report["propagation"]["poses"])
    expected = poses_at(trajectory, times + 0.0123)
    logged = [k for k, ok in zip(written, expected.ok) if ok]  # the last frame's time now lies past the end
    assert sorted(content["/world/camera"]) == logged and len(logged) >= 4
    recorded = np.array([content["/world/camera"][k]["Transform3D:translation"][0] for k in logged])
    assert np.allclose(recorded, expected.translations[expected.ok], atol=1e-6)
    assert not np.allclose(recorded, poses_at(trajectory, times).translations[expected.ok], atol=1e-4)

"""Plane-GT exports read back with each consumer's own decoding, written out here independently:
PlaneRCNN's segmentation decoding and plane transform (its datasets/scannet_scene.py), COCO's RLE
and PlaneRecNet's plane check (point . normal - offset), EVOPS per-point label arrays; and the
planes against the rendered scene's true planes."""

from __future__ import annotations

import csv
import json
import logging
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.config.settings import load_config
from annotate_rgbd.cvat.writer import write_cvat_video
from annotate_rgbd.errors import InputError, OutputError
from annotate_rgbd.evaluate.metrics import frame_statistics
from annotate_rgbd.export import export_run
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.io.rotations import quaternion_matrices
from annotate_rgbd.pipeline.scene import run_cvat2mask
from annotate_rgbd.synthetic import make_sequence, room_scene

CAMERA = Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, depth_scale=5000.0)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A rendered room walk with its exact trajectory, relabelled with poses."""
    root = tmp_path_factory.mktemp("exports")
    annotation = make_sequence(root / "sequence", n_frames=6, width=320, height=240, camera=CAMERA, seed=5,
                               dropped_rgb_frames=(), write_trajectory=True)
    xml = root / "annotations.xml"
    write_cvat_video(annotation, xml, width=320, height=240)
    config = load_config(None, {"camera.fx": 262.5, "camera.fy": 262.5, "camera.cx": 159.5, "camera.cy": 119.5})
    run_cvat2mask(root / "sequence", [xml], root / "run", config, poses=root / "sequence" / "groundtruth.txt")
    run_cvat2mask(root / "sequence", [xml], root / "flat", config)
    return root


def plane_table(run_dir: Path) -> dict[int, dict]:
    with open(run_dir / "planes.csv", newline="") as handle:
        return {int(row["plane_id"]): row for row in csv.DictReader(handle)}


def mask_ids(run_dir: Path, name: str) -> np.ndarray:
    """Plane ids of a colour mask, decoded through planes.csv's r, g, b."""
    image = cv2.imread(str(run_dir / "masks" / f"{name}.png"), cv2.IMREAD_COLOR)[..., ::-1].astype(np.int64)
    ids = np.zeros(image.shape[:2], dtype=np.int64)
    for plane, row in plane_table(run_dir).items():
        ids[(image == (int(row["r"]), int(row["g"]), int(row["b"]))).all(axis=2)] = plane
    return ids


def true_world_planes(run_dir: Path) -> dict[int, tuple[np.ndarray, float]]:
    """Plane id -> (unit normal, offset) with normal . X = offset, from the rendered scene."""
    by_label = {p.label: p for p in room_scene().planes}
    planes = {}
    for plane, row in plane_table(run_dir).items():
        scene_plane = by_label[row["label"]]
        normal = np.cross(scene_plane.edge_u, scene_plane.edge_v)
        normal /= np.linalg.norm(normal)
        planes[plane] = (normal, float(normal @ np.asarray(scene_plane.centre)))
    return planes


def written_frames(run_dir: Path) -> list[dict]:
    report = json.loads((run_dir / "report.json").read_text())
    return [f for f in report["frames"] if f["status"] == "written"]


def test_planercnn_layout_reads_back_with_its_decoding(run, tmp_path):
    out = tmp_path / "annotation"
    result = CliRunner().invoke(app, ["export", str(run / "run"), "--format", "planercnn", str(out)])
    assert result.exit_code == 0, result.output
    planes = np.load(out / "planes.npy")
    table = plane_table(run / "run")
    assert planes.shape == (len(table), 3)
    frames = written_frames(run / "run")
    kept = {p["plane"] for f in frames for p in f["kept"]}
    truth = true_world_planes(run / "run")
    for plane in kept:
        normal, offset = truth[plane]
        # normal * offset: the same vector whichever way the normal points.
        assert np.linalg.norm(planes[plane - 1] - normal * offset) < 0.03, table[plane]["label"]
    # The rendered floor is z = 0: its row holds no normal, and the export says so in one line.
    through_origin = sorted(p for p in kept if abs(truth[p][1]) < 0.02)
    assert [table[p]["label"] for p in through_origin] == ["floor"]
    warned = [line for line in result.output.splitlines() if line.startswith("warning: ")]
    assert len(warned) == 1 and f"plane {through_origin[0]} passes within 2 cm of the world origin" in warned[0]
    assert not planes[[p - 1 for p in table if p not in kept]].any()  # never kept: 0 0 0, skipped by the loader
    for frame in frames:
        name = Path(frame["depth"]).stem
        segmentation = cv2.imread(str(out / "segmentation" / f"{name}.png"), -1).astype(np.int32)
        decoded = (segmentation[:, :, 2] * 256 * 256 + segmentation[:, :, 1] * 256 + segmentation[:, :, 0]) // 100 - 1
        np.testing.assert_array_equal(decoded, mask_ids(run / "run", name) - 1)
    record = json.loads((out / "export.json").read_text())
    assert record["complete"] and record["frames_with_pose"] == len(frames) == 6
    assert "d > 0" in record["conventions"]["plane_equation"]


def planercnn_transform(extrinsics: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """PlaneRCNN's ScanNetScene.transformPlanes (world -> camera with a world-to-camera matrix),
    rewritten: the plane's foot point and a point one normal towards the origin, transformed."""
    offsets = np.linalg.norm(planes, axis=-1, keepdims=True)
    centres = planes @ extrinsics[:3, :3].T + extrinsics[:3, 3]
    references = (planes - planes / np.maximum(offsets, 1e-4)) @ extrinsics[:3, :3].T + extrinsics[:3, 3]
    normals = references - centres
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    return normals * np.sum(centres * normals, axis=-1, keepdims=True)


def test_planercnn_planes_come_back_to_each_frames_own_plane(run, tmp_path):
    export_run(run / "run", "planercnn", tmp_path / "p")
    export_run(run / "run", "planes", tmp_path / "f")
    planes = np.load(tmp_path / "p" / "planes.npy")
    for frame in written_frames(run / "run"):
        per_frame = json.loads((tmp_path / "f" / "frames" / f"{Path(frame['depth']).stem}.json").read_text())
        world_to_camera = np.linalg.inv(np.array(per_frame["camera_to_world"]))
        for entry in per_frame["planes"]:
            camera = np.array(entry["camera"])
            expected = -camera[3] * camera[:3]  # normal * offset of a . X + d = 0 in the camera
            found = planercnn_transform(world_to_camera, planes[entry["plane"] - 1][None])[0]
            assert np.linalg.norm(found - expected) < 0.03


def test_frame_planes_in_camera_and_world(run, tmp_path):
    export_run(run / "run", "planes", tmp_path / "f")
    truth = true_world_planes(run / "run")
    for frame in written_frames(run / "run"):
        entry = json.loads((tmp_path / "f" / "frames" / f"{Path(frame['depth']).stem}.json").read_text())
        assert [p["plane"] for p in entry["planes"]] == [p["plane"] for p in frame["kept"]]
        assert [p["camera"] for p in entry["planes"]] == [p["equation"] for p in frame["kept"]]
        pose = np.array(entry["camera_to_world"])
        for plane in entry["planes"]:
            camera, world = np.array(plane["camera"]), np.array(plane["world"])
            assert camera[3] > 0  # the normal points towards the camera
            # Points of the camera-frame plane, taken to the world with the pose, lie on the world plane.
            basis = np.linalg.svd(camera[None, :3])[2][1:]
            points = -camera[3] * camera[:3] + np.array([[0, 0], [1, 0], [0, 1], [2, 3]]) @ basis
            in_world = points @ pose[:3, :3].T + pose[:3, 3]
            assert np.abs(in_world @ world[:3] + world[3]).max() < 1e-6
            normal, offset = truth[plane["plane"]]
            assert abs(abs(world[:3] @ normal) - 1) < 1e-3 and abs(abs(world[3]) - abs(offset)) < 0.03


def test_frame_planes_without_poses(run, tmp_path):
    result = export_run(run / "flat", "planes", tmp_path / "f")
    assert result.posed == 0
    entry = json.loads(next((tmp_path / "f" / "frames").iterdir()).read_text())
    assert entry["camera_to_world"] is None and all(p["world"] is None for p in entry["planes"])
    assert "d > 0" in entry["convention"]
    with pytest.raises(InputError, match="give the camera trajectory with --poses"):
        export_run(run / "flat", "planercnn", tmp_path / "p")
    assert not (tmp_path / "p").exists()  # refused before the folder is made
    # A trajectory given to the export puts them in the world frame.
    result = export_run(run / "flat", "planercnn", tmp_path / "p", poses=run / "sequence" / "groundtruth.txt")
    assert result.posed == 6


def test_a_trajectory_given_to_the_export_must_cover_the_frames(run, tmp_path, caplog):
    # Another recording's trajectory (every timestamp 5000 s later): no frame has a pose, which
    # would leave every plane without world coordinates. One line naming the file, nothing written.
    lines = (run / "sequence" / "groundtruth.txt").read_text().splitlines()
    rows = [line.split() for line in lines if line and not line.startswith("#")]
    later = tmp_path / "later.txt"
    later.write_text("".join(f"{float(r[0]) + 5000:.6f} {' '.join(r[1:])}\n" for r in rows))
    with pytest.raises(InputError, match=r"later.txt: no written frame has a pose: the trajectory spans .* a clock offset"):
        export_run(run / "flat", "planes", tmp_path / "none", poses=later)
    assert not (tmp_path / "none").exists()
    # One that stops halfway: the frames after it are said, and exported without world planes.
    times = sorted(frame["depth_timestamp"] for frame in written_frames(run / "flat"))
    cut = tmp_path / "cut.txt"
    cut.write_text("".join(" ".join(r) + "\n" for r in rows if float(r[0]) <= (times[2] + times[3]) / 2))
    with caplog.at_level(logging.WARNING, logger="annotate_rgbd"):
        result = export_run(run / "flat", "planes", tmp_path / "half", poses=cut)
    assert result.posed == 3
    assert [r.getMessage().split(" (")[0] for r in caplog.records] == [
        f"{cut}: 3 of 6 written frames have no pose: their planes have no world coordinates"]
    # Formats without world-frame planes never read the trajectory: no warning, and one that
    # is given says it is not used.
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="annotate_rgbd"):
        for fmt in ("evops", "coco"):
            assert export_run(run / "flat", fmt, tmp_path / f"{fmt}_cut", poses=cut).posed == 0
            assert export_run(run / "flat", fmt, tmp_path / f"{fmt}_later", poses=later).posed == 0
    assert [r.getMessage() for r in caplog.records] == [
        f"{path}: not used: the {fmt} export holds no world-frame plane (only planercnn and planes do)"
        for fmt in ("evops", "coco") for path in (cut, later)]


def test_evops_labels_score_like_the_masks(run, tmp_path):
    export_run(run / "run", "evops", tmp_path / "posed")
    export_run(run / "flat", "evops", tmp_path / "flat")
    for frame in written_frames(run / "run"):
        name = Path(frame["depth"]).stem
        labels = np.load(tmp_path / "posed" / "labels" / f"{name}.npy")
        ids = mask_ids(run / "run", name)
        assert labels.dtype == np.int32 and labels.shape == (ids.size,)
        np.testing.assert_array_equal(labels, ids.ravel())  # row-major, 0 = unsegmented
        other = np.load(tmp_path / "flat" / "labels" / f"{name}.npy")
        # Scored as 1-D point arrays exactly as the two masks are.
        assert frame_statistics(labels, other) == frame_statistics(ids, mask_ids(run / "flat", name))
        truth = cv2.imread(str(run / "sequence" / "ground_truth" / f"{name}.png"), cv2.IMREAD_UNCHANGED)
        assert frame_statistics(truth.ravel().astype(np.int32), labels).precision > 0.8


def decode_rle(segmentation: dict) -> np.ndarray:
    """COCO's uncompressed RLE: alternating background / foreground runs, column-major."""
    height, width = segmentation["size"]
    flat = np.repeat(np.arange(len(segmentation["counts"])) % 2, segmentation["counts"]).astype(bool)
    return flat.reshape((width, height)).T


def test_coco_instances_with_plane_paras(run, tmp_path):
    export_run(run / "run", "coco", tmp_path / "c")
    document = json.loads((tmp_path / "c" / "annotations.json").read_text())
    frames = written_frames(run / "run")
    assert len(document["images"]) == len(frames)
    assert document["categories"] == [{"id": 1, "name": "plane", "supercategory": "plane"}]
    by_image = {}
    for annotation in document["annotations"]:
        by_image.setdefault(annotation["image_id"], []).append(annotation)
    for image, frame in zip(document["images"], frames):
        assert image["depth_file_name"] == frame["depth"] and image["file_name"] == frame["rgb"]
        ids = mask_ids(run / "run", image["frame"])
        depth = cv2.imread(str(run / "sequence" / frame["depth"]), cv2.IMREAD_UNCHANGED) / 5000.0
        rows, cols = np.indices(depth.shape)
        points = np.stack([(cols - 159.5) / 262.5 * depth, (rows - 119.5) / 262.5 * depth, depth], axis=-1)
        assert sorted(a["plane_id"] for a in by_image[image["id"]]) == sorted(p["plane"] for p in frame["kept"])
        for annotation in by_image[image["id"]]:
            mask = decode_rle(annotation["segmentation"])
            np.testing.assert_array_equal(mask, ids == annotation["plane_id"])
            ys, xs = np.nonzero(mask)
            assert annotation["bbox"] == [xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1]
            assert annotation["area"] == mask.sum()
            # PlaneRecNet's own check: |X . normal - offset| over the instance's points.
            normal, offset = np.array(annotation["plane_paras"][:3]), annotation["plane_paras"][3]
            assert offset > 0 and abs(np.linalg.norm(normal) - 1) < 1e-6
            assert np.mean(np.abs(points[mask] @ normal - offset)) < 0.01


def test_export_folder_contract(run, tmp_path, monkeypatch):
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="no export wrote"):
        export_run(run / "run", "evops", foreign)
    with pytest.raises(OutputError, match="the run's folder"):
        export_run(run / "run", "evops", run / "run")
    # A refused folder is the only line: no warning about the run or its poses comes before it.
    trajectory = str(run / "sequence" / "groundtruth.txt")
    for target in (foreign, run / "run"):
        said = CliRunner().invoke(app, ["export", str(run / "run"), "--format", "evops", str(target), "--poses", trajectory])
        assert said.exit_code == 1 and len(said.stderr.splitlines()) == 1, said.stderr
        assert said.stderr.startswith(f"error: {target}: ")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(OutputError, match="an export is a folder of files, not a stream"):
        export_run(run / "run", "coco", "-")  # export-cvat's standard output: not a folder named "-"
    assert not (tmp_path / "-").exists()
    with pytest.raises(InputError, match="unknown export format 'png'"):
        export_run(run / "run", "png", tmp_path / "x")
    out = tmp_path / "again"
    export_run(run / "run", "evops", out)
    (out / "labels" / "old_frame.npy").write_bytes(b"")
    record = json.loads((out / "export.json").read_text())
    record["files"].append("labels/old_frame.npy")
    (out / "export.json").write_text(json.dumps(record))
    result = export_run(run / "run", "planes", out)  # another format into the same folder: the old files go
    assert "labels/old_frame.npy" in result.removed
    assert not (out / "labels").exists()  # emptied: removed too
    assert len(list((out / "frames").iterdir())) == 6
    said = CliRunner().invoke(app, ["export", str(run / "run"), "--format", "evops", str(out)])
    assert said.exit_code == 0, said.output
    # An info line on standard error, as a run says the files it removed; the summary alone on standard output.
    assert said.stderr == "info: removed 6 files of an earlier export (frames/" + sorted(
        p.name for p in (run / "run" / "masks").iterdir())[0].replace(".png", ".json") + ", ...)\n"
    assert not (out / "frames").exists() and len(list((out / "labels").iterdir())) == 6
    # EVOPS labels hold no world-frame plane: the trajectory is not read, no pose is counted.
    files = sum(p.is_file() for p in out.rglob("*"))  # export.json too
    assert said.stdout == f"evops: 6 frames, {files} files in {out}\n"
    said = CliRunner().invoke(app, ["export", str(run / "run"), "--format", "planes", str(out)])
    files = sum(p.is_file() for p in out.rglob("*"))
    assert said.output.splitlines()[-1] == f"planes: 6 frames (6 with a pose), {files} files in {out}"


def files_of(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_a_refused_or_failed_export_leaves_an_earlier_one_whole(run, tmp_path, monkeypatch):
    earlier = tmp_path / "earlier"
    export_run(run / "flat", "evops", earlier)
    before = files_of(earlier)
    # Refused before anything is written (no pose for the world-frame layout).
    with pytest.raises(InputError, match="give the camera trajectory"):
        export_run(run / "flat", "planercnn", earlier)
    assert files_of(earlier) == before
    # Failed while writing (the disk fills at the third frame): nothing was moved in yet.
    import annotate_rgbd.export.planes as planes
    real_write, calls = planes.write_json, []

    def fills_up(path, data):
        calls.append(path)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        real_write(path, data)

    monkeypatch.setattr(planes, "write_json", fills_up)
    with pytest.raises(OSError, match="No space left"):
        export_run(run / "flat", "planes", earlier)
    assert len(calls) == 3 and files_of(earlier) == before


def test_an_export_that_fails_while_moving_in_names_every_file_it_left(run, tmp_path, monkeypatch):
    # Over an earlier export of another format, the move of the third file fails: the folder holds
    # files of both, its record says incomplete and names them all, and the next export (a third
    # format) removes every one of them.
    import annotate_rgbd.export as export
    out = tmp_path / "out"
    export_run(run / "flat", "evops", out)
    real_replace, calls = export.os.replace, []

    def fails_third(source, target):  # os.replace: the atomic writes' renames too, passed on
        if export.STAGING not in str(source) or export.STAGING in str(target):
            return real_replace(source, target)
        calls.append(target)
        if len(calls) == 3:
            raise OSError(5, "Input/output error")
        real_replace(source, target)

    monkeypatch.setattr(export.os, "replace", fails_third)
    with pytest.raises(OSError, match="Input/output error"):
        export_run(run / "flat", "planes", out)
    monkeypatch.undo()
    record = json.loads((out / "export.json").read_text())
    left = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file() and p.name != "export.json")
    assert not record["complete"] and len([n for n in left if n.startswith("frames/")]) == 2
    assert set(left) <= set(record["files"]) and not (out / export.STAGING).exists()
    export_run(run / "flat", "coco", out)
    assert sorted(files_of(out)) == ["annotations.json", "export.json"]


def test_a_failed_export_removes_only_what_it_wrote(run, tmp_path, monkeypatch):
    # Into a new folder (with new parents) and into an empty one: the disk fills at the third
    # frame, a file lands in the folder meanwhile (a user's, a sync tool's). Only the export's
    # own files and the folders it made go: the user's file stays, with its folder.
    import annotate_rgbd.export.evops as evops
    real_write, calls = evops.write_bytes_atomic, []

    def fills_up(path, data):
        calls.append(path)
        if len(calls) == 3:
            if dropped is not None:
                dropped.write_text("mine")
            raise OSError(28, "No space left on device")
        real_write(path, data)

    monkeypatch.setattr(evops, "write_bytes_atomic", fills_up)
    for out, dropped in ((tmp_path / "a" / "b" / "new", None), (tmp_path / "empty", None),
                         (tmp_path / "busy", tmp_path / "busy" / "notes.txt")):
        if out.name != "new":
            out.mkdir()
        calls.clear()
        with pytest.raises(OSError, match="No space left"):
            export_run(run / "run", "evops", out)
        assert len(calls) == 3
        if out.name == "new":
            assert not (tmp_path / "a").exists()  # the parents it made go too
        else:
            assert files_of(out) == ({} if dropped is None else {"notes.txt": b"mine"})
            assert [p.name for p in out.iterdir()] == ([] if dropped is None else ["notes.txt"])
    # A failure after the last file is in place (the final record cannot be written) also
    # leaves a new folder as it was.
    monkeypatch.undo()
    import annotate_rgbd.export as export
    real_json = export.write_json

    def record_fails(path, data):
        if data.get("complete"):
            raise OSError(28, "No space left on device")
        real_json(path, data)

    monkeypatch.setattr(export, "write_json", record_fails)
    with pytest.raises(OSError, match="No space left"):
        export_run(run / "run", "evops", tmp_path / "late")
    assert not (tmp_path / "late").exists()


def test_one_export_at_a_time_into_a_folder(run, tmp_path):
    from annotate_rgbd.io.outdir import OutputLock

    out = tmp_path / "shared"
    export_run(run / "flat", "evops", out)
    before = files_of(out)
    with OutputLock(out, owner_file=False):  # another export is writing there
        with pytest.raises(OutputError, match="is writing to this folder"):
            export_run(run / "flat", "planes", out)
    assert files_of(out) == before


def test_the_export_folder_and_xml_file_may_be_given_as_out_too(run, tmp_path):
    # As cvat2mask and propose take their output: a user who types --out gets what they meant.
    runner = CliRunner()
    said = runner.invoke(app, ["export", str(run / "run"), "--format", "evops", "--out", str(tmp_path / "a")])
    assert said.exit_code == 0, said.output
    export_run(run / "run", "evops", tmp_path / "b")
    assert files_of(tmp_path / "a") == files_of(tmp_path / "b")
    said = runner.invoke(app, ["export-cvat", str(run / "run"), "-o", str(tmp_path / "a.xml")])
    assert said.exit_code == 0, said.output
    assert (tmp_path / "a.xml").read_bytes().startswith(b"<?xml")
    for command, problem in ((["export", str(run / "run"), "--format", "evops"],
                              "error: no export folder given: give it as OUT_DIR or as --out"),
                             (["export", str(run / "run"), str(tmp_path / "c"), "--format", "evops", "--out",
                               str(tmp_path / "d")],
                              f"error: two export folders given, {tmp_path / 'c'} and --out {tmp_path / 'd'}: give one"),
                             (["export-cvat", str(run / "run")], "error: no XML file given: give it as FILE.xml or as --out")):
        said = runner.invoke(app, command)
        assert said.exit_code == 1 and said.output.strip() == problem
    assert not (tmp_path / "c").exists() and not (tmp_path / "d").exists()


def test_world_planes_use_the_poses_the_masks_were_made_with(run, tmp_path, caplog):
    # The report holds every frame's camera pose as the run used it (the trajectory's, aligned to
    # the keyframes' depth): the export reads those, not the trajectory again, even once the
    # trajectory is gone, and its record says so.
    from annotate_rgbd.export.frames import read_run
    from annotate_rgbd.io.poses import poses_at, read_trajectory

    report = json.loads((run / "run" / "report.json").read_text())
    written = [f for f in report["frames"] if f["status"] == "written"]
    # An independent check of the record's layout (tx ty tz qx qy qz qw, camera to world): the
    # rendered walk's exact trajectory, from which the alignment moves no pose by a centimetre.
    truth = poses_at(read_trajectory(report["propagation"]["poses"]),
                     np.array([f["depth_timestamp"] for f in written]) + report["propagation"]["time_offset_s"])
    for f, rotation, centre in zip(written, truth.rotations, truth.translations):
        values = np.array(f["camera_pose"])
        assert np.linalg.norm(values[:3] - centre) < 0.01
        assert np.degrees(np.arccos(np.clip((np.trace(quaternion_matrices(values[None, 3:])[0].T @ rotation) - 1) / 2,
                                            -1, 1))) < 0.5
    shutil.copytree(run / "run", tmp_path / "run")
    written[0]["camera_pose"][0] += 0.1  # the run made this frame's mask 10 cm off the trajectory (in report too)
    written[-1].update(pose="pose_gap", camera_pose=None)  # and this one without a pose
    del written[-2]["camera_pose"]  # and this one's taken out of the report by hand
    report["propagation"]["poses"] = str(tmp_path / "moved.txt")  # and the trajectory is gone
    (tmp_path / "run" / "report.json").write_text(json.dumps(report))
    with caplog.at_level(logging.WARNING, logger="annotate_rgbd"):
        exported = read_run(tmp_path / "run")
    assert exported.poses_from == "run"
    records = [f for f in report["frames"] if f["status"] == "written"]
    assert len(exported.frames) == len(records) >= 5
    assert exported.frames[-1].pose is None and exported.frames[-2].pose is None
    assert [r.getMessage() for r in caplog.records] == [
        f"{tmp_path / 'run' / 'report.json'}: 2 of {len(records)} written frames have no pose in the run (1 without a "
        "camera_pose in the report, 1 in a gap of the trajectory): their planes have no world coordinates"]
    for frame, record in zip(exported.frames[:-2], records):
        values = np.array(record["camera_pose"])
        np.testing.assert_allclose(frame.pose[1], values[:3], atol=1e-12)
        np.testing.assert_allclose(frame.pose[0], quaternion_matrices(values[None, 3:])[0], atol=1e-12)
    export_run(tmp_path / "run", "planes", tmp_path / "out")
    record = json.loads((tmp_path / "out" / "export.json").read_text())
    assert record["poses"] == "run" and record["trajectory_time_offset_s"] == report["propagation"]["time_offset_s"]
    # A trajectory given to the export is read instead.
    given = read_run(tmp_path / "run", run / "sequence" / "groundtruth.txt")
    assert given.poses_from == "trajectory" and abs(given.frames[0].pose[1][0] - exported.frames[0].pose[1][0]) > 0.09


def test_the_report_holds_the_aligned_poses_the_masks_were_made_with(tmp_path, monkeypatch):
    # The alignment moves every pose 5 cm along x here: the report's camera_pose is the moved
    # pose, not the trajectory's (the exact walk's alignment alone moves them too little to tell).
    import annotate_rgbd.pipeline.propagation as propagation
    from annotate_rgbd.io.poses import poses_at, read_trajectory

    aligned = propagation.align_frames

    def moved(depth_poses, *args, **kwargs):
        poses, alignment = aligned(depth_poses, *args, **kwargs)
        return poses._replace(translations=poses.translations + [0.05, 0.0, 0.0]), alignment

    monkeypatch.setattr(propagation, "align_frames", moved)
    annotation = make_sequence(tmp_path / "sequence", n_frames=4, width=320, height=240, camera=CAMERA, seed=5,
                               dropped_rgb_frames=(), write_trajectory=True)
    write_cvat_video(annotation, tmp_path / "a.xml", width=320, height=240)
    config = load_config(None, {"camera.fx": 262.5, "camera.fy": 262.5, "camera.cx": 159.5, "camera.cy": 119.5})
    trajectory = tmp_path / "sequence" / "groundtruth.txt"
    run_cvat2mask(tmp_path / "sequence", [tmp_path / "a.xml"], tmp_path / "run", config, poses=trajectory)
    report = json.loads((tmp_path / "run" / "report.json").read_text())
    times = np.array([f["depth_timestamp"] for f in report["frames"]]) + report["propagation"]["time_offset_s"]
    given = poses_at(read_trajectory(trajectory), times)
    recorded = np.array([f["camera_pose"][:3] for f in report["frames"]])
    shift = recorded - given.translations
    assert np.abs(shift[:, 0] - 0.05).max() < 0.005 and np.abs(shift[:, 1:]).max() < 0.005


def test_world_planes_read_the_trajectory_at_the_runs_time_offset(run, tmp_path, caplog):
    # A report without the frames' camera poses (an earlier version's): the run read its
    # trajectory -0.03 s off the frames' clock (configured and estimated: the report's
    # time_offset_s); the export must read the same poses, and say which offset.
    from annotate_rgbd.export.frames import read_run
    from annotate_rgbd.io.poses import poses_at, read_trajectory

    shutil.copytree(run / "run", tmp_path / "run")
    report = json.loads((tmp_path / "run" / "report.json").read_text())
    report["propagation"]["time_offset_s"] = -0.03
    for frame in report["frames"]:
        del frame["camera_pose"]
    (tmp_path / "run" / "report.json").write_text(json.dumps(report))
    exported = read_run(tmp_path / "run")
    times = np.array([f.timestamp for f in exported.frames])
    expected = poses_at(read_trajectory(report["propagation"]["poses"]), times - 0.03)
    assert exported.time_offset == -0.03 and expected.ok.sum() >= 4
    assert [f.pose is not None for f in exported.frames] == expected.ok.tolist()
    # The warning about frames without a pose says its times are shifted by the offset.
    assert not expected.ok.all()
    said = [r.getMessage() for r in caplog.records if "have no pose" in r.getMessage()]
    assert len(said) == 1 and said[0].endswith("; times are the frames' timestamps -0.03 s, the run's clock offset)"), said
    for i in np.flatnonzero(expected.ok):
        np.testing.assert_allclose(exported.frames[i].pose[0], expected.rotations[i], atol=1e-12)
        np.testing.assert_allclose(exported.frames[i].pose[1], expected.translations[i], atol=1e-12)
    unshifted = poses_at(read_trajectory(report["propagation"]["poses"]), times)
    both = expected.ok & unshifted.ok
    assert np.abs(unshifted.translations[both] - expected.translations[both]).max() > 1e-3  # the offset matters
    # Another trajectory than the run's: the configured offset (0 here), not the estimate.
    other = tmp_path / "other.txt"
    shutil.copy(report["propagation"]["poses"], other)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="annotate_rgbd"):
        assert read_run(tmp_path / "run", other).time_offset == 0.0
    assert [r.getMessage() for r in caplog.records][0] == (
        f"{other}: read at the configured propagate.time_offset (0 s), not at the -0.03 s the run estimated for its "
        f"own trajectory {report['propagation']['poses']}")  # no camera poses in this report to export with instead
    export_run(tmp_path / "run", "planes", tmp_path / "out")
    assert json.loads((tmp_path / "out" / "export.json").read_text())["trajectory_time_offset_s"] == -0.03


def test_the_stated_camera_frame_is_the_one_of_the_equations_when_fy_is_negative(tmp_path):
    # ICL-NUIM's intrinsics have a negative fy: its camera frame's y points up. Every equation
    # must hold for the mask's pixels back-projected with the run's own intrinsics, and the
    # export must say y up (a y-down reader would swap floor and ceiling).
    camera = Camera(fx=262.5, fy=-262.5, cx=159.5, cy=119.5, depth_scale=5000.0)
    annotation = make_sequence(tmp_path / "sequence", n_frames=2, width=320, height=240, camera=camera, seed=5,
                               dropped_rgb_frames=())
    xml = tmp_path / "annotations.xml"
    write_cvat_video(annotation, xml, width=320, height=240)
    config = load_config(None, {"camera.fx": 262.5, "camera.fy": -262.5, "camera.cx": 159.5, "camera.cy": 119.5})
    run_cvat2mask(tmp_path / "sequence", [xml], tmp_path / "run", config)
    export_run(tmp_path / "run", "planes", tmp_path / "e")
    record = json.loads((tmp_path / "e" / "export.json").read_text())
    assert "y up" in record["conventions"]["plane_equation"] and "y down" not in record["conventions"]["plane_equation"]
    checked = 0
    for path in sorted((tmp_path / "e" / "frames").iterdir()):
        entry = json.loads(path.read_text())
        assert "y up" in entry["convention"]
        ids = mask_ids(tmp_path / "run", entry["frame"])
        depth = cv2.imread(str(tmp_path / "sequence" / entry["depth"]), cv2.IMREAD_UNCHANGED) / 5000.0
        for plane in entry["planes"]:
            rows, cols = np.nonzero(ids == plane["plane"])
            z = depth[rows, cols]
            points = np.stack([(cols - 159.5) * z / 262.5, (rows - 119.5) * z / -262.5, z], axis=1)
            a, b, c, d = plane["camera"]
            assert np.median(np.abs(points @ [a, b, c] + d)) < 0.01
            checked += 1
    assert checked >= 4


def test_the_stated_camera_frame_follows_the_focal_lengths_signs():
    from annotate_rgbd.export.frames import equation_convention

    assert "x right, y down, z forward)" in equation_convention(517.3, 516.5)
    assert "x right, y up, z forward, as the camera's focal lengths fx = 481.2, fy = -480 give" in equation_convention(481.2, -480.0)
    assert "x left, y down" in equation_convention(-500.0, 500.0)

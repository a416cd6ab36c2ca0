"""End to end: proposals on a rendered room against its exact ground truth; the CVAT files read
back by cvat2mask and by datumaro; the export-cvat round trip on the sample run."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from lxml import etree
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.cli import app
from annotate_rgbd.config.settings import Config, load_config
from annotate_rgbd.errors import InputError
from annotate_rgbd.io.labelmaps import read_label_map
from annotate_rgbd.evaluate.metrics import frame_statistics
from annotate_rgbd.pipeline.scene import run_cvat2mask
from annotate_rgbd.segment.rasterize import shape_mask
from annotate_rgbd.propose import run_propose
from annotate_rgbd.io.sequence import read_sequence
from annotate_rgbd.synthetic import make_sequence, room_trajectory

SAMPLE_DATA = Path(__file__).resolve().parents[2] / "sample_data"

CAMERA = Camera(fx=525.0, fy=525.0, cx=319.5, cy=239.5, depth_scale=5000.0)
N_FRAMES = 40
MIN_AREA = 0.01  # the default smallest plane: the ground truth keeps the planes a labeller keeps


def write_trajectory(sequence: Path, n_frames: int) -> Path:
    """The renderer's camera poses as a TUM groundtruth.txt at the depth timestamps."""
    poses = room_trajectory(n_frames)
    times = read_sequence(sequence).depth.timestamps
    quaternions = Rotation.from_matrix(np.array([p.rotation for p in poses])).as_quat()  # x y z w
    lines = [f"{t:.6f} " + " ".join(f"{v:.9f}" for v in (*p.position, *q)) for t, p, q in zip(times, poses, quaternions)]
    path = sequence / "groundtruth.txt"
    path.write_text("# timestamp tx ty tz qx qy qz qw\n" + "\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    root = tmp_path_factory.mktemp("propose")
    sequence = root / "sequence"
    make_sequence(sequence, n_frames=N_FRAMES, width=640, height=480, camera=CAMERA, seed=3)
    trajectory = write_trajectory(sequence, N_FRAMES)
    config = Config()
    run_propose(sequence, root / "posed", config, poses=trajectory, workers=2)
    run_propose(sequence, root / "plain", config, workers=2)
    run_cvat2mask(sequence, [root / "posed" / "proposals.xml"], root / "refined", config, workers=1)
    return sequence, root


def ground_truth(sequence: Path) -> dict[str, np.ndarray]:
    """Per depth file name: the planes a labeller keeps (expected kept, >= 1 % of the frame)."""
    description = json.loads((sequence / "ground_truth" / "planes.json").read_text())
    dropped = [p["gt_value"] for p in description["planes"] if p["expected"] != "kept"]
    frames = {}
    for frame in description["frames"]:
        gt = read_label_map(sequence / "ground_truth" / frame["ground_truth"]).astype(np.int64)
        gt[np.isin(gt, dropped)] = 0
        gt[(np.bincount(gt.ravel()) < MIN_AREA * gt.size)[gt]] = 0
        frames[Path(frame["depth"]).name] = gt
    return frames


#: A ground-truth plane has a colour on a frame when a mask matches it with at least this IoU (the
#: real-data kit's identity threshold): a plane not found there has no colour to keep, and a few
#: stray pixels of another track on it (IoU 0.002) say nothing about the tracks.
IDENTITY_IOU = 0.5


def score(sequence: Path, masks: Path) -> dict[str, float]:
    """Mean best IoU of the ground-truth planes, EVOPS precision and recall at IoU 0.8, and the
    share of (plane, frame) pairs whose best-matching colour (IoU >= IDENTITY_IOU) is the plane's usual one."""
    ious, precision, recall, matches = [], [], [], {}
    for name, gt in ground_truth(sequence).items():
        if not (masks / name).exists():
            continue
        pred = read_label_map(masks / name).astype(np.int64)
        stats = frame_statistics(gt, pred, full=0.8)
        precision.append(stats.precision)
        recall.append(stats.recall)
        n_pred = int(pred.max()) + 1
        joint = np.bincount(gt.ravel() * n_pred + pred.ravel(), minlength=(gt.max() + 1) * n_pred)
        joint = joint.reshape(-1, n_pred)
        union = joint.sum(1)[:, None] + joint.sum(0)[None, :] - joint
        iou = joint / np.maximum(union, 1)
        for g in np.flatnonzero(joint[1:, :].sum(1)) + 1:
            best = int(np.argmax(iou[g, 1:])) + 1
            ious.append(iou[g, best])
            if iou[g, best] >= IDENTITY_IOU:
                # Colour of the prediction, not its per-file label number.
                matches.setdefault(int(g), []).append(_colour_of(masks / name, pred == best))
    consistent = sum(max(np.unique(c, return_counts=True)[1]) for c in matches.values())
    return {"mean_iou": float(np.mean(ious)), "precision": float(np.mean(precision)),
            "recall": float(np.mean(recall)), "colour": consistent / sum(len(c) for c in matches.values()),
            "frames": len(precision)}


def _colour_of(path: Path, where: np.ndarray) -> int:
    image = cv2.imread(str(path)).astype(np.int64)
    b, g, r = image[where][0]
    return int(r << 16 | g << 8 | b)


def test_proposals_with_poses_reach_the_targets(room):
    sequence, root = room
    result = score(sequence, root / "posed" / "masks")
    assert result["frames"] == N_FRAMES - 1  # the middle frame has no RGB frame
    assert result["mean_iou"] >= 0.85, result
    assert result["precision"] >= 0.85 and result["recall"] >= 0.85, result
    assert result["colour"] >= 0.95, result


def test_the_next_step_after_propose_names_the_trajectory(room):
    # stats (as export and export-cvat) takes a cvat2mask run: it says how the proposals become one.
    sequence, root = room
    result = CliRunner().invoke(app, ["stats", str(root / "posed")])
    assert result.exit_code == 1
    assert (f"`annotate-rgbd cvat2mask {sequence.absolute()} {(root / 'posed' / 'proposals.xml').absolute()} --poses "
            f"{(sequence / 'groundtruth.txt').absolute()} --config CONFIG --out DIR`") in result.stderr


def test_the_trajectorys_time_offset_is_applied(room, tmp_path):
    # The trajectory on a clock 100 s ahead of the camera's: with propagate.time_offset = 100 the
    # proposals are those of the trajectory on the camera's clock; without, no frame has a pose.
    sequence, root = room
    lines = (sequence / "groundtruth.txt").read_text().splitlines()
    ahead = tmp_path / "ahead.txt"
    ahead.write_text("\n".join(line if line.startswith("#") else f"{float(line.split()[0]) + 100:.6f} "
                               + " ".join(line.split()[1:]) for line in lines) + "\n")
    run_propose(sequence, tmp_path / "shifted", load_config(None, {"propagate.time_offset": 100.0}), poses=ahead,
                workers=1)
    for mask in sorted((root / "posed" / "masks").iterdir()):
        assert (tmp_path / "shifted" / "masks" / mask.name).read_bytes() == mask.read_bytes(), mask.name
    with pytest.raises(InputError, match="no processed depth frame has a pose"):
        run_propose(sequence, tmp_path / "unshifted", Config(), poses=ahead, workers=1)


def test_proposals_without_poses(room):
    sequence, root = room
    result = score(sequence, root / "plain" / "masks")
    assert result["mean_iou"] >= 0.85, result
    assert result["precision"] >= 0.85 and result["recall"] >= 0.85, result
    # Linking on image overlap alone breaks where the room camera turns fast (see the report).
    assert result["colour"] >= 0.9, result


def test_cvat2mask_on_proposals_is_at_least_as_good(room):
    sequence, root = room
    proposed = score(sequence, root / "posed" / "masks")
    refined = score(sequence, root / "refined" / "masks")
    assert refined["frames"] == proposed["frames"]
    for key in ("mean_iou", "precision", "recall", "colour"):
        assert refined[key] >= proposed[key] - 0.005, (key, refined, proposed)


def test_report_and_proposals_agree(room):
    sequence, root = room
    report = json.loads((root / "posed" / "report.json").read_text())
    frames = [f for f in report["frames"] if f["status"] == "written"]
    assert len(frames) == N_FRAMES - 1
    for frame in frames:
        mask = read_label_map(root / "posed" / frame["mask"])
        areas = sorted(int(a) for a in np.bincount(mask.ravel())[1:] if a)
        assert areas == sorted(p["area"] for p in frame["planes"])
        for plane in frame["planes"]:
            assert len(plane["equation"]) == 4 and abs(np.linalg.norm(plane["equation"][:3]) - 1) < 1e-6
    assert {t["equation_frame"] for t in report["tracks"]} == {"world"}


def keyframe_polygons(xml: Path) -> list[tuple[int, int, np.ndarray]]:
    """(track, frame, points) of every keyframe polygon of a CVAT video export."""
    from annotate_rgbd.cvat import read_cvat

    return [(t.track_id, f, t.shapes[f].points) for t in read_cvat(xml).tracks for f in sorted(t.keyframes)]


def test_proposals_are_simple_and_within_the_vertex_budget(room):
    shapely = pytest.importorskip("shapely", reason="shapely (a test tool): pip install -e '.[test]'")
    sequence, root = room
    polygons = keyframe_polygons(root / "posed" / "proposals.xml")
    assert polygons
    budget = Config().propose.max_vertices
    for _, _, points in polygons:
        assert shapely.Polygon(points).is_valid and shapely.LinearRing(points).is_simple
        assert 3 <= len(points) <= budget
    # The report tells each keyframe polygon's vertices and its IoU with the plane's pixels.
    report = json.loads((root / "posed" / "report.json").read_text())
    drawn = {(t, f): p for t, f, p in polygons}
    checked = 0
    for frame in report["frames"]:
        if frame["status"] != "written" or not frame["cvat_keyframe"]:
            continue
        image = cv2.imread(str(root / "posed" / frame["mask"]))
        for plane in frame["planes"]:
            points = drawn[(plane["track"], frame["rgb_index"])]
            assert plane["vertices"] == len(points)
            hex_colour = next(t["colour"] for t in report["tracks"] if t["track"] == plane["track"])
            bgr = tuple(int(hex_colour[i : i + 2], 16) for i in (5, 3, 1))
            mask = (image == bgr).all(axis=-1)
            top, left, window = shape_mask(Shape("polygon", points), *mask.shape)
            inside = np.zeros_like(mask)
            inside[top : top + window.shape[0], left : left + window.shape[1]] = window
            iou = np.count_nonzero(inside & mask) / np.count_nonzero(inside | mask)
            assert abs(iou - plane["polygon_iou"]) < 0.01, (iou, plane)
            if plane["budget_iou_cost"] is not None:  # the budget stopped this polygon's simplification
                assert -0.05 < plane["budget_iou_cost"] < 0.2
            checked += 1
    summary = report["summary"]["polygons"]
    assert summary["polygons"] == checked and summary["largest_vertices"] <= budget
    assert summary["at_budget"] == sum(p["budget_iou_cost"] is not None for f in report["frames"]
                                       if f["status"] == "written" and f["cvat_keyframe"] for p in f["planes"])


def test_datumaro_reads_the_proposals(room):
    datumaro = pytest.importorskip("datumaro", reason="datumaro: pip install '.[interop]'")
    sequence, root = room
    report = json.loads((root / "posed" / "report.json").read_text())
    dataset = datumaro.Dataset.import_from(str(root / "posed" / "proposals.xml"), "cvat")
    shapes = {int(item.attributes["frame"]) if "frame" in item.attributes else int(item.id.split("_")[-1]):
              [a for a in item.annotations if not a.attributes.get("outside")] for item in dataset}
    expected = {f["rgb_index"]: len(f["planes"]) for f in report["frames"] if f["status"] == "written"}
    assert {frame: len(shapes.get(frame, [])) for frame in expected} == expected
    one = next(a for anns in shapes.values() for a in anns)
    assert len(one.attributes["equation"].split()) == 4


@pytest.fixture(scope="module")
def sample_round_trip(tmp_path_factory):
    """The sample run, its export-cvat file, and cvat2mask run again on that file."""
    root = tmp_path_factory.mktemp("round_trip")
    config = load_config(SAMPLE_DATA / "camera.toml")
    first, second, xml = root / "first", root / "second", root / "export.xml"
    run_cvat2mask(SAMPLE_DATA / "sequence", [SAMPLE_DATA / "annotations.xml"], first, config, workers=1)
    outcome = CliRunner().invoke(app, ["export-cvat", str(first), str(xml)])
    assert outcome.exit_code == 0, outcome.output
    run_cvat2mask(SAMPLE_DATA / "sequence", [xml], second, config, workers=1)
    return first, second, xml


def test_export_cvat_with_helpers_writes_the_same_file(sample_round_trip, tmp_path):
    from annotate_rgbd.export.cvat import export_cvat

    first, _, xml = sample_round_trip  # written by the command line with every core
    calls = []
    (tmp_path / "one").mkdir()
    assert export_cvat(first, tmp_path / "one" / xml.name, workers=1, progress=lambda *c: calls.append(c)) > 0
    assert (tmp_path / "one" / xml.name).read_bytes() == xml.read_bytes()
    assert calls == [(done, 19) for done in range(1, 20)]
    (tmp_path / "three").mkdir()
    export_cvat(first, tmp_path / "three" / xml.name, workers=3)
    assert (tmp_path / "three" / xml.name).read_bytes() == xml.read_bytes()


def test_export_cvat_round_trip_on_the_sample(sample_round_trip):
    first, second, xml = sample_round_trip
    names = sorted(p.name for p in (first / "masks").iterdir())
    assert names == sorted(p.name for p in (second / "masks").iterdir())
    gt_dir = SAMPLE_DATA / "ground_truth"
    pairwise, before, after = [], [], []
    for name in names:
        a, b = read_label_map(first / "masks" / name), read_label_map(second / "masks" / name)
        pairwise.append(frame_statistics(a, b, full=0.5).mean)
        gt = read_label_map(gt_dir / name)
        before.append(frame_statistics(gt, a, full=0.5).mean)
        after.append(frame_statistics(gt, b, full=0.5).mean)
    assert np.mean(pairwise) >= 0.98
    assert abs(np.mean(after) - np.mean(before)) <= 0.01
    # Tracks carry the run's plane ids and labels (the planes that reach a mask).
    report = json.loads((first / "report.json").read_text())
    kept = {p["plane"] for f in report["frames"] if f["status"] == "written" for p in f["kept"]}
    planes = {p["plane"]: p["label"] for p in report["planes"] if p["plane"] in kept}
    tracks = {int(t.get("id")): t.get("label") for t in etree.parse(str(xml)).getroot().iter("track")}
    assert tracks == planes


def colour_agreement(first: Path, second: Path) -> float:
    """Of the pixels that both runs' colour masks label, the share that has the same colour in
    both (frames of both runs)."""
    same = both = 0
    for path in sorted((first / "masks").iterdir()):
        a, b = cv2.imread(str(path)), cv2.imread(str(second / "masks" / path.name))
        labelled = a.any(axis=-1) & b.any(axis=-1)
        both += int(np.count_nonzero(labelled))
        same += int(np.count_nonzero(labelled & (a == b).all(axis=-1)))
    return same / both


def plane_table(run: Path) -> dict[int, tuple[str, str]]:
    """planes.csv: plane id -> (colour, label)."""
    import csv

    with open(run / "planes.csv", newline="") as handle:
        return {int(r["plane_id"]): (r["colour"], r["label"]) for r in csv.DictReader(handle)}


def test_export_cvat_round_trip_keeps_plane_ids_and_colours(sample_round_trip):
    # Without the plane_id attribute the read-back renumbered the planes from 1 (planes 1 and 7
    # of the sample reach no mask), and 82 % of the pixels changed colour.
    first, second, _ = sample_round_trip
    assert colour_agreement(first, second) >= 0.998
    before, after = plane_table(first), plane_table(second)
    assert after and all(before[plane] == entry for plane, entry in after.items())


def test_export_cvat_polygons_are_simple_and_within_the_budget(sample_round_trip, tmp_path):
    shapely = pytest.importorskip("shapely", reason="shapely (a test tool): pip install -e '.[test]'")
    first, _, xml = sample_round_trip
    from annotate_rgbd.config.propose import EXPORT_MAX_VERTICES

    for _, _, points in keyframe_polygons(xml):
        assert shapely.Polygon(points).is_valid and shapely.LinearRing(points).is_simple
        assert len(points) <= EXPORT_MAX_VERTICES
    small = tmp_path / "small.xml"
    outcome = CliRunner().invoke(app, ["export-cvat", str(first), str(small), "--max-vertices", "12", "--tolerance", "1"])
    assert outcome.exit_code == 0, outcome.output
    counts = [len(points) for _, _, points in keyframe_polygons(small)]
    assert max(counts) <= 12 and max(counts) > 4
    outcome = CliRunner().invoke(app, ["export-cvat", str(first), str(tmp_path / "bad.xml"), "--max-vertices", "2"])
    assert outcome.exit_code != 0 and "at least a polygon's 3 vertices" in outcome.output
    assert not (tmp_path / "bad.xml").exists()


def test_a_track_added_in_cvat_gets_an_unused_plane_id(sample_round_trip, tmp_path):
    # The labeller draws a new plane (no plane_id) and copies a wall track over frames where
    # the wall is still visible (the copy keeps the wall's plane_id): both become new planes,
    # above every id the first run had, and the copy is warned about.
    first, _, xml = sample_round_trip
    tree = etree.parse(str(xml))
    root = tree.getroot()
    tracks = root.findall("track")
    wall = next(t for t in tracks if t.get("label") == "wall_left")
    added = etree.fromstring(etree.tostring(wall))
    added.set("id", "40")
    added.set("label", "poster")
    for attribute in added.iter("attribute"):
        attribute.getparent().remove(attribute)
    copied = etree.fromstring(etree.tostring(wall))
    copied.set("id", "41")
    root.extend([added, copied])
    edited = tmp_path / "edited.xml"
    tree.write(str(edited))
    config = load_config(SAMPLE_DATA / "camera.toml")
    result = run_cvat2mask(SAMPLE_DATA / "sequence", [edited], tmp_path / "third", config, workers=1)
    report = json.loads((tmp_path / "third" / "report.json").read_text())
    planes = {(t["track"]): t["plane"] for t in report["tracks"]}
    known = set(plane_table(first))
    assert max(known) == 10 and planes[40] == 11 and planes[41] == 12
    assert all(planes[int(t.get("id"))] == int(t.get("id")) for t in tracks)
    assert any("tracks 2 and 41 both carry plane_id 2" in w for w in report["warnings"]), report["warnings"]
    assert result is not None


def test_cvat2mask_on_proposals_keeps_the_track_ids(room):
    # propose's track numbers are the plane ids cvat2mask gives, and so their colours.
    sequence, root = room
    report = json.loads((root / "refined" / "report.json").read_text())
    assert all(t["plane"] == t["track"] and t["how"] == "plane_id" for t in report["tracks"])
    assert colour_agreement(root / "posed", root / "refined") >= 0.99


def test_export_cvat_round_trip_on_the_rendered_room_keeps_the_colours(room, tmp_path):
    # The refined run on the rendered room (plane ids = proposal tracks, with gaps where tracks
    # were dropped) through export-cvat and cvat2mask again.
    sequence, root = room
    xml = tmp_path / "round2.xml"
    outcome = CliRunner().invoke(app, ["export-cvat", str(root / "refined"), str(xml)])
    assert outcome.exit_code == 0, outcome.output
    run_cvat2mask(sequence, [xml], tmp_path / "second", Config(), workers=1)
    assert colour_agreement(root / "refined", tmp_path / "second") >= 0.995
    before, after = plane_table(root / "refined"), plane_table(tmp_path / "second")
    assert after and all(before[plane] == entry for plane, entry in after.items())


def test_datumaro_reads_the_export(sample_round_trip):
    datumaro = pytest.importorskip("datumaro", reason="datumaro: pip install '.[interop]'")
    first, _, xml = sample_round_trip
    report = json.loads((first / "report.json").read_text())
    dataset = datumaro.Dataset.import_from(str(xml), "cvat")
    expected = {f["rgb_index"]: len(f["kept"]) for f in report["frames"] if f["status"] == "written"}
    counted = {}
    for item in dataset:
        frame = int(item.attributes.get("frame", -1))
        counted[frame] = len([a for a in item.annotations if not a.attributes.get("outside")])
    assert {frame: counted.get(frame, 0) for frame in expected} == expected


def test_propose_command(tmp_path):
    out = tmp_path / "out"
    outcome = CliRunner().invoke(app, ["propose", str(SAMPLE_DATA / "sequence"), "--out", str(out), "--config",
                                       str(SAMPLE_DATA / "camera.toml"), "--every", "3", "--jobs", "1",
                                       "--label", "surface", "--min-area", "0.02"])
    assert outcome.exit_code == 0, outcome.output
    report = json.loads((out / "report.json").read_text())
    assert report["inputs"]["every"] == 3 and report["inputs"]["min_area_fraction"] == 0.02
    written = [f for f in report["frames"] if f["status"] == "written"]
    assert written and all(p["area"] >= 0.02 * 320 * 240 for f in written for p in f["planes"])  # the sample is 320x240
    assert 'label="surface"' in (out / "proposals.xml").read_text()
    # The sample has no trajectory: no word about one.
    assert "trajectory beside the frames" not in outcome.output


def test_propose_without_poses_names_the_trajectory_beside_the_frames(tmp_path):
    # A TUM folder holds its motion-capture trajectory (groundtruth.txt), which propose does not
    # read unless given as --poses: it says so once, naming the file, and runs on without it.
    sequence = tmp_path / "sequence"
    shutil.copytree(SAMPLE_DATA / "sequence", sequence)
    (sequence / "groundtruth.txt").write_text("# timestamp tx ty tz qx qy qz qw\n")
    outcome = CliRunner().invoke(app, ["propose", str(sequence), "--out", str(tmp_path / "out"), "--config",
                                       str(SAMPLE_DATA / "camera.toml"), "--every", "6", "--jobs", "1"])
    assert outcome.exit_code == 0, outcome.output
    assert outcome.output.count(f"info: {sequence / 'groundtruth.txt'}: a camera trajectory beside the frames; "
                                "give it as --poses") == 1
    assert json.loads((tmp_path / "out" / "report.json").read_text())["inputs"]["poses"] is None


@pytest.mark.parametrize("blank", ["no depth", "noise"])
def test_a_frame_without_a_plane_gets_an_empty_mask(tmp_path, blank):
    # A frame the sensor saw nothing on (all zero), or nothing flat: no plane detected, which
    # raised in the merge of coplanar pieces (pool_groups of no groups).
    sequence = tmp_path / "sequence"
    shutil.copytree(SAMPLE_DATA / "sequence", sequence)
    first = sorted((sequence / "depth").iterdir())[0]
    depth = cv2.imread(str(first), cv2.IMREAD_UNCHANGED)
    rng = np.random.default_rng(0)
    cv2.imwrite(str(first), np.zeros_like(depth) if blank == "no depth"
                else (rng.random(depth.shape) * 20000).astype(np.uint16))
    outcome = CliRunner().invoke(app, ["propose", str(sequence), "--out", str(tmp_path / "out"), "--config",
                                       str(SAMPLE_DATA / "camera.toml"), "--every", "6", "--jobs", "1"])
    assert outcome.exit_code == 0, outcome.output
    mask = cv2.imread(str(tmp_path / "out" / "masks" / first.name), cv2.IMREAD_UNCHANGED)
    assert mask is not None and not mask.any()
    frame = next(f for f in json.loads((tmp_path / "out" / "report.json").read_text())["frames"]
                 if f["depth"].endswith(first.name))
    assert frame["status"] == "written" and frame["planes"] == []


def test_frames_without_an_rgb_frame_are_one_warning_and_none_is_one_error(tmp_path):
    from builders import error_line
    from conftest import SAMPLE_DATA

    args = ["propose", str(SAMPLE_DATA / "sequence"), "--config", str(SAMPLE_DATA / "camera.toml"), "--jobs", "1"]
    # Of the four frames --every 5 picks, none lies within 6 ms of its RGB frame (three others do):
    # the error says which frames it looked at, and nothing is written.
    none = CliRunner().invoke(app, args + ["--out", str(tmp_path / "none"), "--every", "5",
                                           "--set", "sequence.max_time_diff=0.006"])
    assert none.exit_code == 1
    assert error_line(none) == (f"error: {SAMPLE_DATA / 'sequence'}: no depth frame of the 4 that --every 5 picks has an "
                                "RGB frame within 0.006 s (sequence.max_time_diff): each is 0.006485 to 0.02591 s from "
                                "the nearest (median 0.00904 s)")
    assert "warning:" not in none.stderr and not (tmp_path / "none").exists()
    # Every frame: eleven without one, one warning line.
    some = CliRunner().invoke(app, args + ["--out", str(tmp_path / "some"), "--set", "sequence.max_time_diff=0.008"])
    assert some.exit_code == 0, some.output
    depth = SAMPLE_DATA / "sequence" / "depth"
    assert [line for line in some.stderr.splitlines() if "no RGB frame" in line] == [
        f"warning: {depth}/1700000000.044158.png, {depth}/1700000000.075739.png, {depth}/1700000000.108053.png and 8 more: "
        "no RGB frame within 0.008 s; skipped"]
    report = json.loads((tmp_path / "some" / "report.json").read_text(encoding="utf-8"))
    assert report["summary"]["frames_skipped"] == len(report["skipped"]) == 11
    assert report["skipped"][0] == "depth/1700000000.044158.png: no RGB frame within 0.008 s"

"""Pose-guided propagation: keyframes lifted onto their planes and carried to every frame."""

from __future__ import annotations

import json
import re
import shutil
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from annotate_rgbd.errors import InputError
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.cli import app
from annotate_rgbd.config.settings import PropagateConfig, load_config
from annotate_rgbd.cvat import read_cvat, write_cvat_video
from annotate_rgbd.geometry.lift import plane_agreement
from annotate_rgbd.pipeline.scene import run_cvat2mask
from annotate_rgbd.propagate.lift import consensus_plane
from annotate_rgbd.report.run_folder import read_report
from annotate_rgbd.report.stats import run_stats
from annotate_rgbd.synthetic import make_sequence

CAMERA = Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, depth_scale=5000.0)
FRAMES, STEP = 24, 8


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> dict:
    """A rendered room walk with its exact trajectory, annotated on every 8th frame only."""
    root = tmp_path_factory.mktemp("propagate")
    annotation = make_sequence(root / "sequence", n_frames=FRAMES, width=320, height=240, camera=CAMERA, seed=3,
                               dropped_rgb_frames=(), write_trajectory=True)
    keyframes = root / "keyframes.xml"
    write_cvat_video(annotation, keyframes, width=320, height=240, keyframe_step=STEP, keyframes_only=True)
    config = root / "camera.toml"
    config.write_text("[camera]\nfx = 262.5\nfy = 262.5\ncx = 159.5\ncy = 119.5\ndepth_scale = 5000.0\n")
    return {"root": root, "sequence": root / "sequence", "keyframes": keyframes, "config": config,
            "poses": root / "sequence" / "groundtruth.txt", "truth": root / "sequence" / "ground_truth"}


def _mean_iou(out: Path, truth: Path) -> float:
    """Mean IoU of the planes the ground truth keeps, matched by label through planes.csv."""
    planes = json.loads((truth / "planes.json").read_text())
    kept = {p["label"]: p["gt_value"] for p in planes["planes"] if p["expected"] == "kept"}
    rows = (out / "planes.csv").read_text().splitlines()[1:]
    colour_of = {}
    for row in rows:
        fields = row.split(",")
        colour_of[fields[5]] = tuple(int(v) for v in fields[2:5])
    ious = []
    for mask in sorted((out / "masks").iterdir()):
        rgb = cv2.cvtColor(cv2.imread(str(mask)), cv2.COLOR_BGR2RGB)
        gt = cv2.imread(str(truth / mask.name), cv2.IMREAD_UNCHANGED)
        for label, value in kept.items():
            if label not in colour_of or not (gt == value).any():
                continue
            ours = (rgb == colour_of[label]).all(axis=2)
            ious.append(((ours & (gt == value)).sum()) / ((ours | (gt == value)).sum()))
    return float(np.mean(ious))


def test_poses_carry_keyframes_to_the_frames_between(rendered, tmp_path):
    config = load_config(rendered["config"])
    flat = run_cvat2mask(rendered["sequence"], [rendered["keyframes"]], tmp_path / "flat", config)
    posed = run_cvat2mask(rendered["sequence"], [rendered["keyframes"]], tmp_path / "posed", config,
                          poses=rendered["poses"])
    iou_flat, iou_posed = _mean_iou(tmp_path / "flat", rendered["truth"]), _mean_iou(tmp_path / "posed", rendered["truth"])
    assert iou_posed > iou_flat + 0.05 and iou_posed > 0.85, (iou_flat, iou_posed)
    report = json.loads((tmp_path / "posed" / "report.json").read_text())
    assert all(f["pose"] == "ok" for f in report["frames"])
    assert report["propagation"]["frames_with_pose"] == FRAMES
    drawn_on = {}  # plane -> frames where its shape was drawn (keyframes)
    labels = {t.track_id: t for t in read_cvat(rendered["keyframes"]).tracks}
    for track in posed.tracks:
        drawn_on[track.plane] = labels[track.track].keyframes
    propagated = 0
    for frame in (f for f in report["frames"] if f["status"] == "written"):
        for plane in frame["kept"] + frame["dropped"]:
            assert plane["propagated"] == (frame["cvat_frame"] not in drawn_on[plane["plane"]])
            propagated += plane["propagated"]
    assert propagated > 0.5 * sum(len(f["kept"]) + len(f["dropped"]) for f in report["frames"] if f["status"] == "written")
    # Without poses the report has none of this.
    plain = json.loads((tmp_path / "flat" / "report.json").read_text())
    assert "propagation" not in plain and "pose" not in plain["frames"][0]
    assert "propagated" not in next(f for f in plain["frames"] if f["status"] == "written")["kept"][0]
    assert posed.written == flat.written


def test_helper_processes_fit_the_keyframes_to_the_same_planes_and_masks(rendered, tmp_path):
    config = load_config(rendered["config"])
    for workers in (1, 2):  # with 2, the helper fits keyframe frames while this process does too
        run_cvat2mask(rendered["sequence"], [rendered["keyframes"]], tmp_path / str(workers), config,
                      poses=rendered["poses"], workers=workers)
    one, two = (json.loads((tmp_path / w / "report.json").read_text()) for w in ("1", "2"))
    assert one["propagation"] == two["propagation"] and one["propagation"]["tracks"]
    masks = sorted(p.name for p in (tmp_path / "1" / "masks").iterdir())
    assert masks and masks == sorted(p.name for p in (tmp_path / "2" / "masks").iterdir())
    assert all((tmp_path / "1" / "masks" / m).read_bytes() == (tmp_path / "2" / "masks" / m).read_bytes() for m in masks)


def test_lifted_planes_are_the_rendered_planes(rendered, tmp_path):
    config = load_config(rendered["config"])
    run = run_cvat2mask(rendered["sequence"], [rendered["keyframes"]], tmp_path / "out", config, poses=rendered["poses"])
    lifts = run.propagation.lifts
    assert lifts and all(lift.consistent for lift in lifts.values())
    # Independent: the scene's planes in world coordinates (point and normal from the scene).
    from annotate_rgbd.synthetic import room_scene

    scene = {plane.label: plane for plane in room_scene().planes}
    labels = {t.track_id: t.label for t in read_cvat(rendered["keyframes"]).tracks}
    checked = 0
    for (part, track), lift in lifts.items():
        plane = scene[labels[track]]
        normal = np.cross(plane.edge_u, plane.edge_v)
        normal = normal / np.linalg.norm(normal)
        truth = np.append(normal, -normal @ np.asarray(plane.centre))
        for keyframe in lift.keyframes:
            angle, offset = plane_agreement(truth, keyframe.plane, at=keyframe.world.mean(axis=0))
            if plane.valid_fraction >= 1:  # glass returns too little depth to fit well
                assert angle < 2.0 and offset < 0.02, (labels[track], angle, offset)
                checked += 1
    assert checked >= 6


def test_frames_without_a_pose_keep_the_2d_shapes(rendered, tmp_path):
    lines = rendered["poses"].read_text().splitlines()
    samples = [line for line in lines if not line.startswith("#")]
    short = tmp_path / "half.txt"
    short.write_text("\n".join(samples[: len(samples) // 2]) + "\n")
    run = run_cvat2mask(rendered["sequence"], [rendered["keyframes"]], tmp_path / "out",
                        load_config(rendered["config"]), poses=short)
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    reasons = [f["pose"] for f in report["frames"]]
    assert reasons[0] == "ok" and reasons[-1] == "outside_trajectory"
    late = [f for f in report["frames"] if f["pose"] != "ok" and f["status"] == "written"]
    assert late and all(not p["propagated"] for f in late for p in f["kept"])
    assert any("depth frames have no pose; their shapes are interpolated in 2-D" in w for w in run.warnings)


def test_a_trajectory_that_gives_no_frame_a_pose_is_refused(rendered, tmp_path):
    # Another recording's (every timestamp 1000 s later): one line with the two time ranges,
    # before any work, and no output folder (propose and export refuse it the same way).
    rows = [line.split() for line in rendered["poses"].read_text().splitlines() if line and not line.startswith("#")]
    later = tmp_path / "later.txt"
    later.write_text("".join(f"{float(r[0]) + 1000:.6f} {' '.join(r[1:])}\n" for r in rows))
    with pytest.raises(InputError, match=r"later.txt: no depth frame has a pose: the trajectory spans .* a clock offset"):
        run_cvat2mask(rendered["sequence"], [rendered["keyframes"]], tmp_path / "out", load_config(rendered["config"]),
                      poses=later)
    assert not (tmp_path / "out").exists()


def test_a_keyframe_drawn_over_another_surface_is_listed_and_lifted_onto_the_agreed_plane(rendered, tmp_path):
    annotation = read_cvat(rendered["keyframes"])
    by_label = {t.label: t for t in annotation.tracks}
    floor, table = by_label["floor"], by_label["table_top"]
    frame = STEP  # a keyframe both have: the floor's outline there is the table's, drawn on top
    assert frame in floor.keyframes and frame in table.keyframes
    floor.shapes[frame] = replace(table.shapes[frame], z_order=10)
    export = tmp_path / "wrong.xml"
    write_cvat_video(annotation, export, width=320, height=240, keyframe_step=STEP, keyframes_only=True)
    run = run_cvat2mask(rendered["sequence"], [export], tmp_path / "out", load_config(rendered["config"]),
                        poses=rendered["poses"])
    lift = run.propagation.lifts[(export.name, floor.track_id)]
    assert frame in lift.substantial and lift.angle < 2 and lift.offset > 0.6  # the table top, 0.74 m up
    floor_plane = np.array([0.0, 0.0, 1.0, 0.0])  # the rendered floor: z = 0 in the world
    for keyframe in lift.keyframes:  # the table's outline too was lifted onto the floor
        angle, offset = plane_agreement(floor_plane, keyframe.plane, at=keyframe.world.mean(axis=0))
        assert angle < 2 and offset < 0.02, (keyframe.frame, angle, offset)
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert f"{export.name}:{floor.track_id}" in report["propagation"]["inconsistent_tracks"]
    assert any(f"track {floor.track_id}" in w and "off the plane its other keyframes agree on" in w for w in report["warnings"])
    said = next(w for w in report["warnings"] if f"track {floor.track_id}" in w)
    assert len(lift.substantial) == 1 and "keyframe 8 lies" in said and said.endswith("it was lifted onto the agreed plane")


def test_consensus_plane_is_the_best_supported_one():
    floor = np.array([0.0, 0.0, 1.0, 0.0])
    tilted = np.array([0.0, np.sin(np.radians(2)), np.cos(np.radians(2)), 0.001])
    wall = np.array([1.0, 0.0, 0.0, -2.0])
    outline = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    plane, agree = consensus_plane([wall, floor, tilted, floor], [outline + [2, 0, 0], outline, outline, outline])
    assert plane is floor and agree == [False, True, True, True]
    assert plane_agreement(floor, tilted)[0] < PropagateConfig().same_surface_angle
    # With a tighter angle than the tilted keyframe's 2 degrees, it no longer agrees.
    tight = PropagateConfig(same_surface_angle=1.0)
    plane, agree = consensus_plane([wall, floor, tilted, floor], [outline + [2, 0, 0], outline, outline, outline],
                                   propagate=tight)
    assert plane is floor and agree == [False, True, False, True]


def test_cli_poses_option_and_a_bad_pose_file(rendered, tmp_path):
    runner = CliRunner()
    base = ["cvat2mask", str(rendered["sequence"]), str(rendered["keyframes"]), "--config", str(rendered["config"])]
    good = runner.invoke(app, [*base, "--out", str(tmp_path / "a"), "--poses", str(rendered["poses"])])
    assert good.exit_code == 0, good.output
    bad = tmp_path / "bad.txt"
    bad.write_text("1700000000.0 0 0 0 0 0 0 1\n1700000000.1 0 0 nan 0 0 0 1\n")
    result = runner.invoke(app, [*base, "--out", str(tmp_path / "b"), "--poses", str(bad)])
    assert result.exit_code == 1
    last = result.output.strip().splitlines()[-1]
    assert last.startswith(f"error: {bad}") and "line 2" in last


def test_manifest_and_configuration_take_poses(rendered, tmp_path):
    shutil.copy(rendered["poses"], tmp_path / "trajectory.txt")
    config = tmp_path / "scene.toml"
    config.write_text(rendered["config"].read_text() + '\n[sequence]\nposes = "trajectory.txt"\n')
    assert load_config(config).sequence.poses == str(tmp_path / "trajectory.txt")  # relative to the file
    run = run_cvat2mask(rendered["sequence"], [rendered["keyframes"]], tmp_path / "out", load_config(config))
    assert run.propagation is not None
    manifest = tmp_path / "batch.toml"
    manifest.write_text(
        f'[[scene]]\nsequence = "{rendered["sequence"]}"\nannotations = ["{rendered["keyframes"]}"]\n'
        f'config = "{rendered["config"]}"\nout = "batch_out"\nposes = "trajectory.txt"\n'
    )
    result = CliRunner().invoke(app, ["batch", str(manifest), "--jobs", "1"])
    assert result.exit_code == 0, result.output
    report = json.loads((tmp_path / "batch_out" / "report.json").read_text())
    assert report["propagation"]["poses"] == str(tmp_path / "trajectory.txt")


def test_review_and_stats_show_drawn_and_propagated_planes_and_tracks_to_review(rendered, tmp_path):
    annotation = read_cvat(rendered["keyframes"])
    by_label = {t.label: t for t in annotation.tracks}
    floor, table = by_label["floor"], by_label["table_top"]
    floor.shapes[STEP] = replace(table.shapes[STEP], z_order=10)
    export = tmp_path / "wrong.xml"
    write_cvat_video(annotation, export, width=320, height=240, keyframe_step=STEP, keyframes_only=True)
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["cvat2mask", str(rendered["sequence"]), str(export), "--config",
                                      str(rendered["config"]), "--out", str(out), "--poses", str(rendered["poses"]),
                                      "--overlays"])
    assert result.exit_code == 0, result.output
    page = (out / "review.html").read_text()
    start = page.index('<script type="application/json" id="run-data">') + len('<script type="application/json" id="run-data">')
    data = json.loads(page[start: page.index("</script>", start)])
    sources = {row[6] for frame in data["frames"] for row in frame["planes"]}
    assert sources == {"drawn", "propagated"}
    assert data["stats"]["tracks_to_review"] == [f"wrong.xml:{floor.track_id}"]
    stats = CliRunner().invoke(app, ["stats", str(out)])
    assert re.search(rf"tracks to review \(keyframes off their plane\) +wrong.xml:{floor.track_id}\n", stats.output)


def test_a_plane_carried_between_keyframes_that_disagree_is_listed_to_check(rendered, tmp_path):
    """The floor's middle keyframe outlines a small patch of what the others outline: on the frames
    between it and its neighbours the floor is listed, worst first; the run as drawn lists nothing."""
    annotation = read_cvat(rendered["keyframes"])
    floor = next(t for t in annotation.tracks if t.label == "floor")
    shape = floor.shapes[STEP]
    centre = shape.points.mean(axis=0)
    floor.shapes[STEP] = replace(shape, points=centre + 0.3 * (shape.points - centre))
    export = tmp_path / "patch.xml"
    write_cvat_video(annotation, export, width=320, height=240, keyframe_step=STEP, keyframes_only=True)
    config = load_config(rendered["config"])
    patched = run_cvat2mask(rendered["sequence"], [export], tmp_path / "patch", config, poses=rendered["poses"])
    run_cvat2mask(rendered["sequence"], [rendered["keyframes"]], tmp_path / "good", config, poses=rendered["poses"])
    plane = next(t.plane for t in patched.tracks if t.track == floor.track_id)
    report = read_report(tmp_path / "patch")
    listed = run_stats(report)["carried_to_check"]
    index = {frame.depth: i for i, frame in enumerate(report.frames)}  # depth frame i shows CVAT frame i
    frames = [index[c["depth"]] for c in listed]
    assert [c["cvat_frame"] for c in listed] == frames and {c["part"] for c in listed} == {"patch.xml"}
    assert listed and {c["plane"] for c in listed} == {plane}
    assert set(frames) <= set(range(1, 2 * STEP)) - {STEP} and len(frames) >= STEP
    assert [c["keyframes_agree"] for c in listed] == sorted(c["keyframes_agree"] for c in listed)
    assert all(c["keyframes_agree"] < 0.3 for c in listed)
    assert run_stats(read_report(tmp_path / "good"))["carried_to_check"] == []
    result = CliRunner().invoke(app, ["stats", str(tmp_path / "patch")])
    assert f"carried planes to check ({len(listed)}, worst first)" in result.output
    # The review page's plane table gives each carried plane its keyframes' agreement.
    from annotate_rgbd.review.page import page_data

    rows = {(frame["depth"], row[0]): row for frame in page_data(report, {})["frames"] for row in frame["planes"]}
    assert all(rows[c["depth"], plane][6:] == ["propagated", c["keyframes_agree"]] for c in listed)
    assert all(row[7] is None for row in rows.values() if row[6] == "drawn")


def test_review_of_a_run_with_poses_draws_the_shapes_the_poses_carried(rendered, tmp_path):
    """Review reads the carried shapes from the run's records: its overlays are those the run
    drew with --overlays (the trajectory is not read again)."""
    from annotate_rgbd.review.review import review_run

    out, drawn = tmp_path / "out", tmp_path / "drawn"
    for folder, overlays in ((out, False), (drawn, True)):
        run_cvat2mask(rendered["sequence"], [rendered["keyframes"]], folder, load_config(rendered["config"]),
                      poses=rendered["poses"], overlays=overlays)
    result = review_run(out)
    assert result.overlays
    assert all(p.read_bytes() == (drawn / "overlays" / p.name).read_bytes() for p in result.overlays)


def test_outline_edges_on_the_image_border_are_carried_past_it():
    from annotate_rgbd.propagate.lift import beyond_the_border

    reach = PropagateConfig().beyond_reach

    # A floor seen to the bottom-left corner: its left and bottom edges are the view's, the
    # diagonal is the floor's own edge (against a wall).
    outline = np.array([[1.0, 200.0], [400.0, 478.5], [2.5, 479.0]])
    quads = beyond_the_border(outline, (640, 480))
    assert len(quads) == 2
    left = next(q for q in quads if q[2, 0] < 0)
    bottom = next(q for q in quads if q[2, 1] > 480)
    np.testing.assert_allclose(left, [[2.5, 479.0], [1.0, 200.0], [1.0 - reach * 640, 200.0],
                                      [2.5 - reach * 640, 479.0]])
    np.testing.assert_allclose(bottom, [[400.0, 478.5], [2.5, 479.0], [2.5, 479.0 + reach * 480],
                                        [400.0, 478.5 + reach * 480]])
    # A narrower margin: the vertex 2.5 px from the left edge is no longer on it (the bottom
    # edge's vertices, 1.0 and 1.5 px from the bottom, still are).
    narrow = beyond_the_border(outline, (640, 480), margin=2.0)
    assert len(narrow) == 1 and np.array_equal(narrow[0], bottom)
    # Inside the image, or crossing from one side to another: the plane's own edges.
    assert beyond_the_border(np.array([[10.0, 10.0], [100.0, 10.0], [100.0, 90.0]]), (640, 480)) == []
    assert beyond_the_border(np.array([[0.0, 100.0], [200.0, 480.0], [200.0, 100.0]]), (640, 480)) == []


def test_planes_cut_by_the_keyframes_view_are_carried_past_it(tmp_path, monkeypatch):
    # The contact scene's walk turns from the back wall to the table: the floor and walls come
    # into view past where the keyframes (every 10th frame) saw them end at the image border.
    from annotate_rgbd.segment import frame as segment
    from annotate_rgbd.synthetic.contact import contact_scene, contact_trajectory

    frames = 30
    annotation = make_sequence(tmp_path / "sequence", n_frames=frames, width=320, height=240, camera=CAMERA, seed=12,
                               scene=contact_scene(), poses=contact_trajectory(frames), dropped_rgb_frames=(),
                               write_trajectory=True)
    keyframes = tmp_path / "keyframes.xml"
    write_cvat_video(annotation, keyframes, width=320, height=240, keyframe_step=10, keyframes_only=True)
    config = load_config(None, {"camera.fx": 262.5, "camera.fy": 262.5, "camera.cx": 159.5, "camera.cy": 119.5})
    sequence, poses, truth = tmp_path / "sequence", tmp_path / "sequence" / "groundtruth.txt", tmp_path / "sequence" / "ground_truth"
    both = run_cvat2mask(sequence, [keyframes], tmp_path / "both", config, poses=poses)
    assert any(k.beyond for lift in both.propagation.lifts.values() for k in lift.keyframes)
    # The outlines carried past the border, on their own: without growing past the shapes.
    monkeypatch.setattr(segment, "grow_connected", lambda labels, *args: (labels.copy(), {}))
    run_cvat2mask(sequence, [keyframes], tmp_path / "beyond", config, poses=poses)
    cut = load_config(None, {"camera.fx": 262.5, "camera.fy": 262.5, "camera.cx": 159.5, "camera.cy": 119.5,
                             "propagate.beyond_reach": 0.0})
    run_cvat2mask(sequence, [keyframes], tmp_path / "cut", cut, poses=poses)
    with_beyond, without = _mean_iou(tmp_path / "beyond", truth), _mean_iou(tmp_path / "cut", truth)
    # The contact scene: 0.900 with the outlines carried past the border, 0.896 without them.
    assert with_beyond > without + 0.002, (with_beyond, without)
    # Growing over the plane past every keyframe's view adds to that.
    assert _mean_iou(tmp_path / "both", truth) > with_beyond, with_beyond


def test_a_track_whose_keyframes_disagree_holds_no_frame_to_its_plane(rendered, tmp_path):
    # The floor's keyframe at STEP moved onto the table top: the floor's track is listed for
    # review, and on the frames between keyframes its shape gets no expected plane (the frame's
    # own depth decides), while the table's still does.
    from annotate_rgbd.pipeline.plan import plan_run

    annotation = read_cvat(rendered["keyframes"])
    by_label = {t.label: t for t in annotation.tracks}
    floor, table = by_label["floor"], by_label["table_top"]
    floor.shapes[STEP] = replace(table.shapes[STEP], z_order=10)
    export = tmp_path / "wrong.xml"
    write_cvat_video(annotation, export, width=320, height=240, keyframe_step=STEP, keyframes_only=True)
    plan = plan_run(rendered["sequence"], [export], tmp_path / "out", load_config(rendered["config"]),
                    poses=rendered["poses"])
    lifts = {lift.track: lift for lift in plan.propagation.lifts.values()}
    assert not lifts[floor.track_id].consistent and lifts[table.track_id].consistent
    plane_of = {t.track: t.plane for t in plan.tracks}
    carried = [job for _, job in plan.jobs if job.propagated]
    assert carried
    expected = {plane for job in carried for plane, _ in job.expected_planes}
    assert plane_of[table.track_id] in expected and plane_of[floor.track_id] not in expected
    assert any(plane_of[floor.track_id] in job.propagated for job in carried)

"""The real-data benchmark's arithmetic (benchmarks/bench_real.py and its real_losses.py), on made-up
kit results and runs."""

import importlib.util
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from annotate_rgbd.errors import InputError

SCRIPT = Path(__file__).resolve().parent.parent / "benchmarks" / "bench_real.py"


@pytest.fixture(scope="module")
def bench_real():
    spec = importlib.util.spec_from_file_location("bench_real", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def losses():
    """benchmarks/real_losses.py, the analyses bench_real.py imports."""
    spec = importlib.util.spec_from_file_location("real_losses", SCRIPT.parent / "real_losses.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _result(planes: dict) -> dict:
    """A kit ``evaluate.py --json`` result holding only what the deficit reads."""
    return {"planes": {plane: {"name": name, "frames": frames, "mean_iou": iou}
                       for plane, (name, frames, iou) in planes.items()}}


DENSE = _result({"1": ("floor", 100, 0.90), "2": ("desk", 400, 0.95), "3": ("wall", 50, 0.80), "4": ("door", 10, 0.9)})
SPARSE = _result({"1": ("floor", 100, 0.70), "2": ("desk", 400, 0.85), "3": ("wall", 50, 0.85)})


def test_plane_deficits_weigh_each_plane_by_its_frames(bench_real):
    rows = bench_real.plane_deficits(SPARSE, DENSE)
    # Lost: floor 100 x 0.20 = 20, desk 400 x 0.10 = 40; the wall gained and the door is absent.
    assert [row[1] for row in rows] == ["desk", "floor"]
    assert rows[0][2:5] == (400, 0.95, 0.85)
    assert [row[5] for row in rows] == pytest.approx([40 / 60, 20 / 60])


def test_deficit_lines_compare_each_posed_row_with_the_dense_row(bench_real):
    results = {"full_pose": DENSE, "every10_pose": SPARSE, "every30_nopose": SPARSE}
    lines = bench_real.deficit_lines(results, top=1)
    assert lines == ["  every 10th frame: desk 67% (0.85 against 0.95 on 400 frames)"]
    assert bench_real.deficit_lines({"every10_pose": SPARSE}) == []  # no dense row: nothing to compare


def _run_folder(tmp_path, name: str, labels: np.ndarray, carried: list) -> Path:
    """A finished cvat2mask output folder whose masks are ``labels`` (plane ids) on each frame and
    whose shapes record says the poses carried ``carried`` to each."""
    from annotate_rgbd.report.run_folder import colour_table, read_report, write_drawn_shapes

    folder = tmp_path / name
    shutil.copytree(tmp_path / "base", folder)
    keys, ids = colour_table(read_report(folder))
    colours = np.zeros((int(ids.max()) + 1, 3), np.uint8)
    for key, plane in zip(keys.tolist(), ids.tolist()):
        colours[plane] = (key & 0xFF, key >> 8 & 0xFF, key >> 16)  # BGR, as OpenCV writes
    masks = sorted(p.name for p in (folder / "masks").glob("*.png"))
    for mask in masks:
        cv2.imwrite(str(folder / "masks" / mask), colours[labels])
    write_drawn_shapes(folder, [(f"masks/{mask}", [], carried) for mask in masks])
    return folder


def _box(x0, y0, x1, y1) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)


def test_excluded_misses_counts_what_a_keyframe_left_out(bench_real, losses, tmp_path):
    """Made-up runs on a 320 x 240 grid, two frames alike. Ground truth: plane 7 on rows 0-99,
    plane 9 on rows 100-139, "don't care" below. Dense run: plane 1 on rows 0-89, plane 2 on rows
    90-199 (most of it on "don't care", then on plane 9: it stands for plane 9). Posed run: plane 1
    on rows 0-49 and plane 3 on rows 60-69, plane 2 on rows 120-199; its keyframes left rows
    50-79 and, in a second entry of the same plane, rows 80-84 out of plane 1, and rows 95-119 out
    of plane 2."""
    from annotate_rgbd.pipeline.scene import run_cvat2mask
    from annotate_rgbd.synthetic import make_sequence
    from annotate_rgbd.cvat import write_cvat_video
    from annotate_rgbd.config.settings import load_config
    from annotate_rgbd.geometry.camera import Camera

    camera = Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, depth_scale=5000.0)
    annotation = make_sequence(tmp_path / "sequence", n_frames=2, width=320, height=240, camera=camera, seed=5,
                               dropped_rgb_frames=())
    write_cvat_video(annotation, tmp_path / "export.xml", width=320, height=240)
    config = load_config(None, {"camera.fx": 262.5, "camera.fy": 262.5, "camera.cx": 159.5, "camera.cy": 119.5})
    run_cvat2mask(tmp_path / "sequence", [tmp_path / "export.xml"], tmp_path / "base", config)
    masks = sorted(p.name for p in (tmp_path / "base" / "masks").glob("*.png"))
    assert len(masks) == 2
    truth = np.full((240, 320), losses.GT_IGNORE, np.uint16)
    truth[:100] = 7
    truth[100:140] = 9
    (tmp_path / "gt").mkdir()
    for mask in masks:
        cv2.imwrite(str(tmp_path / "gt" / mask), truth)
    dense_labels = np.zeros((240, 320), np.intp)
    dense_labels[:90], dense_labels[90:200] = 1, 2
    run_labels = np.zeros((240, 320), np.intp)
    run_labels[:50], run_labels[60:70], run_labels[120:200] = 1, 3, 2
    first = ((1, _box(0, 0, 320, 50)), (-1, _box(0, 50, 320, 80)))
    second = ((-1, _box(0, 80, 320, 85)),)
    desk = ((-1, _box(0, 95, 320, 120)), (1, _box(0, 120, 320, 200)))
    dense = _run_folder(tmp_path, "dense", dense_labels, [])
    posed = _run_folder(tmp_path, "posed", run_labels, [(0, 1, 0, first, ()), (1, 1, 0, second, ()), (2, 2, 0, desk, ())])
    counts = losses.excluded_misses(tmp_path / "gt", posed, dense, inner_px=5)
    # Plane 1 (plane 7): missed rows 50-89 (plane 3's too), left out rows 50-84, deep rows 55-79
    # (the image's border does not count as the region's edge). Plane 2 (plane 9): missed rows
    # 100-119 (rows 90-99 are plane 7's), left out there all of them, deep rows 100-114.
    per_frame = {"missed": (40 + 20) * 320, "excluded": (35 + 20) * 320, "deep": (25 + 15) * 320}
    assert counts == {kind: 2 * count for kind, count in per_frame.items()}
    # A run without carried planes has nothing to count.
    assert losses.excluded_misses(tmp_path / "gt", dense, dense)["missed"] == 0
    # An image of another size than the ground truth: one clear error.
    cv2.imwrite(str(tmp_path / "gt" / masks[0]), truth[:100])
    with pytest.raises(InputError, match="not the size of the ground truth"):
        losses.excluded_misses(tmp_path / "gt", posed, dense)


def test_excluded_lines_read_only_the_rows_that_were_scored(bench_real, tmp_path):
    (tmp_path / "full_pose" / "masks").mkdir(parents=True)
    (tmp_path / "every10_pose" / "masks").mkdir(parents=True)
    # A dense row that is not among the results (a folder left from another invocation): none.
    assert bench_real.excluded_lines(tmp_path, tmp_path, {"every10_pose": {"mean_iou": 0.9}}) == []
    # A row that failed is not read.
    failed = {"full_pose": {"mean_iou": 0.9, "returncode": 0}, "every10_pose": {"mean_iou": 0.8, "returncode": 1}}
    assert bench_real.excluded_lines(tmp_path, tmp_path, failed) == []
    # A scored row whose folder cannot be read: one line says so.
    results = {"full_pose": {"mean_iou": 0.9, "returncode": 0}, "every10_pose": {"mean_iou": 0.8}}
    lines = bench_real.excluded_lines(tmp_path, tmp_path, results)
    assert len(lines) == 1 and lines[0].startswith("  every 10th frame: not measured (") and "report" in lines[0]


def test_pair_ious_match_each_ground_truth_plane_with_the_run_plane_that_overlaps_it_most(bench_real, losses):
    truth = np.full((10, 10), losses.GT_IGNORE, np.int64)
    truth[:4], truth[4:6], truth[6:7] = 7, 9, 0
    labels = np.zeros((10, 10), np.intp)
    labels[:3], labels[3:5, :5], labels[3:5, 5:] = 1, 2, 3
    labels[8:] = 2  # on "don't care": not counted
    # Plane 7 (40 px): plane 1 holds 30 of it (IoU 30 / 40); plane 9 (20 px): planes 2 and 3 hold
    # 5 each, the lower id wins: 5 of 10 known pixels of plane 2 -> 5 / (10 + 20 - 5).
    found = losses.pair_ious(truth, labels, min_pixels=1)
    assert found == {7: (1, 0.75), 9: (2, 0.2)}
    assert losses.pair_ious(truth, labels, min_pixels=21) == {7: (1, 0.75)}
    assert losses.pair_ious(truth, np.zeros_like(labels), min_pixels=1) == {7: (0, 0.0), 9: (0, 0.0)}


def test_review_scores_count_the_listed_carried_planes_that_lose_against_the_dense_row(bench_real, losses, tmp_path):
    """The runs of the test above, with planes 1 and 2 carried on both frames: plane 1 (for plane 7)
    loses 0.4 IoU against the dense row and its keyframes agree 0.2 (listed), plane 2 (for plane 9)
    gains and its keyframes agree 0.9 (not listed)."""
    import json

    test_excluded_misses_counts_what_a_keyframe_left_out(bench_real, losses, tmp_path)
    run_labels = np.zeros((240, 320), np.intp)
    run_labels[:50], run_labels[60:70], run_labels[100:200] = 1, 3, 2
    posed = _run_folder(tmp_path, "posed_again", run_labels, [])
    first, second = sorted(p.name for p in (posed / "masks").glob("*.png"))
    shutil.copy(tmp_path / "gt" / second, tmp_path / "gt" / first)  # the test above cut the first one short
    report = json.loads((posed / "report.json").read_text())
    for frame in report["frames"]:
        if frame["status"] == "written":
            kept = {record["plane"]: record for record in frame["kept"]}
            template = next(iter(kept.values()))
            frame["kept"] = [{**template, "plane": plane, "propagated": plane in (1, 2)} for plane in (1, 2, 3)]
            frame["keyframes_agree"] = {"1": 0.2, "2": 0.9}
    (posed / "report.json").write_text(json.dumps(report))
    scores = losses.review_scores(tmp_path / "gt", posed, tmp_path / "dense")
    assert scores == {"carried": 4, "bad": 2, "listed": 2, "listed_bad": 2, "loss": pytest.approx(0.8),
                      "listed_loss": pytest.approx(0.8), "auc": 1.0}
    assert bench_real.review_lines(tmp_path / "gt", tmp_path, {"every10_pose": {"mean_iou": 0.8}}) == []


def _fake_scene(tmp_path):
    """A kit and a scene with the files bench_real.py looks for (their contents never read: the
    scripts are not run)."""
    kit, scene = tmp_path / "kit", tmp_path / "scene"
    for path in (kit / "evaluate.py", kit / "thin_keyframes.py", scene / "seq" / "camera.toml",
                 scene / "seq" / "groundtruth.txt", scene / "eval" / "gt_strict" / "planes.json", scene / "eval" / "full.xml"):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("")
    return kit, scene


def test_a_trajectory_that_is_not_there_is_a_usage_error(bench_real, tmp_path, monkeypatch, capsys):
    """``--trajectory`` (the runs with poses read another trajectory, e.g. the kit's refined
    poses) must exist: a typo stops the benchmark as a bad option does (status 2), before anything runs."""
    kit, scene = _fake_scene(tmp_path)
    out, missing = tmp_path / "out", scene / "gt_work" / "poses_2.txt"
    monkeypatch.setattr("sys.argv", ["bench_real.py", str(scene), "--kit", str(kit), "--out", str(out),
                                     "--trajectory", str(missing)])
    with pytest.raises(SystemExit) as stopped:
        bench_real.main()
    assert stopped.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith(f"error: --trajectory {missing}: no such file")
    assert not out.exists()


def test_the_runs_with_poses_read_the_trajectory_given_and_record_it(bench_real, tmp_path, monkeypatch):
    """The runs with poses get ``--poses`` the trajectory given (the others none), their scores
    name it, and ``--reuse`` keeps only scores of the same trajectory."""
    import json
    import subprocess
    from types import SimpleNamespace

    kit, scene = _fake_scene(tmp_path)
    refined = scene / "gt_work" / "poses_2.txt"
    refined.parent.mkdir()
    refined.write_text("")
    tool_runs = []

    def fake_run(command, **kwargs):
        if str(command[1]).endswith("thin_keyframes.py"):
            return SimpleNamespace(returncode=0, stdout="polygons drawn: 12\n", stderr="")
        if str(command[1]).endswith("evaluate.py"):
            return SimpleNamespace(returncode=0, stdout=json.dumps({"mean_iou": 0.5, "precision": 0.6, "recall": 0.7, "leak": 0.01, "planes": {}}), stderr="")
        tool_runs.append([str(part) for part in command])
        return SimpleNamespace(returncode=0, stdout="", stderr="")

    monkeypatch.setattr(subprocess, "run", fake_run)
    out = tmp_path / "out"
    base = ["bench_real.py", str(scene), "--kit", str(kit), "--out", str(out), "--variants", "every10"]
    monkeypatch.setattr("sys.argv", [*base, "--trajectory", str(refined)])
    bench_real.main()
    poses = [run[run.index("--poses") + 1] if "--poses" in run else None for run in tool_runs]
    assert poses == [None, str(refined.resolve())]
    assert json.loads((out / "every10_pose.json").read_text())["trajectory"] == str(refined.resolve())
    assert json.loads((out / "every10_nopose.json").read_text())["trajectory"] is None
    # Reused: the runs of the same trajectory; the motion capture's runs again (its scores would differ).
    tool_runs.clear()
    monkeypatch.setattr("sys.argv", [*base, "--trajectory", str(refined), "--reuse"])
    bench_real.main()
    assert tool_runs == []
    monkeypatch.setattr("sys.argv", [*base, "--reuse"])
    bench_real.main()
    assert [run[run.index("--poses") + 1] for run in tool_runs] == [str((scene / "seq" / "groundtruth.txt").resolve())]

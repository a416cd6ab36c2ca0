"""End to end on sample_data: the masks against the renderer's exact ground truth."""

from __future__ import annotations

import csv
import json
import logging
import re
import shutil
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.config.settings import load_config
from annotate_rgbd.pipeline.execute import FrameCounts
from annotate_rgbd.pipeline.scene import run_cvat2mask

from builders import error_line
from conftest import SAMPLE_DATA

SEQUENCE = SAMPLE_DATA / "sequence"
ANNOTATIONS = SAMPLE_DATA / "annotations.xml"
GROUND_TRUTH = SAMPLE_DATA / "ground_truth"


def read_mask_ids(path, colour_to_plane):
    image = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
    packed = (image[..., 0].astype(np.int64) << 16) | (image[..., 1].astype(np.int64) << 8) | image[..., 2]
    ids = np.zeros(packed.shape, np.int64)
    for colour, plane in colour_to_plane.items():
        ids[packed == colour] = plane
    assert np.all((ids > 0) | (packed == 0)), "a colour that is in no plane of planes.csv"
    return ids


def planes_table(out):
    with open(out / "planes.csv", newline="") as handle:
        return list(csv.DictReader(handle))


def test_masks_match_the_ground_truth(sample_run):
    out, report = sample_run
    truth = json.loads((GROUND_TRUTH / "planes.json").read_text())
    gt_value_of_track = {p["track_id"]: p["gt_value"] for p in truth["planes"]}
    kept_values = {p["gt_value"] for p in truth["planes"] if p["expected"] == "kept"}
    rows = planes_table(out)
    colour_to_plane = {(int(r["r"]) << 16) | (int(r["g"]) << 8) | int(r["b"]): int(r["plane_id"]) for r in rows}
    gt_of_plane = {int(r["plane_id"]): gt_value_of_track[int(r["track_id"])] for r in rows}

    ious, wrong, checked = [], 0, 0
    written = [f for f in report.frames if f.written]
    assert len(written) == 19
    for frame in written:
        ours = read_mask_ids(out / frame.mask, colour_to_plane)
        gt = cv2.imread(str(GROUND_TRUTH / (frame.mask.split("/")[-1])), cv2.IMREAD_UNCHANGED).astype(np.int64)
        ours_as_gt = np.vectorize(lambda p: gt_of_plane.get(p, 0))(ours) if ours.any() else ours
        for value in kept_values & set(np.unique(gt).tolist()):
            a, b = ours_as_gt == value, gt == value
            ious.append((a & b).sum() / (a | b).sum())
        # Clutter, missing depth, background and the planes that must be dropped.
        should_be_empty = ~np.isin(gt, list(kept_values))
        wrong += int((should_be_empty & (ours > 0)).sum())
        checked += int(should_be_empty.sum())
    assert np.mean(ious) >= 0.95
    assert wrong / checked < 0.01


def test_far_and_glass_planes_are_dropped_with_their_reason(sample_run):
    out, report = sample_run
    truth = json.loads((GROUND_TRUTH / "planes.json").read_text())
    rows = {int(r["track_id"]): int(r["plane_id"]) for r in planes_table(out)}
    expected_drop = {rows[p["track_id"]]: p["reason"] for p in truth["planes"] if p["expected"] == "dropped"}
    assert set(expected_drop.values()) == {"too_far", "invalid_depth"}
    for frame in (f for f in report.frames if f.written):
        dropped = {d.plane: d.reason for d in frame.dropped}
        kept = {k.plane for k in frame.kept}
        for plane, reason in expected_drop.items():
            assert plane not in kept
            if plane in dropped:
                assert dropped[plane] == reason


def test_one_colour_per_plane_through_the_sequence(sample_run):
    out, report = sample_run
    truth = json.loads((GROUND_TRUTH / "planes.json").read_text())
    rows = planes_table(out)
    assert len({r["colour"] for r in rows}) == len(rows) == len(truth["planes"])
    colour_to_plane = {(int(r["r"]) << 16) | (int(r["g"]) << 8) | int(r["b"]): int(r["plane_id"]) for r in rows}
    gt_of_plane = {int(r["plane_id"]): int(r["track_id"]) + 1 for r in rows}
    for frame in (f for f in report.frames if f.written):
        ours = read_mask_ids(out / frame.mask, colour_to_plane)
        gt = cv2.imread(str(GROUND_TRUTH / frame.mask.split("/")[-1]), cv2.IMREAD_UNCHANGED)
        for plane in set(np.unique(ours).tolist()) - {0}:
            values, counts = np.unique(gt[ours == plane], return_counts=True)
            assert values[np.argmax(counts)] == gt_of_plane[plane]  # the same physical plane every frame


def test_report_lists_every_depth_frame(sample_run):
    out, report = sample_run
    data = json.loads((out / "report.json").read_text())
    depth_files = [line.split()[1] for line in (SEQUENCE / "depth.txt").read_text().splitlines() if not line.startswith("#")]
    assert [f["depth"] for f in data["frames"]] == depth_files
    skipped = [f for f in data["frames"] if f["status"] == "skipped"]
    assert [f["reason"] for f in skipped] == ["no_rgb_frame_within_max_time_diff"]
    for frame in (f for f in data["frames"] if f["status"] == "written"):
        assert abs(frame["time_offset"]) <= 0.02
        for kept in frame["kept"]:
            assert kept["inliers"] <= kept["valid_pixels"] <= kept["pixels"]
            assert len(kept["equation"]) == 4
    assert data["summary"]["masks_written"] == 19


def test_cli_rerun_parallel_gives_identical_files(sample_run, tmp_path):
    out, _ = sample_run
    runner = CliRunner()
    args = ["cvat2mask", str(SEQUENCE), str(ANNOTATIONS), "--config", str(SAMPLE_DATA / "camera.toml")]
    result = runner.invoke(app, args + ["--out", str(tmp_path / "again"), "--jobs", "2"])
    assert result.exit_code == 0, result.output
    assert "19 masks" in result.output
    for name in ["planes.csv", "tracks.csv", "report.json", *(f"masks/{p.name}" for p in (out / "masks").iterdir())]:
        assert (tmp_path / "again" / name).read_bytes() == (out / name).read_bytes(), name


def test_rerun_redoes_only_changed_frames(tmp_path):
    seq = tmp_path / "sequence"
    shutil.copytree(SEQUENCE, seq)
    config = load_config(SAMPLE_DATA / "camera.toml")
    first = run_cvat2mask(seq, [ANNOTATIONS], tmp_path / "out", config)
    assert first.counts == FrameCounts(made=19, reused=0, failed=0)
    before = {p.name: p.read_bytes() for p in (tmp_path / "out" / "masks").iterdir()}
    again = run_cvat2mask(seq, [ANNOTATIONS], tmp_path / "out", config)
    assert again.counts == FrameCounts(made=0, reused=19, failed=0)
    # The command's summary line says so (the CLI prints SceneResult.summary()).
    out = tmp_path / "out"
    assert first.summary() == (
        f"19 masks in {out / 'masks'} (19 made, 0 unchanged), 10 planes (8 in the masks), 1 frame skipped, "
        f"29 of 146 planes drawn on frames dropped (too far 19, no depth 10), 1 warning (see {out / 'report.json'})")
    assert again.summary().startswith(f"19 masks in {out / 'masks'} (0 made, 19 unchanged), ")
    assert first.drop_hint() is None
    # A depth image changes: that frame only is made again.
    depth_file = next(f for f in first.frames if f.written).depth
    depth = cv2.imread(str(seq / depth_file), cv2.IMREAD_UNCHANGED)
    depth[:20] = 0
    cv2.imwrite(str(seq / depth_file), depth)
    third = run_cvat2mask(seq, [ANNOTATIONS], tmp_path / "out", config)
    assert third.counts == FrameCounts(made=1, reused=18, failed=0)
    # A mask is deleted: that frame only is made again, with the same bytes.
    lost = tmp_path / "out" / "masks" / Path(depth_file).name
    kept_bytes = lost.read_bytes()
    lost.unlink()
    fourth = run_cvat2mask(seq, [ANNOTATIONS], tmp_path / "out", config, workers=2)
    assert fourth.counts == FrameCounts(made=1, reused=18, failed=0)
    assert lost.read_bytes() == kept_bytes
    forced = run_cvat2mask(seq, [ANNOTATIONS], tmp_path / "out", config, force=True)
    assert forced.counts == FrameCounts(made=19, reused=0, failed=0)
    after = {p.name: p.read_bytes() for p in (tmp_path / "out" / "masks").iterdir()}
    assert sum(before[name] != after[name] for name in before) == 1


def test_errors_raised_in_worker_processes_stay_one_line(tmp_path):
    # The annotation is for 320x240 images; a 640x480 depth image is a fatal size mismatch,
    # raised inside a worker process and carried back pickled.
    sequence = tmp_path / "sequence"
    shutil.copytree(SEQUENCE, sequence)
    for path in sorted((sequence / "depth").iterdir())[1:]:  # the first frame is checked before the run
        cv2.imwrite(str(path), cv2.resize(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), (640, 480)))
    result = CliRunner().invoke(
        app, ["cvat2mask", str(sequence), str(ANNOTATIONS), "--out", str(tmp_path / "out"), "--jobs", "2",
              "--config", str(SAMPLE_DATA / "camera.toml")]
    )
    assert result.exit_code == 1
    last = result.output.strip().splitlines()[-1]
    assert last.startswith(f"error: {sequence}/depth/") and "depth image is 640x480 but annotations.xml annotates 320x240" in last
    assert "Traceback" not in result.output


def test_a_size_mismatch_is_found_before_the_run_starts(tmp_path):
    sequence = tmp_path / "sequence"
    shutil.copytree(SEQUENCE, sequence)
    for path in (sequence / "depth").iterdir():
        cv2.imwrite(str(path), cv2.resize(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), (640, 480)))
    out = tmp_path / "out"
    result = CliRunner().invoke(
        app, ["cvat2mask", str(sequence), str(ANNOTATIONS), "--out", str(out), "--jobs", "2",
              "--config", str(SAMPLE_DATA / "camera.toml")]
    )
    assert result.exit_code == 1
    # One line: no per-frame warning before it (the sample's skipped 11th frame has one), no
    # progress line, and nothing in the output folder (no journal).
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "depth image is 640x480 but annotations.xml annotates 320x240" in lines[0], lines
    assert not out.exists() or not any(out.iterdir())


def test_a_rerun_removes_outputs_it_did_not_make_and_leaves_the_users_files(tmp_path, caplog):
    config = load_config(SAMPLE_DATA / "camera.toml")
    run_cvat2mask(SEQUENCE, [ANNOTATIONS], tmp_path, config, raw_masks=True)
    (tmp_path / "review.html").write_text("the user's own page")
    (tmp_path / "masks" / "old_frame.png").write_bytes(b"the user's own file")
    with caplog.at_level(logging.INFO, logger="annotate_rgbd"):
        report = run_cvat2mask(SEQUENCE, [ANNOTATIONS], tmp_path, config)
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        ".annotate-rgbd-outputs.json", ".annotate-rgbd-shapes.jsonl",  # the run's records
        "masks", "planes.csv", "report.json", "review.html", "tracks.csv",
    ]
    assert len(list((tmp_path / "masks").iterdir())) == 20 and (tmp_path / "masks" / "old_frame.png").is_file()
    assert "removed 19 raw masks no longer asked for (masks_raw/)" in caplog.text
    assert ("left alone 2 file(s) in the output folder that annotate-rgbd did not write: masks/old_frame.png, "
            "review.html") in report.warnings


def test_an_unknown_label_is_a_warning(tmp_path):
    config = load_config(SAMPLE_DATA / "camera.toml", {"annotation.labels": ["floor", "ceiling"]})
    report = run_cvat2mask(SEQUENCE, [ANNOTATIONS], tmp_path, config)
    assert ("no shape in the exports has the label 'ceiling' (--label / [annotation] labels); their labels: cabinet_front, "
            "cabinet_side, cabinet_top, floor, table_top, wall_back, wall_corridor, wall_left, wall_right, window") in report.warnings
    assert report.n_planes == 1


def test_labels_that_match_no_shape_are_an_error(tmp_path):
    result = CliRunner().invoke(app, ["cvat2mask", str(SEQUENCE), str(ANNOTATIONS), "--out", str(tmp_path / "out"),
                                      "--config", str(SAMPLE_DATA / "camera.toml"), "--label", "Plane"])
    assert result.exit_code == 1 and result.output.count("error:") == 1 and "Traceback" not in result.output
    assert "no shape has the label 'Plane'" in result.output and "the exports' labels: cabinet_front" in result.output
    assert not (tmp_path / "out").exists()


def test_cvat2mask_exits_1_when_a_frame_failed_after_writing_every_other_mask(tmp_path):
    seq = tmp_path / "sequence"
    shutil.copytree(SEQUENCE, seq)
    depth_files = sorted((seq / "depth").iterdir())
    broken = depth_files[3]
    cv2.imwrite(str(broken), (cv2.imread(str(broken), cv2.IMREAD_UNCHANGED) // 256).astype(np.uint8))  # an 8-bit preview
    result = CliRunner().invoke(app, ["cvat2mask", str(seq), str(ANNOTATIONS), "--config", str(SAMPLE_DATA / "camera.toml"),
                                      "--out", str(tmp_path / "out")])
    assert result.exit_code == 1
    assert "18 masks in" in result.output and "1 frame failed" in result.output
    assert f"  failed: {broken}: " in result.output
    assert len(list((tmp_path / "out" / "masks").iterdir())) == 18
    assert json.loads((tmp_path / "out" / "report.json").read_text())["summary"]["frames_failed"] == 1


def test_overlays_say_where_the_review_page_is(tmp_path):
    result = CliRunner().invoke(app, ["cvat2mask", str(SEQUENCE), str(ANNOTATIONS), "--config",
                                      str(SAMPLE_DATA / "camera.toml"), "--out", str(tmp_path / "out"), "--overlays"])
    assert result.exit_code == 0, result.output
    assert result.stdout.splitlines()[-1] == f"review page: {tmp_path / 'out' / 'review.html'}"  # the last line


def test_instance_id_masks_hold_the_plane_ids_of_planes_csv(tmp_path):
    out = tmp_path / "out"
    result = CliRunner().invoke(
        app, ["cvat2mask", str(SEQUENCE), str(ANNOTATIONS), "--out", str(out), "--jobs", "1",
              "--config", str(SAMPLE_DATA / "camera.toml"), "--instance-ids"]
    )
    assert result.exit_code == 0, result.output
    with open(out / "planes.csv", newline="") as handle:
        colour_of = {int(row["plane_id"]): (int(row["r"]), int(row["g"]), int(row["b"])) for row in csv.DictReader(handle)}
    masks = sorted((out / "masks").iterdir())
    assert [p.name for p in sorted((out / "masks_id").iterdir())] == [p.name for p in masks] and len(masks) == 19
    for path in masks:
        ids = cv2.imread(str(out / "masks_id" / path.name), cv2.IMREAD_UNCHANGED)
        colours = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
        assert ids.dtype == np.uint8 and ids.shape == colours.shape[:2]
        # Independently: the colour mask read back through planes.csv gives the same ids.
        expected = np.zeros(ids.shape, np.uint8)
        for plane, rgb in colour_of.items():
            expected[(colours == rgb).all(axis=2)] = plane
        assert np.array_equal(ids, expected)
    assert any(cv2.imread(str(p), cv2.IMREAD_UNCHANGED).max() > 0 for p in (out / "masks_id").iterdir())
    # Recorded like the other outputs: a run without the option removes them, and says so.
    again = CliRunner().invoke(app, ["cvat2mask", str(SEQUENCE), str(ANNOTATIONS), "--out", str(out), "--jobs", "1",
                                     "--config", str(SAMPLE_DATA / "camera.toml")])
    assert again.exit_code == 0 and "removed 19 instance-id masks no longer asked for (masks_id/)" in again.output
    assert not (out / "masks_id").exists()


def test_the_summary_counts_the_planes_not_the_highest_plane_id(tmp_path):
    # The first track carries plane_id 7 (a labeller deleted the planes before it in CVAT): the
    # nine others get ids 8-16, so the ids reach 16, but the run has 10 planes, as planes.csv.
    text = ANNOTATIONS.read_text(encoding="utf-8")
    first = text.index('<track id="0"')
    end = text.index("</track>", first)
    track = re.sub(r'(<polygon [^>]*?)\s*/>', r'\1><attribute name="plane_id">7</attribute></polygon>', text[first:end])
    export = tmp_path / "ids.xml"
    export.write_text(text[:first] + track + text[end:], encoding="utf-8")
    result = CliRunner().invoke(app, ["cvat2mask", str(SEQUENCE), str(export), "--config", str(SAMPLE_DATA / "camera.toml"),
                                      "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    with open(tmp_path / "out" / "planes.csv", newline="", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 10 and max(int(row["plane_id"]) for row in rows) == 16
    # ... and says how many of them are in a mask when not all are (the sample's far wall and its
    # window are dropped on every frame, by design).
    report = json.loads((tmp_path / "out" / "report.json").read_text(encoding="utf-8"))
    in_masks = {plane["plane"] for frame in report["frames"] for plane in frame.get("kept", [])}
    assert len(in_masks) == 8
    assert "10 planes (8 in the masks)," in result.output
    # The drop reasons, as the report counts them, in words.
    reasons = Counter(plane["reason"] for frame in report["frames"] for plane in frame.get("dropped", []))
    assert reasons == {"too_far": 19, "invalid_depth": 10}
    assert "29 of 146 planes drawn on frames dropped (too far 19, no depth 10)," in result.output


def test_no_depth_frame_near_an_rgb_frame_is_one_error_and_writes_nothing(tmp_path):
    # sequence.max_time_diff = 0 on the sample (its pairs are 5-26 ms apart): every frame would
    # be skipped. Not 20 warnings and an empty run with exit 0: one line, with the gaps there are.
    out = tmp_path / "out"
    args = ["cvat2mask", str(SEQUENCE), str(ANNOTATIONS), "--config", str(SAMPLE_DATA / "camera.toml"), "--out", str(out)]
    result = CliRunner().invoke(app, args + ["--max-time-diff", "0"])
    assert result.exit_code == 1
    assert error_line(result) == (f"error: {SEQUENCE}: no depth frame has an RGB frame within 0 s "
                                  "(sequence.max_time_diff): each is 0.005023 to 0.02591 s from the nearest (median "
                                  "0.008071 s)")
    assert "warning:" not in result.stderr and not out.exists()
    # Some frames: one warning line for all of them.
    some = CliRunner().invoke(app, args + ["--max-time-diff", "0.008", "--jobs", "1"])
    assert some.exit_code == 0, some.output
    warnings = [line for line in some.stderr.splitlines() if line.startswith("warning:")]
    assert warnings == [f"warning: {SEQUENCE / 'depth'}/1700000000.044158.png, {SEQUENCE / 'depth'}/1700000000.075739.png, "
                        f"{SEQUENCE / 'depth'}/1700000000.108053.png and 8 more: no RGB frame within 0.008 s; skipped"]
    assert "11 frames skipped" in some.stdout


def test_a_job_timeout_that_is_not_a_number_of_seconds_is_one_error(tmp_path):
    # NaN passes the option's own minimum (every comparison with it is false) and would then never
    # take a hung helper for hung; both commands that take it refuse it, and write nothing.
    out = tmp_path / "out"
    cvat = ["cvat2mask", str(SEQUENCE), str(ANNOTATIONS), "--config", str(SAMPLE_DATA / "camera.toml"), "--out", str(out)]
    manifest = tmp_path / "scenes.toml"
    manifest.write_text(f'[[scene]]\nsequence = "{SEQUENCE}"\nannotations = ["{ANNOTATIONS}"]\n'
                        f'config = "{SAMPLE_DATA / "camera.toml"}"\nout = "{out}"\n', encoding="utf-8")
    for args in (cvat, ["batch", str(manifest)]):
        result = CliRunner().invoke(app, args + ["--job-timeout", "nan"])
        assert result.exit_code == 2, result.output  # out of the option's range, as --job-timeout 0 is
        assert error_line(result).startswith(
            "error: Invalid value for '--job-timeout': must be a number of seconds >= 1 (inf: wait for ever), not nan (see ")
        assert not out.exists()
    # inf stays what the help says: wait for ever (the option's check lets it through).
    from annotate_rgbd.cli.options import seconds

    assert seconds(float("inf")) == float("inf") and seconds(1.0) == 1.0

"""Run summary: EVOPS dataset-table numbers, drops by reason, inlier ratio; the stats command."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.report.records import RecordError, RunRecord
from annotate_rgbd.report.stats import format_stats, merge_stats, run_stats


def _kept(plane: int, ratio: float) -> dict:
    return {"plane": plane, "pixels": 100, "valid_pixels": 100, "mean_distance": 1.0,
            "inliers": round(100 * ratio), "inlier_ratio": ratio, "equation": [0.0, 0.0, -1.0, 1.0]}


def _dropped(plane: int, reason: str) -> dict:
    return {"plane": plane, "pixels": 50, "valid_pixels": 5, "mean_distance": 4.0, "reason": reason}


def _frame(index: int, status: str, **entries) -> dict:
    frame = {"depth": f"d{index}.png", "depth_timestamp": float(index), "rgb": f"r{index}.png", "rgb_index": index,
             "time_offset": 0.0, "status": status}
    if status == "written":
        frame.update(fingerprint="0" * 64, mask=f"masks/d{index}.png")
    return {**frame, **entries}


REPORT = {
    "inputs": {"sequence": "seq", "parts": []},
    "config": {},
    "planes": [{"plane": k, "colour": "#000000", "label": f"p{k}", "part": "a.xml", "track_id": k} for k in (1, 2, 3, 4)],
    "frames": [
        _frame(0, "skipped", reason="outside_annotated_range"),
        _frame(1, "written", kept=[_kept(1, 0.9), _kept(2, 0.8)], dropped=[_dropped(3, "too_far")]),
        _frame(2, "written", kept=[_kept(1, 1.0)], dropped=[_dropped(3, "too_far"), _dropped(2, "invalid_depth")]),
        _frame(3, "written", kept=[], dropped=[]),
        _frame(4, "skipped", reason="no_rgb_frame_within_max_time_diff"),
        _frame(5, "skipped", reason="outside_annotated_range"),
    ],
}


def test_run_stats_counts_observations_planes_and_drops():
    stats = run_stats(RunRecord.from_json(REPORT))
    assert stats["observations"] == 3
    assert stats["total_planes"] == 3
    assert stats["planes_per_observation"] == 1.0
    assert stats["distinct_planes"] == 2  # plane 3 is never kept, plane 4 never drawn
    assert stats["planes_annotated"] == 4
    assert stats["depth_frames"] == 6
    assert stats["frames_skipped"] == {"no_rgb_frame_within_max_time_diff": 1, "outside_annotated_range": 2}
    assert stats["planes_dropped"] == 3
    assert stats["dropped_by_reason"] == {"invalid_depth": 1, "too_far": 2}
    assert stats["mean_inlier_ratio"] == 0.9


def test_frames_where_a_carried_plane_was_not_where_the_poses_put_it_are_listed_for_review():
    frames = [dict(f) for f in REPORT["frames"]]
    frames[2] = _frame(2, "written", kept=[_kept(1, 1.0)], dropped=[_dropped(2, "not_where_expected")])
    stats = run_stats(RunRecord.from_json({**REPORT, "frames": frames}))
    assert stats["frames_to_review"] == ["d2.png"]
    assert "frames to review (1: a carried plane not where the poses put it)  d2.png" in format_stats(stats)
    assert run_stats(RunRecord.from_json(REPORT))["frames_to_review"] == []
    from annotate_rgbd.report import stats as module
    from annotate_rgbd.segment.filters import NOT_WHERE_EXPECTED

    assert module.NOT_WHERE_EXPECTED == NOT_WHERE_EXPECTED


def test_frames_whose_pose_was_off_the_keyframes_depth_are_listed_poses_to_check():
    alignment = {"beyond_limits": [{"depth_frame": 2, "shift_cm": 7.1, "turn_deg": 0.4, "depth_timestamp": 2.0},
                                   {"depth_frame": 9, "shift_cm": 8.0, "turn_deg": 1.0, "depth_timestamp": 9.0}]}
    stats = run_stats(RunRecord.from_json({**REPORT, "propagation": {"alignment": alignment}}))
    assert stats["poses_to_check"] == ["d2.png"]  # 9.0 is no frame of the run
    assert ("poses to check (1: off the keyframes' depth beyond the alignment's limits, or not meeting it)  d2.png"
            in format_stats(stats))
    # ... and the frames whose depth did not meet the keyframes', in the frames' order.
    alignment["apart_from_keyframes"] = [{"depth_frame": 1, "met_share": 0.03, "depth_timestamp": 1.0}]
    stats = run_stats(RunRecord.from_json({**REPORT, "propagation": {"alignment": alignment}}))
    assert stats["poses_to_check"] == ["d1.png", "d2.png"]
    del alignment["apart_from_keyframes"]
    stats = run_stats(RunRecord.from_json({**REPORT, "propagation": {"alignment": alignment}}))
    assert run_stats(RunRecord.from_json(REPORT))["poses_to_check"] == []
    assert merge_stats([stats, stats], ["a", "b"])["poses_to_check"] == ["a:d2.png", "b:d2.png"]


def test_carried_planes_whose_keyframes_disagree_are_listed_worst_first():
    frames = [dict(f) for f in REPORT["frames"]]
    frames[1] = {**frames[1], "part": "a.xml", "cvat_frame": 11, "keyframes_agree": {"1": 0.2, "2": 0.7, "3": 0.1}}
    frames[2] = {**frames[2], "part": "a.xml", "cvat_frame": 12, "keyframes_agree": {"1": 0.05, "2": 0.09}}
    frames[3] = {**frames[3], "keyframes_agree": {"4": 0.0}}  # plane 4 is not in the frame's records
    stats = run_stats(RunRecord.from_json({**REPORT, "frames": frames}))
    # Plane 3 of d1 and plane 2 of d2 were dropped from the masks: not listed.
    assert [(c["depth"], c["plane"], c["keyframes_agree"]) for c in stats["carried_to_check"]] == [
        ("d2.png", 1, 0.05), ("d1.png", 1, 0.2)]
    assert {(c["part"], c["cvat_frame"]) for c in stats["carried_to_check"]} == {("a.xml", 11), ("a.xml", 12)}
    assert format_stats(stats).splitlines()[-1].split() == ["carried", "planes", "to", "check", "(2,", "worst", "first)",
                                                             "d2.png", "plane", "1", "(0.05),", "d1.png", "plane", "1", "(0.20)"]
    assert run_stats(RunRecord.from_json(REPORT))["carried_to_check"] == []
    assert "carried planes" not in format_stats(run_stats(RunRecord.from_json(REPORT)))
    # Read back as written; a layout that is not plane ids to numbers is an error naming the field.
    record = RunRecord.from_json({**REPORT, "frames": frames})
    assert record.frames[1].keyframes_agree == {1: 0.2, 2: 0.7, 3: 0.1}
    assert RunRecord.from_json(record.to_json()).frames[1].to_json() == record.frames[1].to_json()
    assert record.frames[1].to_json()["keyframes_agree"] == {"1": 0.2, "2": 0.7, "3": 0.1}
    for bad in ({"a": 0.1}, {"1": "x"}, [0.1], {"\u00b2": 0.1}):
        frames[1] = {**frames[1], "keyframes_agree": bad}
        with pytest.raises(RecordError, match="keyframes_agree"):
            RunRecord.from_json({**REPORT, "frames": frames})


def test_a_frames_camera_pose_reads_back_and_a_bad_one_is_an_error_naming_the_field():
    from annotate_rgbd.report.run_folder import camera_poses

    frames = [dict(f) for f in REPORT["frames"]]
    turn = 0.3  # about the y axis: x goes to -z
    frames[1] = {**frames[1], "camera_pose": [1.0, 2.0, 3.0, 0.0, np.sin(turn / 2), 0.0, np.cos(turn / 2)]}
    record = RunRecord.from_json({**REPORT, "frames": frames})
    rotation, centre = record.frames[1].rotation_translation()
    np.testing.assert_allclose(rotation, [[np.cos(turn), 0, np.sin(turn)], [0, 1, 0], [-np.sin(turn), 0, np.cos(turn)]],
                               atol=1e-12)
    np.testing.assert_array_equal(centre, [1.0, 2.0, 3.0])
    assert record.frames[0].camera_pose is None and record.frames[0].rotation_translation() is None
    assert RunRecord.from_json(record.to_json()).frames[1].to_json() == record.frames[1].to_json()
    poses = camera_poses(record.frames)
    assert poses.ok.tolist() == [k == 1 for k in range(len(frames))]
    np.testing.assert_array_equal(poses.rotations[1], rotation)
    assert np.isnan(poses.translations[0]).all()
    # A pose copied from a trajectory file with 4 decimals is a unit quaternion to 2e-5: read, and normalised.
    frames[1] = {**frames[1], "camera_pose": [0, 0, 0, -0.6793, -0.5448, 0.0036, 0.4917]}
    rotation = RunRecord.from_json({**REPORT, "frames": frames}).frames[1].rotation_translation()[0]
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    for bad in ([1.0, 2.0, 3.0], [0, 0, 0, 0, 0, 0, 2.0], [0, 0, 0, 0, 0, 0, 1.01], [0, 0, 0, "x", 0, 0, 1], "ok",
                [float("nan"), 0, 0, 0, 0, 0, 1]):
        frames[1] = {**frames[1], "camera_pose": bad}
        with pytest.raises(RecordError, match="camera_pose"):
            RunRecord.from_json({**REPORT, "frames": frames})


def test_merged_stats_list_the_carried_planes_to_check_of_all_runs_worst_first():
    from annotate_rgbd.report.stats import merge_stats

    frames = [dict(f) for f in REPORT["frames"]]
    frames[1] = {**frames[1], "keyframes_agree": {"1": 0.3}}
    first = run_stats(RunRecord.from_json({**REPORT, "frames": frames}))
    frames[1] = {**frames[1], "keyframes_agree": {"2": 0.1, "1": 0.3}}
    second = run_stats(RunRecord.from_json({**REPORT, "frames": frames}))
    merged = merge_stats([first, second])
    assert [(c["scene"], c["depth"], c["plane"], c["keyframes_agree"]) for c in merged["carried_to_check"]] == [
        ("2", "d1.png", 2, 0.1), ("1", "d1.png", 1, 0.3), ("2", "d1.png", 1, 0.3)]
    assert "2:d1.png plane 2 (0.10), 1:d1.png plane 1 (0.30)" in format_stats(merged)


def test_run_stats_of_a_run_without_masks():
    stats = run_stats(RunRecord.from_json({**REPORT, "planes": [], "frames": [REPORT["frames"][0]]}))
    assert stats["observations"] == 0 and stats["planes_per_observation"] == 0.0
    assert stats["mean_inlier_ratio"] is None
    last = format_stats(stats).splitlines()[-1]
    assert last.startswith("mean inlier ratio") and last.endswith(" -")


def test_format_stats_is_an_aligned_table():
    lines = format_stats(run_stats(RunRecord.from_json(REPORT))).splitlines()
    names = [line.rsplit("  ", 1)[0] for line in lines]
    assert len({len(name) for name in names}) == 1  # the values start in one column
    table = {name.strip(): line[len(name) + 2 :] for name, line in zip(names, lines)}
    assert table["observations (masks)"] == "3"
    assert table["planes per observation"] == "1.00"
    assert table["distinct planes"] == "2 of 4 annotated"
    assert table["too_far"] == "2" and table["invalid_depth"] == "1"
    assert table["skipped: outside_annotated_range"] == "2"
    assert table["mean inlier ratio"] == "0.900"


def test_stats_command_prints_table_and_json(tmp_path):
    (tmp_path / "report.json").write_text(json.dumps(REPORT), encoding="utf-8")
    runner = CliRunner()
    table = runner.invoke(app, ["stats", str(tmp_path)])
    assert table.exit_code == 0, table.output
    assert table.output.startswith("observations (masks)")
    as_json = runner.invoke(app, ["stats", str(tmp_path), "--json"])
    assert as_json.exit_code == 0, as_json.output
    assert json.loads(as_json.output) == run_stats(RunRecord.from_json(REPORT))


def test_stats_command_on_a_folder_without_a_run(tmp_path):
    result = CliRunner().invoke(app, ["stats", str(tmp_path)])
    assert result.exit_code == 1
    assert "error:" in result.output and "report.json" in result.output
    (tmp_path / "report.json").write_text("{not json", encoding="utf-8")
    broken = CliRunner().invoke(app, ["stats", str(tmp_path)])
    assert broken.exit_code == 1 and "cannot read the report" in broken.output


def test_a_wrong_depth_scale_is_named_when_most_planes_are_dropped_as_too_far(tmp_path):
    from conftest import SAMPLE_DATA

    result = CliRunner().invoke(app, ["cvat2mask", str(SAMPLE_DATA / "sequence"), str(SAMPLE_DATA / "annotations.xml"),
                                      "--config", str(SAMPLE_DATA / "camera.toml"), "--out", str(tmp_path / "out"),
                                      "--set", "camera.depth_scale=500", "--jobs", "1"])
    assert result.exit_code == 0, result.output
    assert ("planes were dropped as too_far: is camera.depth_scale = 500 right for this sensor?" in result.output)
    # Advice on the run, not one of the report's warnings that the summary counts.
    assert "\nhint: 136 of 146 planes were dropped as too_far" in result.output and "warning: 136 of" not in result.output
    assert "1 frame skipped, 146 of 146 planes drawn on frames dropped" in result.output
    normal = CliRunner().invoke(app, ["cvat2mask", str(SAMPLE_DATA / "sequence"), str(SAMPLE_DATA / "annotations.xml"),
                                      "--config", str(SAMPLE_DATA / "camera.toml"), "--out", str(tmp_path / "ok"),
                                      "--jobs", "1"])
    assert "were dropped as" not in normal.output and "1 frame skipped, 29 of 146 planes drawn on frames dropped" in normal.output


def test_every_drop_reason_has_a_hint_and_an_unknown_one_no_dangling_colon():
    from annotate_rgbd.report.records import RunSummary
    from annotate_rgbd.report.stats import DROP_HINTS, drop_hint
    from annotate_rgbd.segment import filters

    reasons = {value for name, value in vars(filters).items() if name.isupper() and isinstance(value, str)}
    assert reasons == {"invalid_depth", "too_far", "too_few_points", "not_where_expected", "no_plane"}
    assert reasons == set(DROP_HINTS)

    def summary(reason):
        return RunSummary(depth_frames=3, masks_written=3, frames_skipped={}, frames_failed=0, planes_kept=1,
                          planes_dropped=5, distinct_planes=2, dropped_by_reason={reason: 5}, mean_inlier_ratio=0.9)

    for reason in reasons - {"too_far"}:
        assert drop_hint(summary(reason), 5000.0) == f"5 of 6 planes were dropped as {reason}: {DROP_HINTS[reason]}"
    too_far = drop_hint(summary("too_far"), 5000.0)
    assert too_far.startswith("5 of 6 planes were dropped as too_far: is camera.depth_scale = 5000 right")
    assert drop_hint(summary("something_new"), 5000.0) == "5 of 6 planes were dropped as something_new"


def test_propose_says_what_it_did_not_propose_and_why_and_names_a_wrong_depth_scale(tmp_path):
    # Propose drops small and flickering detections by design: their counts are said, without a
    # hint. A wrong depth scale makes most detections too far: then the hint names it.
    from conftest import SAMPLE_DATA

    def propose(out, *extra):
        result = CliRunner().invoke(app, ["propose", str(SAMPLE_DATA / "sequence"), "--config",
                                          str(SAMPLE_DATA / "camera.toml"), "--out", str(out), "--jobs", "1", *extra])
        assert result.exit_code == 0, result.output
        report = json.loads((out / "report.json").read_text())
        reasons = Counter(d["reason"] for f in report["frames"] for d in f["dropped"])
        summary = [line for line in result.stdout.splitlines() if "plane track" in line][0]
        counted = ", ".join(f"{n} {r}" for r, n in sorted(reasons.items(), key=lambda r: (-r[1], r[0])))
        assert summary.endswith(f"; {report['summary']['planes_proposed']} planes proposed on frames, "
                                f"{sum(reasons.values())} not ({counted})")
        return result, reasons

    normal, reasons = propose(tmp_path / "ok", "--every", "3")
    assert "hint:" not in normal.output and sum(reasons.values()) > 0
    wrong, reasons = propose(tmp_path / "far", "--every", "3", "--set", "camera.depth_scale=500")
    assert reasons["too_far"] > 0
    assert wrong.stderr.splitlines()[-1].startswith(f"hint: {reasons['too_far']} of ") and (
        " detected planes were dropped as too_far: is camera.depth_scale = 500 right" in wrong.stderr)


def test_a_drop_rule_set_stricter_than_its_default_is_what_the_hint_names():
    # --set filter.max_invalid_ratio=0 drops every plane with one pixel without depth: the hint
    # names that setting, not the depth's registration; a looser rule keeps the usual hint.
    from annotate_rgbd.config.masks import FilterConfig
    from annotate_rgbd.report.records import RunSummary
    from annotate_rgbd.report.stats import DROP_HINTS, drop_hint

    def summary(reason):
        return RunSummary(depth_frames=3, masks_written=3, frames_skipped={}, frames_failed=0, planes_kept=1,
                          planes_dropped=5, distinct_planes=2, dropped_by_reason={reason: 5}, mean_inlier_ratio=0.9)

    cases = [("invalid_depth", FilterConfig(max_invalid_ratio=0.0), "filter.max_invalid_ratio is 0 here, stricter than its default 0.8"),
             ("too_far", FilterConfig(max_mean_distance=0.5), "filter.max_mean_distance is 0.5 here, stricter than its default 3.5"),
             ("too_few_points", FilterConfig(min_valid_pixels=5000), "filter.min_valid_pixels is 5000 here, stricter than its default 50")]
    for reason, strict, named in cases:
        # The setting first, then the cause in the data (a preset may set the rule on purpose:
        # fr2_pioneer_slam's max_invalid_ratio = 0.75 is EVOPS's own).
        data = drop_hint(summary(reason), 5000.0).split(": ", 1)[1]
        assert drop_hint(summary(reason), 5000.0, strict) == (
            f"5 of 6 planes were dropped as {reason}: {named}, which drops more planes; or {data[0].lower()}{data[1:]}")
        assert drop_hint(summary(reason), 5000.0, FilterConfig()) == drop_hint(summary(reason), 5000.0)
    loose = FilterConfig(max_invalid_ratio=0.95)
    assert drop_hint(summary("invalid_depth"), 5000.0, loose).endswith(DROP_HINTS["invalid_depth"])


def test_cvat2mask_and_propose_name_a_strict_drop_rule(tmp_path):
    from conftest import SAMPLE_DATA

    common = [str(SAMPLE_DATA / "sequence")]
    config = ["--config", str(SAMPLE_DATA / "camera.toml"), "--jobs", "1", "--set", "filter.max_mean_distance=0.5"]
    runs = {"cvat2mask": ["cvat2mask", *common, str(SAMPLE_DATA / "annotations.xml"), "--out", str(tmp_path / "a")],
            "propose": ["propose", *common, "--out", str(tmp_path / "b")]}
    for name, args in runs.items():
        result = CliRunner().invoke(app, args + config)
        assert result.exit_code == 0, result.output
        hints = [line for line in result.stderr.splitlines() if line.startswith("hint:")]
        assert len(hints) == 1 and "dropped as too_far: filter.max_mean_distance is 0.5 here, stricter than its default " \
            "3.5, which drops more planes; or is camera.depth_scale = 5000 right" in hints[0], (name, hints)


@pytest.mark.parametrize(("alignment", "problem"), [
    ("broken", "propagation.alignment is not an object"),
    ({"apart_from_keyframes": None}, "propagation.alignment.apart_from_keyframes is not a list"),
    ({"beyond_limits": "oops"}, "propagation.alignment.beyond_limits is not a list"),
    ({"apart_from_keyframes": ["a"]}, "propagation.alignment.apart_from_keyframes[0] is not an object with a "
                                      "depth_frame (an index) and a depth_timestamp"),
    ({"apart_from_keyframes": [{"depth_frame": 44}]}, "apart_from_keyframes[0] is not an object"),
    ({"beyond_limits": [{"depth_frame": "44", "depth_timestamp": 1.0}]}, "beyond_limits[0] is not an object"),
    ({"beyond_limits": [{"depth_frame": 1, "depth_timestamp": True}]}, "beyond_limits[0] is not an object"),
])
def test_a_broken_alignment_record_is_one_line_naming_the_field(tmp_path, alignment, problem):
    # A hand-edited report: stats and review read the frames to check from these lists.
    (tmp_path / "report.json").write_text(json.dumps({**REPORT, "propagation": {"alignment": alignment}}),
                                          encoding="utf-8")
    result = CliRunner().invoke(app, ["stats", str(tmp_path)])
    assert result.exit_code == 1 and result.output.startswith("error: ") and problem in result.output, result.output
    assert len(result.output.strip().splitlines()) == 1 and "Traceback" not in result.output

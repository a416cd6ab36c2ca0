"""Cluster shards: `batch --shard K/N` runs disjoint, stable subsets of a manifest's scenes, and N
shards run as separate processes make exactly the files of one unsharded run."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.errors import InputError
from annotate_rgbd.pipeline.shards import parse_shard, select_shard, shard_of
from annotate_rgbd.report.stats import merge_stats

from conftest import REPO_ROOT, SAMPLE_DATA

#: Scenes of the sample sequence with different settings (so that their masks differ).
SETTINGS = {
    "room": [],
    "room_tight": ["ransac.distance_threshold=0.02"],
    "room_seed": ["ransac.seed=7"],
    "room_nogrow": ["refine.grow_pixels=0"],
    "room_far": ["filter.max_mean_distance=2.0"],
}


def names(count: int) -> list[str]:
    return [f"scene{i:04d}_00" for i in range(count)]


def test_shards_are_disjoint_and_cover_the_scenes():
    scenes = names(200)
    for n in (1, 2, 3, 7):
        shards = [select_shard(scenes, k, n, name=str) for k in range(1, n + 1)]
        assert sorted(s for shard in shards for s in shard) == sorted(scenes)
        assert sum(len(shard) for shard in shards) == len(scenes)
        for shard in shards:  # manifest order is kept
            assert shard == [s for s in scenes if s in shard]


def test_shards_are_stable_when_scenes_are_added_or_reordered():
    before = {s: shard_of(s, 5) for s in names(300)}
    grown = names(450)[::-1]  # 150 scenes added, and the order reversed
    for k in range(1, 6):
        assert set(select_shard(grown, k, 5, name=str)) >= {s for s, shard in before.items() if shard == k}
    # The same on every machine and run: a fixed hash, not Python's salted hash().
    assert [shard_of(s, 4) for s in ("fr1_desk", "scene0000_00", "living_room")] == [
        shard_of(s, 4) for s in ("fr1_desk", "scene0000_00", "living_room")]
    code = "from annotate_rgbd.pipeline.shards import shard_of; print([shard_of(f'scene{i}', 7) for i in range(50)])"
    other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                           env={"PYTHONHASHSEED": "123"})
    assert other.stdout.strip() == str([shard_of(f"scene{i}", 7) for i in range(50)])


def test_shards_are_balanced():
    sizes = [len(select_shard(names(1513), k, 8, name=str)) for k in range(1, 9)]  # ScanNet's scans
    assert max(sizes) < 1.15 * 1513 / 8 and min(sizes) > 0.85 * 1513 / 8


@pytest.mark.parametrize("text", ["0/3", "4/3", "1", "a/b", "1/0", "-1/2", "1/2/3"])
def test_bad_shard(text):
    with pytest.raises(InputError, match="expected K/N"):
        parse_shard(text)


def write_manifest(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    tables = "".join(
        f'\n[[scene]]\nname = "{name}"\nsequence = "{SAMPLE_DATA / "sequence"}"\n'
        f'annotations = ["{SAMPLE_DATA / "annotations.xml"}"]\nconfig = "{SAMPLE_DATA / "camera.toml"}"\n'
        f'out = "out/{name}"\nset = {json.dumps(settings)}\n'
        for name, settings in SETTINGS.items()
    )
    manifest = folder / "batch.toml"
    manifest.write_text(tables, encoding="utf-8")
    return manifest


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.slow
def test_shards_as_processes_make_the_unsharded_files(tmp_path):
    n = 3
    shards = {k: [s for s in SETTINGS if shard_of(s, n) == k] for k in range(1, n + 1)}
    assert sum(1 for scenes in shards.values() if scenes) >= 2  # the test shards something
    sharded = write_manifest(tmp_path / "sharded")
    command = [sys.executable, "-m", "annotate_rgbd", "batch", str(sharded), "--jobs", "1"]
    processes = [subprocess.Popen(command + ["--shard", f"{k}/{n}"], cwd=REPO_ROOT, stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True) for k in range(1, n + 1)]
    outputs = [p.communicate(timeout=600) for p in processes]
    for k, (process, (stdout, stderr)) in enumerate(zip(processes, outputs), start=1):
        assert process.returncode == 0, stderr
        assert stdout.startswith(f"shard {k}/{n}: {len(shards[k])} scene")
    whole = write_manifest(tmp_path / "whole")
    result = CliRunner().invoke(app, ["batch", str(whole), "--jobs", "1"])
    assert result.exit_code == 0, result.output
    expected = snapshot(tmp_path / "whole" / "out")
    assert {name.split("/")[0] for name in expected} == set(SETTINGS)
    assert snapshot(tmp_path / "sharded" / "out") == expected  # the same files, byte for byte

    merged = CliRunner().invoke(app, ["batch", str(sharded), "--merge", "--json"])
    assert merged.exit_code == 0, merged.output
    summary = json.loads(merged.output)
    reports = [json.loads(expected[f"{name}/report.json"]) for name in SETTINGS]
    assert summary["scenes"] == len(SETTINGS) and summary["scenes_without_a_run"] == []
    assert summary["observations"] == sum(r["summary"]["masks_written"] for r in reports)
    assert summary["total_planes"] == sum(r["summary"]["planes_kept"] for r in reports)
    assert summary["planes_dropped"] == sum(r["summary"]["planes_dropped"] for r in reports)
    assert summary["depth_frames"] == sum(r["summary"]["depth_frames"] for r in reports)


def test_merge_names_scenes_without_a_run(tmp_path):
    manifest = write_manifest(tmp_path)
    result = CliRunner().invoke(app, ["batch", str(manifest), "--merge"])
    assert result.exit_code == 1
    assert "room_tight: " in result.output and "room_tight: no such folder" in result.output  # never run
    as_json = CliRunner().invoke(app, ["batch", str(manifest), "--merge", "--json"])
    assert as_json.exit_code == 1
    summary = json.loads(as_json.stdout)
    assert summary["scenes"] == 0 and summary["scenes_without_a_run"] == list(SETTINGS)
    # --json without --merge was ignored without a word (a run prints lines, not JSON): refused,
    # before anything runs.
    alone = CliRunner().invoke(app, ["batch", str(manifest), "--json"])
    assert alone.exit_code == 1 and alone.stderr.startswith("error: --json is for --merge")
    assert len(alone.stderr.splitlines()) == 1 and not any((tmp_path / "out").glob("*/report.json"))


def test_merge_stats_sums_and_weights():
    one = {"observations": 10, "total_planes": 30, "distinct_planes": 4, "planes_annotated": 5, "depth_frames": 12,
           "frames_skipped": {"a": 2}, "frames_failed": 0, "planes_dropped": 3, "dropped_by_reason": {"too_far": 3},
           "mean_inlier_ratio": 0.9, "tracks_to_review": ["p.xml:1"]}
    two = {"observations": 5, "total_planes": 10, "distinct_planes": 2, "planes_annotated": 2, "depth_frames": 5,
           "frames_skipped": {"a": 1, "b": 4}, "frames_failed": 1, "planes_dropped": 0, "dropped_by_reason": {},
           "mean_inlier_ratio": 0.5, "tracks_to_review": []}
    merged = merge_stats([one, two])
    assert merged["observations"] == 15 and merged["total_planes"] == 40 and merged["planes_per_observation"] == 2.667
    assert merged["frames_skipped"] == {"a": 3, "b": 4} and merged["frames_failed"] == 1
    assert merged["mean_inlier_ratio"] == pytest.approx((0.9 * 30 + 0.5 * 10) / 40)
    assert merged["tracks_to_review"] == ["1:p.xml:1"] and merged["scenes"] == 2
    assert merge_stats([one, two], ["kitchen", "office"])["tracks_to_review"] == ["kitchen:p.xml:1"]


def test_merged_lists_name_their_scene_when_an_earlier_scene_has_no_run(tmp_path, sample_run):
    # The prefix was the position among the scenes with a run: the second scene's entries were
    # said to be scene 1's, the name of another scene in the manifest.
    manifest = write_manifest(tmp_path)
    first, second = list(SETTINGS)[:2]
    shutil.copytree(sample_run[0], tmp_path / "out" / second)
    path = tmp_path / "out" / second / "report.json"
    report = json.loads(path.read_text(encoding="utf-8"))
    written = next(f for f in report["frames"] if f["status"] == "written")
    written["kept"][0]["propagated"] = True
    written["keyframes_agree"] = {str(written["kept"][0]["plane"]): 0.2}
    path.write_text(json.dumps(report), encoding="utf-8")
    result = CliRunner().invoke(app, ["batch", str(manifest), "--merge", "--json"])
    summary = json.loads(result.stdout)
    assert summary["scenes"] == 1 and first in summary["scenes_without_a_run"]
    assert [c["scene"] for c in summary["carried_to_check"]] == [second]
    text = CliRunner().invoke(app, ["batch", str(manifest), "--merge"]).stdout
    assert f"{second}:{written['depth']} plane {written['kept'][0]['plane']} (0.20)" in text

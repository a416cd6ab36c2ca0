"""Batch runs: several scenes, one pool, resumable after a kill, only changed frames redone."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from annotate_rgbd.pipeline.manifest import read_manifest
from annotate_rgbd.cli import app
from annotate_rgbd.errors import InputError
from annotate_rgbd.pipeline.resume import JOURNAL

from conftest import REPO_ROOT, SAMPLE_DATA


def write_manifest(folder: Path, annotations: Path, extra: str = "") -> Path:
    manifest = folder / "batch.toml"
    manifest.write_text(
        f"""
[[scene]]
name = "room"
sequence = "{SAMPLE_DATA / 'sequence'}"
annotations = ["{annotations}"]
config = "{SAMPLE_DATA / 'camera.toml'}"
out = "out/room"

[[scene]]
name = "room_tight"
sequence = "{SAMPLE_DATA / 'sequence'}"
annotations = ["{annotations}"]
config = "{SAMPLE_DATA / 'camera.toml'}"
set = ["ransac.distance_threshold=0.02"]
out = "out/room_tight"
{extra}"""
    )
    return manifest


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    folder = tmp_path_factory.mktemp("uninterrupted")
    result = CliRunner().invoke(app, ["batch", str(write_manifest(folder, SAMPLE_DATA / "annotations.xml")), "--jobs", "1"])
    assert result.exit_code == 0, result.output
    return snapshot(folder / "out")


def test_batch_summary_per_scene(uninterrupted):
    assert {"room/report.json", "room_tight/report.json", "room/planes.csv"} <= set(uninterrupted)
    assert sum(name.startswith("room/masks/") for name in uninterrupted) == 19
    assert not any(JOURNAL in name or name.endswith(".tmp") for name in uninterrupted)
    # The scenes differ only by the threshold, so their masks differ.
    assert uninterrupted["room/report.json"] != uninterrupted["room_tight/report.json"]


def test_killed_batch_resumes_to_identical_files(tmp_path, uninterrupted):
    manifest = write_manifest(tmp_path, SAMPLE_DATA / "annotations.xml")
    command = [sys.executable, "-m", "annotate_rgbd", "batch", str(manifest), "--jobs", "2"]
    process = subprocess.Popen(command, cwd=REPO_ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                               start_new_session=True)
    journal = tmp_path / "out" / "room" / JOURNAL
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        if journal.is_file() and journal.read_text().count("\n") >= 3:
            break
        time.sleep(0.02)
    assert process.poll() is None, "the batch finished before it could be killed"
    os.killpg(process.pid, signal.SIGKILL)  # the harshest interruption: no clean-up at all
    process.wait()
    assert not (tmp_path / "out" / "room" / "report.json").exists()

    result = CliRunner().invoke(app, ["batch", str(manifest), "--jobs", "2"])
    assert result.exit_code == 0, result.output
    assert "unchanged" in result.output and "0 failed" in result.output
    made = [line for line in result.output.splitlines() if line.startswith("room:")][0]
    assert "(19 made" not in made  # finished frames of the killed run were reused
    assert snapshot(tmp_path / "out") == uninterrupted


def test_changed_polygon_redoes_one_frame_and_force_redoes_all(tmp_path, uninterrupted):
    annotations = tmp_path / "annotations.xml"
    text = (SAMPLE_DATA / "annotations.xml").read_text()
    original = 'points="118.52,175.41;176.57,195.26;178.43,101.47;114.54,93.25"'
    assert text.count(original) == 1
    annotations.write_text(text)
    manifest = write_manifest(tmp_path, annotations)
    runner = CliRunner()
    assert runner.invoke(app, ["batch", str(manifest), "--jobs", "1"]).exit_code == 0
    before = snapshot(tmp_path / "out")
    annotations.write_text(text.replace(original, 'points="100.52,175.41;176.57,195.26;178.43,101.47;114.54,93.25"'))
    result = runner.invoke(app, ["batch", str(manifest), "--jobs", "1"])
    assert result.exit_code == 0, result.output
    assert "room: 19 masks (1 made, 18 unchanged)" in result.output
    after = snapshot(tmp_path / "out")
    changed = sorted(name for name in before if name.startswith("room/masks/") and before[name] != after[name])
    assert len(changed) == 1
    forced = runner.invoke(app, ["batch", str(manifest), "--jobs", "1", "--force"])
    assert "room: 19 masks (19 made, 0 unchanged)" in forced.output
    assert "room_tight: 19 masks (19 made, 0 unchanged)" in forced.output


def batch_with_a_third_scene(tmp_path: Path, name: str, lines: str):
    """The manifest of the two sample scenes and a third one, ``name``, of the sample sequence with
    these manifest ``lines``, and the result of ``batch`` on it with one worker."""
    extra = f'\n[[scene]]\nname = "{name}"\nsequence = "{SAMPLE_DATA / "sequence"}"\n{lines}\nout = "out/{name}"\n'
    manifest = write_manifest(tmp_path, SAMPLE_DATA / "annotations.xml", extra)
    return manifest, CliRunner().invoke(app, ["batch", str(manifest), "--jobs", "1"])


def test_a_broken_scene_fails_alone(tmp_path):
    _, result = batch_with_a_third_scene(tmp_path, "broken", 'annotations = ["missing.xml"]')
    assert result.exit_code == 1
    assert f"broken: FAILED: {tmp_path / 'missing.xml'}: file not found" in result.stdout
    # Standard error has it too, in the form of every error: a log of standard error alone shows it.
    assert f"error: broken: {tmp_path / 'missing.xml'}: file not found" in result.stderr.splitlines()
    assert (tmp_path / "out" / "room" / "report.json").is_file()
    assert (tmp_path / "out" / "room_tight" / "report.json").is_file()
    assert not (tmp_path / "out" / "broken").exists()


def test_batch_overlays_and_warnings_that_name_their_scene(tmp_path):
    manifest = write_manifest(tmp_path, SAMPLE_DATA / "annotations.xml")
    manifest.write_text(manifest.read_text().replace('out = "out/room"\n', 'out = "out/room"\noverlays = true\n'))
    result = CliRunner().invoke(app, ["batch", str(manifest), "--jobs", "1"])
    assert result.exit_code == 0, result.output
    room, tight = tmp_path / "out" / "room", tmp_path / "out" / "room_tight"
    assert len(list((room / "overlays").iterdir())) == 19
    assert (room / "review.html").is_file() and (room / "contact_sheet.png").is_file()
    assert not (tight / "overlays").exists() and not (tight / "review.html").exists()
    assert f"  review page: {room / 'review.html'}" in result.stdout.splitlines()
    # The sample's 11th depth frame has no RGB frame near it: one warning per scene, each named.
    skipped = [line for line in result.stderr.splitlines() if "no RGB frame within" in line]
    assert [line.split(":")[:2] for line in skipped] == [["warning", " room"], ["warning", " room_tight"]]
    # The first progress line already counts both scenes' frames.
    first = next(line for line in result.stderr.splitlines() if "frames/s" in line)
    assert "all scenes: 1/38" in first, first


def test_a_failed_frame_fails_the_batch_and_is_listed(tmp_path):
    sequence = tmp_path / "sequence"
    import shutil

    shutil.copytree(SAMPLE_DATA / "sequence", sequence)
    broken = sorted((sequence / "depth").iterdir())[3]
    broken.write_bytes(b"not a png")
    manifest = tmp_path / "batch.toml"
    manifest.write_text(
        f'[[scene]]\nsequence = "sequence"\nannotations = ["{SAMPLE_DATA / "annotations.xml"}"]\n'
        f'config = "{SAMPLE_DATA / "camera.toml"}"\nout = "out/one"\n'
    )
    result = CliRunner().invoke(app, ["batch", str(manifest), "--jobs", "1"])
    assert result.exit_code == 1
    assert "one: 18 masks" in result.output and "1 failed" in result.output
    assert f"failed: {broken}: not a readable image" in result.output


@pytest.mark.parametrize(
    "text, message",
    [
        ("", "no scenes"),
        ("[[scene]]\nsequence = 'a'\nout = 'o'\n", "'annotations' is missing"),
        ("[[scene]]\nsequence = 'a'\nannotations = ['x.xml']\nout = 'o'\ncolour = 1\n", "unknown key 'colour'"),
        ("[[scene]]\nsequence = 'a'\nannotations = ['x.xml']\nout = 'o'\npose = 'g'\noverlay = true\n",
         "unknown keys 'overlay', 'pose' \\(known: "),
        ("jobs = 0\n[[scene]]\nsequence = 'a'\nannotations = ['x.xml']\nout = 'o'\n", "'jobs' must be a positive integer"),
        ("[[scene]]\nsequence = 'a'\nannotations = 'x.xml'\nout = 'o'\n[[scene]]\nsequence = 'b'\nannotations = 'y.xml'\nout = 'o'\n",
         "two scenes write to"),
        ("[[scene]]\nname = 'same'\nsequence = 'a'\nannotations = 'x.xml'\nout = 'a'\n[[scene]]\nsequence = 'b'\nannotations = 'y.xml'\nout = 'b'\n"
         "[[scene]]\nname = 'same'\nsequence = 'c'\nannotations = 'z.xml'\nout = 'c'\n",
         r"\[\[scene\]\] 1 and 3 are both named 'same': give each scene a 'name' of its own"),
        ("[[scene]]\nsequence = 'a'\nannotations = ['x.xml']\nout = 'o'\nparts = ['x.xml']\n", "expected FILE:OFFSET"),
        ("[[scene\n", "invalid TOML"),
        ("[[scene]]\nsequence = 'a'\nannotations = ['x.xml']\nout = 'o'\noverlays = 'yes'\n", "raw_masks, overlays, instance_ids are true or false"),
    ],
)
def test_bad_manifests_are_one_line_errors(tmp_path, text, message):
    manifest = tmp_path / "batch.toml"
    manifest.write_text(text)
    with pytest.raises(InputError, match=message) as error:
        read_manifest(manifest)
    assert str(manifest) in str(error.value)


def test_a_bad_set_value_of_a_scene_names_the_manifest_not_the_command_line(tmp_path):
    manifest, result = batch_with_a_third_scene(tmp_path, "typo", f"""annotations = ["{SAMPLE_DATA / 'annotations.xml'}"]
config = "{SAMPLE_DATA / 'camera.toml'}"
set = ["ransac.distance_treshold=0.01"]""")
    assert result.exit_code == 1
    assert f"error: typo: {manifest}: [[scene]] 3: set: unknown key 'ransac.distance_treshold'" in result.stderr
    assert "command-line option" not in result.output


def test_scenes_whose_output_folders_share_a_name_are_named_by_their_out(tmp_path):
    # A ScanNet-like layout: every scene writes to scans/<scene>/annotate. The default name (the
    # output folder's) would be 'annotate' for all: summaries, warnings and --merge could not
    # tell them apart. They are named by 'out' as written; a name of its own is kept.
    manifest = tmp_path / "batch.toml"
    manifest.write_text("".join(f"[[scene]]\nsequence = 's{i}'\nannotations = 'x.xml'\nout = 'scans/s{i}/annotate'\n"
                                for i in range(2))
                        + "[[scene]]\nname = 'kept'\nsequence = 's2'\nannotations = 'x.xml'\nout = 'scans/s2/annotate'\n"
                        + "[[scene]]\nsequence = 's3'\nannotations = 'x.xml'\nout = 'alone'\n")
    scenes, _ = read_manifest(manifest)
    assert [scene.name for scene in scenes] == ["scans/s0/annotate", "scans/s1/annotate", "kept", "alone"]


def test_a_scenes_advice_is_given_in_the_manifests_words(tmp_path):
    # A batch scene has no command line: "--part one.xml:OFFSET" and "--set camera.depth_scale=5000"
    # are its manifest's parts and set.
    for name in ("one.xml", "two.xml"):
        shutil.copy(SAMPLE_DATA / "annotations.xml", tmp_path / name)
    scene = f'sequence = "{SAMPLE_DATA / "sequence"}"\nconfig = "{SAMPLE_DATA / "camera.toml"}"\n'
    manifest = tmp_path / "batch.toml"
    manifest.write_text(f'[[scene]]\n{scene}annotations = ["one.xml", "two.xml"]\nout = "parts"\n'
                        f'[[scene]]\n{scene}annotations = ["one.xml"]\nout = "scale"\nset = ["camera.depth_scale=500"]\n')
    result = CliRunner().invoke(app, ["batch", str(manifest), "--jobs", "1"])
    assert result.exit_code == 1
    assert (f"error: parts: {tmp_path / 'one.xml'}: cannot tell where this part starts in the sequence: give "
            'parts = ["one.xml:OFFSET"] (the RGB index of its frame 0)') in result.stderr
    assert "or with set = [\"camera.depth_scale=5000\"]" in result.stderr and "--set" not in result.stderr
    assert "--part" not in result.output

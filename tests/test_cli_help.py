"""The help of every command reads like a Unix tool's: option values named, flags bare."""

import re

import pytest
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.config.settings import DEFAULT_CAMERA, Config, load_config, preset_names
from annotate_rgbd.geometry.noise import SENSOR_MODELS

COMMANDS = ["cvat2mask", "batch", "presets", "evaluate", "review", "stats", "propose", "export-cvat"]


def _help(*args: str) -> str:
    result = CliRunner().invoke(app, [*args, "--help"], prog_name="annotate-rgbd", env={"COLUMNS": "100"})
    assert result.exit_code == 0, result.output
    return result.output


@pytest.mark.parametrize("command", [[], *([c] for c in COMMANDS)])
def test_help_names_values_and_leaves_flags_bare(command):
    text = _help(*command)
    # Type tags as typer >= 0.27 prints them ('<bool>', '<list[Path]>', '{SEQUENCE_DIR}').
    assert not re.search(r"<[a-z][\w\[\], ]*>|\{[A-Z_.]+\}", text), text
    # A flag takes no value: its line is the flag, then spaces and its help.
    for flag in ("--help", "--force", "--overlays", "--raw-masks", "--json", "--version"):
        for line in text.splitlines():
            if line.strip().startswith(flag + " "):
                assert re.match(rf"\s+{flag}( / --no-[a-z-]+)?\s{{2,}}\S", line), line


def test_cvat2mask_help_names_every_value():
    text = _help("cvat2mask")
    assert "Usage: annotate-rgbd cvat2mask [OPTIONS] SEQUENCE_DIR ANNOTATIONS..." in text
    for shown in ("-o, --out DIR", "-c, --config FILE|PRESET", "--set SECTION.KEY=VALUE", "-j, --jobs N",
                  "--poses FILE", "--part FILE:OFFSET", "--distance-threshold METRES"):
        assert shown in text
    # Square brackets in help text are printed, not taken for markup.
    assert "[noise]" in text


def test_h_is_short_for_help():
    short = CliRunner().invoke(app, ["cvat2mask", "-h"], prog_name="annotate-rgbd", env={"COLUMNS": "100"})
    assert short.exit_code == 0 and short.output == _help("cvat2mask")


@pytest.mark.parametrize("command", ["cvat2mask", "propose"])
def test_config_help_says_which_camera_is_used_without_it(command):
    text = " ".join(_help(command).split())
    camera = DEFAULT_CAMERA
    assert camera.fx == camera.fy == 525.0 and camera.depth_scale == 5000.0 and Config().noise.model == SENSOR_MODELS["kinect_v1"]
    assert "without it: the camera the layout states" in text
    assert "fx = fy = 525, depth in 1/5000 m" in text and "kinect_v1 noise model" in text


def test_presets_lists_each_preset_with_its_camera_and_source():
    result = CliRunner().invoke(app, ["presets"])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    for name in preset_names():
        camera = load_config(name).camera
        entry = lines[lines.index(next(line for line in lines if line.startswith(f"{name}: "))) + 1]
        values = f"fx {camera.fx:g}, fy {camera.fy:g}, cx {camera.cx:g}, cy {camera.cy:g}, depth_scale {camera.depth_scale:g}"
        assert entry.startswith(f"    camera: {values}; "), entry
        assert len(entry) > len(f"    camera: {values}; ") + 10, f"{name}: no source of the camera"


@pytest.mark.parametrize(("args", "line"), [
    (["evaluate", "gt", "pred", "--full", ""],
     "error: Invalid value for '--full': '' is not a valid float (see annotate-rgbd evaluate -h)"),
    (["evaluate", "gt", "pred", "--fulll", "3"],
     "error: No such option: --fulll (Possible options: --full) (see annotate-rgbd evaluate -h)"),
    (["cvat2mask", "seq", "a.xml", "-j", "0"],
     "error: Invalid value for '--jobs' / '-j': 0 is not in the range x>=1 (see annotate-rgbd cvat2mask -h)"),
    (["stats"], "error: Missing argument 'RUN_DIR' (see annotate-rgbd stats -h)"),
    (["relabel"], "error: No such command 'relabel' (see annotate-rgbd -h)"),
    (["export", "run", "--format"], "error: Option '--format' requires an argument (see annotate-rgbd export -h)"),
])
def test_a_command_line_that_cannot_be_parsed_is_one_error_line(args, line):
    # Click printed the usage, a hint, a blank line and the error: four lines, where every other
    # problem is one. The status stays Click's 2 (a command line, not an input, is wrong).
    result = CliRunner().invoke(app, args, prog_name="annotate-rgbd")
    assert result.exit_code == 2
    assert result.stderr == line + "\n" and result.stdout == ""


def test_the_command_alone_still_prints_its_help():
    result = CliRunner().invoke(app, [], prog_name="annotate-rgbd")
    assert result.exit_code == 2  # Click's for no_args_is_help, as before
    assert "Usage: annotate-rgbd [OPTIONS] COMMAND [ARGS]..." in result.output


@pytest.mark.parametrize(("args", "shown"), [
    (["evaluate", "gt", "pred", "--per-frame", ""], "--per-frame"),
    (["propose", "", "--out", "o"], "SEQUENCE_DIR"),
    (["cvat2mask", "s", "a.xml", "-o", "o", "--poses", ""], "--poses"),
    (["cvat2mask", "s", "a.xml", "-o", "o", "--config", ""], "--config"),
    (["cvat2mask", "s", "a.xml", "", "-o", "o"], "ANNOTATIONS"),
    (["stats", ""], "RUN_DIR"),
    (["stats", " "], "RUN_DIR"),
    (["cvat2mask", "s", "a.xml", "-o", ""], "--out"),
])
def test_an_empty_path_is_named_not_taken_for_the_current_folder(args, shown, tmp_path, monkeypatch):
    # Path("") is ".": `--poses "$UNSET"` was reported as a problem of the current folder.
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, args, prog_name="annotate-rgbd")
    assert result.exit_code == 2
    assert result.stderr == f"error: {shown} is empty (an unset shell variable?) (see annotate-rgbd {args[0]} -h)\n"
    assert list(tmp_path.iterdir()) == []

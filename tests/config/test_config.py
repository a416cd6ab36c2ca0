from __future__ import annotations  # annotations stay text, as in annotate_rgbd/config.py

from dataclasses import dataclass
from importlib import resources
from typing import Optional

import numpy as np
import pytest

from annotate_rgbd.config.command_line import parse_part_offsets, parse_settings
from annotate_rgbd.config.settings import (
    Config,
    _build_list,
    config_from_dict,
    config_to_dict,
    load_config,
    preset_names,
)
from annotate_rgbd.geometry.noise import SENSOR_MODELS, NoiseSettings, QuadraticNoise
from annotate_rgbd.errors import InputError

ISSUE_EXAMPLE = """
[camera]
fx = 517.3
fy = 516.5
cx = 318.6
cy = 255.3
depth_scale = 5000.0
[filter]
max_invalid_ratio = 0.8
max_mean_distance = 3.5
[ransac]
distance_threshold = 0.02
"""


def test_defaults_are_the_papers():
    config = load_config()
    assert config == Config()
    assert config.filter.max_invalid_ratio == 0.8
    assert config.filter.max_mean_distance == 3.5
    assert config.ransac.distance_threshold == 0.0  # no fixed band: the sensor's noise decides
    assert config.inlier_band() == NoiseSettings(SENSOR_MODELS["kinect_v1"], 3.0, 0.002, 0.1)
    assert SENSOR_MODELS["kinect_v1"] == QuadraticNoise(0.0012, 0.0019, 0.4)  # Nguyen et al. 2012
    assert config.sequence.max_time_diff == 0.02


def test_documented_keys_are_read(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(ISSUE_EXAMPLE)
    config = load_config(path)
    assert (config.camera.fx, config.camera.fy, config.camera.cx, config.camera.cy) == (517.3, 516.5, 318.6, 255.3)
    assert config.camera.depth_scale == 5000.0


def test_overrides_beat_the_file(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(ISSUE_EXAMPLE)
    config = load_config(path, {"ransac.distance_threshold": 0.01, "annotation.labels": ["wall"]})
    assert config.ransac.distance_threshold == 0.01
    assert config.annotation.labels == ("wall",)
    assert config.camera.fx == 517.3


#: preset -> (noise model, max_invalid_ratio, fy, depth_scale); the EVOPS scenes' fixed bands
#: (0.005 m ICL-NUIM, 0.01 fr1_desk, 0.03 fr2_pioneer_slam, 0.02 fr3) are in their comments.
EXPECTED_PRESETS = {
    "living_room": ("icl_nuim", 0.8, -480.0, 5000.0),
    "office_room": ("icl_nuim", 0.8, -480.0, 5000.0),
    "fr1_desk": ("kinect_v1", 0.8, 516.469215, 5000.0),
    "fr2_pioneer_slam": ("kinect_v1", 0.75, 521.007327, 5000.0),
    "fr3_cabinet": ("kinect_v1", 0.8, 539.2, 5000.0),
    "fr3_long_office_household_validation": ("kinect_v1", 0.8, 539.2, 5000.0),
    "realsense_d435": ("realsense_d435", 0.8, 615.0, 1000.0),
}


def test_every_preset_has_its_sensor_noise_model_and_thresholds():
    assert set(preset_names()) == set(EXPECTED_PRESETS)
    for name, (model, invalid, fy, depth_scale) in EXPECTED_PRESETS.items():
        config = load_config(name)
        assert config.ransac.distance_threshold == 0.0, name  # no fixed band: the noise model's
        assert config.inlier_band().model == SENSOR_MODELS[model], name
        assert config.filter.max_invalid_ratio == invalid, name
        assert config.filter.max_mean_distance == 3.5, name
        assert config.camera.fy == fy, name
        assert config.camera.depth_scale == depth_scale, name


def test_a_fixed_distance_threshold_replaces_the_noise_model():
    config = load_config("fr1_desk", {"ransac.distance_threshold": 0.01})
    band = config.inlier_band()
    np.testing.assert_array_equal(band.band(np.array([0.5, 1.0, 3.0, 6.0])), [0.01] * 4)
    # The noise section round-trips through the report's configuration.
    assert config_from_dict(config_to_dict(load_config("living_room"))) == load_config("living_room")


@pytest.mark.parametrize(
    "text, message",
    [
        ("[ransac]\ndistance_treshold = 0.1\n", "unknown key 'ransac.distance_treshold'"),
        ("[filters]\nmax_mean_distance = 3\n", "unknown section [filters]"),
        ("[ransac]\ndistance_threshold = 'big'\n", "'ransac.distance_threshold' must be a number"),
        ("[ransac]\ndistance_threshold = -1.0\n", "'ransac.distance_threshold' must be >= 0 (0: the [noise] band)"),
        ("[noise]\nmodel = 'kinect_v2'\n", "'noise.model' must be one of constant, quadratic, icl_nuim, kinect_v1"),
        ("[noise]\nmodel = 'kinect_v1'\nb = 0.1\n", "'noise.b' is not a parameter of model 'kinect_v1'"),
        ("[refine]\ngrow_pixels = -1\n", "'refine.grow_pixels' must be in [0, 50]"),
        ("[camera]\nfy = 0\n", "'camera.fy' must not be 0"),
        ("[filter]\nmin_valid_pixels = 2.5\n", "'filter.min_valid_pixels' must be an integer"),
        ("[filter\n", "invalid TOML"),
        ("ransac = 3\n", "[ransac] must be a table"),
    ],
)
def test_bad_files_are_one_line_errors_naming_the_file(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError) as error:
        load_config(path)
    assert message in str(error.value)
    assert str(path) in str(error.value)
    assert "\n" not in str(error.value)


def test_unknown_preset_lists_the_presets():
    with pytest.raises(InputError, match="fr1_desk"):
        load_config("fr9_nowhere")


def test_config_to_dict_is_plain_data():
    data = config_to_dict(load_config(None, {"annotation.labels": ["a"]}))
    assert data["annotation"]["labels"] == ["a"]
    assert data["camera"]["fx"] == 525.0


def test_a_bad_override_is_blamed_on_the_command_line(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(ISSUE_EXAMPLE)
    with pytest.raises(InputError) as error:
        load_config(path, {"ransac.sed": 3})
    assert str(error.value).startswith("command-line option: unknown key 'ransac.sed'")


def test_input_errors_survive_pickling_between_processes():
    import pickle

    from annotate_rgbd.errors import OutputError

    for error in (InputError("a/b.png", "broken"), OutputError("out", "disk full"), InputError(None, "no path")):
        again = pickle.loads(pickle.dumps(error))
        assert type(again) is type(error) and str(again) == str(error)


def test_set_values_are_read_as_toml():
    overrides = parse_settings(["ransac.seed=3", "filter.max_mean_distance=2.5", "annotation.labels=['wall', 'floor']",
                                "annotation.labels2=wall", " sequence.max_time_diff =0.01"])
    assert overrides == {"ransac.seed": 3, "filter.max_mean_distance": 2.5, "annotation.labels": ["wall", "floor"],
                         "annotation.labels2": "wall", "sequence.max_time_diff": 0.01}
    assert type(overrides["ransac.seed"]) is int
    for bad in ("ransac.seed", "seed=3"):
        with pytest.raises(InputError, match=r"expected SECTION\.KEY=VALUE"):
            parse_settings([bad])


def test_part_offsets_split_at_the_last_colon():
    assert parse_part_offsets(["950-1900.xml:950", "C:/labels/a.xml:0", "b.xml: 7"]) == {
        "950-1900.xml": 950, "C:/labels/a.xml": 0, "b.xml": 7,
    }
    for bad in ("a.xml", ":5", "a.xml:-1", "a.xml:x", "a.xml:"):
        with pytest.raises(InputError, match="expected FILE:OFFSET"):
            parse_part_offsets([bad])


@dataclass(frozen=True)
class Checkpoint:  # a type whose name contains "int", "str" nowhere near it
    frame: int


@dataclass(frozen=True)
class Entry:
    file: str
    weight: float = 1.0
    track: Optional[int] = None
    plane: int | None = None
    new: bool = False


@dataclass(frozen=True)
class EntryWithCheckpoint:
    at: Checkpoint


def test_list_entries_are_checked_against_their_field_types():
    entries = _build_list("entries", Entry, [{"file": "a.xml", "weight": 2, "track": 3, "plane": 4, "new": True},
                                             {"file": "b.xml", "weight": 0.5}], "t.toml")
    assert entries == (Entry("a.xml", 2.0, 3, 4, True), Entry("b.xml", 0.5))
    assert type(entries[0].weight) is float  # an integer where a float is expected is converted
    for key, value in [("file", 3), ("weight", "heavy"), ("weight", True), ("track", True), ("track", 2.0),
                       ("plane", "4"), ("new", 1)]:
        with pytest.raises(InputError, match=f"t.toml: \\[\\[entries\\]\\] entry 1: '{key}' has the wrong type"):
            _build_list("entries", Entry, [{"file": "a.xml", key: value}], "t.toml")


def test_a_list_entry_field_of_another_type_is_a_programming_error():
    # Judged by its name, "Checkpoint" would pass for an int; an int is no Checkpoint.
    with pytest.raises(TypeError, match="EntryWithCheckpoint.at"):
        _build_list("entries", EntryWithCheckpoint, [{"at": 5}], "t.toml")


@pytest.mark.parametrize("text, message", [
    ("[camera]\nfx = nan\n", "'camera.fx' must be a finite number, got nan"),
    ("[camera]\ncx = inf\n", "'camera.cx' must be a finite number, got inf"),
    ("[filter]\nmax_mean_distance = nan\n", "'filter.max_mean_distance' must be a finite number"),
    ("[ransac]\nnum_iterations = 2147483648\n", "'ransac.num_iterations' must be at most 2147483647"),
    ("[ransac]\nnum_iterations = 1000001\n", "'ransac.num_iterations' must be in [1, 1000000]"),
    ("[ransac]\nnum_iterations = 0\n", "'ransac.num_iterations' must be in [1, 1000000]"),
    ("[ransac]\nseed = 2147483648\n", "'ransac.seed' must be at most 2147483647"),
])
def test_numbers_must_be_finite_and_fit_their_use(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError, match=message.replace("[", r"\[")) as error:
        load_config(path)
    assert str(error.value).startswith(str(path))


def test_max_points_3_is_valid_and_runs(tmp_path):
    from annotate_rgbd.pipeline.scene import run_cvat2mask

    from conftest import SAMPLE_DATA

    config = load_config(SAMPLE_DATA / "camera.toml", {"ransac.max_points": 3})
    run = run_cvat2mask(SAMPLE_DATA / "sequence", [SAMPLE_DATA / "annotations.xml"], tmp_path / "out", config)
    assert run.written == 19


@pytest.mark.parametrize("depth", [17, 100_000])
def test_values_nested_absurdly_deep_are_one_error_everywhere(tmp_path, depth):
    from annotate_rgbd.pipeline.manifest import read_manifest

    deep = "[" * depth + "]" * depth
    config = tmp_path / "deep.toml"
    config.write_text(f"[ransac]\nseed = {deep}\n")
    with pytest.raises(InputError, match="nested more than 16 levels deep") as error:
        load_config(config)
    assert error.value.path == config
    with pytest.raises(InputError, match=r"--set ransac.seed: .*nested more than 16"):
        parse_settings([f"ransac.seed={deep}"])
    manifest = tmp_path / "scenes.toml"
    manifest.write_text(f"[[scene]]\nname = {'{a=' * depth}1{'}' * depth}\n")
    with pytest.raises(InputError, match="nested more than 16 levels deep"):
        read_manifest(manifest)


def test_brackets_in_strings_and_comments_do_not_count_as_nesting(tmp_path):
    config = tmp_path / "c.toml"
    config.write_text('# [[[[[[[[[[[[[[[[[[[[\n[annotation]\nlabels = ["[[[[[[[[[[[[[[[[[[[[", \'{{{{{{{{{{{{{{{{{{{{\']\n')
    assert load_config(config).annotation.labels == ("[" * 20, "{" * 20)


def test_presets_are_listed_with_their_camera_and_its_source():
    from typer.testing import CliRunner

    from annotate_rgbd.cli import app
    from annotate_rgbd.config.settings import preset_names, preset_summaries

    summaries = {name: (what, camera) for name, what, camera in preset_summaries()}
    assert sorted(summaries) == preset_names()
    what, camera = summaries["fr1_desk"]
    assert what.startswith("TUM RGB-D freiburg1_desk")
    assert camera.startswith("fx 517.306, fy 516.469, cx 318.643, cy 255.314, depth_scale 5000; ")
    assert "calibration" in camera  # the source of the numbers
    assert "depth_scale 1000" in summaries["realsense_d435"][1]
    output = CliRunner().invoke(app, ["presets"]).output
    assert all(f"{name}: " in output for name in summaries) and output.count("camera: ") == len(summaries)
    # Each with its noise model and drop rules, as its file sets them.
    assert "realsense_d435: " in output and (
        "    noise: realsense_d435; planes dropped above 0.8 invalid depth or beyond 3.5 m on average" in output)
    assert output.count("    noise: ") == len(summaries)


def test_a_preset_is_printed_to_start_a_configuration_from():
    from typer.testing import CliRunner

    from annotate_rgbd.cli import app
    from annotate_rgbd.config.settings import load_config

    result = CliRunner().invoke(app, ["presets", "fr1_desk"])
    assert result.exit_code == 0
    assert result.stdout == (resources.files("annotate_rgbd.configs") / "fr1_desk.toml").read_text(encoding="utf-8")
    assert load_config(None, {}) != load_config("fr1_desk")
    unknown = CliRunner().invoke(app, ["presets", "fr9"])
    assert unknown.exit_code == 1 and unknown.output.startswith("error: no preset 'fr9' (presets: fr1_desk, ")


def test_overrides_may_complete_a_file_that_is_not_valid_alone(tmp_path):
    # docs/configuration.md: --set overrides the file. A file that needs the override to be
    # valid (a model's missing parameter) is completed by it, not refused first.
    path = tmp_path / "noise.toml"
    path.write_text('[noise]\nmodel = "quadratic"\n')
    config = load_config(path, {"noise.b": 0.003})
    assert type(config.noise.model).__name__ == "QuadraticNoise" and config.noise.model.b == 0.003
    # What the overrides do not mend is the file's error, named as the file's.
    with pytest.raises(InputError) as error:
        load_config(path, {"noise.c": 1.0})
    assert str(error.value).startswith(f"{path}: 'noise.b' is missing")
    with pytest.raises(InputError) as error:
        load_config(path)
    assert str(error.value).startswith(f"{path}: 'noise.b' is missing")
    # A bad override of a valid file is the command line's.
    with pytest.raises(InputError) as error:
        load_config(None, {"refine.grow_pixels": -1})
    assert str(error.value).startswith("command-line option: 'refine.grow_pixels' must be in [0, 50]")


def test_a_camera_file_in_a_sequence_folder_without_its_own_camera_is_named_when_not_read(tmp_path, caplog):
    """A TUM folder states no camera: without --config the default camera is used, and a
    camera TOML lying in the folder (most likely the sequence's own) gets a warning naming it."""
    import logging

    from annotate_rgbd.config.layout import load_run_config
    from annotate_rgbd.config.settings import DEFAULT_CAMERA
    from annotate_rgbd.geometry.camera import Camera
    from annotate_rgbd.synthetic import make_sequence

    sequence = tmp_path / "seq"
    make_sequence(sequence, n_frames=2, width=64, height=48, seed=1,
                  camera=Camera(fx=52.5, fy=52.5, cx=31.5, cy=23.5, depth_scale=5000.0))
    with caplog.at_level(logging.INFO, logger="annotate_rgbd"):
        assert load_run_config(sequence, None).camera == DEFAULT_CAMERA
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    own = sequence / "camera.toml"
    own.write_text("[camera]\nfx = 52.5\nfy = 52.5\ncx = 31.5\ncy = 23.5\ndepth_scale = 5000.0\n")
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="annotate_rgbd"):
        assert load_run_config(sequence, None).camera == DEFAULT_CAMERA
    warned = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warned) == 1 and f"{own} is not read (no --config)" in warned[0] and "fx 525" in warned[0]
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="annotate_rgbd"):
        assert load_run_config(sequence, str(own)).camera.fx == 52.5
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]

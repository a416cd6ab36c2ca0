"""Camera intrinsics that are likely a mistake: a half-written [camera] table, focal lengths
that do not fit the images."""

from __future__ import annotations

import logging
import math

import pytest

from annotate_rgbd.config.camera_checks import partial_intrinsics
from annotate_rgbd.config.settings import DEFAULT_CAMERA, load_config
from annotate_rgbd.io.sequence import focal_problem


@pytest.mark.parametrize("table, problem", [
    ({"fx": 517.3, "fy": 516.5, "cx": 318.6, "cy": 255.3}, None),
    ({"depth_scale": 1000.0}, None),  # only the units: the default camera is meant
    ({}, None),
    ({"fy": 516.5, "cx": 318.6, "cy": 255.3, "depth_scale": 5000.0},
     "[camera] gives fy, cx, cy but not fx: the default fx = 525 is used"),
    ({"fx": 1}, "[camera] gives fx but not fy, cx, cy: the default fy = 525, cx = 319.5, cy = 239.5 are used"),
])
def test_partial_intrinsics(table, problem):
    found = partial_intrinsics(table, DEFAULT_CAMERA)
    assert found == problem if problem is None else found.startswith(problem)


def test_a_config_file_without_fx_warns_once_naming_the_file(tmp_path, caplog):
    path = tmp_path / "camera.toml"
    path.write_text("[camera]\nfy = 516.5\ncx = 318.6\ncy = 255.3\n")
    with caplog.at_level(logging.WARNING, logger="annotate_rgbd"):
        config = load_config(path, {"camera.depth_scale": 1000.0})
    assert config.camera.fx == DEFAULT_CAMERA.fx and config.camera.fy == 516.5
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and lines[0].startswith(f"{path}: [camera] gives fy, cx, cy but not fx")
    # The command line completes the file: no warning; it alone half-writes the camera: one.
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="annotate_rgbd"):
        assert load_config(path, {"camera.fx": 517.3}).camera.fx == 517.3
        assert not caplog.records
        load_config(None, {"camera.fx": 517.3})
    assert [r.getMessage() for r in caplog.records] == [
        "command-line option: [camera] gives fx but not fy, cx, cy: the default fy = 525, cx = 319.5, cy = 239.5 are used "
        "(the ROS default of a Kinect v1 at 640x480); give all four intrinsics of your camera"]


@pytest.mark.parametrize("fx, fy, width, expect", [
    (525.0, 525.0, 640, None),       # Kinect v1: 63 degrees
    (481.2, -480.0, 640, None),      # ICL-NUIM: fy negative
    (262.5, 262.5, 320, None),       # half resolution
    (1.0, 1.0, 640, "180 degree field of view"),
    (525.0, 525.0, 4000, "151 degree"),   # intrinsics of another resolution
    (5250.0, 5250.0, 640, "7 degree"),     # a tenth-pixel unit
    (525.0, 700.0, 640, "1.33 times fx"),
])
def test_focal_problem(fx, fy, width, expect):
    found = focal_problem(fx, fy, width, 480)
    if expect is None:
        assert found is None
    else:
        assert expect in found
    # The bound is the field of view: check it independently.
    fov = 2 * math.degrees(math.atan(width / 2 / abs(fx)))
    assert (found is not None and "field of view" in found) == (not 30 <= fov <= 150)


@pytest.mark.parametrize("command", ["cvat2mask", "propose"])
def test_both_commands_warn_about_focal_lengths_of_another_resolution(tmp_path, command):
    # The sample is 320x240: full-resolution focal lengths (and principal point) do not fit it.
    from conftest import SAMPLE_DATA

    from annotate_rgbd.pipeline.scene import run_cvat2mask
    from annotate_rgbd.propose.run import run_propose

    config = load_config(SAMPLE_DATA / "camera.toml", {"camera.fx": 2100.0, "camera.fy": 2100.0,
                                                         "propose.every": 6})
    if command == "cvat2mask":
        warnings = run_cvat2mask(SAMPLE_DATA / "sequence", [SAMPLE_DATA / "annotations.xml"], tmp_path / "o",
                                 config).warnings
    else:
        warnings = run_propose(SAMPLE_DATA / "sequence", tmp_path / "o", config, workers=1).warnings
    focal = [line for line in warnings if "field of view" in line]
    assert len(focal) == 1 and "fx = 2100 gives the 320x240 depth images a 9 degree field of view" in focal[0]

"""The depth-scale sanity check: what the first frames' depth says about the configured scale."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest
from conftest import SAMPLE_DATA, reference_data
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.geometry.depth_range import depth_scale_hint, median_raw_depth


def test_a_plausible_scale_gives_no_hint():
    assert depth_scale_hint([7500.0, 8000.0], 5000.0) is None  # TUM: 1.5-1.6 m
    assert depth_scale_hint([800.0], 1000.0) is None  # RealSense: 0.8 m
    assert depth_scale_hint([None], 5000.0) is None  # no valid depth: nothing to say


def test_millimetres_read_as_tum_units_suggest_1000():
    hint = depth_scale_hint([797.0, 810.0, 790.0], 5000.0)
    assert "median depth of the first frames is 0.16 m, closer than an indoor RGB-D sensor sees" in hint
    assert "suggests depth_scale 1000 (millimetres: median 0.80 m)" in hint


def test_tum_units_read_as_millimetres_suggest_5000():
    hint = depth_scale_hint([7500.0], 1000.0)
    assert "is 7.50 m, farther than" in hint and "suggests depth_scale 5000" in hint


def test_no_common_scale_fits():
    hint = depth_scale_hint([3.0], 1000.0)  # 3 mm
    assert hint.endswith("check [camera] depth_scale")


def test_invalid_values_are_left_out_of_the_median():
    depth = np.array([[0, 65535, 800], [810, 790, 0]], dtype=np.uint16)
    assert median_raw_depth(depth) == 800.0
    assert median_raw_depth(np.zeros((3, 3), np.uint16)) is None


def _millimetre_copy(tmp_path):
    """The sample's room shrunk to a third (median 0.8 m, a desk-sized scene) with its depth in
    millimetres, while the camera.toml still says 5000."""
    sequence = tmp_path / "sequence"
    shutil.copytree(SAMPLE_DATA / "sequence", sequence)
    for path in (sequence / "depth").glob("*.png"):
        depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.float64)
        cv2.imwrite(str(path), np.round(depth / 5000 / 3 * 1000).astype(np.uint16))
    return sequence


@pytest.mark.parametrize("command", ["cvat2mask", "propose"])
def test_both_commands_say_which_scale_the_data_suggests(tmp_path, command):
    sequence = _millimetre_copy(tmp_path)
    args = [command, str(sequence), *([str(SAMPLE_DATA / "annotations.xml")] if command == "cvat2mask" else []),
            "--out", str(tmp_path / "out"), "--config", str(SAMPLE_DATA / "camera.toml"), "--jobs", "1"]
    result = CliRunner().invoke(app, args)
    assert result.output.count("suggests depth_scale 1000") == 1, result.output


def test_real_realsense_millimetres_without_a_config_are_caught():
    folder = reference_data("realsense_d435_office")
    depth = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted((folder / "depth").glob("*.png"))[:3]]
    hint = depth_scale_hint([median_raw_depth(d) for d in depth], 5000.0)  # the default camera's scale
    assert hint is not None and "suggests depth_scale 1000" in hint
    tum = reference_data("tum_fr1_rpy")
    depth = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted((tum / "depth").glob("*.png"))[:3]]
    assert depth_scale_hint([median_raw_depth(d) for d in depth], 5000.0) is None
    assert "suggests depth_scale 5000" in depth_scale_hint([median_raw_depth(d) for d in depth], 1000.0)

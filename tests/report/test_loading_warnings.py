"""Warnings of loading the configuration (a half-written [camera] table) reach the run's report,
not only the terminal: the summary's "N warnings (see report.json)" counts them, and a reader
of the report later learns that the camera was partly the default one."""

from __future__ import annotations

import json
import logging
import subprocess
import sys

from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.logs import collect_warnings, scene_warnings

from conftest import SAMPLE_DATA

HALF_CAMERA = "[camera]\nfx = 262.5\ncx = 159.5\ncy = 119.5\ndepth_scale = 5000.0\n"
PROBLEM = "[camera] gives fx, cx, cy but not fy: the default fy = 525 is used"


def _report_warnings(out) -> list[str]:
    return json.loads((out / "report.json").read_text())["warnings"]


def test_cvat2mask_keeps_the_configuration_warning_in_its_report(tmp_path):
    camera = tmp_path / "camera.toml"
    camera.write_text(HALF_CAMERA)
    result = CliRunner().invoke(app, ["cvat2mask", str(SAMPLE_DATA / "sequence"), str(SAMPLE_DATA / "annotations.xml"),
                                      "-c", str(camera), "-o", str(tmp_path / "out"), "-j", "1"])
    assert result.exit_code == 0, result.output
    warnings = _report_warnings(tmp_path / "out")
    assert warnings[0].startswith(f"{camera}: {PROBLEM}")
    assert sum(PROBLEM in line for line in warnings) == 1
    printed = [line for line in result.stderr.splitlines() if line.startswith("warning: ")]
    assert len(printed) == len(warnings)  # each printed once, and each in the report
    assert f"{len(warnings)} warnings (see {tmp_path / 'out' / 'report.json'})" in result.stdout


def test_propose_keeps_the_configuration_warning_in_its_report(tmp_path):
    camera = tmp_path / "camera.toml"
    camera.write_text(HALF_CAMERA)
    result = CliRunner().invoke(app, ["propose", str(SAMPLE_DATA / "sequence"), "-c", str(camera), "-o",
                                      str(tmp_path / "out"), "-j", "1", "--every", "6"])
    assert result.exit_code == 0, result.output
    warnings = _report_warnings(tmp_path / "out")
    assert warnings[0].startswith(f"{camera}: {PROBLEM}") and sum(PROBLEM in line for line in warnings) == 1


def test_a_batch_scene_keeps_its_configuration_warning_without_the_scene_name(tmp_path):
    camera = tmp_path / "camera.toml"
    camera.write_text(HALF_CAMERA)
    manifest = tmp_path / "batch.toml"
    manifest.write_text(f"""
[[scene]]
name = "half"
sequence = "{SAMPLE_DATA / 'sequence'}"
annotations = ["{SAMPLE_DATA / 'annotations.xml'}"]
config = "{camera}"
out = "out/half"

[[scene]]
name = "whole"
sequence = "{SAMPLE_DATA / 'sequence'}"
annotations = ["{SAMPLE_DATA / 'annotations.xml'}"]
config = "{SAMPLE_DATA / 'camera.toml'}"
out = "out/whole"
""")
    result = CliRunner().invoke(app, ["batch", str(manifest), "--jobs", "1"])
    assert result.exit_code == 0, result.output
    assert f"warning: half: {camera}: {PROBLEM}" in result.stderr  # the terminal names the scene
    assert _report_warnings(tmp_path / "out" / "half")[0].startswith(f"{camera}: {PROBLEM}")
    assert not any(PROBLEM in line for line in _report_warnings(tmp_path / "out" / "whole"))


def test_collect_warnings_takes_warnings_only_and_leaves_them_printed(caplog):
    log = logging.getLogger("annotate_rgbd")  # as every module of the package logs
    with caplog.at_level(logging.INFO, logger="annotate_rgbd"):
        with scene_warnings("scene"), collect_warnings() as found:
            log.info("a note")
            log.warning("%s: %s", "f.png", "a problem")
        log.warning("after the block")
    assert found == ["f.png: a problem"]
    assert [r.getMessage() for r in caplog.records] == ["scene: a note", "scene: f.png: a problem", "after the block"]


def test_collected_warnings_are_still_printed_where_no_logging_is_set_up():
    # A library caller that configured no logging sees the package's warnings through Python's
    # last resort; collecting them must not take that away.
    code = ("import logging\nfrom annotate_rgbd.logs import collect_warnings\n"
            "with collect_warnings() as found:\n    logging.getLogger('annotate_rgbd').warning('a problem')\n"
            "print(found)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "['a problem']" and result.stderr.strip() == "a problem"


def test_counted_is_plural_unless_one():
    from annotate_rgbd.logs import counted

    assert [counted(n, "plane track") for n in (0, 1, 2)] == ["0 plane tracks", "1 plane track", "2 plane tracks"]

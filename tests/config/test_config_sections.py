"""The ``[detect]``, ``[propose]``, ``[link]`` and ``[evaluate]`` sections: read from TOML and
``--set`` like every other section, checked with the same one-line errors, documented in the
the configuration page (docs/configuration.md), and really used by ``propose`` (``evaluate``'s section: tests/test_evaluate.py)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.config.evaluate import EvaluateConfig
from annotate_rgbd.config.propose import DetectorConfig, LinkConfig, ProposeConfig
from annotate_rgbd.config.settings import OTHER_COMMANDS_SECTIONS, Config, config_to_dict, load_config
from annotate_rgbd.errors import InputError
from annotate_rgbd.io.sequence import read_sequence

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "sample_data"
SAMPLE_PIXELS = 320 * 240


def test_the_sections_are_read_from_toml_and_set(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text("[detect]\ncell_px = 16\n[propose]\nevery = 4\nlabel = 'surface'\n[link]\nmax_gap = 0\n"
                    "[evaluate]\nfull = 0.5\n")
    config = load_config(path, {"detect.band_k": 4, "link.min_iou": 0.5})
    assert config.detect == DetectorConfig(cell_px=16, band_k=4.0)
    assert config.propose == ProposeConfig(every=4, label="surface")
    assert config.link == LinkConfig(max_gap=0, min_iou=0.5)
    assert config.evaluate == EvaluateConfig(full=0.5)
    assert isinstance(config.detect.band_k, float)  # an integer given for a float is a float


CONFIGURATION_PAGE = ROOT / "docs" / "configuration.md"


def _section_blocks(text: str) -> dict[str, list[str]]:
    """The ```toml blocks of the configuration page under each ``## `[section]` `` heading (a
    heading may name several sections: ``## `[stitch]`, `[[parts]]` ``)."""
    blocks: dict[str, list[str]] = {}
    for chunk in text.split("\n## ")[1:]:
        heading, _, body = chunk.partition("\n")
        names = [name.strip("[]") for name in heading.replace("`", "").split(", ")]
        found = body.split("```toml\n")[1:]
        blocks[names[0]] = [block[: block.index("```")] for block in found]
        for name in names[1:]:
            blocks[name] = blocks[names[0]]
    return blocks


def test_the_configuration_page_documents_every_key_with_its_default(tmp_path):
    blocks = _section_blocks(CONFIGURATION_PAGE.read_text(encoding="utf-8"))
    defaults = config_to_dict(Config())
    sections = [name for name, value in defaults.items() if isinstance(value, dict)]
    assert {"camera", "ransac", "noise", "detect", "propose", "link", "evaluate"} <= set(sections)
    for name in sections:
        assert name in blocks, f"docs/configuration.md has no section [{name}]"
        # The section's first block holds every key with its default, one line per key, in order.
        block = next(b for b in blocks[name] if f"[{name}]" in b)
        assert tomllib.loads(block) == {name: defaults[name]}, name
        keys = [line.split("=")[0].strip() for line in block.splitlines()[1:] if "=" in line and not line.startswith("#")]
        assert keys == list(defaults[name]), name
    # Every other block (examples: [colour_camera], [[parts]], a quadratic noise model) is a valid
    # configuration.
    for number, block in enumerate(b for name, found in blocks.items() for b in found):
        path = tmp_path / f"block{number}.toml"
        path.write_text(block)
        load_config(path)


def test_the_configuration_check_fails_on_a_missing_key_or_another_default(tmp_path, monkeypatch):
    text = CONFIGURATION_PAGE.read_text(encoding="utf-8")
    for broken in (text.replace("max_gap = 2 ", "max_gap = 3 "), text.replace("band_k = 3.0 ", "")):
        assert broken != text
        page = tmp_path / "configuration.md"
        page.write_text(broken)
        monkeypatch.setattr(sys.modules[__name__], "CONFIGURATION_PAGE", page)
        with pytest.raises(AssertionError):
            test_the_configuration_page_documents_every_key_with_its_default(tmp_path)


@pytest.mark.parametrize(
    "text, message",
    [
        ("[detect]\ncell_px = 1\n", "'detect.cell_px' must be an integer >= 2, got 1"),
        ("[detect]\ncell_px = 20.5\n", "'detect.cell_px' must be an integer, got 20.5"),
        ("[detect]\nband_k = nan\n", "'detect.band_k' must be a finite number, got nan"),
        ("[detect]\nplanar_k = 0\n", "'detect.planar_k' must be > 0, got 0.0"),
        ("[detect]\nmin_angle_deg = 30\n", "'detect.min_angle_deg' must be > 0 and at most detect.max_angle_deg, got 30.0"),
        ("[detect]\nmin_area_fraction = 2\n", "'detect.min_area_fraction' must be in (0, 1], got 2.0"),
        ("[detect]\ncell_size = 20\n", "unknown key 'detect.cell_size' (known in [detect]: cell_px, "),
        ("[detect]\nnoise_a = 0.001\n", "unknown key 'detect.noise_a'"),  # the noise model is [noise]'s
        ("[propose]\nevery = 0\n", "'propose.every' must be an integer >= 1, got 0"),
        ("[propose]\nlabel = ' '\n", "'propose.label' must be a CVAT label: visible text without control characters, got ' '"),
        ("[propose]\nlabel = 3\n", "'propose.label' must be a string, got 3"),
        ("[propose]\npiece_fraction = 1.5\n", "'propose.piece_fraction' must be in (0, 1], got 1.5"),
        ("[link]\nmin_iou = 1.5\n", "'link.min_iou' must be in (0, 1], got 1.5"),
        ("[link]\nmax_gap = -1\n", "'link.max_gap' must be >= 0, got -1"),
        ("[evaluate]\nfull = 0\n", "'evaluate.full' must be in (0, 1], got 0.0"),
        ("[evaluate]\npartial = true\n", "'evaluate.partial' must be a number, got True"),
    ],
)
def test_bad_values_are_one_line_errors_naming_the_file_and_key(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError) as error:
        load_config(path)
    assert str(error.value).startswith(f"{path}: {message}")
    assert "\n" not in str(error.value)


def test_set_reaches_the_sections_and_is_blamed_on_the_command_line():
    assert load_config(None, {"detect.merge_gap_cells": 0}).detect.merge_gap_cells == 0
    with pytest.raises(InputError) as error:
        load_config(None, {"detect.x": 1})
    assert str(error.value).startswith("command-line option: unknown key 'detect.x' (known in [detect]: ")
    with pytest.raises(ValueError, match=r"^'link.max_speed' must be >= 0, got -1.0$"):
        LinkConfig(max_speed=-1.0)  # from Python: the same rule, as a ValueError


def test_a_cvat2mask_record_leaves_the_other_commands_sections_out():
    recorded = config_to_dict(Config(), leave_out=OTHER_COMMANDS_SECTIONS)
    assert not set(OTHER_COMMANDS_SECTIONS) & set(recorded)
    assert {"camera", "filter", "ransac", "noise", "refine"} <= set(recorded)
    assert set(config_to_dict(Config())) == set(recorded) | set(OTHER_COMMANDS_SECTIONS)


def _propose(out: Path, *options: str):
    result = CliRunner().invoke(app, ["propose", str(SAMPLE / "sequence"), "--out", str(out), "--jobs", "1", *options])
    report = json.loads((out / "report.json").read_text()) if result.exit_code == 0 else None
    return result, report


def _areas(report: dict) -> list[int]:
    return [p["area"] for f in report["frames"] if f["status"] == "written" for p in f["planes"]]


def test_set_detect_changes_what_propose_proposes(tmp_path):
    camera = ["--config", str(SAMPLE / "camera.toml"), "--every", "6"]
    result, default = _propose(tmp_path / "default", *camera)
    assert result.exit_code == 0, result.output
    # The sample has planes between 1 % and 10 % of its 320x240 frames: the setting must matter.
    assert any(area < 0.1 * SAMPLE_PIXELS for area in _areas(default))
    result, larger = _propose(tmp_path / "larger", *camera, "--set", "detect.min_area_fraction=0.1")
    assert result.exit_code == 0, result.output
    assert _areas(larger) and all(area >= 0.1 * SAMPLE_PIXELS for area in _areas(larger))
    assert larger["config"]["detect"]["min_area_fraction"] == 0.1
    assert larger["inputs"]["min_area_fraction"] == 0.1


def test_a_toml_propose_section_changes_the_frames_and_the_label(tmp_path):
    config = tmp_path / "scene.toml"
    config.write_text((SAMPLE / "camera.toml").read_text() + "\n[propose]\nevery = 7\nlabel = 'surface'\n")
    result, report = _propose(tmp_path / "out", "--config", str(config))
    assert result.exit_code == 0, result.output
    depth = read_sequence(SAMPLE / "sequence").depth.files

    def processed(report: dict, every: int) -> None:  # each N-th depth frame, unless it has no RGB frame
        done = [f["depth"] for f in report["frames"]]
        assert done == [d for d in depth[::every] if not any(s.startswith(d) for s in report["skipped"])]
        assert len(done) + len(report["skipped"]) == len(depth[::every])

    processed(report, 7)
    assert report["inputs"]["every"] == 7 and report["config"]["propose"]["label"] == "surface"
    assert 'label="surface"' in (tmp_path / "out" / "proposals.xml").read_text()
    # The option beats the file, as in cvat2mask.
    result, report = _propose(tmp_path / "again", "--config", str(config), "--every", "9")
    processed(report, 9)


@pytest.mark.parametrize(
    "options, message",
    [
        (["--set", "detect.cell_px=1"], "error: command-line option: 'detect.cell_px' must be an integer >= 2, got 1"),
        (["--set", "link.min_iou=0"], "error: command-line option: 'link.min_iou' must be in (0, 1], got 0.0"),
        (["--label", ""], "error: --label '' is empty: give the CVAT label of the proposed planes"),
    ],
)
def test_propose_refuses_bad_values_in_one_line(tmp_path, options, message):
    result, _ = _propose(tmp_path / "out", *options)
    assert result.exit_code == 1
    assert result.stderr == message + "\n"
    assert not (tmp_path / "out").exists()

"""One output-folder contract for every command that writes (annotate_rgbd.io.outdir.OutputFolder):
links refused, one run at a time, one command per folder, no stale file after a re-run or a crash."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import SAMPLE_DATA
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.config.settings import load_config
from annotate_rgbd.errors import InputError, OutputError
from annotate_rgbd.io.outdir import OUTPUTS_RECORD, OutputFolder, OutputLock, read_outputs_record
from annotate_rgbd.pipeline.scene import run_cvat2mask

FAST = {"ransac.num_iterations": 200}
SEQUENCE, ANNOTATIONS = SAMPLE_DATA / "sequence", SAMPLE_DATA / "annotations.xml"


def _config():
    return load_config(SAMPLE_DATA / "camera.toml", FAST)


def _masks(folder: Path) -> list[str]:
    return sorted(p.name for p in (folder / "masks").iterdir()) if (folder / "masks").is_dir() else []


def _propose(out: Path, *extra: str):
    return CliRunner().invoke(app, ["propose", str(SEQUENCE), "--out", str(out), "--config",
                                    str(SAMPLE_DATA / "camera.toml"), "--jobs", "1", *extra])


def test_propose_refuses_a_symlinked_masks_folder(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    out = tmp_path / "out"
    out.mkdir()
    (out / "masks").symlink_to(elsewhere)
    result = _propose(out)
    assert result.exit_code == 1
    assert "is a symbolic link" in result.output and "Traceback" not in result.output
    assert not any(elsewhere.iterdir())


def test_propose_refuses_a_busy_folder(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    with OutputLock(out):
        result = _propose(out)
    assert result.exit_code == 1 and "is writing to this folder" in result.output
    assert not (out / "masks").exists()


def test_propose_leaves_no_stale_mask_after_a_sparser_run(tmp_path):
    out = tmp_path / "out"
    assert _propose(out).exit_code == 0
    every_frame = _masks(out)
    assert _propose(out, "--every", "5").exit_code == 0
    report = json.loads((out / "report.json").read_text())
    written = sorted(Path(f["mask"]).name for f in report["frames"] if f["status"] == "written")
    assert _masks(out) == written and len(written) < len(every_frame)
    assert read_outputs_record(out) == ("propose", {f"masks/{name}" for name in written})


def test_a_folder_holds_one_commands_output(tmp_path):
    run_cvat2mask(SEQUENCE, [ANNOTATIONS], tmp_path / "masks_run", _config())
    result = _propose(tmp_path / "masks_run", "--set", "camera.depth_scale=500")
    assert result.exit_code == 1 and "holds the output of `cvat2mask`" in result.output
    # The folder's error is the only line: propose checks it before it reads a frame (with a wrong
    # depth scale, the frames' own warning came first).
    assert result.stderr.splitlines() == [f"error: {tmp_path / 'masks_run'}: holds the output of `cvat2mask`, not of "
                                          "`propose`: choose another --out (or remove this folder)"]
    assert json.loads((tmp_path / "masks_run" / "report.json").read_text())["tool"]["name"] == "annotate-rgbd"
    assert _propose(tmp_path / "proposals").exit_code == 0
    with pytest.raises(OutputError, match="holds the output of `propose`"):
        run_cvat2mask(SEQUENCE, [ANNOTATIONS], tmp_path / "proposals", _config())


def test_a_folder_of_an_older_version_is_known_by_its_report(tmp_path):
    """Runs made before the outputs record: the report says which command made them."""
    run_cvat2mask(SEQUENCE, [ANNOTATIONS], tmp_path, _config())
    (tmp_path / OUTPUTS_RECORD).unlink()
    with pytest.raises(OutputError, match="holds the output of `cvat2mask`"):
        OutputFolder(tmp_path, "propose").open()


@pytest.mark.parametrize("command", [["review"], ["stats"], ["export-cvat", "X"]])
def test_readers_and_review_wait_for_a_run_that_writes(tmp_path, command):
    run_cvat2mask(SEQUENCE, [ANNOTATIONS], tmp_path / "run", _config())
    args = [command[0], str(tmp_path / "run"), *[str(tmp_path / "out.xml") for _ in command[1:]]]
    with OutputLock(tmp_path / "run"):
        result = CliRunner().invoke(app, args)
    assert result.exit_code == 1 and "is writing to this folder" in result.output
    assert not (tmp_path / "run" / "overlays").exists() and not (tmp_path / "out.xml").exists()
    assert CliRunner().invoke(app, args).exit_code == 0


def test_a_run_stopped_by_a_bad_frame_leaves_nothing_stale(tmp_path):
    """A fatal frame half-way (another size): the next run owns what the stopped one wrote."""
    sequence = tmp_path / "sequence"
    shutil.copytree(SEQUENCE, sequence)
    depth = sorted((sequence / "depth").iterdir())
    original = depth[12].read_bytes()
    cv2.imwrite(str(depth[12]), np.zeros((10, 10), np.uint16))
    out = tmp_path / "out"
    with pytest.raises(InputError, match="depth image is 10x10"):
        run_cvat2mask(sequence, [ANNOTATIONS], out, _config(), workers=2)
    assert _masks(out)  # it stopped half-way
    depth[12].write_bytes(original)
    part = SAMPLE_DATA / "parts" / "0-11.xml"
    run_cvat2mask(sequence, [part], out, _config(), offsets={"0-11.xml": 0})
    run_cvat2mask(sequence, [part], tmp_path / "clean", _config(), offsets={"0-11.xml": 0})
    assert _masks(out) == _masks(tmp_path / "clean")


KILLED_RUN = textwrap.dedent("""
    import os, sys
    from pathlib import Path
    from annotate_rgbd.config.settings import load_config
    from annotate_rgbd.pipeline import resume
    from annotate_rgbd.pipeline.scene import run_cvat2mask

    recorded = resume.Journal.record
    count = [0]

    def record_then_die(self, name, result):
        count[0] += 1
        if count[0] == 6:  # the 6th mask is on disk, not in the journal: a kill between the two
            os._exit(9)
        recorded(self, name, result)

    resume.Journal.record = record_then_die
    data = Path(sys.argv[1])
    run_cvat2mask(data / "sequence", [data / "annotations.xml"], Path(sys.argv[2]),
                  load_config(data / "camera.toml", {"ransac.num_iterations": 200}), raw_masks=True, instance_ids=True)
""")


@pytest.mark.slow  # kills or interrupts processes: `pytest -m "not slow"` leaves it out
def test_a_killed_run_leaves_nothing_stale(tmp_path):
    out = tmp_path / "out"
    killed = subprocess.run([sys.executable, "-c", KILLED_RUN, str(SAMPLE_DATA), str(out)], capture_output=True,
                            timeout=300)
    assert killed.returncode == 9, killed.stderr.decode()
    assert len(_masks(out)) == 6 and (out / "masks_raw").is_dir() and (out / "masks_id").is_dir()
    part = SAMPLE_DATA / "parts" / "9-18.xml"
    run_cvat2mask(SEQUENCE, [part], out, _config(), offsets={"9-18.xml": 9})
    run_cvat2mask(SEQUENCE, [part], tmp_path / "clean", _config(), offsets={"9-18.xml": 9})
    assert _masks(out) == _masks(tmp_path / "clean")
    assert not (out / "masks_raw").exists() and not (out / "masks_id").exists()
    assert sorted(os.listdir(out)) == sorted(os.listdir(tmp_path / "clean"))


@pytest.mark.parametrize("command", ["cvat2mask", "propose"])
def test_an_output_folder_in_the_sequence_s_image_folders_or_the_sequence_itself_is_refused(tmp_path, command):
    # A run's own files (contact_sheet.png, report.json) in depth/ would be read as frames by the
    # next run of a layout that lists the folder; in the sequence folder they mix with the inputs.
    # Refused before anything is written; a new folder inside the sequence folder is fine.
    sequence = tmp_path / "seq"
    shutil.copytree(SEQUENCE, sequence)
    before = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*"))
    runner = CliRunner()
    inputs = [str(sequence)] + ([str(ANNOTATIONS)] if command == "cvat2mask" else [])
    options = ["--config", str(SAMPLE_DATA / "camera.toml"), "--jobs", "1", "--set", "ransac.num_iterations=200"]
    for out, message in [(sequence, "is the sequence folder"), (sequence / "depth", "is the sequence's image folder"),
                         (sequence / "rgb" / "new" / "deeper", "is inside the sequence's image folder")]:
        result = runner.invoke(app, [command, *inputs, "--out", str(out), *options])
        assert result.exit_code == 1 and message in result.output and "Traceback" not in result.output
        assert result.output.count("\n") == 1 and result.output.startswith(f"error: {out}:")
        assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == before
    result = runner.invoke(app, [command, *inputs, "--out", str(sequence / "out"), *options, "--every", "5"]
                           if command == "propose" else [command, *inputs, "--out", str(sequence / "out"), *options])
    assert result.exit_code == 0, result.output
    assert (sequence / "out" / "masks").is_dir()

"""Standard output as the command line writes to it: a write that fails is one ``error:`` line
naming standard output, whichever command (or ``--help``, ``--version``) wrote."""

from __future__ import annotations

import errno
import os
import subprocess
import sys

import pytest
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from conftest import REPO_ROOT, SAMPLE_DATA

#: The command line of this tree (``-m`` puts the working folder first on ``sys.path``).
CLI = [sys.executable, "-m", "annotate_rgbd"]


def run_cli(args: list, stdout) -> subprocess.CompletedProcess:
    """The command line in a process of its own, standard output ``stdout``, standard error read."""
    return subprocess.run([*CLI, *map(str, args)], stdout=stdout, stderr=subprocess.PIPE, cwd=REPO_ROOT,
                          timeout=120)


#: Command lines that print only to standard output, besides the commands of a run.
HELP_AND_VERSION = [["--version"], ["stats", "-h"]]


def stdout_writers(run) -> list[list]:
    """Commands that print to standard output and nothing to standard error, given a run's folder."""
    return [["stats", run], ["stats", run, "--json"], ["evaluate", SAMPLE_DATA / "ground_truth", run / "masks"],
            ["presets"], ["presets", "fr1_desk"]]


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
def test_a_full_standard_output_is_one_line_naming_it(sample_run):
    # `stats RUN > /dev/full` said "error: No space left on device": no word of which file.
    with open("/dev/full", "wb") as full:
        for args in stdout_writers(sample_run[0]) + HELP_AND_VERSION:
            done = run_cli(args, full)
            assert (done.returncode, done.stderr.decode()) == (
                1, "error: cannot write to standard output: No space left on device\n"), args


def test_a_failed_write_of_another_file_is_not_said_as_standard_output(sample_run, monkeypatch):
    # An OSError without a file name (a failed write of an open file, as the journal's) is not
    # standard output's only because it names no file.
    def full_disk(report):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr("annotate_rgbd.report.stats.run_stats", full_disk)
    result = CliRunner().invoke(app, ["stats", str(sample_run[0])])
    assert (result.exit_code, result.stderr) == (1, "error: No space left on device\n")


def test_a_reader_of_standard_output_gone_ends_a_command_quietly(sample_run):
    # `stats RUN | head -c0`: as for export-cvat's stream output (test_output_integrity), status
    # 141 and nothing said; stats said "error: [Errno 32] Broken pipe".
    for args in stdout_writers(sample_run[0]):  # not HELP_AND_VERSION: Click's own exit 1, silent
        reader, writer = os.pipe()
        os.close(reader)
        try:
            done = run_cli(args, writer)
        finally:
            os.close(writer)
        assert (done.returncode, done.stderr.decode()) == (141, ""), args


def test_a_closed_standard_output_is_refused_before_any_work(sample_run, tmp_path):
    # `stats RUN >&-` exited 0 having printed nothing; `export-cvat RUN - >&-` ended in a traceback.
    run = sample_run[0]
    for args in [*stdout_writers(run), *HELP_AND_VERSION, ["export-cvat", run, "-"],
                 ["export", run, "--format", "coco", tmp_path / "coco"]]:
        done = subprocess.run([*CLI, *map(str, args)], stderr=subprocess.PIPE, cwd=REPO_ROOT, timeout=120,
                              preexec_fn=lambda: os.close(1))
        assert (done.returncode, done.stderr.decode()) == (1, "error: cannot write to standard output: it is closed "
                                                              "(to discard what the command prints, send it to "
                                                              "/dev/null)\n"), args
    assert not (tmp_path / "coco").exists()


def test_an_interrupt_while_a_class_is_defined_is_one_line(tmp_path):
    # SIGTERM arriving while an imported module defines a dataclass (the command's first imports)
    # surfaced in Python 3.11 as "RuntimeError: Error calling __set_name__", with a traceback.
    script = tmp_path / "script.py"
    script.write_text(
        "import os, signal\n"
        "from annotate_rgbd.cli.console import user_errors\n"
        "class Field:\n"
        "    def __set_name__(self, owner, name):\n"
        "        os.kill(os.getpid(), signal.SIGTERM)\n"
        "with user_errors():\n"
        "    class Record:\n"
        "        removed = Field()\n"
        "print('not reached')\n", encoding="utf-8")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60)
    assert (done.returncode, done.stdout) == (143, "")
    assert done.stderr.splitlines() == ["error: terminated; finished files are complete, nothing partial was left; "
                                        "run the same command again to continue"]

"""Outputs named on the command line: ``-`` is standard output, ``./-`` a file or folder named ``-``."""

from __future__ import annotations

from typer.testing import CliRunner

from annotate_rgbd.cli import app


def test_export_into_dot_slash_dash_is_a_folder_named_dash(sample_run, tmp_path, monkeypatch):
    # Path("./-") is Path("-"): export refused ./- as standard output, the name a user gives a
    # folder called "-".
    monkeypatch.chdir(tmp_path)
    run = str(sample_run[0])
    refused = CliRunner().invoke(app, ["export", run, "--format", "coco", "-"])
    assert (refused.exit_code, refused.stderr) == (
        1, "error: -: an export is a folder of files, not a stream: name the folder to write\n")
    assert not (tmp_path / "-").exists()
    for args in (["./-"], ["--out", "./-"], ["./-", "--out", str(tmp_path / "-")]):
        said = CliRunner().invoke(app, ["export", run, "--format", "coco", *args])
        assert said.exit_code == 0, said.output
        assert said.stdout == f"coco: 19 frames, 2 files in {tmp_path / '-'}\n"
        assert sorted(p.name for p in (tmp_path / "-").iterdir()) == ["annotations.json", "export.json"]
    both = CliRunner().invoke(app, ["export", run, "--format", "coco", "-", "--out", "./-"])
    assert (both.exit_code, both.stderr) == (1, f"error: two export folders given, - and --out {tmp_path / '-'}: "
                                                "give one\n")


def test_export_cvat_into_dot_slash_dash_is_a_file_named_dash(sample_run, tmp_path, monkeypatch):
    # It wrote the XML to standard output.
    monkeypatch.chdir(tmp_path)
    said = CliRunner().invoke(app, ["export-cvat", str(sample_run[0]), "./-", "--jobs", "1"])
    assert said.exit_code == 0, said.output
    assert said.stdout == f"8 plane tracks: {tmp_path / '-'}\n"
    assert (tmp_path / "-").read_bytes().startswith(b"<?xml")


def test_evaluate_per_frame_into_dot_slash_dash_is_a_file_named_dash(sample_run, tmp_path, monkeypatch):
    # It wrote the CSV to standard output (and the means to standard error).
    monkeypatch.chdir(tmp_path)
    masks = str(sample_run[0] / "masks")
    said = CliRunner().invoke(app, ["evaluate", masks, masks, "--per-frame", "./-"])
    assert said.exit_code == 0, said.output
    assert said.stdout.startswith("metric     mean\n")
    assert (tmp_path / "-").read_text().startswith("frame,")
    streamed = CliRunner().invoke(app, ["evaluate", masks, masks, "--per-frame", "-"])
    assert streamed.exit_code == 0 and streamed.stdout.startswith("frame,")
    empty = CliRunner().invoke(app, ["evaluate", masks, masks, "--per-frame", ""])
    assert empty.exit_code == 2 and "--per-frame is empty" in empty.stderr

"""Hostile and careless input, round 2 (issue 15): the items whose fix lives in the sequence
reader, the overlays, the palette and the writers.

Each test fails on the code before its fix: frames without shapes crash the overlays; a PNG
header announcing 2.5 Gpixel, a FIFO, a symlink out of the sequence, a 10-million-line list,
timestamps of 1.7e308 or ``NaN`` end in a traceback, a hang, a read outside the sequence or an
invalid report; the palette repeats colours after 3,823 planes; labels reach the CSV tables as
spreadsheet formulas.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import SAMPLE_DATA
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.review import review_run

W, H = 40, 30
CAMERA = "[camera]\nfx = 40.0\nfy = 40.0\ncx = 19.5\ncy = 14.5\ndepth_scale = 5000.0\n"


def timestamp(i: int) -> str:
    return f"{100 + 0.1 * i:.6f}"


def make_sequence(root: Path, n: int = 3) -> None:
    """TUM layout of ``n`` 40 x 30 frames of one tilted plane (2 to 2.3 m, every pixel valid)."""
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rows, cols = np.mgrid[0:H, 0:W]
    depth = (10000 + 30 * cols + 20 * rows).astype(np.uint16)
    for i in range(n):
        cv2.imwrite(str(root / f"depth/{timestamp(i)}.png"), depth)
        cv2.imwrite(str(root / f"rgb/{timestamp(i)}.png"), np.full((H, W, 3), 90 + 40 * i, np.uint8))
    for kind in ("rgb", "depth"):
        lines = [f"{timestamp(i)} {kind}/{timestamp(i)}.png" for i in range(n)]
        (root / f"{kind}.txt").write_text("# timestamp filename\n" + "\n".join(lines) + "\n")


def video_export(path: Path, n: int, body: str) -> Path:
    """A "CVAT for video 1.1" task of frames 0 .. n - 1."""
    path.write_text(
        '<?xml version="1.0" encoding="utf-8"?>\n<annotations><version>1.1</version><meta><task>'
        f"<start_frame>0</start_frame><stop_frame>{n - 1}</stop_frame><frame_filter></frame_filter>"
        f"<original_size><width>{W}</width><height>{H}</height></original_size></task></meta>\n"
        f"{body}\n</annotations>\n"
    )
    return path


def box(frame: int, outside: int = 0) -> str:
    return (
        f'<box frame="{frame}" keyframe="1" outside="{outside}" occluded="0" '
        'xtl="2" ytl="2" xbr="30" ybr="25" z_order="0"/>'
    )


def cvat2mask(*args: str):
    """``annotate-rgbd cvat2mask`` in this process (one worker); a traceback is re-raised."""
    result = CliRunner().invoke(app, ["cvat2mask", *map(str, args), "-j", "1"])
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result


def tiny_run(tmp_path: Path, *extra: str, n: int = 3, body: str | None = None):
    """cvat2mask on a tiny sequence; the default export has one track over every frame."""
    seq, out = tmp_path / "seq", tmp_path / "out"
    if not seq.exists():
        make_sequence(seq, n)
    camera = tmp_path / "camera.toml"
    camera.write_text(CAMERA)
    body = body if body is not None else '<track id="0" label="wall">' + "".join(box(f) for f in range(n)) + "</track>"
    xml = video_export(tmp_path / "a.xml", n, body)
    return cvat2mask(seq, xml, "-c", camera, "-o", out, *extra), out


def report_of(out: Path) -> dict:
    return json.loads((out / "report.json").read_text(encoding="utf-8"))


def error_line(result) -> str:
    """The single ``error:`` line of a failed run, which must have no traceback."""
    errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "Traceback" not in result.stderr, result.stderr
    return errors[0]


# --------------------------------------------------------------------------------------------
# 1. Overlays of annotated frames without shapes
# --------------------------------------------------------------------------------------------


def rgb_on_depth_grid(rgb_path: Path, shape: tuple[int, int]) -> np.ndarray:
    rgb = cv2.cvtColor(cv2.imread(str(rgb_path), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    return cv2.resize(rgb, (shape[1], shape[0]), interpolation=cv2.INTER_AREA) if rgb.shape[:2] != shape else rgb


def test_overlays_of_frames_without_shapes_on_the_sample(tmp_path):
    # wall_left is seen on some frames only: the others are annotated but have no shape.
    out = tmp_path / "out"
    result = cvat2mask(
        SAMPLE_DATA / "sequence", SAMPLE_DATA / "annotations.xml", "--config", SAMPLE_DATA / "camera.toml",
        "--out", out, "--overlays", "--label", "wall_left", "--set", "ransac.num_iterations=200",
    )
    assert result.exit_code == 0, result.stderr
    written = [f for f in report_of(out)["frames"] if f["status"] == "written"]
    empty = [f for f in written if not f["kept"] and not f["dropped"]]
    assert empty and len(empty) < len(written)
    assert sorted(p.name for p in (out / "overlays").iterdir()) == sorted(Path(f["mask"]).name for f in written)
    for frame in empty:  # nothing drawn: the overlay is the RGB frame itself, the mask all black
        overlay = cv2.cvtColor(cv2.imread(str(out / "overlays" / Path(frame["mask"]).name)), cv2.COLOR_BGR2RGB)
        assert not cv2.imread(str(out / frame["mask"])).any()
        assert np.array_equal(overlay, rgb_on_depth_grid(SAMPLE_DATA / "sequence" / frame["rgb"], overlay.shape[:2]))
    reviewed = review_run(out)
    assert len(reviewed.overlays) == len(written) and reviewed.warnings == []


def test_overlays_after_a_track_ends_before_the_task(tmp_path):
    # The track leaves the view at frame 1 (outside="1"); frames 1 and 2 stay annotated, empty.
    body = f'<track id="0" label="wall">{box(0)}{box(1, outside=1)}</track>'
    result, out = tiny_run(tmp_path, "--overlays", body=body)
    assert result.exit_code == 0, result.stderr
    frames = report_of(out)["frames"]
    assert [(f["status"], len(f["kept"])) for f in frames] == [("written", 1), ("written", 0), ("written", 0)]
    for i in (1, 2):
        overlay = cv2.imread(str(out / "overlays" / f"{timestamp(i)}.png"))
        assert np.array_equal(overlay, np.full((H, W, 3), 90 + 40 * i, np.uint8))
    assert len(review_run(out).overlays) == 3

"""Hostile and careless input, round 2 (issue 15): the items whose fix lives in the sequence
reader, the overlays, the palette and the writers.

Each test fails on the code before its fix: frames without shapes crash the overlays; a PNG
header announcing 2.5 Gpixel, a FIFO, a symlink out of the sequence, a 10-million-line list,
timestamps of 1.7e308 or ``NaN`` end in a traceback, a hang, a read outside the sequence or an
invalid report; the palette repeats colours after 3,823 planes; labels reach the CSV tables as
spreadsheet formulas.
"""

from __future__ import annotations

import csv
import json
import os
import struct
import threading
import zlib
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import SAMPLE_DATA
from skimage.color import rgb2lab
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.errors import InputError, OutputError
from annotate_rgbd.report.palette import MAX_PLANES, MIN_LIGHTNESS, plane_colours
from annotate_rgbd.review.review import review_run
from annotate_rgbd.io.sequence import MAX_FRAMES, MAX_IMAGE_PIXELS, MAX_LIST_BYTES, MAX_LIST_LINES, png_size, read_depth, read_sequence
from annotate_rgbd.io.writer import write_csv, write_json

from builders import CAMERA, H, W, box, error_line, timestamp, video_export
from builders import make_sequence as _make_sequence


def make_sequence(root: Path, n: int = 3) -> None:
    """The tiny scene with a different grey on every RGB frame."""
    _make_sequence(root, n, varied_rgb=True)


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
    drawn = {p.name: p.read_bytes() for p in (out / "overlays").iterdir()}
    reviewed = review_run(out)  # from the run's records: the same overlays
    assert {p.name: p.read_bytes() for p in reviewed.overlays} == drawn


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


# --------------------------------------------------------------------------------------------
# 2. Depth PNGs whose header announces a huge image
# --------------------------------------------------------------------------------------------


def chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def png_claiming(width: int, height: int) -> bytes:
    """A 16-bit grey PNG whose header says ``width`` x ``height``; its pixel data is a few zero rows."""
    ihdr = struct.pack(">IIBBBBB", width, height, 16, 0, 0, 0, 0)
    rows = zlib.compress(bytes((2 * width + 1) * 4))
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", rows) + chunk(b"IEND", b"")


@pytest.mark.parametrize("size", [(50000, 50000), (10000, 10000)], ids=["beyond-opencv", "beyond-bound"])
def test_a_depth_png_announcing_a_huge_image_fails_its_frame_alone(tmp_path, size):
    make_sequence(tmp_path / "seq")
    bomb = tmp_path / "seq" / "depth" / f"{timestamp(1)}.png"
    bomb.write_bytes(png_claiming(*size))
    result, out = tiny_run(tmp_path)
    assert result.exit_code == 1, result.stderr  # a failed frame fails the run
    message = (
        f"{bomb}: the PNG header says {size[0]}x{size[1]} pixels ({size[0] * size[1] / 1e6:.0f} Mpixel); images "
        f"over {MAX_IMAGE_PIXELS / 1e6:.0f} Mpixel are refused (a corrupt file or a decompression bomb)"
    )
    assert f"warning: {message}; failed (no mask)" in result.stderr.splitlines()
    frames = report_of(out)["frames"]
    assert [f["status"] for f in frames] == ["written", "failed", "written"]
    assert frames[1]["error"] == message
    assert sorted(p.name for p in (out / "masks").iterdir()) == [f"{timestamp(0)}.png", f"{timestamp(2)}.png"]


def test_png_size_reads_the_header_only(tmp_path):
    ok, encoded = cv2.imencode(".png", np.zeros((7, 13), np.uint16))
    assert ok and png_size(encoded, tmp_path / "a.png") == (13, 7)
    assert png_size(png_claiming(50000, 40000), tmp_path / "a.png") == (50000, 40000)


@pytest.mark.parametrize(
    ("data", "problem"),
    [
        (cv2.imencode(".tiff", np.zeros((4, 4), np.uint16))[1].tobytes(), "not a readable image (not a PNG file; depth images are 16-bit PNGs, as in TUM / ICL-NUIM)"),
        (b"", "not a readable image (not a PNG file; depth images are 16-bit PNGs, as in TUM / ICL-NUIM)"),
        (png_claiming(40, 30)[:32], "not a readable image (truncated PNG header)"),
        (png_claiming(40, 30)[:20] + b"\x01" + png_claiming(40, 30)[21:], "not a readable image (corrupt PNG header)"),
        (png_claiming(0, 30), "not a readable image (the PNG header says 0x30 pixels)"),
    ],
    ids=["tiff", "empty", "truncated", "bad-crc", "zero-width"],
)
def test_depth_that_is_no_png_or_has_a_broken_header(tmp_path, data, problem):
    path = tmp_path / "d.png"
    path.write_bytes(data)
    with pytest.raises(InputError) as caught:
        read_depth(path)
    assert str(caught.value) == f"{path}: {problem}"


# --------------------------------------------------------------------------------------------
# 3. FIFOs and symbolic links
# --------------------------------------------------------------------------------------------


@contextmanager
def watch_fifo(path: Path, after: float = 10.0):
    """Make ``path`` a FIFO; after ``after`` s, release anyone blocked reading it and record that."""
    os.mkfifo(path)
    blocked, stop = [], threading.Event()

    def release() -> None:
        while not stop.wait(0.2):
            try:  # succeeds only while a reader has the FIFO open
                fd = os.open(path, os.O_WRONLY | os.O_NONBLOCK)
            except OSError:
                continue
            blocked.append(True)
            os.close(fd)

    timer = threading.Timer(after, release)
    timer.start()
    try:
        yield blocked
    finally:
        timer.cancel()
        stop.set()


def test_a_fifo_in_place_of_a_depth_file_fails_its_frame_alone(tmp_path):
    make_sequence(tmp_path / "seq")
    fifo = tmp_path / "seq" / "depth" / f"{timestamp(1)}.png"
    fifo.unlink()
    with watch_fifo(fifo) as blocked:
        result, out = tiny_run(tmp_path)
    assert not blocked, "the run blocked on the FIFO"
    assert result.exit_code == 1, result.stderr  # a failed frame fails the run
    frames = report_of(out)["frames"]
    assert [f["status"] for f in frames] == ["written", "failed", "written"]
    assert frames[1]["error"] == f"{fifo}: not a regular file (a FIFO); refused"


def test_a_fifo_in_place_of_a_list_is_refused(tmp_path):
    make_sequence(tmp_path / "seq")
    fifo = tmp_path / "seq" / "rgb.txt"
    fifo.unlink()
    with watch_fifo(fifo) as blocked:
        result, out = tiny_run(tmp_path)
    assert not blocked
    assert result.exit_code == 1
    assert error_line(result) == f"error: {fifo}: cannot read frame list: not a regular file (a FIFO); refused"


def link_out(seq: Path, outside: Path, how: str) -> Path:
    """Put a symbolic link in ``seq`` that leads to ``outside``; return the link."""
    if how == "file":
        link = seq / "depth" / f"{timestamp(1)}.png"
        link.unlink()
        link.symlink_to(outside / "secret.png")
    elif how == "folder":
        (seq / "depth").rename(outside / "depth")
        link = seq / "depth"
        link.symlink_to(outside / "depth")
    else:
        (seq / "depth.txt").rename(outside / "depth.txt")
        link = seq / "depth.txt"
        link.symlink_to(outside / "depth.txt")
    return link


@pytest.mark.parametrize("how", ["file", "folder", "list"])
def test_symbolic_links_out_of_the_sequence_are_refused_unopened(tmp_path, how):
    make_sequence(tmp_path / "seq")
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    link = link_out(tmp_path / "seq", outside, how)
    watched = outside / ("secret.png" if how == "file" else "depth.txt" if how == "list" else f"depth/{timestamp(0)}.png")
    watched.unlink(missing_ok=True)
    with watch_fifo(watched, after=5.0) as blocked:
        result, out = tiny_run(tmp_path)
    assert not blocked, f"{watched} was opened"
    assert result.exit_code == 1, result.stderr
    refused = link if how != "folder" else link / f"{timestamp(0)}.png"
    assert error_line(result) == f"error: {refused}: a symbolic link leads outside the sequence folder; refused"


def test_symbolic_links_inside_the_sequence_are_followed(tmp_path):
    seq = tmp_path / "seq"
    make_sequence(seq)
    (seq / "store").mkdir()
    depth = seq / "depth" / f"{timestamp(1)}.png"
    depth.rename(seq / "store" / "d1.png")
    depth.symlink_to(Path("..") / "store" / "d1.png")
    result, out = tiny_run(tmp_path)
    assert result.exit_code == 0, result.stderr
    assert [f["status"] for f in report_of(out)["frames"]] == ["written"] * 3


# --------------------------------------------------------------------------------------------
# 4. Huge lists
# --------------------------------------------------------------------------------------------


def test_a_list_larger_than_the_bound_is_refused_before_reading(tmp_path):
    make_sequence(tmp_path / "seq")
    path = tmp_path / "seq" / "rgb.txt"
    with open(path, "ab") as handle:  # sparse: no disk, and never read
        handle.truncate(MAX_LIST_BYTES + 1)
    with pytest.raises(InputError) as caught:
        read_sequence(tmp_path / "seq")
    assert str(caught.value) == f"{path}: cannot read frame list: file is 128 MiB; at most 128 MiB are read"


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("0 a\n" * (MAX_FRAMES + 1), f"line {MAX_FRAMES + 1}: more than {MAX_FRAMES} frames listed; at most {MAX_FRAMES} are read"),
        ("#\n" * (MAX_LIST_LINES + 1), f"more than {MAX_LIST_LINES} lines; refused"),
    ],
    ids=["frames", "lines"],
)
def test_lists_of_too_many_frames_or_lines_are_refused(tmp_path, text, problem):
    make_sequence(tmp_path / "seq")
    path = tmp_path / "seq" / "rgb.txt"
    path.write_text(text)
    with pytest.raises(InputError) as caught:
        read_sequence(tmp_path / "seq")
    assert str(caught.value) == f"{path}: {problem}"


def test_a_long_ordinary_list_reads_the_same_as_a_short_one(tmp_path):
    # 100,000 frames, shuffled: the fast paths give exactly what the line-by-line definition gives.
    seq = tmp_path / "seq"
    seq.mkdir()
    rng = np.random.default_rng(1)
    times = 1305031102 + np.arange(100_000) / 30
    order = rng.permutation(len(times))
    names = [f"rgb/{t:.6f}.png" if i % 7 else f"./rgb/sub/{t:.6f}.png" for i, t in enumerate(times)]
    (seq / "rgb.txt").write_text("# c\n" + "".join(f"{times[i]:.6f} {names[i]}\n" for i in order))
    (seq / "depth.txt").write_text("1305031102.0 depth/a.png\n")
    sequence = read_sequence(seq)
    np.testing.assert_array_equal(sequence.rgb.timestamps, np.array([f"{t:.6f}" for t in times], dtype=np.float64))
    assert sequence.rgb.files == tuple(names)


# --------------------------------------------------------------------------------------------
# 5. Timestamps and strict JSON
# --------------------------------------------------------------------------------------------


def strict_json(path: Path) -> dict:
    def refuse(constant: str):
        raise ValueError(f"{constant} in {path}")

    return json.loads(path.read_text(encoding="utf-8"), parse_constant=refuse)


@pytest.mark.parametrize("value", ["1.7e308", "-1.7e308", "1e20", "inf", "NaN"])
def test_absurd_timestamps_are_refused_naming_file_and_line(tmp_path, value):
    make_sequence(tmp_path / "seq")
    path = tmp_path / "seq" / "depth.txt"
    path.write_text(path.read_text().replace(f"{timestamp(1)} depth", f"{value} depth"))
    result, out = tiny_run(tmp_path)
    assert result.exit_code == 1, result.stderr
    why = "is not a timestamp" if value in ("inf", "NaN") else "is out of range (timestamps are within +-1e+19)"
    assert error_line(result) == f"error: {path}: line 5: '{value}' {why}"  # after three header lines


def test_timestamps_at_the_bound_give_a_strict_report(tmp_path):
    # Depth at +1e19 s and RGB at -1e19 s: far apart, but every number in report.json is finite.
    make_sequence(tmp_path / "seq")
    for kind, value in (("depth", "1e19"), ("rgb", "-1e19")):
        path = tmp_path / "seq" / f"{kind}.txt"
        path.write_text(path.read_text().replace(f"{timestamp(2)} {kind}", f"{value} {kind}"))
    result, out = tiny_run(tmp_path)
    assert result.exit_code == 0, result.stderr
    frames = strict_json(out / "report.json")["frames"]
    assert frames[-1]["depth_timestamp"] == 1e19 and frames[-1]["time_offset"] == round(timestamp_float(1) - 1e19, 6)


def timestamp_float(i: int) -> float:
    return float(timestamp(i))


@pytest.mark.parametrize("name", ["NaN", "inf", "-1e300"])
def test_image_names_that_are_no_sane_timestamp_are_refused(tmp_path, name):
    seq = tmp_path / "seq"
    make_sequence(seq)
    (seq / "rgb.txt").unlink()
    (seq / "depth.txt").unlink()
    bad = seq / "rgb" / f"{name}.png"
    bad.write_bytes((seq / "rgb" / f"{timestamp(0)}.png").read_bytes())
    with pytest.raises(InputError) as caught:
        read_sequence(seq)
    why = "is out of range (timestamps are within +-1e+19)" if name == "-1e300" else "is not a timestamp"
    assert str(caught.value) == f"{bad}: image name {why} (expected e.g. 1305031102.175304.png)"


@pytest.mark.parametrize(
    ("data", "where"),
    [
        ({"frames": [{"time_offset": 0.5}, {"time_offset": float("inf")}]}, "frames[1].time_offset is inf"),
        ([1.0, {"equation": [0.0, float("nan")]}], "[1].equation[1] is nan"),
        (float("-inf"), "the value is -inf"),
    ],
)
def test_json_with_nan_or_infinity_is_refused(tmp_path, data, where):
    path = tmp_path / "report.json"
    with pytest.raises(OutputError) as caught:
        write_json(path, data)
    assert str(caught.value) == f"{path}: {where}, which JSON cannot hold (a bug: please report it)"
    assert not path.exists()
    write_json(path, {"a": [1.5, None, -0.0, 1e300]})
    assert strict_json(path) == {"a": [1.5, None, -0.0, 1e300]}


# --------------------------------------------------------------------------------------------
# 6. Colours for many planes
# --------------------------------------------------------------------------------------------


def test_every_plane_id_a_16_bit_mask_can_hold_gets_its_own_colour():
    colours = plane_colours(MAX_PLANES)
    assert colours.shape == (MAX_PLANES, 3) and colours.dtype == np.uint8
    assert len(np.unique(colours, axis=0)) == MAX_PLANES
    assert rgb2lab(colours[None] / 255.0)[0][:, 0].min() >= MIN_LIGHTNESS
    # The first 3,823 colours (the whole greedy palette) do not depend on how many are asked for.
    np.testing.assert_array_equal(colours[:3823], plane_colours(3823))
    np.testing.assert_array_equal(plane_colours(4000), colours[:4000])


def test_4000_tracks_get_4000_colours_through_the_command_line(tmp_path):
    n = 2
    body = "".join(
        f'<track id="{t}" label="p{t}"><box frame="0" keyframe="1" outside="0" occluded="0" '
        f'xtl="{t % 40}" ytl="{t // 40 % 30}" xbr="{t % 40 + 1}" ybr="{t // 40 % 30 + 1}" z_order="0"/></track>'
        for t in range(4000)
    )
    result, out = tiny_run(tmp_path, n=n, body=body)
    assert result.exit_code == 0, result.stderr
    colours = (out / "planes.csv").read_text().splitlines()[1:]
    assert len(colours) == 4000 and len({line.split(",")[1] for line in colours}) == 4000


def test_more_planes_than_16_bits_can_number_are_refused():
    with pytest.raises(InputError) as caught:
        plane_colours(MAX_PLANES + 1)
    assert str(caught.value) == f"{MAX_PLANES + 1} planes to colour; masks give distinct colours to at most {MAX_PLANES}"


# --------------------------------------------------------------------------------------------
# 7. Formulas in CSV cells
# --------------------------------------------------------------------------------------------


def test_csv_cells_that_a_spreadsheet_would_run_are_neutralised(tmp_path):
    path = tmp_path / "planes.csv"
    cells = ["=HYPERLINK(\"http://x\")", "+1+cmd|' /C calc'!A0", "-2+3", "@SUM(A1)", "\tx", "\r=1", "wall", "a=b"]
    numbers = [-0.5, "-0.5", "+1e-3", "-7", "-inf", 3, "", None]
    write_csv(path, ["=h", "n"], list(zip(cells, numbers)))
    with open(path, newline="", encoding="utf-8") as handle:
        read = list(csv.reader(handle))
    assert read[0] == ["'=h", "n"]
    assert [r[0] for r in read[1:]] == ["'" + c if c[0] in "=+-@\t\r" else c for c in cells]
    assert [r[1] for r in read[1:]] == ["-0.5", "-0.5", "+1e-3", "-7", "-inf", "3", "", ""]


def test_labels_starting_a_formula_are_neutralised_in_the_tables(tmp_path):
    body = '<track id="0" label="=1+2">' + "".join(box(f) for f in range(3)) + "</track>"
    result, out = tiny_run(tmp_path, body=body)
    assert result.exit_code == 0, result.stderr
    assert (out / "planes.csv").read_text().splitlines()[1].split(",")[5] == "'=1+2"
    assert (out / "tracks.csv").read_text().splitlines()[1].split(",")[2] == "'=1+2"
    assert report_of(out)["planes"][0]["label"] == "=1+2"  # the report keeps the label as drawn

"""Hostile and broken inputs, through the command line: one clear line, the right exit status,
the right report entries, and nothing read or written outside the inputs and the output folder.

Every scenario runs on a tiny synthetic sequence (40 x 30 depth frames of one tilted plane) in
``tmp_path``; the whole ``tmp_path`` tree except the output folder is snapshotted before each
run and compared after it. Files that must never be opened are FIFOs: opening one for reading
blocks until a writer comes, so a run that finishes has not opened it (a watchdog unblocks the
reader and fails the test otherwise).
"""

from __future__ import annotations

import errno
import http.server
import json
import os
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from annotate_rgbd.io import writer
from conftest import SAMPLE_DATA
from annotate_rgbd.cli import app
from annotate_rgbd.cvat import encode_rle, read_cvat
from annotate_rgbd.errors import InputError, OutputError
from annotate_rgbd.io.sequence import camera_problem, read_sequence

from builders import CAMERA, H, W, XML_HEAD, depth_image, error_line, make_sequence, snapshot, timestamp, video_export, wall_track


# --------------------------------------------------------------------------------------------
# A tiny scene, a command-line runner and the proofs
# --------------------------------------------------------------------------------------------


class Scene:
    """``tmp_path`` holding ``seq/``, ``a.xml``, ``camera.toml``; output goes to ``out/``."""

    def __init__(self, root: Path, n: int = 3):
        self.root, self.n = root, n
        self.seq, self.xml, self.out = root / "seq", root / "a.xml", root / "out"
        self.camera = root / "camera.toml"
        make_sequence(self.seq, n)
        video_export(self.xml, n, wall_track(n))
        self.camera.write_text(CAMERA)

    def run(self, *extra: str, xml: Path | None = None, jobs: str = "1"):
        """Run cvat2mask in this process; assert that only ``out/`` changed."""
        before = snapshot(self.root, skip=self.out)
        result = CliRunner().invoke(
            app,
            ["cvat2mask", str(self.seq), str(xml or self.xml), "-c", str(self.camera), "-o", str(self.out), "-j", jobs, *extra],
        )
        assert snapshot(self.root, skip=self.out) == before, "a file outside the output folder changed"
        if result.exception is not None and not isinstance(result.exception, SystemExit):
            raise result.exception
        return result

    def report(self) -> dict:
        return json.loads((self.out / "report.json").read_text())


@pytest.fixture
def scene(tmp_path) -> Scene:
    return Scene(tmp_path)


def assert_fails(result, path: Path, message: str, status: int = 1) -> None:
    assert result.exit_code == status, result.stderr
    assert error_line(result) == f"error: {path}: {message}"


@contextmanager
def never_opened(path: Path, seconds: float = 15.0):
    """Make ``path`` a FIFO and fail if anything opens it for reading."""
    os.mkfifo(path)
    opened = []

    def release() -> None:
        try:  # succeeds only while a reader is blocked in open()
            fd = os.open(path, os.O_WRONLY | os.O_NONBLOCK)
        except OSError:
            return
        opened.append(True)
        os.close(fd)

    watchdog = threading.Timer(seconds, release)
    watchdog.start()
    try:
        yield
    finally:
        watchdog.cancel()
    assert not opened, f"{path} was opened"


def mask_files(out: Path) -> list[Path]:
    return sorted((out / "masks").iterdir()) if (out / "masks").is_dir() else []


def assert_masks_valid(out: Path) -> None:
    """Every file in masks/ is a complete colour PNG; no temporary file is left."""
    for path in mask_files(out):
        assert not path.name.endswith(".tmp"), path
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        assert image is not None and image.shape == (H, W, 3), path


# --------------------------------------------------------------------------------------------
# XML
# --------------------------------------------------------------------------------------------

BOMB = '<!ENTITY a0 "laugh">' + "".join(f'<!ENTITY a{i} "{f"&a{i - 1};" * 10}">' for i in range(1, 10))
DTD_REFUSED = "the file declares a DTD (<!DOCTYPE>), which CVAT exports never do: refused"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        pytest.param(
            lambda s: s.xml.read_text()[:-60],
            "the file ends at line 3 before </annotations> (a truncated export or download?): "
            "Specification mandates value for attribute ytl",
            id="truncated",
        ),
        pytest.param(
            lambda s: f"{XML_HEAD}<annotations><version>1.1</version>\n<track id='0' label='a'>\n</annotations>\n",
            "malformed XML at line 4: Opening and ending tag mismatch: track line 3 and annotations",
            id="malformed",
        ),
        pytest.param(lambda s: "\x00\x01 not xml", "malformed XML at line 1: Start tag expected, '<' not found", id="binary"),
        pytest.param(
            lambda s: f"{XML_HEAD}<dataset><item/></dataset>\n",
            "not a CVAT XML export: the root element is <dataset>, not <annotations>",
            id="wrong-root",
        ),
        pytest.param(
            lambda s: s.xml.read_text().replace("<version>1.1</version>", "<version>2.0</version>"),
            "unsupported CVAT XML version '2.0' (expected 1.1)",
            id="wrong-version",
        ),
        pytest.param(
            lambda s: f"{XML_HEAD}<annotations>" + "<a>" * 300 + "</a>" * 300 + "</annotations>\n",
            "malformed XML at line 2: elements nested more than 256 levels deep",
            id="deep-nesting",
        ),
        pytest.param(
            lambda s: f"{XML_HEAD}<!DOCTYPE annotations [{BOMB}]>\n<annotations><version>&a9;</version></annotations>\n",
            DTD_REFUSED,
            id="billion-laughs",
        ),
        pytest.param(
            lambda s: f'{XML_HEAD}<!DOCTYPE annotations SYSTEM "annotations.dtd">\n<annotations/>\n',
            DTD_REFUSED,
            id="external-dtd",
        ),
        pytest.param(
            lambda s: s.xml.read_text().replace("<stop_frame>2<", "<stop_frame>99999999999<"),
            "<stop_frame> at line 2: a task of 100000000000 frames (0-99999999999, step 1); at most "
            "200000 are read: export a task or job of the sequence",
            id="huge-frame-range",
        ),
    ],
)
def test_broken_xml_is_one_line_and_exit_1(scene, text, message):
    bad = scene.root / "bad.xml"
    bad.write_text(text(scene))
    result = scene.run(xml=bad)
    assert_fails(result, bad, message)
    assert not (scene.out / "report.json").exists()
    assert mask_files(scene.out) == []


def test_external_entities_never_read_a_local_file(scene):
    secret = scene.root / "secret"
    with never_opened(secret):
        for declaration, use in [
            (f'<!ENTITY xxe SYSTEM "{secret.as_uri()}">', "&xxe;"),
            (f'<!ENTITY % xxe SYSTEM "{secret}"> %xxe;', ""),
        ]:
            bad = scene.root / "xxe.xml"
            bad.write_text(f"{XML_HEAD}<!DOCTYPE annotations [{declaration}]>\n<annotations><version>{use}</version></annotations>\n")
            assert_fails(scene.run(xml=bad), bad, DTD_REFUSED)
        bad.write_text(f'{XML_HEAD}<!DOCTYPE annotations SYSTEM "{secret}">\n<annotations/>\n')
        assert_fails(scene.run(xml=bad), bad, DTD_REFUSED)


def test_external_entities_never_fetch_a_url(scene):
    requests = []

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):
            requests.append(self.path)
            self.send_response(200)
            self.end_headers()
            self.wfile.write(b'<!ENTITY leak "fetched">')

        def log_message(self, *args):
            pass

    server = http.server.HTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    url = f"http://127.0.0.1:{server.server_port}"
    try:
        for doctype in [
            f'<!DOCTYPE annotations SYSTEM "{url}/external.dtd">',
            f'<!DOCTYPE annotations [<!ENTITY % p SYSTEM "{url}/parameter"> %p;]>',
            f'<!DOCTYPE annotations [<!ENTITY e SYSTEM "{url}/general">]>',
        ]:
            bad = scene.root / "xxe.xml"
            bad.write_text(f"{XML_HEAD}{doctype}\n<annotations><version>&e;</version></annotations>\n")
            assert_fails(scene.run(xml=bad), bad, DTD_REFUSED)
    finally:
        server.shutdown()
    assert requests == []


def test_unknown_shape_kinds_become_notes(scene):
    body = wall_track(scene.n) + '\n<track id="1" label="lamp"><star frame="0" points="1,1"/></track><hexagon/>'
    video_export(scene.xml, scene.n, body)
    result = scene.run()
    assert result.exit_code == 0, result.stderr
    assert scene.report()["notes"] == ["a.xml: ignored 1 <star> element (unknown shape kind)"]
    assert scene.report()["summary"]["masks_written"] == scene.n


BIG_EXPORT_BYTES = 200 * 1024 * 1024


def write_big_export(path: Path, target_bytes: int) -> int:
    """A file export of one long sequence: many tracks, a polygon on every frame. Returns tracks."""
    frames = 2000
    polygon = '<polygon frame="{f}" keyframe="0" outside="0" occluded="0" points="10.00,10.00;30.00,10.00;30.00,25.00;10.00,25.00" z_order="0"/>\n'
    track_text = "".join(polygon.format(f=f) for f in range(frames))
    tracks = max(1, target_bytes // len(track_text))
    with open(path, "w") as handle:
        handle.write(f"{XML_HEAD}<annotations><version>1.1</version><meta><task><start_frame>0</start_frame>"
                     f"<stop_frame>{frames - 1}</stop_frame></task></meta>\n")
        handle.writelines(f'<track id="{t}" label="plane{t}" source="manual">\n{track_text}</track>\n' for t in range(tracks))
        handle.write("</annotations>\n")
    return tracks


MEASURE = """
import resource, sys, time
from annotate_rgbd.cvat import read_cvat
start = time.perf_counter()
a = read_cvat(sys.argv[1], labels=sys.argv[2:] or None)
shapes = sum(len(t.shapes) for t in a.tracks)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
try:  # Linux keeps ru_maxrss across exec (the forking test process's); VmHWM is this program's own
    with open("/proc/self/status") as status:
        peak = next(int(line.split()[1]) for line in status if line.startswith("VmHWM:"))
except (OSError, StopIteration):
    pass
print(len(a.tracks), shapes, round(time.perf_counter() - start, 1), peak)
"""


@pytest.mark.slow  # about 20 s: `pytest -m "not slow"` leaves it out
def test_200_mb_export_is_parsed_in_bounded_memory(tmp_path):
    # Only one track is kept (--label): what remains in memory is the parser's, whatever the
    # file's size. (Reading all 1.6 million polygons takes about 100 s and 1.3 GiB: the
    # annotation itself, bounded by MAX_SHAPES.)
    path = tmp_path / "big.xml"
    tracks = write_big_export(path, BIG_EXPORT_BYTES)
    size = path.stat().st_size
    out = subprocess.run([sys.executable, "-c", MEASURE, str(path), "plane0"], capture_output=True, text=True, check=True)
    n_tracks, shapes, seconds, peak_kib = out.stdout.split()
    assert (int(n_tracks), int(shapes)) == (1, 2000)
    print(f"{size / 2**20:.0f} MiB, {tracks} tracks: {seconds} s, peak RSS {int(peak_kib) / 1024:.0f} MiB")
    assert int(peak_kib) * 1024 < 200 * 2**20


# --------------------------------------------------------------------------------------------
# Shapes
# --------------------------------------------------------------------------------------------


def test_broken_shapes_are_skipped_with_notes_and_the_rest_is_used(scene):
    def poly(frame, points, track_line=""):
        return f'<polygon frame="{frame}" keyframe="1" outside="0" occluded="0" points="{points}" z_order="1"/>'

    rle = ", ".join(map(str, encode_rle(np.ones((5, 5), bool))))
    body = "\n".join(
        [
            wall_track(scene.n),  # line 3
            f'<track id="1" label="nan">{poly(0, "1,1;nan,5;5,1")}</track>',
            f'<track id="2" label="inf">{poly(0, "1,1;inf,5;5,1")}</track>',
            f'<track id="3" label="huge">{poly(0, "1,1;1e30,5;5,1")}</track>',
            f'<track id="4" label="two">{poly(0, "1,1;5,5")}</track>',
            f'<track id="5" label="line">{poly(0, "1,1;3,3;5,5")}</track>',
            f'<track id="6" label="late">{poly(7, "1,1;9,1;5,7")}</track>',
            '<track id="7" label="rle"><mask frame="0" keyframe="1" outside="0" occluded="0" rle="3, 4" left="0" top="0" width="5" height="5" z_order="1"/></track>',
            f'<track id="8" label="big"><mask frame="0" keyframe="1" outside="0" occluded="0" rle="0, {50 * 50}" left="0" top="0" width="50" height="50" z_order="1"/></track>',
            # usable: negative coordinates are clipped, a bow tie is filled as drawn
            f'<track id="9" label="negative">{poly(1, "-50,-50;8,-50;8,6;-50,6")}</track>',
            f'<track id="10" label="bowtie">{poly(2, "30,2;38,12;38,2;30,12")}</track>',
            f'<track id="11" label="square"><mask frame="0" keyframe="1" outside="1" occluded="0" rle="{rle}" left="1" top="1" width="5" height="5" z_order="1"/></track>',
        ]
    )
    video_export(scene.xml, scene.n, body)
    result = scene.run()
    assert result.exit_code == 0, result.stderr
    report = scene.report()
    # Shapes that make no mask are warnings (on the terminal and in the report), the rest notes.
    assert report["warnings"] == [f"{scene.xml}: {line}" for line in [
        "skipped 2 shapes: non-finite coordinates (first at line 4)",
        "skipped 1 shape: coordinates beyond 1000000 pixels (first at line 6)",
        "skipped 1 shape: polygon with fewer than 3 points (first at line 7)",
        "skipped 1 shape: polygon with zero area (first at line 8)",
        "skipped 1 shape: mask RLE runs do not add up to width x height (first at line 10)",
        "skipped 1 shape: mask larger than the image (first at line 11)",
        "skipped 1 shape: frame outside the task range 0-2 (first at line 9)",
    ]]
    assert report["warnings"][0] in result.stderr and "7 warnings" in result.stdout + result.stderr
    assert report["notes"] == [
        "a.xml: self-intersecting polygons, used as drawn (filled by the even-odd rule): 1 (first at line 13)",
        "a.xml: track 6 (line 9) is never visible: dropped",
        "a.xml: track 11 (line 14) is never visible: dropped",
    ]
    assert [p["label"] for p in report["planes"]] == ["wall", "negative", "bowtie"]
    assert report["summary"]["masks_written"] == scene.n
    labels = {p["label"]: p["plane"] for p in report["planes"]}
    frames = report["frames"]
    drawn = {f["cvat_frame"]: {r["plane"]: r["pixels"] for r in f["kept"] + f["dropped"]} for f in frames}
    # The negative square covers columns 0-7 and rows 0-5 of the image, minus the wall on top of
    # nothing (z_order 1 draws it above the wall).
    assert drawn[1][labels["negative"]] == 8 * 6
    # The bow tie's lobes cover pixels although its signed area is zero.
    assert drawn[2][labels["bowtie"]] > 0


def test_duplicate_track_ids_are_fatal(scene):
    video_export(scene.xml, scene.n, wall_track(scene.n) + "\n" + wall_track(scene.n))
    assert_fails(scene.run(), scene.xml, "<track> at line 4: duplicate track id 0 (first at line 3)")
    assert not scene.out.exists() or mask_files(scene.out) == []


def test_a_mask_that_would_decode_to_gigabytes_is_skipped(tmp_path):
    path = tmp_path / "a.xml"
    path.write_text(
        f"{XML_HEAD}<annotations><version>1.1</version><meta><task><start_frame>0</start_frame><stop_frame>0</stop_frame>"
        "</task></meta>\n<track id=\"0\" label=\"x\"><mask frame=\"0\" keyframe=\"1\" outside=\"0\" occluded=\"0\" "
        f'rle="0, {100000 * 100000}" left="0" top="0" width="100000" height="100000" z_order="0"/></track>\n</annotations>\n'
    )
    annotation = read_cvat(path)
    assert annotation.tracks == []
    assert annotation.notes[0] == "skipped 1 shape: mask larger than 16777216 pixels (first at line 3)"


def test_tracks_filling_too_many_frames_are_refused(tmp_path):
    # 11 tracks of one box each persist over 200 000 frames: 2.2 million shapes.
    boxes = "\n".join(
        f'<track id="{t}" label="x"><box frame="0" keyframe="1" outside="0" occluded="0" xtl="0" ytl="0" xbr="4" ybr="4" z_order="0"/></track>'
        for t in range(11)
    )
    path = tmp_path / "a.xml"
    path.write_text(
        f"{XML_HEAD}<annotations><version>1.1</version><meta><task><start_frame>0</start_frame><stop_frame>199999</stop_frame>"
        f"</task></meta>\n{boxes}\n</annotations>\n"
    )
    with pytest.raises(InputError) as caught:
        read_cvat(path)
    assert caught.value.message == (
        "<track> at line 13: the tracks fill more than 2000000 frames in all (one shape per track and frame): "
        "export a shorter task or job"
    )


# --------------------------------------------------------------------------------------------
# Paths
# --------------------------------------------------------------------------------------------


def images_export(path: Path, names: list[str]) -> Path:
    images = "\n".join(
        f'<image id="{i}" name="{name}" width="{W}" height="{H}"><box label="wall" occluded="0" xtl="2" ytl="2" '
        f'xbr="30" ybr="25" z_order="0"/></image>'
        for i, name in enumerate(names)
    )
    path.write_text(
        f"{XML_HEAD}<annotations><version>1.1</version><meta><task><start_frame>0</start_frame>"
        f"<stop_frame>{len(names) - 1}</stop_frame></task></meta>\n{images}\n</annotations>\n"
    )
    return path


def test_image_names_are_looked_up_by_name_only(scene):
    # An RGB file of the sequence's name outside it, and /etc/passwd's name in the sequence's
    # parent: neither may be opened. The absolute path still finds the sequence's frame 1.
    outside = scene.root / "elsewhere" / "rgb"
    outside.mkdir(parents=True)
    decoy = outside / f"{timestamp(1)}.png"
    (scene.root / "etc").mkdir()
    with never_opened(decoy), never_opened(scene.root / "etc" / "passwd"):
        images_export(scene.xml, ["../../etc/passwd", str(decoy), f"rgb/{timestamp(2)}.png"])
        result = scene.run()
    assert result.exit_code == 0, result.stderr
    report = scene.report()
    assert report["warnings"] == [f"{scene.xml}: frame 0: image '../../etc/passwd' is not in the RGB list; skipped"]
    assert [(f["status"], f.get("reason"), f.get("cvat_frame")) for f in report["frames"]] == [
        ("skipped", "outside_annotated_range", None),
        ("written", None, 1),
        ("written", None, 2),
    ]
    assert [p.name for p in mask_files(scene.out)] == [f"{timestamp(1)}.png", f"{timestamp(2)}.png"]


@pytest.mark.parametrize(
    ("listed", "problem"),
    [
        ("../../x.png", "'../../x.png' leads outside the sequence folder ('..')"),
        ("depth/../../x.png", "'depth/../../x.png' leads outside the sequence folder ('..')"),
        ("{root}/x.png", "'{root}/x.png' is an absolute path; list files relative to the sequence folder"),
        ("C:\\data\\x.png", "'C:\\\\data\\\\x.png' is an absolute path; list files relative to the sequence folder"),
        (".", "'.' is not a file name"),
    ],
)
@pytest.mark.parametrize("list_name", ["depth.txt", "rgb.txt"])
def test_list_entries_outside_the_sequence_are_refused(scene, listed, problem, list_name):
    victim = scene.root / "x.png"
    listed, problem = listed.format(root=scene.root), problem.format(root=scene.root)
    path = scene.seq / list_name
    lines = path.read_text().splitlines()
    lines[4] = f"{timestamp(1)} {listed}"
    path.write_text("\n".join(lines) + "\n")
    with never_opened(victim):
        result = scene.run()
    assert_fails(result, path, f"line 5: {problem}")
    assert not scene.out.exists()


def test_associations_entries_outside_the_sequence_are_refused(tmp_path):
    (tmp_path / "associations.txt").write_text("1.0 depth/1.png 1.0 /etc/passwd\n")
    with pytest.raises(InputError) as caught:
        read_sequence(tmp_path)
    assert str(caught.value) == (
        f"{tmp_path / 'associations.txt'}: line 1: '/etc/passwd' is an absolute path; list files relative to the sequence folder"
    )


def test_depth_files_with_one_name_are_refused(scene):
    (scene.seq / "depth" / "b").mkdir()
    cv2.imwrite(str(scene.seq / "depth" / "b" / f"{timestamp(0)}.png"), depth_image())
    with open(scene.seq / "depth.txt", "a") as handle:
        handle.write(f"{timestamp(5)} depth/b/{timestamp(0)}.png\n")
    result = scene.run()
    assert_fails(
        result,
        scene.seq / "depth.txt",
        f"depth files 'depth/{timestamp(0)}.png' and 'depth/b/{timestamp(0)}.png' have one file name; "
        "masks are named after depth files, so each needs its own",
    )


# --------------------------------------------------------------------------------------------
# Sequences
# --------------------------------------------------------------------------------------------


def break_depth(scene: Scene, how: str) -> Path:
    path = scene.seq / "depth" / f"{timestamp(1)}.png"
    if how == "missing":
        path.unlink()
    elif how == "corrupt":
        path.write_bytes(path.read_bytes()[:40])
    elif how == "8-bit":
        cv2.imwrite(str(path), (depth_image() // 256).astype(np.uint8))
    elif how == "3-channel":
        cv2.imwrite(str(path), np.dstack([depth_image()] * 3))
    elif how == "folder":
        path.unlink()
        path.mkdir()
    return path


@pytest.mark.parametrize(
    ("how", "problem"),
    [
        ("missing", "file not found"),
        ("corrupt", "not a readable image (truncated PNG: its closing IEND chunk is missing, the file was cut short)"),
        ("8-bit", "depth image is 8-bit; expected 16-bit depth (TUM / ICL-NUIM PNG)"),
        ("3-channel", "depth image has 3 channels; expected a single-channel depth map"),
        ("folder", "cannot read (Is a directory)"),
    ],
)
def test_unusable_depth_frame_is_skipped_and_reported(scene, how, problem):
    path = break_depth(scene, how)
    result = scene.run()
    assert result.exit_code == 1, result.stderr  # a failed frame fails the run, after every other mask
    message = f"{path}: {problem}"
    assert f"warning: {message}; failed (no mask)" in result.stderr.splitlines()
    assert f"  failed: {message}" in result.stdout.splitlines()
    report = scene.report()
    entry = report["frames"][1]
    assert (entry["status"], entry["reason"], entry["error"]) == ("failed", "unreadable_depth", message)
    assert report["summary"]["frames_failed"] == 1 and report["summary"]["masks_written"] == scene.n - 1
    assert [p.name for p in mask_files(scene.out)] == [f"{timestamp(0)}.png", f"{timestamp(2)}.png"]


def test_missing_rgb_images_do_not_matter(scene):
    # cvat2mask reads only the RGB list (timestamps and names), never the images.
    for path in (scene.seq / "rgb").iterdir():
        path.unlink()
    result = scene.run()
    assert result.exit_code == 0, result.stderr
    assert scene.report()["summary"]["masks_written"] == scene.n


def test_depth_of_another_size_than_the_annotated_images_is_fatal(scene):
    path = scene.seq / "depth" / f"{timestamp(1)}.png"
    cv2.imwrite(str(path), depth_image((20, 15)))
    assert_fails(scene.run(), path, "depth image is 20x15 but a.xml annotates 40x30 images")
    assert not (scene.out / "report.json").exists()
    assert_masks_valid(scene.out)


def test_timestamps_out_of_order_are_sorted(scene):
    path = scene.seq / "depth.txt"
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:3] + lines[3:][::-1]) + "\n")
    assert scene.run().exit_code == 0
    assert [f["depth_timestamp"] for f in scene.report()["frames"]] == [100.0, 100.1, 100.2]


@pytest.mark.parametrize(
    ("list_name", "text", "problem"),
    [
        ("depth.txt", "# only comments\n", "{seq}: the sequence lists no depth frames"),
        ("rgb.txt", "", "{seq}: the sequence lists no RGB frames"),
        ("depth.txt", "100.0 depth/a.png\n100.000000 depth/b.png\n", "{seq}/depth.txt: line 2: timestamp 100.000000 appears twice (depth/b.png)"),
        ("rgb.txt", "nan rgb/a.png\n", "{seq}/rgb.txt: line 1: 'nan' is not a timestamp"),
        ("rgb.txt", "100.0\n", "{seq}/rgb.txt: line 1: expected 2 columns, got 1"),
    ],
)
def test_broken_lists_are_fatal(scene, list_name, text, problem):
    (scene.seq / list_name).write_text(text)
    result = scene.run()
    assert result.exit_code == 1
    assert error_line(result) == "error: " + problem.format(seq=scene.seq)


def test_unreadable_list_file(scene):
    (scene.seq / "rgb.txt").write_bytes(b"\xff\xfe\x00binary")
    result = scene.run()
    assert result.exit_code == 1
    assert error_line(result).startswith(f"error: {scene.seq / 'rgb.txt'}: cannot read frame list: 'utf-8' codec can't decode")


@pytest.mark.parametrize(
    ("cx", "cy", "problem"),
    [
        (19.5, 14.5, None),
        (319.5, 239.5, "the camera's principal point (319.5, 239.5) is outside the 40x30 depth images: are the [camera] intrinsics for another resolution?"),
        (35.0, 14.5, "the camera's principal point (35, 14.5) is far from the centre of the 40x30 depth images: are the [camera] intrinsics for another resolution?"),
    ],
)
def test_camera_problem(cx, cy, problem):
    assert camera_problem(cx, cy, W, H) == problem


def test_camera_for_another_resolution_is_a_warning(scene):
    scene.camera.write_text(CAMERA.replace("cx = 19.5", "cx = 319.5").replace("cy = 14.5", "cy = 239.5"))
    result = scene.run()
    assert result.exit_code == 0
    warning = "the camera's principal point (319.5, 239.5) is outside the 40x30 depth images: are the [camera] intrinsics for another resolution?"
    assert scene.report()["warnings"] == [f"{scene.seq / 'depth' / timestamp(0)}.png: {warning}"]


# --------------------------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------------------------


def test_output_folder_that_is_a_file(scene):
    scene.out.write_text("not a folder")
    result = scene.run()
    assert result.exit_code == 1
    assert error_line(result) == f"error: {scene.out}: cannot create the output folder: a file of that name is in the way"
    assert scene.out.read_text() == "not a folder"


def test_prepare_output_refuses_unusable_folders(tmp_path, monkeypatch):
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError, match="a file of that name is in the way"):
        writer.prepare_output(tmp_path / "file")
    with pytest.raises(OutputError) as raised:
        writer.prepare_output(tmp_path / "file" / "out" / "run")
    assert str(raised.value) == f"{tmp_path / 'file' / 'out' / 'run'}: cannot create the output folder: {tmp_path / 'file'} is a file"

    def read_only(*args, **kwargs):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))

    monkeypatch.setattr(writer.tempfile, "TemporaryFile", read_only)
    with pytest.raises(OutputError) as caught:
        writer.prepare_output(tmp_path / "ro")
    assert str(caught.value) == f"{tmp_path / 'ro'}: cannot write to the output folder: Permission denied"


def disk_full_after(monkeypatch, files: int) -> None:
    """Let ``files`` atomic writes succeed, then fail every fsync with ENOSPC."""
    real_fsync, calls = os.fsync, []

    def fsync(fd):
        calls.append(fd)
        if len(calls) > files:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_fsync(fd)

    monkeypatch.setattr(writer.os, "fsync", fsync)


def test_full_disk_leaves_no_partial_file(tmp_path, monkeypatch):
    disk_full_after(monkeypatch, 0)
    (tmp_path / "old.png").write_bytes(b"previous content")
    with pytest.raises(OutputError) as caught:
        writer.write_png(tmp_path / "old.png", np.zeros((4, 4, 3), np.uint8))
    assert str(caught.value) == f"{tmp_path / 'old.png'}: cannot write output: No space left on device"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.png"]
    assert (tmp_path / "old.png").read_bytes() == b"previous content"


def test_full_disk_stops_the_run_at_the_first_mask(scene, monkeypatch):
    disk_full_after(monkeypatch, 2)  # the record of the files the run may write, then one mask
    result = scene.run()
    mask = scene.out / "masks" / f"{timestamp(1)}.png"
    assert_fails(result, mask, "cannot write output: No space left on device")
    assert [p.name for p in mask_files(scene.out)] == [f"{timestamp(0)}.png"]
    assert_masks_valid(scene.out)
    monkeypatch.undo()
    rerun = scene.run()
    assert rerun.exit_code == 0 and "(2 made, 1 unchanged)" in rerun.stdout


def test_full_disk_never_leaves_a_partial_file(scene, monkeypatch):
    disk_full_after(monkeypatch, 1)
    result = scene.run()
    assert result.exit_code == 1
    assert error_line(result).endswith(": cannot write output: No space left on device")
    assert_masks_valid(scene.out)
    assert not (scene.out / "report.json").exists()
    monkeypatch.undo()
    rerun = scene.run()
    assert rerun.exit_code == 0, rerun.stderr
    assert scene.report()["summary"]["masks_written"] == scene.n
    assert_masks_valid(scene.out)


INTERRUPTED_FRAMES = 60


@pytest.mark.slow  # kills or interrupts processes: `pytest -m "not slow"` leaves it out
@pytest.mark.parametrize(("signum", "status", "word"), [(signal.SIGTERM, 143, "terminated"), (signal.SIGINT, 130, "interrupted")])
def test_interrupt_mid_run_keeps_finished_masks_and_a_rerun_completes(tmp_path, signum, status, word):
    scene = Scene(tmp_path, n=INTERRUPTED_FRAMES)
    command = [sys.executable, "-c", "from annotate_rgbd.cli import app; app()"]
    journal = scene.out / ".annotate-rgbd-journal.jsonl"
    process = subprocess.Popen(
        [*command, "cvat2mask", str(scene.seq), str(scene.xml), "-c", str(scene.camera), "-o", str(scene.out), "-j", "1"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60
    while not (journal.is_file() and journal.read_text().count("\n") >= 3):
        assert process.poll() is None and time.monotonic() < deadline, "the run ended before it could be interrupted"
        time.sleep(0.01)
    process.send_signal(signum)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == status, stderr
    assert stderr.splitlines()[-1] == (
        f"error: {word}; finished files are complete, nothing partial was left; run the same command again to continue"
    )
    finished = mask_files(scene.out)
    assert 3 <= len(finished) < INTERRUPTED_FRAMES
    assert_masks_valid(scene.out)
    assert not (scene.out / "report.json").exists()
    # A mask finished after its journal line was due is complete but made again.
    journalled = [json.loads(line)["mask"] for line in journal.read_text().splitlines()]
    assert set(journalled) <= {p.name for p in finished} and len(finished) - len(journalled) <= 1

    rerun = scene.run()
    assert rerun.exit_code == 0, rerun.stderr
    made, reused = INTERRUPTED_FRAMES - len(journalled), len(journalled)
    assert f"({made} made, {reused} unchanged)" in rerun.stdout
    assert len(mask_files(scene.out)) == INTERRUPTED_FRAMES
    assert_masks_valid(scene.out)
    assert not journal.exists()


def test_outputs_are_readable_like_any_file_the_user_makes(tmp_path):
    previous = os.umask(0o022)
    try:
        writer.write_png(tmp_path / "m.png", np.zeros((2, 2, 3), np.uint8))
    finally:
        os.umask(previous)
    assert (tmp_path / "m.png").stat().st_mode & 0o777 == 0o644


@pytest.fixture(scope="module")
def command_line_start() -> float:
    """Seconds this machine takes, now, to start Python and import the command line (typer and
    annotate_rgbd.cli, before any handler of ours exists): a signal inside that window meets
    Python's own start-up, which prints its traceback (the limit docs/troubleshooting.md states)."""
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", "from annotate_rgbd.cli import app"], check=True)
    return time.perf_counter() - start


@pytest.mark.slow  # kills or interrupts processes: `pytest -m "not slow"` leaves it out
@pytest.mark.parametrize("delay", [0.3, 0.8, 1.3])
@pytest.mark.parametrize(("signum", "status", "word"), [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")])
def test_interrupt_while_starting_prints_one_line(tmp_path, delay, signum, status, word, command_line_start):
    """Ctrl-C (or SIGTERM) reaches the whole process group, the helpers' server too, while the run
    starts (imports, the server, the helpers being started): one line, exit 130 (143), no
    traceback or report from any process or thread."""
    if delay < 1.5 * command_line_start:
        pytest.skip(f"a signal at {delay} s would land in Python's own start-up on this machine now "
                    f"({command_line_start:.2f} s to import the command line)")
    command = [sys.executable, "-c", "from annotate_rgbd.cli import app; app()", "cvat2mask", str(SAMPLE_DATA / "sequence"),
               str(SAMPLE_DATA / "annotations.xml"), "-c", str(SAMPLE_DATA / "camera.toml"), "-o", str(tmp_path / "out"), "-j", "2"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    time.sleep(delay)
    os.killpg(process.pid, signum)
    stdout, stderr = process.communicate(timeout=60)
    if " masks in " in stdout:
        pytest.skip("the run had finished before the signal")  # its exit status is then the signal's
    assert process.returncode == status, stderr
    assert "Traceback" not in stderr + stdout and "Open3D" not in stderr + stdout, stderr + stdout
    assert stderr.splitlines()[-1].startswith(f"error: {word}; "), stderr

"""Reliability round 3: the attacks of a hostile or careless user that broke the tool, one test
each (extend this list in the next round).

Every case must end in at most one ``error:`` line (or a warning and a correct result), no
traceback, bounded memory, and nothing written or replaced outside the output folder. Memory
bounds are checked in subprocesses under ``RLIMIT_AS`` (the ``ulimit -v`` of a shell), file
sizes under ``RLIMIT_FSIZE``; those tests skip where the platform lacks the limit.

The attacks, by the issue's items:

1. bounded images: a 1 x 20000 sequence with ``--overlays`` under 4 GB (the contact sheet was
   6 GB); the thumbnail box.
2. bounded reads: ``read_bounded`` reads in pieces; ``stats`` (1 GB), ``review`` and a re-run
   (2 GB) of a 640 x 480 run; manifests and configurations within a bound, FIFOs refused.
4. special paths: ``export-cvat`` / ``evaluate --per-frame`` into ``-``, ``/dev/stdout``, a FIFO
   (with and without a reader), ``/dev/full``; ``export-cvat`` over the run's own files.
5. a tampered ``report.json``: one line naming the file and the field.
6. ``propose`` on frames too small or of another size; ``export-cvat`` on masks of mixed sizes.
7. ``propose --label`` checked before any work.
8. ``--out ''``, ``.npy`` headers claiming huge arrays, CAPE CSV bound, URL-encoded review
   links, an output folder moved mid-run, nested batch outputs, the journal's write error, the
   ``--partial`` message, a problem every frame shares said once (8-bit depth).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest
from lxml import etree
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.cvat import read_cvat
from annotate_rgbd.errors import OutputError
from annotate_rgbd.io import bounded, labelmaps, writer
from annotate_rgbd.io.outdir import read_bounded
from annotate_rgbd.pipeline.scene import run_cvat2mask
from annotate_rgbd.config.settings import load_config
from annotate_rgbd.report.records import RunRecord
from annotate_rgbd.review.overlay import MAX_THUMB_ASPECT, contact_sheet, thumbnail_size
from annotate_rgbd.review.page import page_data
from builders import CAMERA, error_line, make_sequence, snapshot, timestamp, video_export, wall_track
from conftest import SAMPLE_DATA as SAMPLE

try:
    import resource
except ImportError:  # not on Windows
    resource = None

LINUX_LIMITS = resource is not None and sys.platform.startswith("linux")
needs_limits = pytest.mark.skipif(not LINUX_LIMITS, reason="needs Linux resource limits (RLIMIT_AS, RLIMIT_FSIZE)")
COMMAND = [sys.executable, "-c", "from annotate_rgbd.cli import app; app()"]


def run_limited(args, *, memory: int | None = None, file_size: int | None = None, cwd: Path | None = None,
                timeout: float = 180, stdout=subprocess.PIPE) -> subprocess.CompletedProcess:
    """Run the command line in a subprocess under an address-space and/or file-size limit."""

    def limit() -> None:
        if memory is not None:
            resource.setrlimit(resource.RLIMIT_AS, (memory, memory))
        if file_size is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (file_size, file_size))
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails (EFBIG)

    return subprocess.run([*COMMAND, *map(str, args)], preexec_fn=limit, stdout=stdout, stderr=subprocess.PIPE,
                          cwd=cwd, timeout=timeout)


class Scene:
    """``root`` holding the tiny scene of :mod:`builders` (``seq/``, ``a.xml``, ``camera.toml``);
    output goes to ``out/``."""

    def __init__(self, root: Path, n: int = 3):
        self.root, self.n = root, n
        self.seq, self.xml, self.out, self.camera = root / "seq", root / "a.xml", root / "out", root / "camera.toml"
        make_sequence(self.seq, n)
        video_export(self.xml, n, wall_track(n))
        self.camera.write_text(CAMERA)

    def run(self):
        """cvat2mask in this process, one worker."""
        return invoke("cvat2mask", self.seq, self.xml, "-c", self.camera, "-o", self.out, "-j", "1")


def one_error(stderr: str) -> str:
    errors = [line for line in stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "Traceback" not in stderr, stderr
    return errors[0]


def invoke(*args: str):
    result = CliRunner().invoke(app, [str(a) for a in args])
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result


def make_frames(root: Path, sizes: list[tuple[int, int]], eight_bit: bool = False) -> None:
    """A TUM sequence of planar depth frames of the given (width, height), 1.6 to 2.6 m."""
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    for i, (width, height) in enumerate(sizes):
        rows, cols = np.mgrid[0:height, 0:width]
        depth = (8000 + (3000 * cols) // width + (2000 * rows) // height).astype(np.uint16)
        cv2.imwrite(str(root / f"depth/{timestamp(i)}.png"), (depth % 256).astype(np.uint8) if eight_bit else depth)
        cv2.imwrite(str(root / f"rgb/{timestamp(i)}.png"), np.full((height, width, 3), 128, np.uint8))
    for kind in ("rgb", "depth"):
        lines = [f"{timestamp(i)} {kind}/{timestamp(i)}.png" for i in range(len(sizes))]
        (root / f"{kind}.txt").write_text("# timestamp filename\n" + "\n".join(lines) + "\n")


def box_export(path: Path, n: int, width: int, height: int) -> Path:
    boxes = "".join(
        f'<box frame="{f}" keyframe="1" outside="0" occluded="0" xtl="0" ytl="0" xbr="{width}" ybr="{height}" '
        'z_order="0"/>' for f in range(n)
    )
    return video_export(path, n, f'<track id="0" label="wall" source="manual">{boxes}</track>', size=(width, height))


def camera_file(path: Path, width: int, height: int) -> Path:
    focal = float(max(width, height))
    path.write_text(f"[camera]\nfx = {focal}\nfy = {focal}\ncx = {(width - 1) / 2}\ncy = {(height - 1) / 2}\n"
                    "depth_scale = 5000.0\n")
    return path


@pytest.fixture
def finished(tmp_path) -> Scene:
    """The tiny 40 x 30 scene of test_hostile, run once (3 masks)."""
    scene = Scene(tmp_path)
    assert scene.run().exit_code == 0
    return scene


# --------------------------------------------------------------------------------------------
# 1. Every image bounded by its input's size
# --------------------------------------------------------------------------------------------


def test_thumbnails_fit_a_box_whatever_the_aspect_ratio():
    assert thumbnail_size((480, 640, 3), 320) == (320, 240)  # landscape: as before
    assert thumbnail_size((640, 480, 3), 320) == (320, 427)  # portrait fits the box
    width, height = thumbnail_size((20000, 1, 3), 320)  # a 1 x 20000 frame: a sliver, not 6.4 M rows
    assert (width, height) == (1, int(MAX_THUMB_ASPECT * 320))
    assert thumbnail_size((1, 20000, 3), 320) == (320, 1)


def test_contact_sheet_of_degenerate_frames_is_small_and_warned_about(caplog):
    images = (np.full((20000, 1, 3), 200, np.uint8) for _ in range(3))  # a generator: one image at a time
    sheet = contact_sheet(images, ["a", "b", "c"], thumb_width=320)
    assert sheet.nbytes < 4 << 20
    assert [r.getMessage() for r in caplog.records] == [
        "frames of 1 x 20000 pixels are too elongated for thumbnails: the contact sheet shows them as slivers"
    ]


@pytest.mark.slow  # stresses processes (memory and file-size limits)
@needs_limits
def test_overlays_of_1_by_20000_frames_run_in_4_gb(tmp_path):
    make_frames(tmp_path / "seq", [(1, 20000)] * 3)
    box_export(tmp_path / "a.xml", 3, 1, 20000)
    camera = camera_file(tmp_path / "camera.toml", 1, 20000)
    result = run_limited(["cvat2mask", tmp_path / "seq", tmp_path / "a.xml", "-c", camera, "-o", tmp_path / "out",
                          "-j", "1", "--overlays"], memory=4_000_000 * 1024)
    stderr = result.stderr.decode()
    assert result.returncode == 0, stderr
    assert "Traceback" not in stderr and "too elongated for thumbnails" in stderr
    sheet = cv2.imread(str(tmp_path / "out" / "contact_sheet.png"))
    assert sheet is not None and sheet.nbytes < 4 << 20


# --------------------------------------------------------------------------------------------
# 2. Bounded reads, in pieces
# --------------------------------------------------------------------------------------------


class CountingReader:
    """A stream that remembers the largest read it was asked for."""

    def __init__(self, data: bytes):
        self.data, self.largest = data, 0

    def read(self, size: int) -> bytes:
        self.largest = max(self.largest, size)
        piece, self.data = self.data[:size], self.data[size:]
        return piece


def test_a_bounded_read_asks_for_pieces_not_for_the_bound():
    stream = CountingReader(b"x" * 3000)
    assert bounded.read_stream_bounded(stream, 1 << 30, "f") == b"x" * 3000
    assert stream.largest <= bounded.READ_CHUNK
    with pytest.raises(OSError, match="larger than 2999 bytes"):
        bounded.read_stream_bounded(CountingReader(b"x" * 3000), 2999, "f")


def test_read_bounded_reads_a_small_file_under_a_huge_bound(tmp_path, monkeypatch):
    asked = []
    real = bounded.read_stream_bounded
    monkeypatch.setattr("annotate_rgbd.io.outdir.read_stream_bounded",
                        lambda handle, limit, path: asked.append(limit) or real(handle, limit, path))
    (tmp_path / "r.json").write_bytes(b"{}")
    assert read_bounded(tmp_path / "r.json", 1 << 30) == b"{}"
    assert asked == [1 << 30]


def test_inputs_read_with_a_bound_refuse_fifos_and_oversized_files(tmp_path, monkeypatch):
    os.mkfifo(tmp_path / "manifest.toml")
    result = run_limited(["batch", tmp_path / "manifest.toml"], timeout=60)  # reading the FIFO would block
    assert result.returncode == 1
    assert one_error(result.stderr.decode()).startswith(
        f"error: {tmp_path / 'manifest.toml'}: cannot read manifest: not a regular file"
    )
    monkeypatch.setattr("annotate_rgbd.pipeline.manifest.MAX_MANIFEST_BYTES", 100)
    (tmp_path / "big.toml").write_text("# " + "x" * 200 + "\n")
    result = invoke("batch", tmp_path / "big.toml")
    assert error_line(result) == f"error: {tmp_path / 'big.toml'}: cannot read manifest: larger than 100 bytes"


@pytest.fixture(scope="module")
def vga_run(tmp_path_factory) -> Path:
    """A finished run of 6 frames of 640 x 480 (the memory a command takes does not grow with frames)."""
    root = tmp_path_factory.mktemp("vga")
    make_frames(root / "seq", [(640, 480)] * 6)
    box_export(root / "a.xml", 6, 640, 480)
    camera_file(root / "camera.toml", 640, 480)
    run_cvat2mask(root / "seq", [root / "a.xml"], root / "out", load_config(str(root / "camera.toml")), workers=1)
    return root


@pytest.mark.slow  # stresses processes (memory and file-size limits)
@needs_limits
def test_stats_runs_in_1_gb_and_imports_no_open3d(vga_run):
    result = run_limited(["stats", vga_run / "out"], memory=1_000_000 * 1024)
    assert result.returncode == 0, result.stderr.decode()
    assert result.stdout.decode().startswith("observations (masks)")
    probe = subprocess.run(
        [sys.executable, "-c", "import sys; from annotate_rgbd.cli import app; from typer.testing import CliRunner; "
         f"r = CliRunner().invoke(app, ['stats', {str(vga_run / 'out')!r}]); "
         "print(r.exit_code, sorted({m.split('.')[0] for m in sys.modules} & {'open3d', 'cv2', 'scipy'}))"],
        capture_output=True, text=True, timeout=120,
    )
    assert probe.stdout.split("\n")[0] == "0 []", probe.stderr


@pytest.mark.slow  # stresses processes (memory and file-size limits)
@needs_limits
@pytest.mark.parametrize("command", ["review", "rerun"])
def test_review_and_a_rerun_run_in_2_gb(vga_run, tmp_path, command):
    out = tmp_path / "out"
    shutil.copytree(vga_run / "out", out)
    if command == "review":
        args = ["review", out, "-j", "1"]
    else:
        args = ["cvat2mask", vga_run / "seq", vga_run / "a.xml", "-c", vga_run / "camera.toml", "-o", out, "-j", "1"]
    result = run_limited(args, memory=2_000_000 * 1024)
    assert result.returncode == 0, result.stderr.decode()
    if command == "rerun":
        assert "(0 made, 6 unchanged)" in result.stdout.decode()


# --------------------------------------------------------------------------------------------
# 4. Special output paths: written into, never replaced
# --------------------------------------------------------------------------------------------


def test_output_paths_that_name_streams():
    assert writer.descriptor_of("-") == 1 and writer.descriptor_of("/dev/stdout") == 1
    assert writer.descriptor_of("/dev/stderr") == 2 and writer.descriptor_of("/proc/self/fd/5") == 5
    assert writer.descriptor_of("/dev/fd/3") == 3 and writer.descriptor_of("out.xml") is None
    assert writer.is_stream("/dev/null") and writer.is_stream("-") and not writer.is_stream("/tmp/x.xml")


def test_export_to_dash_writes_standard_output_and_the_summary_to_standard_error(finished, monkeypatch):
    monkeypatch.chdir(finished.root)
    result = invoke("export-cvat", finished.out, "-")
    assert result.exit_code == 0, result.stderr
    assert result.stdout.startswith("<?xml") and "<track " in result.stdout
    assert "plane track" not in result.stdout and result.stderr.splitlines()[-1] == "1 plane track: -"
    assert "<name>annotate-rgbd</name>" in result.stdout and "<name>-</name>" not in result.stdout  # the task's name
    assert not (finished.root / "-").exists()


def test_export_to_dev_stdout_writes_the_pipe(finished):
    result = run_limited(["export-cvat", finished.out, "/dev/stdout"])
    assert result.returncode == 0, result.stderr.decode()
    assert result.stdout.startswith(b"<?xml") and result.stdout.rstrip().endswith(b"</annotations>")
    assert result.stderr.decode().splitlines()[-1] == "1 plane track: /dev/stdout"
    assert os.path.islink("/dev/stdout")


def read_fifo_in_background(path: Path) -> list[bytes]:
    received: list[bytes] = []

    def read() -> None:
        with open(path, "rb") as fifo:
            received.append(fifo.read())

    threading.Thread(target=read, daemon=True).start()
    return received


def test_export_into_a_fifo_with_a_reader_writes_into_it(finished):
    fifo = finished.root / "pipe"
    os.mkfifo(fifo)
    received = read_fifo_in_background(fifo)
    result = invoke("export-cvat", finished.out, fifo)
    assert result.exit_code == 0, result.stderr
    assert fifo.is_fifo()  # not replaced by a file
    for _ in range(100):
        if received:
            break
        threading.Event().wait(0.05)
    assert received and received[0].startswith(b"<?xml")


def test_export_into_a_fifo_without_a_reader_is_refused_at_once(finished):
    fifo = finished.root / "pipe"
    os.mkfifo(fifo)
    result = invoke("export-cvat", finished.out, fifo)
    assert result.exit_code == 1
    assert error_line(result) == f"error: {fifo}: cannot write output: a FIFO without a reader"
    assert fifo.is_fifo()


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
def test_export_into_a_full_device_is_one_line(finished):
    result = invoke("export-cvat", finished.out, "/dev/full")
    assert result.exit_code == 1
    assert error_line(result) == "error: /dev/full: cannot write output: No space left on device"
    assert os.path.exists("/dev/full") and not os.path.isfile("/dev/full")


def test_export_into_a_folder_that_does_not_exist_says_so(finished):
    target = finished.root / "nodir" / "sub" / "r.xml"
    result = invoke("export-cvat", finished.out, target)
    assert result.exit_code == 1
    assert error_line(result) == f"error: {target}: cannot write output: its folder {target.parent} does not exist"
    assert not (finished.root / "nodir").exists()


def test_export_to_a_folder_or_under_a_file_says_which(finished):
    folder = finished.root / "adir"
    folder.mkdir()
    result = invoke("export-cvat", finished.out, folder)
    assert result.exit_code == 1
    assert error_line(result) == (f"error: {folder}: is a folder: name the XML file to write "
                                  f"(e.g. {folder / 'round2.xml'})")
    (finished.root / "afile").write_text("mine")
    target = finished.root / "afile" / "r.xml"
    result = invoke("export-cvat", finished.out, target)
    assert result.exit_code == 1
    assert error_line(result) == f"error: {target}: cannot write output: its folder {target.parent} is a file, not a folder"
    assert list(folder.iterdir()) == [] and (finished.root / "afile").read_text() == "mine"


def test_export_never_overwrites_the_annotations_the_run_was_made_from(finished):
    # ``export-cvat out a.xml`` beside the labeller's a.xml: the shapes the run read (and a
    # re-run needs) would be gone. Refused through another name of the same file too (a link,
    # which the atomic replace would only re-point: refusing is the plain rule).
    before = finished.xml.read_bytes()
    (finished.root / "same.xml").hardlink_to(finished.xml)
    for target in (finished.xml, finished.root / "same.xml"):
        result = invoke("export-cvat", finished.out, target)
        assert result.exit_code == 1
        assert error_line(result) == (f"error: {target}: is an annotation export the run was made from: the "
                                      f"labeller's shapes would be lost; write the export elsewhere (e.g. "
                                      f"{target.stem}-refined.xml)")
    assert finished.xml.read_bytes() == before
    # The project moved (the report's absolute path is gone): a file of the annotation's name is refused.
    moved = finished.root.parent / (finished.root.name + "-moved")
    shutil.copytree(finished.root, moved)
    result = invoke("export-cvat", moved / "out", moved / "a.xml")
    assert result.exit_code == 1
    assert error_line(result) == (f"error: {moved / 'a.xml'}: has the name of an annotation export the run was made "
                                  f"from ({finished.xml}): it may be the labeller's shapes; write the export elsewhere "
                                  "(e.g. a-refined.xml)")
    assert (moved / "a.xml").read_bytes() == before
    # An earlier export (a CVAT XML file the run did not read) is the user's to replace.
    assert invoke("export-cvat", finished.out, finished.root / "round2.xml").exit_code == 0
    (finished.root / "round2.xml").write_text("<?xml version='1.0'?>\n<annotations><version>1.1</version></annotations>")
    assert invoke("export-cvat", finished.out, finished.root / "round2.xml").exit_code == 0
    assert read_cvat(finished.root / "round2.xml").tracks


@pytest.mark.parametrize("kept", ["groundtruth.txt", "camera.toml", "rgb.txt", "notes.xml"])
def test_export_never_replaces_a_file_that_is_not_a_cvat_export(finished, kept):
    # The run's trajectory, camera file or frame list named as the export by mistake (a CLI
    # trial replaced all three): an existing file that is not CVAT XML stays as it was.
    target = finished.root / kept
    content = {"groundtruth.txt": "# ground truth trajectory\n1.0 0 0 0 0 0 0 1\n", "camera.toml": "[camera]\nfx = 525.0\n",
               "rgb.txt": "# color images\n", "notes.xml": "<?xml version='1.0'?>\n<notes/>\n"}[kept]
    target.write_text(content)
    result = invoke("export-cvat", finished.out, target)
    assert result.exit_code == 1
    first = content.splitlines()[0][:40]
    assert error_line(result) == (f"error: {target}: already exists and is not a CVAT XML file (it begins {first!r}): "
                                  "it is not replaced; write the export elsewhere, or delete that file first")
    assert target.read_text() == content


@pytest.mark.parametrize("name", ["report.json", "planes.csv", "masks/x.xml"])
def test_export_never_overwrites_the_run_it_exports(finished, name):
    before = snapshot(finished.out, skip=finished.root / "none")
    result = invoke("export-cvat", finished.out, finished.out / name)
    assert result.exit_code == 1
    assert error_line(result) == (f"error: {finished.out / name}: is {name} of the run being exported; "
                                  "write the export elsewhere")
    assert snapshot(finished.out, skip=finished.root / "none") == before


@pytest.mark.parametrize("name", ["proposals.xml", "report.json", "masks/x.xml"])
def test_export_never_overwrites_another_output_folders_files(finished, tmp_path, name):
    # Another annotate-rgbd output folder (a copy of the run: its outputs record is what marks it).
    other = tmp_path / "other"
    shutil.copytree(finished.out, other)
    (other / "proposals.xml").write_text("<annotations/>")
    before = snapshot(other, skip=tmp_path / "none")
    result = invoke("export-cvat", finished.out, other / name)
    assert result.exit_code == 1
    assert error_line(result) == (f"error: {other / name}: is {name} of the annotate-rgbd output folder {other}; "
                                  "write the export elsewhere")
    assert snapshot(other, skip=tmp_path / "none") == before
    # A file of the user's own name in that folder is theirs to write.
    assert invoke("export-cvat", finished.out, other / "round2.xml").exit_code == 0
    # A folder of a run made before the outputs record existed: its report says what it is.
    (other / ".annotate-rgbd-outputs.json").unlink()
    before = snapshot(other, skip=tmp_path / "none")
    assert invoke("export-cvat", finished.out, other / name).exit_code == 1
    assert snapshot(other, skip=tmp_path / "none") == before


def test_per_frame_csv_to_dev_stdout_puts_the_means_on_standard_error(finished):
    masks = finished.out / "masks"
    result = run_limited(["evaluate", masks, masks, "--per-frame", "/dev/stdout"], cwd=finished.root)
    assert result.returncode == 0, result.stderr.decode()
    lines = result.stdout.decode().splitlines()
    assert lines[0].startswith("frame,precision,recall") and len(lines) == 1 + finished.n
    assert "precision  1.0000" in result.stderr.decode()
    assert os.path.islink("/dev/stdout")


def test_per_frame_csv_into_a_fifo_with_a_reader(finished):
    fifo = finished.root / "pipe"
    os.mkfifo(fifo)
    received = read_fifo_in_background(fifo)
    masks = finished.out / "masks"
    result = invoke("evaluate", masks, masks, "--per-frame", fifo)
    assert result.exit_code == 0, result.stderr
    assert fifo.is_fifo()
    for _ in range(100):
        if received:
            break
        threading.Event().wait(0.05)
    assert received and received[0].startswith(b"frame,precision")


# --------------------------------------------------------------------------------------------
# 5. A tampered report.json: one line naming the file and the field
# --------------------------------------------------------------------------------------------


def _plane(report):
    return report["planes"][0]


TAMPERING = {
    "label with a control character": (lambda r: _plane(r).update(label="wa\x01ll"),
                                       "planes[0].label: holds the control character U+0001"),
    "label with a lone surrogate": (lambda r: _plane(r).update(label="\ud800"),
                                    "planes[0].label: a text with a lone surrogate"),
    "colour #zzzzzz": (lambda r: _plane(r).update(colour="#zzzzzz"), "planes[0].colour: '#zzzzzz' is not a colour"),
    "empty colour": (lambda r: _plane(r).update(colour=""), "planes[0].colour: '' is not a colour"),
    "plane id 10^30": (lambda r: r["frames"][0]["kept"][0].update(plane=10**30),
                       "frames[0].kept[0].plane: 1e+30 is out of range (1 to 1)"),
    "negative rgb_index": (lambda r: r["frames"][0].update(rgb_index=-1),
                           "frames[0].rgb_index: -1 is out of range (0 to 999999)"),
    "rgb_index 10^8": (lambda r: r["frames"][2].update(rgb_index=10**8),
                       "frames[2].rgb_index: 100000000 is out of range (0 to 999999)"),
    "warnings an integer": (lambda r: r.update(warnings=3), "warnings is not a list"),
    "tracks an integer": (lambda r: r.update(tracks=3), "tracks is not a list"),
    "mask outside masks/": (lambda r: r["frames"][0].update(mask="../../a.xml"),
                            "frames[0].mask: '../../a.xml' is not masks/<file name>"),
    "last_rgb 10^8": (lambda r: r["inputs"]["parts"][0].update(last_rgb=10**8),
                      "inputs.parts[0].last_rgb: 100000000 is out of range"),
    "summary.planes 10^30": (lambda r: r["summary"].update(planes=10**30), "summary.planes: 1e+30 is out of range"),
    "infinite distance": (lambda r: None, "the number 1e999 is beyond the range of a double"),
}


@pytest.mark.parametrize("case", sorted(TAMPERING))
@pytest.mark.parametrize("command", ["stats", "export-cvat", "review"])
def test_a_tampered_report_is_one_line_naming_the_field(finished, case, command):
    path = finished.out / "report.json"
    report = json.loads(path.read_text())
    change, message = TAMPERING[case]
    change(report)
    text = json.dumps(report)
    if case == "infinite distance":
        text = text.replace('"mean_distance": ', '"mean_distance": 1e999, "x": ', 1)
    path.write_text(text)
    args = {"stats": ["stats", finished.out], "export-cvat": ["export-cvat", finished.out, finished.root / "x.xml"],
            "review": ["review", finished.out, "-j", "1"]}[command]
    result = invoke(*args)
    assert result.exit_code == 1
    line = error_line(result)
    assert line.startswith(f"error: {path}: ") and message in line, line
    assert not (finished.root / "x.xml").exists()


# --------------------------------------------------------------------------------------------
# 6. Frames of the wrong size: skipped with a warning, the exports consistent
# --------------------------------------------------------------------------------------------


def test_propose_skips_frames_too_small_or_of_another_size(tmp_path):
    make_frames(tmp_path / "seq", [(64, 48), (64, 48), (1, 1), (60, 40), (64, 48)])
    camera = camera_file(tmp_path / "camera.toml", 64, 48)
    result = invoke("propose", tmp_path / "seq", "-c", camera, "-o", tmp_path / "out", "-j", "1", "--min-area", "0.1")
    assert result.exit_code == 0, result.stderr
    depth = tmp_path / "seq" / "depth"
    warnings = [line for line in result.stderr.splitlines() if line.startswith("warning:")]
    assert warnings == [
        f"warning: {depth / f'{timestamp(2)}.png'}: depth image is 1 x 1 pixels, smaller than the detector's "
        "20-pixel cells; skipped",
        f"warning: {depth / f'{timestamp(3)}.png'}: depth image is 60 x 40 pixels, not 64 x 48 as the first "
        "processed frame; skipped",
    ]
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert [f["status"] for f in report["frames"]] == ["written", "written", "skipped", "skipped", "written"]
    proposals = read_cvat(tmp_path / "out" / "proposals.xml")
    assert set(proposals.image_size.values()) == {(64, 48)}
    keyframes = etree.parse(str(tmp_path / "out" / "proposals.xml")).xpath("//polygon[@keyframe='1' and @outside='0']/@frame")
    assert keyframes and set(map(int, keyframes)) <= {0, 1, 4}


def test_propose_without_a_usable_frame_is_one_line(tmp_path):
    make_frames(tmp_path / "seq", [(1, 20000)] * 3)
    result = invoke("propose", tmp_path / "seq", "-o", tmp_path / "out", "-j", "1")
    assert result.exit_code == 1
    depth = tmp_path / "seq" / "depth"
    assert error_line(result) == (
        f"error: no depth frame can be used: {depth / f'{timestamp(0)}.png'}, {depth / f'{timestamp(1)}.png'}, "
        f"{depth / f'{timestamp(2)}.png'}: depth image is 1 x 20000 pixels, smaller than the detector's 20-pixel cells"
    )
    assert not [line for line in result.stderr.splitlines() if line.startswith("warning:")]


def test_export_of_masks_of_mixed_sizes_leaves_the_odd_one_out(finished):
    odd = finished.out / "masks" / f"{timestamp(2)}.png"
    colour = cv2.imread(str(odd))[15, 20]
    cv2.imwrite(str(odd), np.broadcast_to(colour, (10, 20, 3)).copy())
    result = invoke("export-cvat", finished.out, finished.root / "x.xml")
    assert result.exit_code == 0, result.stderr
    assert [line for line in result.stderr.splitlines() if line.startswith("warning:")] == [
        f"warning: {odd}: mask is 20 x 10 pixels, not 40 x 30 as the first; left out of the export"
    ]
    exported = read_cvat(finished.root / "x.xml")
    assert set(exported.image_size.values()) == {(40, 30)}
    keyframes = etree.parse(str(finished.root / "x.xml")).xpath("//polygon[@keyframe='1' and @outside='0']/@frame")
    assert sorted(map(int, keyframes)) == [0, 1]


# --------------------------------------------------------------------------------------------
# 7. Options checked before any work
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("label", "problem"), [("", "is empty"), ("  ", "is empty"),
                                                ("pla\x01ne", "holds the control character U+0001"),
                                                ("plane\n", "holds the control character U+000A")])
def test_propose_label_is_checked_before_any_work(tmp_path, label, problem):
    make_frames(tmp_path / "seq", [(64, 48)] * 2)
    result = invoke("propose", tmp_path / "seq", "-o", tmp_path / "out", "-j", "1", "--label", label)
    assert result.exit_code == 1
    assert error_line(result) == f"error: --label {label!r} {problem}: give the CVAT label of the proposed planes"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", ["cvat2mask", "propose"])
def test_an_empty_out_is_refused(finished, command, monkeypatch):
    monkeypatch.chdir(finished.root)
    before = snapshot(finished.root, skip=finished.root / "none")
    if command == "cvat2mask":
        result = invoke("cvat2mask", finished.seq, finished.xml, "-c", finished.camera, "-o", "", "-j", "1")
    else:
        result = invoke("propose", finished.seq, "-c", finished.camera, "-o", "", "-j", "1")
    assert result.exit_code == 2  # the command line's own error, as every empty path argument is
    assert error_line(result) == f"error: --out is empty (an unset shell variable?) (see root {command} -h)"
    assert snapshot(finished.root, skip=finished.root / "none") == before


# --------------------------------------------------------------------------------------------
# 8. Smaller ones
# --------------------------------------------------------------------------------------------


def npy_header(shape: tuple[int, ...], dtype: str = "<i8") -> bytes:
    header = f"{{'descr': '{dtype}', 'fortran_order': False, 'shape': {shape}, }}"
    header += " " * (118 - len(header)) + "\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode()


@pytest.mark.parametrize(("shape", "message"), [
    ((100000, 100000), "label array of shape (100000, 100000) is larger than 67108864 pixels"),
    ((30, 40), "label array of shape (30, 40) needs 9600 bytes; the file holds 64 (truncated?)"),
])
def test_npy_headers_are_checked_before_any_allocation(tmp_path, shape, message):
    path = tmp_path / "gt.npy"
    path.write_bytes(npy_header(shape) + bytes(64))
    result = invoke("evaluate", path, path)
    assert result.exit_code == 1
    assert error_line(result) == f"error: {path}: {message}"


def test_cape_csv_has_a_size_bound(tmp_path, monkeypatch):
    monkeypatch.setattr(labelmaps, "MAX_CSV_BYTES", 1000)
    path = tmp_path / "labels.csv"
    path.write_text("1,2,3,\n" * 200)
    result = invoke("evaluate", path, path)
    assert result.exit_code == 1
    assert error_line(result) == f"error: {path}: cannot read label CSV: larger than 1000 bytes"
    path.write_text("1,2,3,\n0,0,x,\n")
    result = invoke("evaluate", path, path)
    assert error_line(result) == f"error: {path}: label CSV line 2 holds a value that is not an integer"


def test_review_page_links_are_url_encoded(finished):
    report = json.loads((finished.out / "report.json").read_text())
    report["frames"][0]["mask"] = "masks/a #1?b%.png"
    data = page_data(RunRecord.from_json(report), {"masks/a #1?b%.png": "overlays/a #1?b%.png"})
    frame = data["frames"][0]
    assert frame["mask"] == "masks/a #1?b%.png"  # the name, as shown
    assert frame["mask_url"] == "masks/a%20%231%3Fb%25.png" and frame["overlay"] == "overlays/a%20%231%3Fb%25.png"
    assert data["frames"][1]["mask_url"] == data["frames"][1]["mask"]


def test_an_output_folder_moved_mid_run_is_not_made_again(tmp_path):
    scene = Scene(tmp_path, n=4)
    moved = tmp_path / "moved"

    def move_after_the_first(done: int, total: int) -> None:
        if done == 1 and not moved.exists():
            scene.out.rename(moved)

    with pytest.raises(OutputError, match="its folder is gone"):
        run_cvat2mask(scene.seq, [scene.xml], scene.out, load_config(str(scene.camera)), workers=1,
                      progress=move_after_the_first)
    assert not scene.out.exists() and moved.is_dir()


def test_writing_into_a_removed_folder_never_makes_it_again(tmp_path):
    with pytest.raises(OutputError, match="its folder is gone"):
        writer.write_png(tmp_path / "out" / "masks" / "m.png", np.zeros((2, 2, 3), np.uint8))
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("outs", "problem"), [
    (["out/a", "out/a/b"], "is inside another scene's"),
    (["out/a", ""], "[[scene]] 2: 'out' is empty"),
])
def test_batch_refuses_nested_or_empty_outputs(tmp_path, outs, problem):
    scenes = "".join(f'[[scene]]\nsequence = "seq"\nannotations = ["a.xml"]\nout = "{out}"\n' for out in outs)
    (tmp_path / "batch.toml").write_text(scenes)
    result = invoke("batch", tmp_path / "batch.toml")
    assert result.exit_code == 1
    line = error_line(result)
    assert line.startswith(f"error: {tmp_path / 'batch.toml'}: ") and problem in line


@pytest.mark.slow  # stresses processes (memory and file-size limits)
@needs_limits
def test_a_journal_that_cannot_be_written_is_named(tmp_path):
    scene = Scene(tmp_path, n=10)
    # Masks (about 150 bytes) fit under the file-size limit; the journal passes it at its 4th line.
    result = run_limited(["cvat2mask", scene.seq, scene.xml, "-c", scene.camera, "-o", scene.out, "-j", "1"],
                         file_size=2000)
    assert result.returncode == 1
    journal = scene.out / ".annotate-rgbd-journal.jsonl"
    assert one_error(result.stderr.decode()) == f"error: {journal}: cannot write output: File too large"
    rerun = scene.run()
    assert rerun.exit_code == 0 and "unchanged)" in rerun.stdout


def test_partial_errors_name_partial(finished):
    masks = finished.out / "masks"
    result = invoke("evaluate", masks, masks, "--partial", "2")
    assert error_line(result) == "error: --partial must be in (0, 1], not 2.0"


def test_a_problem_every_frame_shares_is_one_error(tmp_path):
    make_frames(tmp_path / "seq", [(40, 30)] * 6, eight_bit=True)
    box_export(tmp_path / "a.xml", 6, 40, 30)
    camera = camera_file(tmp_path / "camera.toml", 40, 30)
    result = invoke("cvat2mask", tmp_path / "seq", tmp_path / "a.xml", "-c", camera, "-o", tmp_path / "out", "-j", "1")
    assert result.exit_code == 1
    depth = tmp_path / "seq" / "depth"
    assert error_line(result) == (
        f"error: no depth frame can be used: {depth / f'{timestamp(0)}.png'}, {depth / f'{timestamp(1)}.png'}, "
        f"{depth / f'{timestamp(2)}.png'} and 3 more: depth image is 8-bit; expected 16-bit depth (TUM / ICL-NUIM PNG)"
    )
    assert not [line for line in result.stderr.splitlines() if line.startswith("warning:")]
    assert not (tmp_path / "out" / "report.json").exists()


def test_a_problem_many_frames_share_is_said_once(tmp_path):
    make_frames(tmp_path / "seq", [(40, 30)] * 6)
    for i in (1, 3, 4):
        path = tmp_path / "seq" / "depth" / f"{timestamp(i)}.png"
        cv2.imwrite(str(path), (cv2.imread(str(path), cv2.IMREAD_UNCHANGED) // 256).astype(np.uint8))
    box_export(tmp_path / "a.xml", 6, 40, 30)
    camera = camera_file(tmp_path / "camera.toml", 40, 30)
    result = invoke("cvat2mask", tmp_path / "seq", tmp_path / "a.xml", "-c", camera, "-o", tmp_path / "out", "-j", "1")
    assert result.exit_code == 1  # a failed frame fails the run, after every other mask
    depth = tmp_path / "seq" / "depth"
    problem = (f"{depth / f'{timestamp(1)}.png'}, {depth / f'{timestamp(3)}.png'}, {depth / f'{timestamp(4)}.png'}: "
               "depth image is 8-bit; expected 16-bit depth (TUM / ICL-NUIM PNG)")
    assert [line for line in result.stderr.splitlines() if line.startswith("warning:")] == [f"warning: {problem}; failed (no mask)"]
    assert f"  failed: {problem}" in result.stdout.splitlines()
    assert "3 masks in" in result.stdout and "3 frames failed" in result.stdout


@pytest.mark.parametrize("tolerance", ["inf", "nan"])
def test_export_with_a_tolerance_that_is_no_distance_is_one_line(finished, tolerance):
    target = finished.root / "r.xml"
    result = invoke("export-cvat", finished.out, target, "--tolerance", tolerance, "--jobs", "1")
    assert result.exit_code == 2  # a value out of the option's range, as click's own range checks say
    assert error_line(result).startswith(f"error: Invalid value for '--tolerance': must be a finite distance in pixels "
                                         f">= 0, not {tolerance} (see ")
    assert not target.exists()


@pytest.mark.parametrize("budget", ["1", "2", "-1"])
def test_export_with_a_vertex_budget_under_a_triangle_is_one_line_and_status_2(finished, budget):
    target = finished.root / "r.xml"
    result = invoke("export-cvat", finished.out, target, "--max-vertices", budget, "--jobs", "1")
    assert result.exit_code == 2
    assert error_line(result).startswith(f"error: Invalid value for '--max-vertices': must be 0 (no budget) or at least "
                                         f"a polygon's 3 vertices, not {budget} (see ")
    assert not target.exists()
    help_text = " ".join(invoke("export-cvat", "--help").output.split())
    assert "0 for none, else at least 3 (default 200). -j" in help_text  # no [x>=0] after it


@pytest.mark.parametrize(("option", "value", "rule"), [
    ("--max-invalid-ratio", "1.5", "must be in [0, 1], not 1.5"),
    ("--max-invalid-ratio", "-0.1", "must be in [0, 1], not -0.1"),
    ("--max-mean-distance", "0", "must be > 0, not 0"),
    ("--max-time-diff", "-1", "must be >= 0, not -1"),
    ("--distance-threshold", "-0.01", "must be >= 0 (0: the [noise] band), not -0.01"),
    ("--distance-threshold", "nan", "must be a finite number, got nan"),
])
def test_cvat2mask_options_that_set_a_key_are_checked_by_its_rule_as_the_line_is_parsed(tmp_path, option, value, rule):
    # A CLI trial: these named the configuration key ('filter.max_invalid_ratio' ...) and exited 1,
    # where every other option out of range names the option and exits 2. The rule is the key's
    # own, as --config and --set check it.
    result = invoke("cvat2mask", SAMPLE / "sequence", SAMPLE / "annotations.xml", "-c", SAMPLE / "camera.toml",
                    "-o", tmp_path / "out", option, value)
    assert result.exit_code == 2
    assert error_line(result).startswith(f"error: Invalid value for '{option}': {rule} (see ")
    assert not (tmp_path / "out").exists()
    key = {"--max-invalid-ratio": "filter.max_invalid_ratio", "--max-mean-distance": "filter.max_mean_distance",
           "--max-time-diff": "sequence.max_time_diff", "--distance-threshold": "ransac.distance_threshold"}[option]
    same = invoke("cvat2mask", SAMPLE / "sequence", SAMPLE / "annotations.xml", "-c", SAMPLE / "camera.toml",
                  "-o", tmp_path / "out", "--set", f"{key}={value}")
    assert same.exit_code == 1 and rule.split(", not ")[0] in error_line(same)


@pytest.mark.parametrize("share", ["0", "1.5", "nan"])
def test_propose_min_area_outside_its_range_is_one_line_and_the_help_says_the_range(tmp_path, share):
    # The help said [0.0<=x<=1.0] while 0 was refused; NaN passed the option's own range check.
    result = invoke("propose", SAMPLE / "sequence", "-c", SAMPLE / "camera.toml", "-o", tmp_path / "out",
                    "--min-area", share)
    assert result.exit_code == 2  # out of the option's range, as --every 0 is
    assert error_line(result).startswith(f"error: Invalid value for '--min-area': must be a share of the image in "
                                         f"(0, 1], not {share} (see ")
    assert not (tmp_path / "out").exists()
    help_text = " ".join(invoke("propose", "--help").output.split())  # as wrapped for any width
    assert "as a share of the image, in (0, 1]" in help_text and "0.0<=x<=1.0" not in help_text

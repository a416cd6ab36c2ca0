"""Review of a finished run: overlays, contact sheet, the review page (also in a real browser)."""

from __future__ import annotations

import base64
import fcntl
import io
import itertools
import json
import os
import select
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import SAMPLE_DATA
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.config.settings import load_config
from annotate_rgbd.errors import InputError
from annotate_rgbd.pipeline.scene import run_cvat2mask
from annotate_rgbd.progress import Progress
from annotate_rgbd.report.records import PlaneInfo, RunRecord
from annotate_rgbd.review.review import review_run
from annotate_rgbd.review.page import page_data, render_review_page
from annotate_rgbd.io.sequence import read_rgb

#: Set to a path to keep a copy of the browser test's screenshot (the README's sample_data/review.png).
SCREENSHOT_COPY = "ANNOTATE_RGBD_REVIEW_SCREENSHOT"


@pytest.fixture(scope="module")
def finished_run(sample_run, tmp_path_factory) -> Path:
    """The sample sequence through cvat2mask (the session's run, copied) and review."""
    out = tmp_path_factory.mktemp("run") / "sample_masks"
    shutil.copytree(sample_run[0], out)
    review_run(out)
    return out


def _report(out: Path) -> dict:
    return json.loads((out / "report.json").read_text(encoding="utf-8"))


def test_review_writes_one_overlay_per_mask(finished_run):
    written = [f for f in _report(finished_run)["frames"] if f["status"] == "written"]
    assert written
    overlays = sorted(p.name for p in (finished_run / "overlays").iterdir())
    assert overlays == sorted(Path(f["mask"]).name for f in written)
    assert (finished_run / "contact_sheet.png").is_file()
    assert not list(finished_run.rglob("*.tmp"))


def test_overlay_is_tinted_with_the_mask_colours(finished_run):
    sequence = SAMPLE_DATA / "sequence"
    for frame in [f for f in _report(finished_run)["frames"] if f["status"] == "written"][:3]:
        mask = read_rgb(finished_run / frame["mask"]).astype(float)
        overlay = read_rgb(finished_run / "overlays" / Path(frame["mask"]).name).astype(float)
        rgb = read_rgb(sequence / frame["rgb"]).astype(float)
        on_plane = mask.any(axis=2)
        assert overlay.shape == mask.shape
        # On the mask's pixels the overlay is pulled towards the plane colour.
        before = np.linalg.norm(rgb - mask, axis=2)[on_plane].mean()
        after = np.linalg.norm(overlay - mask, axis=2)[on_plane].mean()
        assert after < 0.7 * before


def test_review_needs_a_finished_run(tmp_path):
    # review draws cvat2mask runs and propose folders: the message names both; stats only the first.
    with pytest.raises(InputError, match="no report: not the output folder of a finished cvat2mask or propose run"):
        review_run(tmp_path)
    from annotate_rgbd.report.run_folder import read_report

    with pytest.raises(InputError, match="no report: not the output folder of a finished cvat2mask run$"):
        read_report(tmp_path)


def test_review_reads_the_run_not_its_inputs(tmp_path, monkeypatch):
    """Review needs the run's folder and the RGB frames only: the CVAT export may be gone, the
    working directory elsewhere, and no stage runs again; its overlays are the ones
    ``cvat2mask --overlays`` draws while it segments."""
    work = tmp_path / "work"
    shutil.copytree(SAMPLE_DATA / "sequence", work / "sequence")
    shutil.copy(SAMPLE_DATA / "annotations.xml", work / "annotations.xml")
    config = load_config(SAMPLE_DATA / "camera.toml", {"ransac.num_iterations": 200})
    monkeypatch.chdir(work)
    run_cvat2mask(Path("sequence"), [Path("annotations.xml")], Path("with_overlays"), config, overlays=True)
    run_cvat2mask(Path("sequence"), [Path("annotations.xml")], Path("plain"), config)
    (work / "annotations.xml").unlink()
    monkeypatch.chdir(tmp_path)

    import annotate_rgbd.segment.frame as frame_stage

    def no_segmenting(*args, **kwargs):
        raise AssertionError("review segmented a frame again")

    monkeypatch.setattr(frame_stage, "segment_frame", no_segmenting)
    result = review_run(work / "plain", page=False, sheet=False)
    assert result.overlays
    for path in result.overlays:
        assert path.read_bytes() == (work / "with_overlays" / "overlays" / path.name).read_bytes()


def test_unreadable_rgb_images_cost_their_overlays_colour_not_the_frame(tmp_path):
    """A missing and a corrupt RGB image: ``cvat2mask --overlays`` still makes every mask and
    overlay (those two on grey) with one warning line for each problem; a re-run redraws the two once
    the images are back; ``review`` does the same without stopping."""
    sequence = tmp_path / "sequence"
    shutil.copytree(SAMPLE_DATA / "sequence", sequence)
    config = load_config(SAMPLE_DATA / "camera.toml")
    clean = run_cvat2mask(sequence, [SAMPLE_DATA / "annotations.xml"], tmp_path / "clean", config, overlays=True)
    frames = [f for f in clean.frames if f.written][3:5]
    broken = [sequence / f.rgb for f in frames]
    saved = [path.read_bytes() for path in broken]
    broken[0].unlink()
    broken[1].write_bytes(b"not a jpeg")
    out = tmp_path / "out"
    result = run_cvat2mask(sequence, [SAMPLE_DATA / "annotations.xml"], out, config, overlays=True)
    assert result.counts.failed == 0 and result.written == clean.written
    lines = [w for w in result.warnings if "overlay is drawn on grey" in w]
    assert lines == [f"{broken[0]}: file not found; its overlay is drawn on grey",
                     f"{broken[1]}: not a readable image (corrupt or unsupported format); its overlay is drawn on grey"]
    for name in sorted(p.name for p in (tmp_path / "clean" / "masks").iterdir()):
        assert (out / "masks" / name).read_bytes() == (tmp_path / "clean" / "masks" / name).read_bytes()
    greyed = {Path(f.mask).name for f in frames}
    for name in sorted(p.name for p in (tmp_path / "clean" / "overlays").iterdir()):
        same = (out / "overlays" / name).read_bytes() == (tmp_path / "clean" / "overlays" / name).read_bytes()
        assert same == (name not in greyed), name
    # review: the same warnings, every overlay written.
    output = review_run(out, page=True, sheet=False)
    assert len(output.overlays) == clean.written and output.warnings == lines
    # With the images back, a re-run redraws those two frames only.
    for path, data in zip(broken, saved):
        path.write_bytes(data)
    again = run_cvat2mask(sequence, [SAMPLE_DATA / "annotations.xml"], out, config, overlays=True)
    assert (again.counts.made, again.counts.reused) == (2, clean.written - 2)
    assert not [w for w in again.warnings if "grey" in w]
    for name in greyed:
        assert (out / "overlays" / name).read_bytes() == (tmp_path / "clean" / "overlays" / name).read_bytes()


def test_review_without_the_drawn_shapes_record_says_what_to_do(finished_run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(finished_run, out, ignore=shutil.ignore_patterns("overlays"))
    (out / ".annotate-rgbd-shapes.jsonl").unlink()
    with pytest.raises(InputError, match="run cvat2mask again"):
        review_run(out, page=False, sheet=False)


def test_review_reports_progress_after_each_overlay(finished_run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(finished_run, out, ignore=shutil.ignore_patterns("overlays"))
    calls = []
    review_run(out, page=False, sheet=False, progress=lambda done, total: calls.append((done, total, len(list((out / "overlays").iterdir())))))
    written = _report(out)["summary"]["masks_written"]
    # Each call comes once its overlay is on disk.
    assert calls == [(i, written, i) for i in range(1, written + 1)]


def test_review_with_helpers_writes_the_same_overlays(finished_run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(finished_run, out, ignore=shutil.ignore_patterns("overlays"))
    report = _report(out)
    result = review_run(out, page=False, sheet=False, workers=2)
    assert result.overlays == [out / "overlays" / Path(f["mask"]).name for f in report["frames"] if f["status"] == "written"]
    for path in result.overlays:
        assert path.read_bytes() == (finished_run / "overlays" / path.name).read_bytes()


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_on_a_terminal_ends_its_line_only_if_it_drew_one():
    terminal = Terminal()
    Progress({"run": 0}, stream=terminal).finish()  # review --no-overlays: no progress at all
    assert terminal.getvalue() == ""
    progress = Progress({"run": 0}, stream=terminal, clock=itertools.count().__next__)
    update = progress.callback("run")
    update(1, 2)
    update(2, 2)
    progress.finish()
    lines = terminal.getvalue().split("\r\033[K")
    assert lines[0] == "" and lines[1].startswith("run: 1/2 frames") and lines[2].startswith("run: 2/2 frames")
    assert lines[2].endswith("\n") and lines[2].count("\n") == 1


def test_review_of_a_run_without_masks_writes_only_the_page(tmp_path):
    report = {"inputs": {"sequence": "gone", "parts": []}, "config": {}, "planes": [],
              "frames": [{"depth": "depth/1.png", "depth_timestamp": 1.0, "rgb": "rgb/1.png", "rgb_index": 0,
                          "time_offset": 0.0, "status": "skipped", "reason": "outside_annotated_range"}]}
    (tmp_path / "report.json").write_text(json.dumps(report), encoding="utf-8")
    result = review_run(tmp_path)
    assert result.overlays == [] and result.sheet is None and result.page.is_file()
    assert _embedded_data(result.page.read_text(encoding="utf-8"))["stats"]["depth_frames"] == 1


def test_contact_sheet_needs_overlays(finished_run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(finished_run, out, ignore=shutil.ignore_patterns("overlays", "review.html", "contact_sheet.png"))
    with pytest.raises(InputError, match="no overlays"):
        review_run(out, overlays=False, page=False)
    # Refused before anything is written: not the page first and then an error.
    with pytest.raises(InputError, match="no overlays"):
        review_run(out, overlays=False)
    assert not (out / "review.html").exists() and not (out / "contact_sheet.png").exists()


def test_cli_review_that_would_write_nothing_says_so(finished_run):
    result = CliRunner().invoke(app, ["review", str(finished_run), "--no-overlays", "--no-page", "--no-sheet"])
    assert result.exit_code == 1
    assert result.output.strip() == ("error: nothing to do: --no-overlays, --no-page and --no-sheet leave no output "
                                     "(add --rerun FILE.rrd for a recording only)")


def test_page_without_overlays_refers_to_none(finished_run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(finished_run, out, ignore=shutil.ignore_patterns("overlays"))
    result = review_run(out, overlays=False, sheet=False)
    assert result.overlays == [] and result.page is not None
    data = _embedded_data(result.page.read_text(encoding="utf-8"))
    assert all(f["overlay"] is None for f in data["frames"])


def test_page_data_follows_the_report(finished_run):
    report = _report(finished_run)
    data = page_data(RunRecord.from_json(report), {})
    written = [(i, f) for i, f in enumerate(report["frames"]) if f["status"] == "written"]
    assert [f["index"] for f in data["frames"]] == [i for i, _ in written]
    for entry, (_, frame) in zip(data["frames"], written):
        assert entry["planes"] == _expected_rows(frame)
    assert data["stats"]["observations"] == len(written)


def test_page_is_self_contained_and_references_images_by_path(finished_run):
    page = (finished_run / "review.html").read_text(encoding="utf-8")
    assert "http://" not in page and "https://" not in page
    assert "data:image" not in page and "<link" not in page and "src=" not in page
    data = _embedded_data(page)
    assert data["frames"][0]["overlay"] == "overlays/" + Path(data["frames"][0]["mask"]).name
    assert all((finished_run / f["overlay"]).is_file() and (finished_run / f["mask"]).is_file() for f in data["frames"])


def test_page_data_cannot_end_the_script_block():
    report = RunRecord("0", "seq", [], {}, [PlaneInfo(1, "#00ff00", "</script><b>x", "a.xml", 0)], 1, [], [])
    page = render_review_page(report, {}, title="<run>")
    assert "</script><b>" not in page and "&lt;run&gt;" in page
    assert _embedded_data(page)["planes"][0]["label"] == "</script><b>x"


def test_cli_review(finished_run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(finished_run, out, ignore=shutil.ignore_patterns("overlays", "review.html", "contact_sheet.png"))
    result = CliRunner().invoke(app, ["review", str(out), "--no-sheet", "--jobs", "2"])
    assert result.exit_code == 0, result.output
    assert (out / "review.html").is_file() and not (out / "contact_sheet.png").exists()
    written = _report(out)["summary"]["masks_written"]
    assert len(list((out / "overlays").iterdir())) == written
    # Progress goes to stderr (not a terminal here: a plain line at the end), stdout keeps the summary.
    assert f"out: {written}/{written} frames" in result.stderr
    assert "frames/s" not in result.stdout
    missing = CliRunner().invoke(app, ["review", str(tmp_path / "nothing")])
    assert missing.exit_code == 1 and "error:" in missing.output


def _expected_rows(frame: dict) -> list[list]:
    def source(r: dict) -> str:
        return {None: "drawn", True: "propagated", False: "drawn"}[r.get("propagated")]

    def agree(r: dict) -> float | None:
        return frame.get("keyframes_agree", {}).get(str(r["plane"]))

    rows = [[r["plane"], "kept", None, r["pixels"], r["inliers"], r["inlier_ratio"], source(r), agree(r)]
            for r in frame["kept"]]
    rows += [[r["plane"], "dropped", r["reason"], r["pixels"], 0, None, source(r), agree(r)] for r in frame["dropped"]]
    return sorted(rows, key=lambda row: row[0])


def _embedded_data(page: str) -> dict:
    start = page.index('<script type="application/json" id="run-data">') + len('<script type="application/json" id="run-data">')
    return json.loads(page[start : page.index("</script>", start)])


# ----------------------------------------------------------------------------------------------
# The page in a real headless browser (Debian's chromium), driven over the DevTools protocol.
# ----------------------------------------------------------------------------------------------

BROWSER_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--remote-debugging-pipe",
]
#: Bound on every wait for the browser.
REPLY_TIMEOUT = 30


@pytest.fixture(scope="module")
def chromium() -> str:
    """Path of Debian's chromium (``bash .ci/setup --tests`` installs it where it can); skip without it."""
    found = shutil.which("chromium")
    if not found:
        pytest.skip("no browser: chromium is not installed (bash .ci/setup --tests installs it as root or through sudo)")
    return found


class DevTools:
    """A minimal Chrome DevTools protocol client over ``--remote-debugging-pipe`` (fds 3 and 4).

    Messages are JSON texts ended by a NUL byte. Events are kept in ``events`` as they arrive.
    """

    def __init__(self, executable: str, profile: Path):
        to_browser_read, self._write = os.pipe()
        self._read, from_browser_write = os.pipe()
        # The browser expects the pipe on fds 3 (commands) and 4 (replies): a small Python
        # trampoline moves them there (from numbers above 4, so neither move overwrites the
        # other's source) and execs the browser.
        to_browser_read, from_browser_write = (_above_4(fd) for fd in (to_browser_read, from_browser_write))
        self.log_path = profile.parent / f"{profile.name}.log"
        self._log = open(self.log_path, "wb")  # noqa: SIM115 - open for the browser's lifetime
        command = [executable, *BROWSER_FLAGS, f"--user-data-dir={profile}", "about:blank"]
        trampoline = f"import os, sys; os.dup2({to_browser_read}, 3); os.dup2({from_browser_write}, 4); os.execv(sys.argv[1], sys.argv[1:])"
        self.process = subprocess.Popen(
            [sys.executable, "-c", trampoline, *command],
            pass_fds=(to_browser_read, from_browser_write), stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL, stderr=self._log,
        )
        os.close(to_browser_read)
        os.close(from_browser_write)
        self._buffer = b""
        self._next_id = 0
        self.events: list[dict] = []

    def call(self, method: str, session: str | None = None, **params) -> dict:
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params}
        if session:
            message["sessionId"] = session
        os.write(self._write, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + REPLY_TIMEOUT
        while True:
            reply = self._receive(deadline)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]
            self.events.append(reply)

    def wait_for_event(self, method: str) -> dict:
        deadline = time.monotonic() + REPLY_TIMEOUT
        while True:
            for event in self.events:
                if event.get("method") == method:
                    self.events.remove(event)
                    return event
            self.events.append(self._receive(deadline))

    def _receive(self, deadline: float) -> dict:
        while b"\0" not in self._buffer:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not select.select([self._read], [], [], remaining)[0]:
                raise TimeoutError("no answer from the browser")
            chunk = os.read(self._read, 1 << 20)
            if not chunk:
                log = self.log_path.read_text(errors="replace").splitlines()
                raise RuntimeError("the browser closed the DevTools pipe; its last words:\n" + "\n".join(log[-10:]))
            self._buffer += chunk
        text, _, self._buffer = self._buffer.partition(b"\0")
        return json.loads(text)

    def close(self) -> None:
        try:
            self.call("Browser.close")
        except (RuntimeError, TimeoutError, OSError):
            pass
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        os.close(self._write)
        os.close(self._read)
        self._log.close()


def _above_4(fd: int) -> int:
    moved = fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10)
    os.close(fd)
    return moved


class Page:
    """One browser tab attached in flat mode: commands go to it by session id."""

    def __init__(self, tools: DevTools):
        self.tools = tools
        target = tools.call("Target.createTarget", url="about:blank")["targetId"]
        self.session = tools.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        for domain in ("Page", "Runtime", "Log"):
            self.call(f"{domain}.enable")

    def call(self, method: str, **params) -> dict:
        return self.tools.call(method, self.session, **params)

    def evaluate(self, expression: str):
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def press(self, key: str, code: int) -> None:
        for kind in ("keyDown", "keyUp"):
            self.call("Input.dispatchKeyEvent", type=kind, key=key, code=key, windowsVirtualKeyCode=code)

    def errors(self) -> list[str]:
        """Console errors, uncaught exceptions and failed loads so far."""
        found = []
        for event in self.tools.events:
            params = event.get("params", {})
            if event.get("method") == "Runtime.exceptionThrown":
                found.append(str(params["exceptionDetails"]))
            elif event.get("method") == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
                found.append(str(params.get("args")))
            elif event.get("method") == "Log.entryAdded" and params["entry"]["level"] == "error":
                found.append(params["entry"].get("text", ""))
        return found


@pytest.fixture
def browser(chromium, tmp_path):
    profile = tmp_path / "browser-profile"
    profile.mkdir()
    tools = DevTools(chromium, profile)
    try:
        yield tools
    finally:
        tools.close()


TABLE_ROWS = """Array.from(document.querySelectorAll('#planes tbody tr')).map(tr =>
    Array.from(tr.cells).map(td => td.textContent))"""
IMAGES_LOADED = """(async () => {
    for (let i = 0; i < 200; i++) {
        const imgs = ['overlay', 'mask'].map(id => document.getElementById(id));
        if (imgs.every(img => img.complete && img.naturalWidth > 0)) return true;
        await new Promise(r => setTimeout(r, 25));
    }
    return false;
})()"""


def test_review_page_in_a_browser(finished_run, browser, tmp_path):
    report = _report(finished_run)
    written = [f for f in report["frames"] if f["status"] == "written"]
    page = Page(browser)
    page.call("Emulation.setDeviceMetricsOverride", width=1280, height=900, deviceScaleFactor=1, mobile=False)
    page.call("Page.navigate", url=(finished_run / "review.html").resolve().as_uri())
    browser.wait_for_event("Page.loadEventFired")
    assert page.evaluate(IMAGES_LOADED)

    def shown() -> tuple[str, str, list[list[str]]]:
        return (page.evaluate("document.getElementById('counter').textContent"),
                page.evaluate("document.getElementById('mask').getAttribute('src')"),
                page.evaluate(TABLE_ROWS))

    counter, mask, rows = shown()
    assert counter == f"frame 1 of {len(written)}" and mask == written[0]["mask"]
    assert rows == _table_text(written[0], report)

    page.press("ArrowRight", 39)
    page.press("ArrowRight", 39)
    counter, mask, rows = shown()
    assert counter == f"frame 3 of {len(written)}" and mask == written[2]["mask"]
    assert rows == _table_text(written[2], report)
    assert page.evaluate("document.getElementById('overlay').getAttribute('src')") == "overlays/" + Path(written[2]["mask"]).name
    page.press("ArrowLeft", 37)
    counter, mask, rows = shown()
    assert counter == f"frame 2 of {len(written)}" and mask == written[1]["mask"]
    assert rows == _table_text(written[1], report)

    # Totals and timeline are drawn from the same data.
    totals = dict(page.evaluate("""Array.from(document.querySelectorAll('#totals tr')).map(tr =>
        Array.from(tr.cells).map(td => td.textContent))"""))
    assert totals["observations (masks)"] == str(len(written))
    assert page.evaluate("document.getElementById('timeline').height") > 0

    assert page.evaluate(IMAGES_LOADED)
    shot = base64.b64decode(page.call("Page.captureScreenshot", format="png", captureBeyondViewport=True)["data"])
    assert shot.startswith(b"\x89PNG")
    (tmp_path / "review.png").write_bytes(shot)
    if os.environ.get(SCREENSHOT_COPY):
        Path(os.environ[SCREENSHOT_COPY]).write_bytes(shot)
    assert page.errors() == []


def _table_text(frame: dict, report: dict) -> list[list[str]]:
    """The plane table of a frame as the page should show it, from report.json."""
    labels = {p["plane"]: p["label"] for p in report["planes"]}
    return [
        [str(plane), labels[plane], status, reason or "", str(pixels), str(kept), "" if ratio is None else f"{ratio:.3f}",
         source if agree is None else f"{source}, keyframes agree {agree:.2f}"]
        for plane, status, reason, pixels, kept, ratio, source, agree in _expected_rows(frame)
    ]


def test_a_run_folder_that_is_not_there_is_said_so(tmp_path):
    # Not "<folder>/report.json: no report: not the output folder of a finished run", which reads
    # as if the folder were there.
    from annotate_rgbd.report.run_folder import read_report

    with pytest.raises(InputError) as missing:
        read_report(tmp_path / "typo")
    assert str(missing.value) == f"{tmp_path / 'typo'}: no such folder"
    (tmp_path / "file.txt").write_text("x")
    with pytest.raises(InputError) as a_file:
        review_run(tmp_path / "file.txt")
    assert str(a_file.value) == f"{tmp_path / 'file.txt'}: not a folder: give a run's output folder"


def test_review_page_shows_what_to_check_of_a_run_with_poses_in_a_browser(finished_run, browser, tmp_path):
    """The lists of a run with poses (its report edited: a carried plane whose keyframes disagree,
    a carried plane dropped where the poses put it) in the page's totals and plane table."""
    out = tmp_path / "posed"
    shutil.copytree(finished_run, out)
    report = _report(out)
    written = [f for f in report["frames"] if f["status"] == "written"]
    carried = written[0]["kept"][0]
    carried["propagated"] = True
    written[0]["keyframes_agree"] = {str(carried["plane"]): 0.21}
    written[1]["dropped"][0]["reason"] = "not_where_expected"
    (out / "report.json").write_text(json.dumps(report), encoding="utf-8")
    review_run(out)
    page = Page(browser)
    page.call("Page.navigate", url=(out / "review.html").resolve().as_uri())
    browser.wait_for_event("Page.loadEventFired")
    assert page.evaluate(IMAGES_LOADED)
    rows = page.evaluate(TABLE_ROWS)
    assert rows == _table_text(written[0], report)
    assert [carried["plane"]] == [int(row[0]) for row in rows if row[-1] == "propagated, keyframes agree 0.21"]
    totals = dict(page.evaluate("""Array.from(document.querySelectorAll('#totals tr')).map(tr =>
        Array.from(tr.cells).map(td => td.textContent))"""))
    assert totals["carried planes to check (1, worst first)"] == \
        f"{written[0]['depth']} plane {carried['plane']} (0.21)"
    assert totals["frames to review (1: a carried plane not where the poses put it)"] == written[1]["depth"]
    # Each entry is a link to its frame.
    page.evaluate("""document.querySelectorAll('#totals a')[0].click()""")  # the frame to review
    assert page.evaluate("document.getElementById('counter').textContent") == f"frame 2 of {len(written)}"
    assert page.evaluate(TABLE_ROWS) == _table_text(written[1], report)
    page.evaluate("""document.querySelectorAll('#totals a')[1].click()""")  # the carried plane to check
    assert page.evaluate("document.getElementById('counter').textContent") == f"frame 1 of {len(written)}"
    assert page.errors() == []

"""Output integrity: no stale mask kept, nothing touched outside --out, no endless wait.

Kill and lock tests use real processes and are bounded in time.
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import os
import random
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time
from concurrent.futures import Future
from pathlib import Path

import pytest
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.config.settings import load_config
from annotate_rgbd.errors import OutputError
from annotate_rgbd.io.outdir import OWNER, OutputLock
from annotate_rgbd.pipeline.scene import run_cvat2mask
from annotate_rgbd.pool import JobOutcome, JobTimeout, run_jobs, start_helpers
from annotate_rgbd.pipeline.resume import JOURNAL, MAX_RECORDS_BYTES, previous_results

REPO_ROOT = Path(__file__).resolve().parents[2]
SAMPLE = REPO_ROOT / "sample_data"
SEQUENCE, ANNOTATIONS, CAMERA = SAMPLE / "sequence", SAMPLE / "annotations.xml", SAMPLE / "camera.toml"
CLI = [sys.executable, "-m", "annotate_rgbd"]


def _masks(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((folder / "masks").iterdir())}


@pytest.fixture(scope="module")
def clean_run(sample_run) -> Path:
    """One uninterrupted run with the sample's settings."""
    return sample_run[0]


@pytest.fixture(scope="module")
def tight_run(tmp_path_factory) -> Path:
    """The same frames with a much tighter inlier band: other masks."""
    out = tmp_path_factory.mktemp("tight") / "out"
    run_cvat2mask(SEQUENCE, [ANNOTATIONS], out, load_config(CAMERA, {"ransac.distance_threshold": 0.005}))
    return out


# --- 1. A re-run never keeps a mask that differs from its record ---------------------------


def test_a_mask_rewritten_after_its_record_is_made_again(clean_run, tight_run, tmp_path):
    # What an interrupted run with other settings leaves: a helper wrote the mask, the main
    # process was killed before it journalled it, so the record still holds the old fingerprint.
    out = tmp_path / "out"
    shutil.copytree(clean_run, out)
    name = sorted(_masks(out))[4]
    assert _masks(tight_run)[name] != _masks(clean_run)[name]
    shutil.copy(tight_run / "masks" / name, out / "masks" / name)
    report = run_cvat2mask(SEQUENCE, [ANNOTATIONS], out, load_config(CAMERA))
    assert (report.counts.made, report.counts.reused) == (1, 18)
    assert _masks(out) == _masks(clean_run)


def test_report_records_the_digest_of_every_output(clean_run):
    import hashlib

    report = json.loads((clean_run / "report.json").read_text())
    for frame in (f for f in report["frames"] if f["status"] == "written"):
        assert list(frame["outputs"]) == [frame["mask"]]
        data = (clean_run / frame["mask"]).read_bytes()
        assert frame["outputs"][frame["mask"]] == hashlib.blake2b(data, digest_size=16).hexdigest()


@pytest.mark.slow  # kills or interrupts processes: `pytest -m "not slow"` leaves it out
@pytest.mark.parametrize("journalled, delay", [(2, 0.015), (5, 0.03), (8, 0.045), (11, 0.02)])
def test_cli_run_killed_with_other_settings_then_rerun_equals_a_clean_run(clean_run, tmp_path, journalled, delay):
    # The reproduction of the issue: helpers finish masks the main process has not journalled
    # yet when the run is killed; the re-run must not take them for the earlier run's masks.
    out = tmp_path / "out"
    args = [str(SEQUENCE), str(ANNOTATIONS), "--config", str(CAMERA), "--out", str(out)]
    subprocess.run([*CLI, "cvat2mask", *args, "-j", "2"], check=True, capture_output=True)
    process = subprocess.Popen([*CLI, "cvat2mask", *args, "--distance-threshold", "0.005", "-j", "2", "--force"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    journal, deadline = out / JOURNAL, time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        if journal.is_file() and journal.read_text().count("\n") >= journalled:
            break
        time.sleep(0.002)
    time.sleep(delay)  # not just after a journal line: helpers' finished masks wait to be journalled
    assert process.poll() is None, "the run finished before it could be killed"
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    rerun = subprocess.run([*CLI, "cvat2mask", *args, "-j", "2"], capture_output=True, text=True)
    assert rerun.returncode == 0, rerun.stderr
    assert _masks(out) == _masks(clean_run)


def _interrupted_run(out: str, overrides: dict, raw_masks: bool, overlays: bool) -> None:
    run_cvat2mask(SEQUENCE, [ANNOTATIONS], out, load_config(CAMERA, overrides), raw_masks=raw_masks, overlays=overlays)


@pytest.mark.slow  # kills or interrupts processes: `pytest -m "not slow"` leaves it out
def test_stress_random_interruptions_with_changing_settings_never_leave_a_wrong_mask(clean_run, tmp_path):
    """Rounds of: start a run with other settings, SIGKILL it at a random point, re-run with
    the clean settings, compare every mask with the clean run's. About a minute at most."""
    rng = random.Random(20261123)
    context = multiprocessing.get_context("forkserver")  # preloaded: a run starts in milliseconds
    out = tmp_path / "out"
    settings = [{"ransac.distance_threshold": 0.005}, {"ransac.distance_threshold": 0.01},
                {"filter.max_mean_distance": 2.0}, {}]
    rounds, started = 0, time.monotonic()
    while rounds < 30 and time.monotonic() - started < 90:
        overrides = rng.choice(settings)
        process = context.Process(target=_interrupted_run,
                                  args=(str(out), overrides, rng.random() < 0.3, rng.random() < 0.2))
        process.start()
        time.sleep(rng.uniform(0.0, 0.6))
        process.kill()
        process.join()
        report = run_cvat2mask(SEQUENCE, [ANNOTATIONS], out, load_config(CAMERA))
        assert _masks(out) == _masks(clean_run), f"round {rounds}: {overrides}, counts {report.counts}"
        assert not (out / "masks_raw").exists() and not (out / "overlays").exists()
        rounds += 1
    assert rounds >= 12


def _stop_after(frames: int):
    def progress(done: int, total: int) -> None:
        if done >= frames:
            raise KeyboardInterrupt
    return progress


@pytest.mark.parametrize("command", [["review"], ["stats"], ["export-cvat", "{out}/again.xml"],
                                     ["export", "{out}/../export", "--format", "planes"],
                                     ["evaluate", str(SAMPLE / "ground_truth")]])
def test_readers_refuse_a_folder_whose_rerun_was_interrupted(clean_run, tmp_path, command):
    # A re-run with other settings, interrupted: some masks are the new run's, report.json and
    # planes.csv still the earlier run's. Every command that reads the folder must say so.
    out = tmp_path / "out"
    shutil.copytree(clean_run, out)
    with pytest.raises(KeyboardInterrupt):
        run_cvat2mask(SEQUENCE, [ANNOTATIONS], out, load_config(CAMERA, {"ransac.distance_threshold": 0.005}),
                      progress=_stop_after(6))
    assert _masks(out) != _masks(clean_run) and (out / "report.json").is_file()

    def invoke(run):
        """The command on ``run`` (evaluate takes it after the ground truth)."""
        args = [part.format(out=out) for part in command]
        return CliRunner().invoke(app, [*args, str(run)] if args[0] == "evaluate" else [args[0], str(run), *args[1:]])

    if command[0] == "evaluate":  # its masks/ named alone is refused too
        masks = invoke(out / "masks")
        assert masks.exit_code == 1 and masks.output.startswith(f"error: {out / JOURNAL}: "), masks.output
    result = invoke(out)
    assert result.exit_code == 1, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {out / JOURNAL}: "), lines
    assert "did not finish" in lines[0] and "run the same cvat2mask (or batch) command again" in lines[0]
    assert not (out / "again.xml").exists() and not (tmp_path / "export").exists()
    # Finishing the run makes the folder readable again.
    run_cvat2mask(SEQUENCE, [ANNOTATIONS], out, load_config(CAMERA, {"ransac.distance_threshold": 0.005}))
    result = invoke(out)
    assert result.exit_code == 0, result.output


# --- Lock: one run at a time in a folder ------------------------------------------------------


def test_a_second_run_into_a_locked_folder_stops_with_one_line(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    holder = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(f"""
            import sys, time
            from annotate_rgbd.io.outdir import OutputLock
            lock = OutputLock({str(out)!r}); lock.acquire(); print("locked", flush=True); time.sleep(60)
        """)],
        stdout=subprocess.PIPE, text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        result = subprocess.run([*CLI, "cvat2mask", str(SEQUENCE), str(ANNOTATIONS), "--config", str(CAMERA),
                                 "--out", str(out)], capture_output=True, text=True, timeout=120)
    finally:
        holder.kill()
        holder.wait()
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert lines[-1] == (f"error: {out}: another annotate-rgbd run (process {holder.pid}) is writing to this folder; "
                         "wait for it to end or choose another --out")
    assert "Traceback" not in result.stderr and not (out / "masks").exists()


def test_the_lock_dies_with_its_process_and_the_owner_file_goes(tmp_path):
    lock = OutputLock(tmp_path)
    lock.acquire()
    assert (tmp_path / OWNER).read_text().strip() == str(os.getpid())
    with pytest.raises(OutputError, match=f"process {os.getpid()}"):
        OutputLock(tmp_path).acquire()
    lock.release()
    assert not (tmp_path / OWNER).exists()
    with OutputLock(tmp_path):  # free again
        pass


# --- 2. Never through a link, only our own files removed ------------------------------------


@pytest.mark.parametrize("name", ["masks", JOURNAL, "report.json", "overlays"])
def test_links_in_the_output_folder_are_refused(tmp_path, name):
    out, victim = tmp_path / "out", tmp_path / "victim"
    out.mkdir()
    victim.mkdir()
    (victim / "precious.png").write_bytes(b"mine")
    target = victim if name in ("masks", "overlays") else victim / "precious.png"
    (out / name).symlink_to(target)
    result = CliRunner().invoke(app, ["cvat2mask", str(SEQUENCE), str(ANNOTATIONS), "--config", str(CAMERA),
                                      "--out", str(out), "--overlays"])
    assert result.exit_code == 1
    assert result.output.strip().splitlines()[-1] == (
        f"error: {out / name}: is a symbolic link: annotate-rgbd never writes or deletes through links in its "
        "output folder; remove it"
    )
    assert [p.name for p in victim.iterdir()] == ["precious.png"] and (victim / "precious.png").read_bytes() == b"mine"


def test_the_users_own_files_are_left_alone_with_a_warning(clean_run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(clean_run, out)
    (out / "masks" / "holiday.png").write_bytes(b"a photo")
    (out / "overlays").mkdir()
    (out / "overlays" / "sketch.png").write_bytes(b"a sketch")
    (out / "review.html").write_text("my notes")
    result = CliRunner().invoke(app, ["cvat2mask", str(SEQUENCE), str(ANNOTATIONS), "--config", str(CAMERA),
                                      "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert (out / "masks" / "holiday.png").read_bytes() == b"a photo"
    assert (out / "overlays" / "sketch.png").read_bytes() == b"a sketch"
    assert (out / "review.html").read_text() == "my notes"
    assert ("left alone 3 file(s) in the output folder that annotate-rgbd did not write: masks/holiday.png, "
            "overlays/sketch.png, review.html") in result.output


def test_removed_files_are_those_of_earlier_runs_and_are_named(tmp_path, caplog):
    out = tmp_path / "out"
    runner = CliRunner()
    base = ["cvat2mask", str(SEQUENCE), str(ANNOTATIONS), "--config", str(CAMERA), "--out", str(out)]
    assert runner.invoke(app, [*base, "--overlays", "--raw-masks"]).exit_code == 0
    assert (out / "review.html").is_file() and (out / "contact_sheet.png").is_file()
    result = runner.invoke(app, [*base, "--max-time-diff", "0.008"])  # 9 frames lose their mask
    assert result.exit_code == 0, result.output
    written = len(list((out / "masks").iterdir()))
    assert written < 19
    assert f"removed {19 - written} masks of frames that no longer get one (masks/)" in result.output
    assert "removed 19 raw masks no longer asked for (masks_raw/)" in result.output
    assert "removed 19 overlays no longer asked for (overlays/)" in result.output
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == ["masks", "planes.csv", "report.json", "tracks.csv"]



def _reviewed_run(out: Path) -> tuple[list[str], dict]:
    """The sample run into ``out`` and its review: the command, and the review's files' bytes."""
    base = ["cvat2mask", str(SEQUENCE), str(ANNOTATIONS), "--config", str(CAMERA), "--out", str(out)]
    assert CliRunner().invoke(app, base).exit_code == 0
    assert CliRunner().invoke(app, ["review", str(out)]).exit_code == 0
    review = {p.relative_to(out): p.read_bytes() for p in [out / "review.html", out / "contact_sheet.png",
                                                          *(out / "overlays").iterdir()]}
    assert len(review) == 2 + 19
    return base, review


def test_a_rerun_that_changes_nothing_keeps_the_review_that_review_made(tmp_path):
    out = tmp_path / "out"
    base, review = _reviewed_run(out)
    runner = CliRunner()
    # review --no-overlays after it: the page is new, the overlays are still the review's.
    assert runner.invoke(app, ["review", str(out), "--no-overlays", "--no-sheet"]).exit_code == 0
    result = runner.invoke(app, base)  # every mask reused: the review still shows this output
    assert result.exit_code == 0, result.output
    assert "info: kept the earlier review (review.html, contact_sheet.png, 19 overlays)" in result.output
    assert "removed" not in result.output and "left alone" not in result.output
    assert {p: (out / p).read_bytes() for p in review} == review
    result = runner.invoke(app, base)  # and again: the kept overlays are still recorded as the tool's
    assert "kept the earlier review" in result.output and "left alone" not in result.output
    result = runner.invoke(app, [*base, "--max-time-diff", "0.008"])  # masks change: the review goes
    assert result.exit_code == 0, result.output
    # One line, and the overlays are said to be the review's: "no longer asked for" would be false.
    assert ("info: removed review.html, contact_sheet.png and 19 overlays (overlays/) of an earlier review (they "
            "showed the earlier output; run review again)") in result.output.splitlines()
    assert "no longer asked for" not in result.output
    assert not (out / "overlays").exists() and not (out / "review.html").exists()


def test_a_resumed_run_with_other_masks_removes_the_review(tmp_path):
    # Interrupted after its last frame, the run with other settings is finished from its journal:
    # it makes no mask itself, but its masks are not those the review showed.
    out = tmp_path / "out"
    base, _ = _reviewed_run(out)
    config = load_config(CAMERA, {"ransac.distance_threshold": 0.005})
    with pytest.raises(KeyboardInterrupt):
        run_cvat2mask(SEQUENCE, [ANNOTATIONS], out, config, progress=_stop_after(19))
    report = run_cvat2mask(SEQUENCE, [ANNOTATIONS], out, config)
    assert report.counts.made == 0
    assert not (out / "review.html").exists() and not (out / "overlays").exists()


def test_a_review_with_an_overlay_gone_is_removed(tmp_path):
    out = tmp_path / "out"
    base, review = _reviewed_run(out)
    next((out / "overlays").iterdir()).unlink()  # the page would show a missing image
    result = CliRunner().invoke(app, base)
    assert result.exit_code == 0, result.output
    assert "kept the earlier review" not in result.output
    assert "removed review.html, contact_sheet.png and 18 overlays (overlays/) of an earlier review" in result.output
    assert not (out / "overlays").exists()


def test_a_rerun_that_changes_nothing_removes_the_runs_own_overlays_not_asked_for(tmp_path):
    # The page of a run's --overlays shows those overlays, which a run without --overlays removes,
    # page and all, whether or not a mask changed (only review's record tells its overlays apart).
    out = tmp_path / "out"
    runner = CliRunner()
    base = ["cvat2mask", str(SEQUENCE), str(ANNOTATIONS), "--config", str(CAMERA), "--out", str(out)]
    assert runner.invoke(app, [*base, "--overlays"]).exit_code == 0
    assert (out / "review.html").is_file() and len(list((out / "overlays").iterdir())) == 19
    result = runner.invoke(app, base)
    assert result.exit_code == 0, result.output
    # Said as it is: the page was the run's own, not review's, and no mask changed.
    assert [line for line in result.stderr.splitlines() if line.startswith("info: removed")] == [
        "info: removed 19 overlays no longer asked for (overlays/)",
        "info: removed review.html and contact_sheet.png of the earlier run's --overlays (they showed its overlays)"]
    assert not (out / "overlays").exists() and not (out / "review.html").exists()
    assert not (out / "contact_sheet.png").exists()


def test_an_identical_rerun_with_overlays_says_nothing_about_its_page(tmp_path):
    # The run writes its review page and sheet again: "removed ... of an earlier review (run
    # review again)" was said on every identical re-run, and was false.
    out = tmp_path / "out"
    runner = CliRunner()
    run = ["cvat2mask", str(SEQUENCE), str(ANNOTATIONS), "--config", str(CAMERA), "--out", str(out), "--overlays"]
    assert runner.invoke(app, run).exit_code == 0
    again = runner.invoke(app, run)
    assert again.exit_code == 0, again.output
    assert "removed" not in again.output and "(0 made, 19 unchanged)" in again.output
    assert (out / "review.html").is_file() and (out / "contact_sheet.png").is_file()

# --- 3. No endless wait on a stopped or killed helper --------------------------------------


def _slow_square(job: tuple[int, float]) -> int:
    time.sleep(job[1])
    return job[0] ** 2


def _pairs(outcomes) -> dict[int, object]:
    found = {}
    for outcome in outcomes:
        assert isinstance(outcome, JobOutcome) and outcome.index not in found
        found[outcome.index] = outcome.error if outcome.error is not None else outcome.value
    return found


def _stop_one_helper_soon(pool, sig: int) -> None:
    def stop() -> None:
        time.sleep(0.3)
        os.kill(next(iter(pool.processes)), sig)

    threading.Thread(target=stop, daemon=True).start()


@pytest.mark.parametrize("sig, message", [(signal.SIGSTOP, "made no progress for 2 s (stopped or hung)"),
                                          (signal.SIGKILL, "a helper process stopped")])
@pytest.mark.slow  # kills or interrupts processes: `pytest -m "not slow"` leaves it out
def test_a_stopped_or_killed_helper_is_replaced_with_a_warning(sig, message, caplog):
    pool = start_helpers(3)
    assert pool.ready.wait(timeout=120)
    stopped = next(iter(pool.processes))
    try:
        _stop_one_helper_soon(pool, sig)
        jobs = [(value, 0.05) for value in range(60)]
        started = time.monotonic()
        with caplog.at_level(logging.WARNING, logger="annotate_rgbd"):
            results = _pairs(run_jobs(jobs, _slow_square, pool, stall_timeout=2.0))
        assert time.monotonic() - started < 60
    finally:
        pool.shutdown(wait=False, cancel_futures=True)
        try:
            os.kill(stopped, signal.SIGKILL)
        except ProcessLookupError:
            pass
    assert results == {index: value ** 2 for index, (value, _) in enumerate(jobs)}
    assert message in caplog.text and "restarted" in caplog.text


class _HangingPool:
    """A stand-in for HelperPool whose helpers take jobs and never finish them."""

    size = 1
    failure = None

    def __init__(self):
        self.ready = threading.Event()
        self.ready.set()
        self.restarts = 0

    def submit(self, fn, *args):
        future = Future()
        future.set_running_or_notify_cancel()  # taken by a helper, never finished
        return future

    def restart(self):
        self.restarts += 1

    def shutdown(self, wait=True, cancel_futures=False):
        pass


def test_jobs_that_hang_in_helpers_twice_are_given_up_and_the_rest_done_here(caplog):
    pool = _HangingPool()
    jobs = [(value, 0.0) for value in range(8)]
    with caplog.at_level(logging.WARNING, logger="annotate_rgbd"):
        results = _pairs(run_jobs(jobs, _slow_square, pool, stall_timeout=0.2))
    # The first 4 jobs went to the helper (its queue), hung there twice and were given up.
    assert all(isinstance(results[i], JobTimeout) for i in range(4))
    assert str(results[0]) == "hung a helper process twice (0.2 s without progress); given up"
    assert {i: results[i] for i in range(4, 8)} == {i: i * i for i in range(4, 8)}
    assert pool.restarts == 2 and caplog.text.count("made no progress for 0.2 s (stopped or hung)") == 2


# --- 4. Journal robustness -------------------------------------------------------------------


def test_a_wrong_typed_journal_line_only_redoes_its_frame(clean_run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(clean_run, out)
    report = json.loads((out / "report.json").read_text())
    frame = next(f for f in report["frames"] if f["status"] == "written")
    name = Path(frame["mask"]).name
    bad = {"mask": name, "fingerprint": frame["fingerprint"], "result": {"kept": 7, "dropped": "x"}}
    (out / JOURNAL).write_text(json.dumps(bad) + "\n" + "not json\n" + json.dumps({"mask": []}) + "\n")
    rerun = run_cvat2mask(SEQUENCE, [ANNOTATIONS], out, load_config(CAMERA))
    assert (rerun.counts.made, rerun.counts.reused) == (1, 18)
    assert _masks(out) == _masks(clean_run)


def test_a_huge_sparse_journal_is_read_bounded(clean_run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(clean_run, out)
    with open(out / JOURNAL, "wb") as journal:
        journal.truncate(3 * MAX_RECORDS_BYTES)  # 3 GiB of NUL bytes, no disk used
    started = time.monotonic()
    previous = previous_results(out)
    assert time.monotonic() - started < 30
    assert len(previous.masks) == 19  # from report.json; the journal held nothing usable


# --- 5. review and stats on a malformed report -------------------------------------------------


@pytest.mark.parametrize("content, problem", [
    ('{"inputs": {}, "config": {}, "frames": "x", "planes": []}', "frames is not a list"),
    ('{"inputs": {"sequence": "s", "parts": []}, "config": {}, "planes": [], "frames": [{"status": "written"}]}',
     "frames[0]: "),
    ("[" * 100_000 + "]" * 100_000, "cannot read the report"),
    ('{"inputs": 1, "config": {}, "frames": [], "planes": []}', "inputs is not an object"),
])
@pytest.mark.parametrize("command", ["review", "stats"])
def test_review_and_stats_on_a_malformed_report_give_one_line(tmp_path, content, problem, command):
    (tmp_path / "report.json").write_text(content)
    result = CliRunner().invoke(app, [command, str(tmp_path)])
    assert result.exit_code == 1
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {tmp_path / 'report.json'}: ") and problem in lines[0]


def test_removals_are_said_in_the_singular_for_one_file():
    from annotate_rgbd.io.cleanup import Cleanup
    from annotate_rgbd.io.outdir import MASKS, OVERLAYS

    assert Cleanup({MASKS: 1, OVERLAYS: 2}).removals() == [
        "removed 1 mask of a frame that no longer gets one (masks/)", "removed 2 overlays no longer asked for (overlays/)"]


def test_a_reader_that_stops_reading_ends_the_export_quietly(clean_run):
    # `export-cvat RUN - | head`: the reader closes the pipe after a few bytes of a 230 KB export.
    # Like `cat`, the command ends with 141 (128 + SIGPIPE) and says nothing: no "error:" line for
    # what is no fault of the input, and no traceback from the flush at exit.
    process = subprocess.Popen([*CLI, "export-cvat", str(clean_run), "-"], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE)
    assert process.stdout.read(100).startswith(b"<?xml")
    process.stdout.close()
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 128 + signal.SIGPIPE
    assert [line for line in stderr.decode().splitlines() if not line.startswith("out: ")] == []


def test_a_run_without_standard_error_finishes(tmp_path):
    # `2>&-`: Python's sys.stderr is None. The progress line was written to it, and the run
    # stopped after its first frame with exit 1, no message and its journal left behind.
    out = tmp_path / "out"
    done = subprocess.run([*CLI, "cvat2mask", str(SEQUENCE), str(ANNOTATIONS), "--config", str(CAMERA), "--out",
                           str(out), "--jobs", "2"], stdout=subprocess.PIPE, preexec_fn=lambda: os.close(2),
                          timeout=120)
    assert done.returncode == 0, done.stdout
    assert b"19 masks in" in done.stdout
    assert (out / "report.json").is_file() and not (out / JOURNAL).exists()
    assert len(list((out / "masks").iterdir())) == 19


def test_readers_refuse_a_propose_folder_whose_rerun_was_interrupted(tmp_path):
    # A propose re-run with other settings, stopped after a few frames: its masks sit beside the
    # earlier run's proposals.xml and report.json. review and evaluate drew or scored that mix.
    from annotate_rgbd.io.outdir import UNFINISHED
    from annotate_rgbd.propose import run_propose

    out = tmp_path / "proposed"
    config = load_config(CAMERA)
    run_propose(SEQUENCE, out, config, workers=1)
    before = _masks(out)
    other = load_config(CAMERA, {"ransac.seed": 9, "detect.band_k": 2.5})
    with pytest.raises(KeyboardInterrupt):
        run_propose(SEQUENCE, out, other, workers=1, progress=_stop_after(6))
    assert _masks(out) != before and (out / UNFINISHED).is_file()
    for command in (["review", str(out)], ["evaluate", str(SAMPLE / "ground_truth"), str(out)],
                    ["evaluate", str(SAMPLE / "ground_truth"), str(out / "masks")]):
        result = CliRunner().invoke(app, command)
        assert result.exit_code == 1, result.output
        assert result.output == (f"error: {out / UNFINISHED}: a propose run in this folder did not finish (interrupted, "
                                 "stopped by an error, or still running): its masks may be incomplete or mixed with an "
                                 "earlier run's; run the same propose command again to finish it\n")
    assert not (out / "review.html").exists()
    # Finishing the run makes the folder readable again, and leaves no marker.
    run_propose(SEQUENCE, out, other, workers=1)
    assert not (out / UNFINISHED).exists()
    assert CliRunner().invoke(app, ["evaluate", str(SAMPLE / "ground_truth"), str(out)]).exit_code == 0


def test_evaluate_refuses_the_first_run_of_a_folder_that_did_not_finish(tmp_path):
    # No report.json yet: the folder was read as a folder of label files ("no label files", or
    # contact_sheet.png taken for one), and its masks_id/ was scored without a word.
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        run_cvat2mask(SEQUENCE, [ANNOTATIONS], out, load_config(CAMERA), instance_ids=True, progress=_stop_after(6))
    assert not (out / "report.json").exists() and any((out / "masks_id").iterdir())
    for pred in (out, out / "masks", out / "masks_id"):
        result = CliRunner().invoke(app, ["evaluate", str(SAMPLE / "ground_truth"), str(pred)])
        assert result.exit_code == 1 and result.output.startswith(f"error: {out / JOURNAL}: "), result.output

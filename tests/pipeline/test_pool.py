"""Running jobs in this process and in helper processes (annotate_rgbd.pool.run_jobs)."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from concurrent.futures.process import BrokenProcessPool

import cv2
import pytest

from annotate_rgbd.errors import InputError
from annotate_rgbd.pool import JobOutcome, helper_context, run_jobs, start_helpers


def _pairs(outcomes) -> list[tuple[int, object]]:
    """(index, value or error) of each JobOutcome, checking that exactly one of them is set."""
    pairs = []
    for outcome in outcomes:
        assert isinstance(outcome, JobOutcome) and (outcome.value is None) != (outcome.error is None)
        pairs.append((outcome.index, outcome.error if outcome.error is not None else outcome.value))
    return pairs


def square(job: tuple[int, int, float, float]) -> dict:
    """A test job: ``(value, pid of this process, seconds it takes here, seconds in a helper)``;
    a helper given a negative time dies."""
    value, main_pid, main_seconds, helper_seconds = job
    if helper_seconds < 0 and os.getpid() != main_pid:
        os._exit(1)
    time.sleep(main_seconds if os.getpid() == main_pid else max(helper_seconds, 0))
    if value < 0:
        raise InputError(f"job{value}.png", "negative")
    return {"square": value * value, "pid": os.getpid(), "opencv_threads": cv2.getNumThreads()}


@pytest.fixture(scope="module")
def helpers():
    pool = start_helpers(2)
    assert pool.ready.wait(timeout=120), "the helper process did not start"
    yield pool
    pool.shutdown()


def test_helpers_are_forked_from_a_server_where_the_platform_allows():
    assert helper_context().get_start_method() == "forkserver"


def test_every_job_runs_once_in_this_process_and_the_helper(helpers):
    threads = cv2.getNumThreads()
    jobs = [(value, os.getpid(), 0.02, 0.02) for value in range(60)]
    results = list(_pairs(run_jobs(jobs, square, helpers)))
    assert sorted(index for index, _ in results) == list(range(60))
    assert all(result["square"] == jobs[index][0] ** 2 for index, result in results)
    pids = {result["pid"] for _, result in results}
    assert os.getpid() in pids and len(pids) == 2
    # One OpenCV thread per process while they share the cores; this process's setting is back after.
    assert {result["opencv_threads"] for _, result in results} == {1}
    assert cv2.getNumThreads() == threads


def test_queued_jobs_come_back_when_this_process_runs_out_of_work(helpers):
    # The helper is slow: instead of waiting for it to get through its queue, this process
    # takes back every job the helper has not started.
    jobs = [(value, os.getpid(), 0.01, 1.0) for value in range(12)]
    results = list(_pairs(run_jobs(jobs, square, helpers)))
    assert sorted(index for index, _ in results) == list(range(12))
    done_by_helper = sum(result["pid"] != os.getpid() for _, result in results)
    assert done_by_helper <= 3  # the job it was running and the one already passed to it


def test_helpers_leave_ctrl_c_to_the_main_process(helpers):
    # Ctrl-C signals the whole process group; only the main process acts on it.
    for pid in helpers.processes:
        os.kill(pid, signal.SIGINT)
    time.sleep(0.3)
    jobs = [(value, os.getpid(), 0.02, 0.02) for value in range(30)]
    results = list(_pairs(run_jobs(jobs, square, helpers)))
    assert sorted(index for index, _ in results) == list(range(30))
    assert {result["pid"] for _, result in results} - {os.getpid()} <= set(helpers.processes)
    assert len({result["pid"] for _, result in results}) == 2


def test_input_errors_come_back_as_results(helpers):
    jobs = [(value, os.getpid(), 0.0, 0.0) for value in (-1, 2, -3, 4, 5, 6)]
    results = dict(_pairs(run_jobs(jobs, square, helpers)))
    assert isinstance(results[0], InputError) and "job-1.png" in str(results[0])
    assert isinstance(results[2], InputError)
    assert results[1]["square"] == 4


def test_without_helpers_this_process_does_everything():
    results = list(_pairs(run_jobs([(3, os.getpid(), 0.0, 0.0), (4, os.getpid(), 0.0, 0.0)], square, None)))
    assert [(index, result["square"]) for index, result in results] == [(0, 9), (1, 16)]
    assert start_helpers(1) is None


def test_when_a_helper_dies_this_process_does_the_rest(caplog):
    pool = start_helpers(2)
    assert pool.ready.wait(timeout=120)
    try:
        jobs = [(value, os.getpid(), 0.01, -1) for value in range(40)]
        with caplog.at_level(logging.WARNING, logger="annotate_rgbd"):
            results = list(_pairs(run_jobs(jobs, square, pool)))
    finally:
        pool.shutdown()
    assert sorted(index for index, _ in results) == list(range(40))
    assert all(result["square"] == jobs[index][0] ** 2 for index, result in results)
    assert "a helper process stopped" in caplog.text


@pytest.mark.slow  # kills or interrupts processes: `pytest -m "not slow"` leaves it out
def test_helpers_exit_when_the_main_process_is_killed(tmp_path):
    # SIGKILL leaves the main process no chance to stop its helpers: they notice and exit,
    # and so does the server they were forked from.
    script = tmp_path / "main.py"
    script.write_text(textwrap.dedent("""
        import time
        from multiprocessing import forkserver
        from annotate_rgbd.pool import start_helpers

        if __name__ == "__main__":
            pool = start_helpers(3)
            assert pool.ready.wait(timeout=120)
            pids = [*pool.processes, forkserver._forkserver._forkserver_pid]
            print(*pids, flush=True)
            time.sleep(600)
    """))
    main = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        pids = [int(pid) for pid in main.stdout.readline().split()]
        assert len(pids) == 3
    finally:
        main.send_signal(signal.SIGKILL)
        main.wait()
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and any(_alive(pid) for pid in pids):
        time.sleep(0.1)
    assert not any(_alive(pid) for pid in pids)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # A process that exited but was not yet reaped by its parent is a zombie: gone for our purposes.
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.parametrize("error", [
    EOFError("the helper server went away"),  # a signal to the process group stopped the server
    OSError("out of processes"),
    BrokenProcessPool("a helper died as it started"),  # a RuntimeError, not a shut-down pool
])
def test_helpers_that_cannot_start_print_nothing_and_this_process_does_everything(monkeypatch, caplog, capfd, error):
    # Starting a helper fails. The start-up thread stays quiet (no "Exception in thread"
    # traceback) and records why; run_jobs warns once per pool, however many batches of jobs it
    # is given, and does every job here.
    from concurrent.futures import ProcessPoolExecutor

    def cannot_start(self, *args, **kwargs):
        raise error

    monkeypatch.setattr(ProcessPoolExecutor, "submit", cannot_start)
    pool = start_helpers(2)
    _join_start_up_threads()
    assert pool.failure == str(error) and not pool.ready.is_set()
    assert pool._executor._shutdown_thread  # the executor that could not start is shut down
    assert "Traceback" not in capfd.readouterr().err
    jobs = [(value, os.getpid(), 0.0, 0.0) for value in range(5)]
    with caplog.at_level(logging.WARNING, logger="annotate_rgbd"):
        results = list(_pairs(run_jobs(jobs, square, pool)))
        again = list(_pairs(run_jobs(jobs, square, pool)))
    pool.shutdown()
    for done in (results, again):
        assert [result["square"] for _, result in sorted(done)] == [0, 1, 4, 9, 16]
        assert {result["pid"] for _, result in done} == {os.getpid()}
    assert caplog.text.count(f"helper processes could not start ({error}); working in one process") == 1
    assert caplog.text.count("could not start") == 1


def _join_start_up_threads(timeout=60.0):
    """Wait for the threads that start helper processes to finish (however loaded the machine)."""
    for thread in threading.enumerate():
        if thread.name == "annotate-rgbd-helpers":
            thread.join(timeout)


def test_a_helper_whose_imports_fail_is_a_start_up_failure(caplog):
    # The helper process starts, but its first step (importing the jobs' modules) fails: the
    # pool is not ready, says why, and run_jobs does every job here after one warning (not "a
    # helper process stopped", nor a restart).
    pool = start_helpers(2, preload=("annotate_rgbd_no_such_module",))
    try:
        _join_start_up_threads()
        assert pool.failure is not None and not pool.ready.is_set()
        jobs = [(value, os.getpid(), 0.0, 0.0) for value in range(3)]
        with caplog.at_level(logging.WARNING, logger="annotate_rgbd"):
            results = list(_pairs(run_jobs(jobs, square, pool)))
    finally:
        pool.shutdown()
    assert sorted(result["square"] for _, result in results) == [0, 1, 4]
    assert caplog.text.count("helper processes could not start") == 1 and "restarted" not in caplog.text


def test_a_start_that_fails_after_a_restart_is_not_blamed_on_the_new_helpers(monkeypatch):
    # The thread that starts the first helpers is slow to fail; the pool was restarted meanwhile
    # and its new helpers are up. The old thread's failure must not mark the new pool broken.
    from concurrent.futures import ProcessPoolExecutor

    gate, original, old = threading.Event(), ProcessPoolExecutor.submit, []

    def slow_then_failing(self, *args, **kwargs):
        if not old or self is old[0]:  # the first executor's start-up
            old[:1] = [self]
            gate.wait(60)
            raise EOFError("the old helper server went away")
        return original(self, *args, **kwargs)

    monkeypatch.setattr(ProcessPoolExecutor, "submit", slow_then_failing)
    pool = start_helpers(2)  # one helper
    try:
        for _ in range(6000):  # until the first start-up thread waits at the gate
            if old:
                break
            time.sleep(0.01)
        assert old and old[0] is pool._executor
        pool.restart()
        assert pool.ready.wait(60)  # the new helpers started
        gate.set()
        _join_start_up_threads()  # the old thread failed, after the restart
        assert pool.failure is None and pool.ready.is_set()
        assert pool.submit(square, (3, os.getpid(), 0.0, 0.0)).result(60)["square"] == 9
    finally:
        gate.set()
        pool.shutdown()


def test_a_waiting_shutdown_waits_for_the_pool_threads_earlier_shutdowns_left_running():
    # run_jobs stops the helpers without waiting on an error or an interrupt, and the caller's
    # `with` or `finally` shuts the pool down again, waiting. ProcessPoolExecutor forgets its
    # pool thread at the first call, so without the pool's own record the second call returned
    # at once and the thread was still closing its pipes when Python exited (Python 3.11:
    # "Bad file descriptor" from its exit handler, "leaked semaphore" warnings).
    pool = start_helpers(3)  # two helpers
    assert pool.ready.wait(timeout=120)
    first = pool._executor._executor_manager_thread
    pool.restart()  # the first executor is shut down without waiting
    assert pool.ready.wait(timeout=120)
    second = pool._executor._executor_manager_thread
    assert first is not None and second is not None and first is not second
    slow = pool.submit(square, (2, os.getpid(), 0.0, 1.0))  # keeps a helper, and the pool thread, busy
    pool.shutdown(wait=False)
    assert second.is_alive()
    pool.shutdown()
    assert not first.is_alive() and not second.is_alive()


def stop_here_hang_there(job: int) -> int:
    """A test job: a helper hangs (as one stuck on a frame), this process fails on its first job."""
    if os.getpid() != job:
        time.sleep(3600)
    raise RuntimeError("stopped")


def test_a_hung_helper_does_not_hold_up_the_shutdown_after_an_error():
    # run_jobs stops on an error (or Ctrl-C, which helpers ignore) while a helper hangs: the
    # caller's waiting shutdown kills it, as its result is not used, instead of waiting forever.
    pool = start_helpers(2)
    assert pool.ready.wait(timeout=120)
    (helper,) = pool.processes.values()
    with pytest.raises(RuntimeError, match="stopped"):
        for _ in run_jobs([os.getpid()] * 20, stop_here_hang_there, pool):
            pass
    stopping = threading.Thread(target=pool.shutdown)
    stopping.start()
    stopping.join(timeout=60)
    assert not stopping.is_alive(), "the shutdown waits for the hung helper"
    assert not helper.is_alive()

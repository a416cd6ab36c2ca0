"""Running jobs in this process and in helper processes (annotate_rgbd.execute.run_jobs)."""

from __future__ import annotations

import os
import time

import pytest

from annotate_rgbd.errors import InputError
from annotate_rgbd.execute import helper_context, run_jobs, start_helpers


def square(job: tuple[int, int, float, float]) -> dict:
    """A test job: ``(value, pid of this process, seconds it takes here, seconds in a helper)``."""
    value, main_pid, main_seconds, helper_seconds = job
    time.sleep(main_seconds if os.getpid() == main_pid else helper_seconds)
    if value < 0:
        raise InputError(f"job{value}.png", "negative")
    return {"square": value * value, "pid": os.getpid()}


@pytest.fixture(scope="module")
def helpers():
    pool = start_helpers(2)
    assert pool.ready.wait(timeout=120), "the helper process did not start"
    yield pool
    pool.shutdown()


def test_helpers_are_forked_from_a_server_where_the_platform_allows():
    assert helper_context().get_start_method() == "forkserver"


def test_every_job_runs_once_in_this_process_and_the_helper(helpers):
    jobs = [(value, os.getpid(), 0.02, 0.02) for value in range(60)]
    results = list(run_jobs(jobs, square, helpers))
    assert sorted(index for index, _ in results) == list(range(60))
    assert all(result["square"] == jobs[index][0] ** 2 for index, result in results)
    pids = {result["pid"] for _, result in results}
    assert os.getpid() in pids and len(pids) == 2


def test_queued_jobs_come_back_when_this_process_runs_out_of_work(helpers):
    # The helper is slow: instead of waiting for it to get through its queue, this process
    # takes back every job the helper has not started.
    jobs = [(value, os.getpid(), 0.01, 1.0) for value in range(12)]
    results = list(run_jobs(jobs, square, helpers))
    assert sorted(index for index, _ in results) == list(range(12))
    done_by_helper = sum(result["pid"] != os.getpid() for _, result in results)
    assert done_by_helper <= 3  # the job it was running and the one already passed to it


def test_input_errors_come_back_as_results(helpers):
    jobs = [(value, os.getpid(), 0.0, 0.0) for value in (-1, 2, -3, 4, 5, 6)]
    results = dict(run_jobs(jobs, square, helpers))
    assert isinstance(results[0], InputError) and "job-1.png" in str(results[0])
    assert isinstance(results[2], InputError)
    assert results[1]["square"] == 4


def test_without_helpers_this_process_does_everything():
    results = list(run_jobs([(3, os.getpid(), 0.0, 0.0), (4, os.getpid(), 0.0, 0.0)], square, None))
    assert [(index, result["square"]) for index, result in results] == [(0, 9), (1, 16)]
    assert start_helpers(1) is None

"""Running frame jobs: in parallel, resumable, redoing only what changed.

Every mask gets a *fingerprint*: a hash of what it is made from — the depth image's bytes, the
frame's shapes and plane ids, the settings that change a mask (camera, filter, RANSAC) and the
tool version. A finished frame's fingerprint is recorded twice: in a journal appended as frames
finish (``.annotate-rgbd-journal.jsonl``, which survives an interrupted run) and in
``report.json`` at the end of a run (when the journal is removed). A re-run reuses a mask whose
recorded fingerprint matches and whose files exist, and makes the others anew (the check is part
of the frame's job, so it runs in parallel and reads the depth image once); since every mask
is written atomically and the work is deterministic, an interrupted run followed by a re-run
gives exactly the files of one uninterrupted run.
"""

from __future__ import annotations

import ctypes
import hashlib
import importlib
import json
import logging
import multiprocessing
import os
import platform
import signal
import threading
from contextlib import contextmanager
from functools import lru_cache
from collections import deque
from concurrent.futures import FIRST_COMPLETED, BrokenExecutor, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np

from . import __version__
from .config import Config, config_to_dict
from .errors import InputError

log = logging.getLogger("annotate_rgbd")

JOURNAL = ".annotate-rgbd-journal.jsonl"

#: Jobs handed to each helper ahead of time (the ones it has not started go back to this
#: process when nothing else is left).
QUEUED_PER_HELPER = 4


def default_workers() -> int:
    """Number of worker processes by default: every core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


def fingerprint(job, config: Config, depth: bytes | np.ndarray) -> str:
    """Hash of everything one mask depends on.

    Parameters
    ----------
    job : FrameJob
    config : Config
    depth : bytes or ndarray of uint8
        The bytes of the job's depth image file.

    Returns
    -------
    str
        Hex digest; equal digests mean an equal mask.
    """
    digest = hashlib.blake2b(_mask_settings(config), digest_size=32)
    digest.update(depth)
    digest.update(json.dumps(job.image_size).encode())
    for plane_id, shape in job.shapes:
        digest.update(f"{plane_id}:{shape.kind}:{shape.z_order}:".encode())
        digest.update(np.ascontiguousarray(shape.points, dtype=np.float64).tobytes())
        if shape.bitmap is not None:
            digest.update(f"{shape.bitmap.shape}".encode())
            digest.update(np.packbits(shape.bitmap).tobytes())
    return digest.hexdigest()


@lru_cache(maxsize=16)
def _mask_settings(config: Config) -> bytes:
    """The tool version and the settings that change a mask (not stitching or part placement,
    whose effect is in the shapes' plane ids)."""
    settings = config_to_dict(config)
    return json.dumps([__version__, settings["camera"], settings["filter"], settings["ransac"]]).encode()


def previous_results(out_dir: Path) -> dict[str, tuple[str, dict]]:
    """Finished frames of earlier runs in ``out_dir``: mask name -> (fingerprint, report entries).

    Read from ``report.json`` and from the journal of an interrupted run (the journal is newer);
    a torn last journal line (the run was killed while writing it) is ignored.
    """
    found: dict[str, tuple[str, dict]] = {}
    try:
        report = json.loads((out_dir / "report.json").read_text(encoding="utf-8"))
        for entry in report.get("frames", []):
            if entry.get("status") == "written" and "fingerprint" in entry:
                found[Path(entry["mask"]).name] = (
                    entry["fingerprint"],
                    {"kept": entry["kept"], "dropped": entry["dropped"]},
                )
    except (OSError, ValueError, KeyError, TypeError):
        pass
    try:
        lines = (out_dir / JOURNAL).read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError):
        lines = []
    for line in lines:
        try:
            record = json.loads(line)
            found[record["mask"]] = (record["fingerprint"], record["result"])
        except (ValueError, KeyError, TypeError):
            continue
    return found


#: glibc's ``mallopt`` parameters (malloc.h) and the values :func:`reuse_freed_memory` sets.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_MMAP_THRESHOLD = 32 * 2**20  # glibc's largest allowed value on 64-bit systems
_TRIM_THRESHOLD = 128 * 2**20


def reuse_freed_memory() -> bool:
    """Let this process keep freed image-sized buffers for the next frame (glibc only).

    Every frame allocates and frees the same few dozen image-sized arrays. By default glibc
    gives large freed blocks back to the system, and the next frame then pays a page fault for
    every 4 KiB page again: on a 2-core virtual machine a frame at 640x480 took 41 ms instead
    of 31 ms. With higher mmap and trim thresholds the blocks stay in the heap and are reused;
    the process keeps about one frame's working set (tens of MiB), whatever the sequence length.
    The command line and the helper processes call this; it changes this whole process.

    Returns
    -------
    bool
        Whether the settings were applied (False where the C library is not glibc).
    """
    if platform.libc_ver()[0] != "glibc":
        return False  # pragma: no cover - musl, macOS, Windows
    libc = ctypes.CDLL(None)
    return bool(libc.mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD) and libc.mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD))


#: What a helper process imports before its first job.
FRAME_JOB_MODULE = "annotate_rgbd.frame_job"


def helper_context() -> multiprocessing.context.BaseContext:
    """How helper processes are started.

    "forkserver" where the platform has it: a server process imports what frame jobs need once
    and every helper is forked from it, so a helper is ready in milliseconds instead of the ~2 s
    a new interpreter needs to import Open3D ("spawn"), and it inherits nothing of this
    process's thread pools (forking a process that has run Open3D's OpenMP code is not safe).
    """
    if "forkserver" in multiprocessing.get_all_start_methods():
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload([FRAME_JOB_MODULE])
        return context
    return multiprocessing.get_context("spawn")  # pragma: no cover - not on Linux


def prepare_helpers(workers: int) -> None:
    """Start, in the background, the server that helper processes are forked from.

    Call it as early as possible (the command line calls it before importing the pipeline):
    the server's imports then overlap this process's own, and :func:`start_helpers` finds it
    ready. Does nothing when ``workers`` <= 1 or where helpers are spawned.
    """
    if workers > 1 and helper_context().get_start_method() == "forkserver":
        from multiprocessing import forkserver

        forkserver.ensure_running()


def prepare_process(workers: int) -> None:
    """What the command line does first, before its heavy imports: start the helpers' server
    (:func:`prepare_helpers`) and keep freed image buffers for reuse (:func:`reuse_freed_memory`)."""
    prepare_helpers(workers)
    reuse_freed_memory()


class HelperPool(ProcessPoolExecutor):
    """A pool of ``size`` helper processes, started by :func:`helper_context`.

    The processes are started in a background thread (while the helper server is still
    importing, starting one waits for it); ``ready`` is set once they are running. Each runs
    :func:`_start_helper` first.
    """

    def __init__(self, size: int):
        super().__init__(max_workers=size, mp_context=helper_context(), initializer=_start_helper)
        self.size = size
        self.ready = threading.Event()
        threading.Thread(target=self._start, name="annotate-rgbd-helpers", daemon=True).start()

    def _start(self) -> None:
        try:
            for _ in range(self.size):  # the pool starts one process per task it is given
                self.submit(_no_op)
        except (BrokenExecutor, OSError) as exc:  # e.g. out of processes
            log.warning("helper processes could not start (%s); working in one process", exc)
            return
        except RuntimeError:  # shut down before the helpers were up: nothing to start
            return
        self.ready.set()


def start_helpers(workers: int) -> HelperPool | None:
    """Start the ``workers - 1`` helper processes, in the background.

    Started before the inputs are read and planned, the helpers get ready meanwhile (see
    :func:`prepare_helpers` to start their server earlier still). Shut the pool down when done
    (``pool.shutdown()``, or use it in a ``with`` block).

    Returns
    -------
    HelperPool or None
        None when ``workers`` <= 1.
    """
    if workers <= 1:
        return None
    prepare_helpers(workers)
    return HelperPool(workers - 1)


def run_jobs(
    jobs: Sequence,
    worker: Callable,
    helpers: HelperPool | None,
) -> Iterator[tuple[int, dict | InputError]]:
    """Run ``worker(job)`` for every job, in this process and in the helper processes.

    This process works too: it takes jobs itself until the helpers are ready and whenever
    they have enough queued, and at the end it takes back the jobs no helper has started. If a
    helper dies, this process does its jobs and all that remain.

    Parameters
    ----------
    jobs : sequence
        Picklable arguments, one per task.
    worker : callable
        A module-level function (so that it can be sent to other processes); it returns a
        dict, or raises :class:`InputError` for a problem with that task's input.
    helpers : HelperPool or None
        From :func:`start_helpers`; None: only this process works.

    Yields
    ------
    (int, dict or InputError)
        Index of the job and its result (or the input error it raised), in completion order.
    """
    pending = deque(enumerate(jobs))
    if helpers is None or len(jobs) <= 1:
        for index, job in pending:
            yield index, _call(worker, job)
        return
    try:
        with _one_thread_each():
            yield from _share(pending, worker, helpers)
    except BaseException:
        helpers.shutdown(wait=False, cancel_futures=True)
        raise


def _share(pending: deque, worker: Callable, helpers: HelperPool) -> Iterator[tuple[int, dict | InputError]]:
    """The loop of :func:`run_jobs` with helpers: ``pending`` holds ``(index, job)`` pairs."""
    # Enough queued that a helper never waits for this process to finish its own job.
    queue_length = QUEUED_PER_HELPER * helpers.size
    in_flight: dict = {}
    helpers_alive = True
    while pending or in_flight:
        while helpers_alive and pending and len(in_flight) < queue_length and helpers.ready.is_set():
            index, job = pending.popleft()
            try:
                in_flight[helpers.submit(_call, worker, job)] = (index, job)
            except BrokenExecutor:
                pending.appendleft((index, job))
                helpers_alive = False
        for future in [f for f in in_flight if f.done()]:
            index, job = in_flight.pop(future)
            try:
                result = future.result()
            except BrokenExecutor as exc:
                # A helper died (killed, out of memory): its jobs and the rest are done here
                # (a job's outputs are written atomically, so doing it again is safe).
                if helpers_alive:
                    log.warning("a helper process stopped (%s); the remaining frames are made in this process", exc)
                helpers_alive = False
                pending.appendleft((index, job))
                continue
            yield index, result
        if pending:
            index, job = pending.popleft()
            yield index, _call(worker, job)
            continue
        # Nothing left to hand out: take back the queued jobs no helper has started and do them
        # here, rather than wait for the helpers to get through their queues.
        for future in reversed(list(in_flight)):
            if future.cancel():
                index, job = in_flight.pop(future)
                yield index, _call(worker, job)
                break
        else:
            if in_flight:
                wait(in_flight, return_when=FIRST_COMPLETED)


@contextmanager
def _one_thread_each() -> Iterator[None]:
    """OpenCV single-threaded in this process while helpers work beside it: its thread pool
    would compete with them for the cores (2 workers on 2 cores: 7 % slower)."""
    import cv2  # loaded already by the frame jobs; this module stays light for the CLI's start

    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(threads)


def _start_helper() -> None:
    """First thing in every helper process: import what frame jobs need (nothing to do where the
    helper was forked from a server that imported it), reuse freed buffers, run OpenCV in one
    thread (see :func:`_one_thread_each`), leave Ctrl-C to the main process, and exit when the
    main process dies (killed with SIGKILL, it cannot tell its helpers to stop; they would wait
    for work forever and keep their server alive)."""
    importlib.import_module(FRAME_JOB_MODULE)
    reuse_freed_memory()
    import cv2  # imported above

    cv2.setNumThreads(1)  # one of several processes sharing the cores
    # Ctrl-C reaches the whole process group: the main process stops the helpers (after their
    # current frame), so they do not print tracebacks of their own.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent = multiprocessing.parent_process()
    if parent is not None:
        threading.Thread(target=_exit_after, args=(parent,), name="annotate-rgbd-watch", daemon=True).start()


def _exit_after(parent: multiprocessing.process.BaseProcess) -> None:
    parent.join()
    os._exit(1)


def _no_op() -> None:
    """A task that only makes the pool start a process."""


def _call(worker: Callable, job) -> dict | InputError:
    try:
        return worker(job)
    except InputError as exc:
        return exc

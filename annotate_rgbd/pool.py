"""Helper processes: a pool of worker processes beside this one, and the loop that shares jobs.

Generic machinery, with no knowledge of frames or masks: what helpers import before their first
job is an argument (``preload``), jobs are picklable arguments of a module-level function, and
each job's outcome comes back as a :class:`JobOutcome`. Used by
:mod:`annotate_rgbd.pipeline.execute` for frame jobs.
"""

from __future__ import annotations

import ctypes
import importlib
import logging
import multiprocessing
import os
import platform
import signal
import threading
import time
from collections import deque
from concurrent.futures import FIRST_COMPLETED, BrokenExecutor, CancelledError, Future, ProcessPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Sequence

from annotate_rgbd.errors import InputError

log = logging.getLogger("annotate_rgbd")

#: Jobs handed to each helper ahead of time (the ones it has not started go back to this
#: process when nothing else is left).
QUEUED_PER_HELPER = 4
#: Seconds without any finished helper job, while this process waits for them, after which the
#: helpers are taken to hang (a frame takes tens of milliseconds; the slowest seen, a
#: 2000x1500 frame with hundreds of planes, a few seconds).
STALL_TIMEOUT = 60.0
#: Times the helpers are restarted in one call of :func:`run_jobs` before this process does
#: the remaining jobs alone.
MAX_RESTARTS = 3
#: Seconds a waiting shutdown waits for the manager thread of a pool stopped earlier, once its
#: helpers are killed (it then ends within milliseconds; the bound only keeps a stuck thread
#: from holding up the exit).
STOP_TIMEOUT = 10.0


def default_workers() -> int:
    """Number of worker processes by default: every core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


@dataclass(frozen=True)
class JobOutcome:
    """How one job ended: its ``value``, or the input ``error`` it raised.

    Parameters
    ----------
    index : int
        The job's position in the list given to :func:`run_jobs`.
    value : object
        What the worker function returned (None when it raised).
    error : InputError or None
        The problem with the job's input that the worker raised.
    """

    index: int
    value: Any = None
    error: InputError | None = None


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


def helper_context(preload: Sequence[str] = ()) -> multiprocessing.context.BaseContext:
    """How helper processes are started.

    "forkserver" where the platform has it: a server process imports the ``preload`` modules
    once and every helper is forked from it, so a helper is ready in milliseconds instead of the
    time a new interpreter needs for its imports ("spawn"), and it inherits nothing of this
    process's thread pools (forking a process that has run threaded native code is not safe).

    Parameters
    ----------
    preload : sequence of str
        Modules the server imports (the preload list is process-wide: the last call sets it).
    """
    if "forkserver" in multiprocessing.get_all_start_methods():
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload(list(preload))
        return context
    return multiprocessing.get_context("spawn")  # pragma: no cover - not on Linux


def prepare_helpers(workers: int, preload: Sequence[str] = ()) -> None:
    """Start, in the background, the server that helper processes are forked from.

    Call it as early as possible (the command line calls it before importing the pipeline):
    the server's imports then overlap this process's own, and :func:`start_helpers` finds it
    ready. Does nothing when ``workers`` <= 1 or where helpers are spawned.
    """
    if workers > 1 and helper_context(preload).get_start_method() == "forkserver":
        from multiprocessing import forkserver

        if threading.current_thread() is not threading.main_thread():
            forkserver.ensure_running()
            return
        # The server inherits SIGINT blocked (a process's signal mask survives exec): Ctrl-C
        # during its ~2 s of imports would otherwise print its own traceback. Helpers ignore
        # Ctrl-C in any case; the main process stops them. Here, a Ctrl-C that arrives while
        # the server starts stays pending and is delivered when the mask is restored.
        from multiprocessing import resource_tracker

        resource_tracker.ensure_running()  # first: it unblocks SIGINT after starting its own process
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            forkserver.ensure_running()
        finally:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


class HelperPool:
    """A pool of ``size`` helper processes, started by :func:`helper_context`, that can be
    restarted when a helper dies or hangs.

    The processes are started in a background thread (while the helper server is still
    importing, starting one waits for it); ``ready`` is set once each has run a first task
    (its ``preload`` imports done), and
    ``failure`` says why they could not start (the thread itself never prints: when a signal
    to the whole process group stops the helper server, the main process is stopping too and
    says so in one line; otherwise :func:`run_jobs` warns and works alone). Each runs
    :func:`_start_helper` first, which imports the ``preload`` modules (already imported where
    the helper was forked from a server that preloaded them).
    """

    def __init__(self, size: int, preload: Sequence[str] = ()):
        _quiet_cancelled_futures()
        self.size = size
        self.preload = tuple(preload)
        self.ready = threading.Event()
        self.failure: str | None = None
        #: Whether :func:`run_jobs` said that the helpers could not start (it says so once).
        self.failure_reported = False
        self._state = threading.Lock()  # the executor, ready and failure change together
        #: Executors shut down without waiting (their jobs' results are not used): their manager
        #: thread and helper processes, for ``shutdown(wait=True)`` to end.
        self._stopped: list[tuple[threading.Thread, list]] = []
        self._start_executor()

    def _start_executor(self) -> None:
        executor = ProcessPoolExecutor(
            max_workers=self.size, mp_context=helper_context(self.preload), initializer=_start_helper,
            initargs=(self.preload,),
        )
        with self._state:
            self._executor = executor
            self.ready.clear()
            self.failure = None
        threading.Thread(target=self._start, args=(executor,), name="annotate-rgbd-helpers", daemon=True).start()

    def _start(self, executor: ProcessPoolExecutor) -> None:
        """Start ``executor``'s processes and wait until each has run a first (empty) task;
        ``ready`` or ``failure`` then tell how it went, unless the pool was restarted meanwhile
        (``executor`` is no longer its own)."""
        failure = None
        try:
            # The pool starts one process per task it is given; a process that cannot start
            # (its imports fail, it is killed) fails the tasks: BrokenProcessPool.
            for task in [executor.submit(_no_op) for _ in range(self.size)]:
                task.result()
        except BrokenExecutor as exc:  # before RuntimeError: a subclass
            failure = str(exc) or type(exc).__name__
        except (RuntimeError, CancelledError):  # shut down before the helpers were up: nothing to start
            return
        except Exception as exc:  # e.g. out of processes, or the helper server was stopped
            failure = str(exc) or type(exc).__name__
        with self._state:
            if executor is not self._executor:
                return  # restarted meanwhile: the new executor has a thread of its own
            if failure is None:
                self.ready.set()
                return
            self.failure = failure
        self._stop(executor, wait=False, cancel_futures=True)  # whatever did start is not used

    @property
    def processes(self) -> dict[int, multiprocessing.process.BaseProcess]:
        """The running helper processes by process id."""
        return dict(self._executor._processes or {})

    def submit(self, fn: Callable, *args) -> Future:
        """Run ``fn(*args)`` in a helper (see :meth:`concurrent.futures.Executor.submit`)."""
        return self._executor.submit(fn, *args)

    def restart(self) -> None:
        """Kill the helpers (their unfinished jobs are lost) and start new ones."""
        for process in self.processes.values():
            process.kill()
        # Not cancel_futures: the pool's own thread fails the lost jobs' futures as it finds the
        # helpers dead, and one it finds cancelled makes that thread raise (Python 3.11).
        self._stop(self._executor, wait=False)
        self._start_executor()

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        """Stop the helpers once their current jobs are done (see ``Executor.shutdown``).

        With ``wait``, it also ends what every earlier shutdown that did not wait left running
        (a restart, a failed start, ``run_jobs`` stopping on an error or interrupt): their
        helpers, whose results nothing uses, are killed (one may hang, and helpers ignore
        Ctrl-C), and their manager threads, which ``ProcessPoolExecutor`` forgets after its
        first shutdown call, are waited for. A manager thread still closing its pipes when
        Python exits races with Python's own exit handler (Python 3.11): "Bad file descriptor"
        tracebacks and "leaked semaphore" warnings after a Ctrl-C.
        """
        self._stop(self._executor, wait=wait, cancel_futures=cancel_futures)
        if wait:
            with self._state:
                stopped, self._stopped = self._stopped, []
            for thread, processes in stopped:
                for process in processes:
                    if process.is_alive():
                        process.kill()
                thread.join(timeout=STOP_TIMEOUT)  # bounded: a thread that does not end is left to Python

    def _stop(self, executor: ProcessPoolExecutor, wait: bool, cancel_futures: bool = False) -> None:
        """``executor.shutdown``, keeping what a shutdown without waiting leaves running (its
        manager thread and helper processes) for a later ``shutdown(wait=True)``."""
        thread = getattr(executor, "_executor_manager_thread", None)  # both set to None by shutdown
        processes = list((getattr(executor, "_processes", None) or {}).values())
        executor.shutdown(wait=wait, cancel_futures=cancel_futures)
        if thread is not None and not wait:
            with self._state:
                self._stopped.append((thread, processes))

    def __enter__(self) -> HelperPool:
        return self

    def __exit__(self, *exc) -> None:
        self.shutdown()


def _quiet_cancelled_futures() -> None:
    """Silence one harmless error of Python < 3.12's process pool (once per process).

    When a helper dies, the pool's manager thread fails every queued job's future, including
    those this process took back (cancelled) and does itself: ``set_exception`` on a cancelled
    future raises ``InvalidStateError`` in that thread, which Python prints as a traceback
    (fixed in Python 3.12). Only that error of that thread is dropped.
    """
    from concurrent.futures import InvalidStateError
    from concurrent.futures.process import _ExecutorManagerThread

    previous = threading.excepthook
    if getattr(previous, "annotate_rgbd", False):
        return

    def hook(args: threading.ExceptHookArgs) -> None:
        if isinstance(args.thread, _ExecutorManagerThread) and issubclass(args.exc_type, InvalidStateError):
            return
        previous(args)

    hook.annotate_rgbd = True
    threading.excepthook = hook


class JobTimeout(InputError):
    """A job that hung its helper twice: given up (the job's input is the likely cause)."""


def start_helpers(workers: int, preload: Sequence[str] = ()) -> HelperPool | None:
    """Start the ``workers - 1`` helper processes, in the background.

    Started before the inputs are read and planned, the helpers get ready meanwhile (see
    :func:`prepare_helpers` to start their server earlier still). Shut the pool down when done
    (``pool.shutdown()``, or use it in a ``with`` block).

    Parameters
    ----------
    workers : int
        Processes in all, this one included.
    preload : sequence of str
        Modules every helper imports before its first job (those the jobs' function needs).

    Returns
    -------
    HelperPool or None
        None when ``workers`` <= 1.
    """
    if workers <= 1:
        return None
    prepare_helpers(workers, preload)
    return HelperPool(workers - 1, preload)


def run_jobs(
    jobs: Sequence,
    worker: Callable,
    helpers: HelperPool | None,
    stall_timeout: float = STALL_TIMEOUT,
) -> Iterator[JobOutcome]:
    """Run ``worker(job)`` for every job, in this process and in the helper processes.

    This process works too: it takes jobs itself until the helpers are ready and whenever
    they have enough queued, and at the end it takes back the jobs no helper has started.
    If a helper dies (killed, out of memory) or no helper finishes a job for ``stall_timeout``
    seconds while this process has nothing else to do (a helper stopped or hung), the helpers
    are restarted (at most :data:`MAX_RESTARTS` times, then this process does the rest) and
    their unfinished jobs are done again, with a warning; a job that was running during two
    such stalls is given up (:class:`JobTimeout`).

    Parameters
    ----------
    jobs : sequence
        Picklable arguments, one per task.
    worker : callable
        A module-level function (so that it can be sent to other processes); it returns a
        picklable value, or raises :class:`InputError` for a problem with that job's input.
    helpers : HelperPool or None
        From :func:`start_helpers`; None: only this process works.
    stall_timeout : float
        Seconds without any finished helper job after which the helpers are taken to hang.

    Yields
    ------
    JobOutcome
        One per job, in completion order.
    """
    pending = deque(enumerate(jobs))
    if helpers is None or len(jobs) <= 1:
        for index, job in pending:
            yield _call(worker, index, job)
        return
    try:
        with _one_thread_each():
            yield from _share(pending, worker, helpers, stall_timeout)
    except BaseException:
        helpers.shutdown(wait=False, cancel_futures=True)
        raise


def _share(pending: deque, worker: Callable, helpers: HelperPool, stall_timeout: float) -> Iterator[JobOutcome]:
    """The loop of :func:`run_jobs` with helpers: ``pending`` holds ``(index, job)`` pairs."""
    # Enough queued that a helper never waits for this process to finish its own job.
    queue_length = QUEUED_PER_HELPER * helpers.size
    in_flight: dict[Future, tuple[int, object]] = {}
    stalls: dict[int, int] = {}  # job index -> stalls it was running in
    restarts = 0
    helpers_alive = True
    last_progress = time.monotonic()

    def take_back(problem: str, hung: bool) -> Iterator[JobOutcome]:
        """Restart the helpers (or give them up) and queue their unfinished jobs again; after a
        hang (``hung``), count the stalls of the jobs that were running and give up on those
        that hung twice."""
        nonlocal restarts, helpers_alive, last_progress
        given_up = []
        for future, (index, job) in list(in_flight.items()):
            if hung and future.running():
                stalls[index] = stalls.get(index, 0) + 1
                if stalls[index] >= 2:
                    given_up.append(index)
                    continue
            pending.appendleft((index, job))
        in_flight.clear()
        if restarts < MAX_RESTARTS:
            restarts += 1
            what = "the helpers were restarted"
            helpers.restart()
        else:
            what = "the remaining jobs are done in this process"
            helpers_alive = False
        log.warning("a helper process %s; its unfinished jobs are done again and %s", problem, what)
        last_progress = time.monotonic()
        for index in given_up:
            message = f"hung a helper process twice ({stall_timeout:g} s without progress); given up"
            yield JobOutcome(index, error=JobTimeout(None, message))

    while pending or in_flight:
        if helpers_alive and helpers.failure is not None:
            if not helpers.failure_reported:  # once per pool, not once per batch of jobs
                log.warning("helper processes could not start (%s); working in one process", helpers.failure)
                helpers.failure_reported = True
            helpers_alive = False
        while helpers_alive and pending and len(in_flight) < queue_length and helpers.ready.is_set():
            index, job = pending.popleft()
            try:
                in_flight[helpers.submit(_call, worker, index, job)] = (index, job)
            except BrokenExecutor:
                pending.appendleft((index, job))
                yield from take_back("stopped", hung=False)
                break
        broken = False
        for future in [f for f in in_flight if f.done() and not f.cancelled()]:
            try:
                result = future.result()
            except BrokenExecutor:
                # A helper died (killed, out of memory): every job of the pool is lost
                # (a job's outputs are written atomically, so doing it again is safe).
                broken = True
                break
            in_flight.pop(future)
            last_progress = time.monotonic()
            yield result
        if broken:
            yield from take_back("stopped", hung=False)
            continue
        if pending:
            index, job = pending.popleft()
            yield _call(worker, index, job)
            continue
        # Nothing left to hand out: take back the queued jobs no helper has started and do them
        # here, rather than wait for the helpers to get through their queues.
        for future in reversed(list(in_flight)):
            if future.cancel():
                index, job = in_flight.pop(future)
                yield _call(worker, index, job)
                break
        else:
            if in_flight:
                done, _ = wait(in_flight, timeout=min(1.0, stall_timeout), return_when=FIRST_COMPLETED)
                if not done and time.monotonic() - last_progress > stall_timeout:
                    yield from take_back(f"made no progress for {stall_timeout:g} s (stopped or hung)", hung=True)


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


def _start_helper(preload: tuple[str, ...]) -> None:
    """First thing in every helper process: import what the jobs need (nothing to do where the
    helper was forked from a server that imported it), reuse freed buffers, run OpenCV in one
    thread (see :func:`_one_thread_each`), leave Ctrl-C to the main process, and exit when the
    main process dies (killed with SIGKILL, it cannot tell its helpers to stop; they would wait
    for work forever and keep their server alive)."""
    for module in preload:
        importlib.import_module(module)
    reuse_freed_memory()
    import cv2  # imported by the jobs in any case

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


def _call(worker: Callable, index: int, job) -> JobOutcome:
    try:
        return JobOutcome(index, value=worker(job))
    except InputError as exc:
        return JobOutcome(index, error=exc)

"""What the command line shows and how it exits: warnings as ``warning: ...`` lines, input and
file-system problems as one ``error:`` line with status 1, interrupts with 130 (Ctrl-C) or 143
(SIGTERM) after the clean-up, a standard output that cannot be written (a full disk) as one
``error:`` line naming it, and a reader of standard output that stopped reading (``| head``)
with 141 and nothing printed, as a shell tool that SIGPIPE ends."""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import typer
from typer._click.exceptions import NoArgsIsHelpError, UsageError  # typer 0.26 (pinned) carries its own Click
from typer.core import TyperCommand, TyperGroup
from typer.models import TyperPath

from annotate_rgbd.errors import InputError


class OneLineUsageError(UsageError):
    """A command line that cannot be parsed (an unknown option, a value of the wrong type), as
    one ``error:`` line like every other problem (Click prints the usage, a hint and the error on
    four), with Click's status 2."""

    def __init__(self, error: UsageError, command: str | None = None):
        super().__init__(error.format_message(), error.ctx)
        # The command's path for the pointer to its help; Click's parser errors carry no context.
        self.command = error.ctx.command_path if error.ctx is not None else command

    def show(self, file=None) -> None:
        where = f" (see {self.command} -h)" if self.command else ""
        typer.echo(f"error: {self.format_message().rstrip('.')}{where}", err=True)


#: Parameters that name a file or folder without being typed as a path (``--config`` may be a
#: preset's name; ``cvat2mask`` and ``propose`` take ``--out`` as text, ``export`` and
#: ``export-cvat`` their outputs (:func:`one_output`), ``evaluate`` its ``--per-frame``
#: (:func:`output_path`)).
NAMED_PATHS = ("config", "out", "out_option", "xml", "xml_option", "per_frame_text")


class CheckedCommand(TyperCommand):
    """A command whose path arguments, ``--config`` and ``--out`` may not be empty (or blank):
    ``Path("")`` is the current folder, so ``--poses "$UNSET"`` was reported as a problem of
    ``.``."""

    def parse_args(self, ctx, args):
        rest = super().parse_args(ctx, args)
        for param in self.params:
            value = ctx.params.get(param.name)
            values = value if isinstance(value, (list, tuple)) else [value]
            named = isinstance(param.type, TyperPath) or param.name in NAMED_PATHS
            if named and any(isinstance(v, str) and not v.strip() for v in values):
                shown = param.opts[0] if param.opts and param.opts[0].startswith("-") else param.human_readable_name
                raise UsageError(f"{shown.rstrip('.')} is empty (an unset shell variable?)", ctx)
        return rest


class _WatchedOutput:
    """Standard output as the command line writes to it (its text stream, or the binary buffer
    under it), keeping the errors its writes raise.

    A failed write of standard output raises an ``OSError`` without a file name, as a failed
    write of any other open file does (the journal's): the errors kept here tell them apart.

    Parameters
    ----------
    stream : file object
        The stream written to.
    failures : list of OSError, optional
        Where the errors are kept; shared with the wrapper of the buffer.
    """

    def __init__(self, stream, failures: list[OSError] | None = None):
        self._stream = stream
        self.failures = [] if failures is None else failures

    def write(self, data):
        return self._watched(self._stream.write, data)

    def flush(self) -> None:
        self._watched(self._stream.flush)

    def _watched(self, call, *args):
        """``call(*args)``, keeping the ``OSError`` it raises."""
        try:
            return call(*args)
        except OSError as exc:
            self.failures.append(exc)
            raise

    @property
    def buffer(self) -> "_WatchedOutput":
        # Click writes bytes there, and into a text stream of its own over it when the
        # encoding of this one is ASCII.
        return _WatchedOutput(self._stream.buffer, self.failures)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def _stdout_failed(error: BaseException) -> bool:
    """Whether ``error`` was raised by a write to standard output (:class:`_WatchedOutput`)."""
    stdout = sys.stdout
    return isinstance(stdout, _WatchedOutput) and any(error is failure for failure in stdout.failures)


def _stdout_error(problem: str, standalone_mode: bool) -> int:
    """Say that standard output cannot be written, in one line on standard error, and exit 1
    (return 1 to a caller that asked Click not to exit)."""
    _silence_stdout()  # what is left in its buffer fails again at exit, with a traceback of its own
    typer.echo(f"error: cannot write to standard output: {problem}", err=True)
    if standalone_mode:
        sys.exit(1)
    return 1


class OneLineErrors(TyperGroup):
    """The command group: its usage errors are :class:`OneLineUsageError`; the help that a
    command given without arguments prints stays as it is. A write to standard output that
    fails (``> /dev/full``), in any command, ``--help`` or ``--version``, is one ``error:`` line
    naming standard output, with status 1; a closed standard output (``>&-``) is refused so,
    before any work: every command prints to it."""

    def main(self, *args, **kwargs):
        stdout = sys.stdout
        if stdout is None:  # closed (``>&-``): Click would print nothing, and exit 0
            return _stdout_error("it is closed (to discard what the command prints, send it to /dev/null)",
                                 kwargs.get("standalone_mode", True))
        sys.stdout = watched = _WatchedOutput(stdout)
        try:
            return super().main(*args, **kwargs)
        except OSError as exc:
            if not _stdout_failed(exc):
                raise
            return _stdout_error(exc.strerror or str(exc), kwargs.get("standalone_mode", True))
        finally:
            if sys.stdout is watched:  # Click's own wrapper after a broken pipe stays
                sys.stdout = stdout

    def make_context(self, *args, **kwargs):
        try:
            return super().make_context(*args, **kwargs)
        except NoArgsIsHelpError:
            raise
        except UsageError as error:
            raise OneLineUsageError(error) from None

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except (NoArgsIsHelpError, OneLineUsageError):
            raise
        except UsageError as error:
            command = " ".join(filter(None, (ctx.command_path, ctx.invoked_subcommand)))
            raise OneLineUsageError(error, command) from None


def _reader_gone(error: BaseException) -> bool:
    """Whether ``error`` is the reader of an output stream gone: an output file that is a stream
    (``-``, a FIFO; the writers turn the failed write into an OutputError and keep the OSError
    as its context), or standard output itself (a write of it raised ``error``, or it fails
    again when flushed). Not any other broken pipe, such as one to a helper process."""
    from annotate_rgbd.io.writer import is_stream  # OpenCV: not for the command line's start

    if isinstance(error, InputError):
        return isinstance(error.__context__, BrokenPipeError) and error.path is not None and is_stream(error.path)
    if isinstance(error, BrokenPipeError) and _stdout_failed(error):  # its buffer is emptied: a flush passes
        return True
    try:
        if sys.stdout is not None:
            sys.stdout.flush()
    except BrokenPipeError:
        return True
    return False


def _silence_stdout() -> None:
    """Python's own advice after a broken pipe: point standard output at /dev/null, so that its
    flush at exit does not fail again with a message of its own; only when it is this process's
    descriptor 1 (not a test runner's or a notebook's stand-in)."""
    try:
        if sys.stdout is None or sys.stdout.fileno() != 1:
            return
    except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation is both
        return
    os.dup2(os.open(os.devnull, os.O_WRONLY), 1)


class _LowerCaseLevel(logging.Formatter):
    """``warning: ...``, ``info: ...``: the level in lower case, like the ``error:`` lines."""

    def format(self, record: logging.LogRecord) -> str:
        return f"{record.levelname.lower()}: {record.getMessage()}"


@contextmanager
def user_errors() -> Iterator[None]:
    """Turn input and file-system problems into one ``error:`` line and exit status 1.

    An interrupt (Ctrl-C, SIGINT) exits with status 130 and SIGTERM with 143, after the
    ``finally`` clauses have removed temporary files: finished outputs stay, a re-run goes on.
    Standard output's reader gone (``annotate-rgbd export-cvat RUN - | head``) is no error of the
    input: status 141 (128 + SIGPIPE, as ``cat`` gets), without a message.
    """
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_LowerCaseLevel())
    logger = logging.getLogger("annotate_rgbd")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    received: list[int] = []

    def interrupt(signum, frame):
        # SIGTERM unwinds like Ctrl-C, so that no temporary file is left behind.
        received.append(signum)
        raise KeyboardInterrupt("SIGTERM") if signum == signal.SIGTERM else KeyboardInterrupt

    in_main_thread = threading.current_thread() is threading.main_thread()
    previous = {s: signal.signal(s, interrupt) for s in (signal.SIGINT, signal.SIGTERM)} if in_main_thread else {}
    try:
        yield
    except (BrokenPipeError, InputError) as exc:
        if _reader_gone(exc):
            _silence_stdout()
            raise typer.Exit(128 + signal.SIGPIPE) from None
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    except OSError as exc:  # a file system problem outside the writers (e.g. the journal)
        if _stdout_failed(exc):
            raise  # said by OneLineErrors.main, as a failed write of --help or --version
        where = f"{exc.filename}: " if exc.filename else ""
        typer.echo(f"error: {where}{exc.strerror or exc}", err=True)
        raise typer.Exit(1) from None
    except (KeyboardInterrupt, ImportError, RuntimeError) as exc:
        if not isinstance(exc, KeyboardInterrupt) and not _interrupted_import(exc, received):
            raise
        terminated = received[-1] == signal.SIGTERM if received else exc.args == ("SIGTERM",)
        typer.echo(
            f"error: {'terminated' if terminated else 'interrupted'}; finished files are complete, "
            "nothing partial was left; run the same command again to continue",
            err=True,
        )
        status = 143 if terminated else 130
        if not isinstance(exc, KeyboardInterrupt):
            # Interrupted while a module initialised (the interrupt surfaces as another error):
            # its half-made state can print at a normal exit, so leave at once.
            for stream in (sys.stdout, sys.stderr):
                if stream is not None:  # None: closed by the caller (``2>&-``)
                    stream.flush()
            os._exit(status)
        raise typer.Exit(status) from None
    finally:
        for signum, handler_before in previous.items():
            signal.signal(signum, signal.SIG_DFL if handler_before is None else handler_before)
        logger.removeHandler(handler)


def _interrupted_import(error: BaseException, received: list[int]) -> bool:
    """Whether ``error`` is an interrupt that arrived while a module was being imported: a
    compiled module's initialisation turns it into an ``ImportError``, and a class being defined
    (a dataclass's fields, Python 3.11) into a ``RuntimeError`` caused by the ``KeyboardInterrupt``."""
    if not received:
        return False
    if isinstance(error, ImportError):
        return True
    cause = error.__cause__
    while cause is not None and not isinstance(cause, KeyboardInterrupt):
        cause = cause.__cause__
    return cause is not None


def output_path(text: str) -> Path:
    """An output named on the command line, as a path: ``-`` (standard output) stays ``-``; any
    other name that ``Path`` shortens to ``-`` (``./-``, the way to name a file or folder ``-``)
    is made absolute, so that no writer takes it for standard output."""
    path = Path(text)
    return path.absolute() if str(path) == "-" and text != "-" else path


def one_output(positional: str | None, option: str | None, what: str, metavar: str) -> Path:
    """The output a command was given, as its argument or as ``--out`` (as ``cvat2mask`` and
    ``propose`` take theirs), as the text given (:func:`output_path`); an ``InputError`` when
    neither or both (unless the same path)."""
    positional, option = (None if text is None else output_path(text) for text in (positional, option))
    if positional is not None and option is not None and positional != option:
        raise InputError(None, f"two {what}s given, {positional} and --out {option}: give one")
    if positional is None and option is None:
        raise InputError(None, f"no {what} given: give it as {metavar} or as --out")
    return positional if positional is not None else option

"""Warnings: of one scene among several (a batch names the scene in front of each), and one
line per problem that many frames share."""

from __future__ import annotations

import logging
import re
from contextlib import contextmanager
from typing import Iterable, Iterator

LOGGER = "annotate_rgbd"

#: Command-line advice in a message, and the manifest's way of saying it (:func:`manifest_words`).
_MANIFEST_WORDS = (
    (re.compile(r"--part (.+?):OFFSET"), r'parts = ["\1:OFFSET"]'),
    (re.compile(r"--set ([A-Za-z_]+\.[A-Za-z_]+=[^\s;,)]+)"), r'set = ["\1"]'),
    (re.compile(r"--(config|poses|out)\b"), r"'\1'"),
)


def manifest_words(message: str) -> str:
    """A message's command-line advice in a batch manifest's words: ``--part FILE:OFFSET`` is a
    scene's ``parts = ["FILE:OFFSET"]``, ``--set KEY=VALUE`` its ``set = ["KEY=VALUE"]``,
    ``--config``, ``--poses`` and ``--out`` its ``'config'``, ``'poses'`` and ``'out'``."""
    for pattern, words in _MANIFEST_WORDS:
        message = pattern.sub(words, message)
    return message


@contextmanager
def scene_warnings(name: str | None) -> Iterator[None]:
    """Put ``name: `` in front of every message the package logs inside the block, its advice in
    a manifest's words (:func:`manifest_words`: the scene is one of a batch).

    Parameters
    ----------
    name : str or None
        The scene's name; None leaves the messages as they are (a run of one scene).
    """
    if name is None:
        yield
        return

    def prefix(record: logging.LogRecord) -> bool:
        # For collect_warnings: a scene's report names no scene.
        record.unprefixed = manifest_words(record.getMessage())
        record.msg, record.args = f"{name}: {record.unprefixed}", ()
        return True

    logger = logging.getLogger(LOGGER)
    logger.addFilter(prefix)
    try:
        yield
    finally:
        logger.removeFilter(prefix)


@contextmanager
def collect_warnings() -> Iterator[list[str]]:
    """The warnings the package logs inside the block, as they are logged (and still printed):
    for a run's report, of steps that happen before the run has one (loading the configuration).

    Yields
    ------
    list of str
        Filled as warnings are logged; without the scene name :func:`scene_warnings` puts in
        front of them.
    """
    found: list[str] = []

    def collect(record: logging.LogRecord) -> bool:
        # A filter that lets every record through, not a handler: with a handler of its own the
        # package logger would no longer print through Python's last resort (a library caller
        # that set up no logging would see nothing).
        if record.levelno >= logging.WARNING:
            found.append(getattr(record, "unprefixed", None) or record.getMessage())
        return True

    logger = logging.getLogger(LOGGER)
    logger.addFilter(collect)
    try:
        yield found
    finally:
        logger.removeFilter(collect)


def counted(count: int, noun: str) -> str:
    """``count`` and ``noun``, plural unless it is one: ``1 mask``, ``0 masks``, ``2 plane tracks``."""
    return f"{count} {noun}{'' if count == 1 else 's'}"


def group_problems(problems: Iterable[tuple[str, str]], shown: int = 3) -> list[str]:
    """One line per distinct problem, naming the files that have it: a problem every frame
    shares is said once, not once per frame.

    Parameters
    ----------
    problems : iterable of (str, str)
        ``(file, problem)`` pairs, in the order to report them.
    shown : int
        Files named per line; the others are counted.

    Returns
    -------
    list of str
        ``"<file>: <problem>"`` for a problem of one file, ``"<file>, <file> and 57 more: <problem>"``
        for a shared one, in the order each problem first occurs.
    """
    files: dict[str, list[str]] = {}
    for file, problem in problems:
        files.setdefault(problem, []).append(file)
    lines = []
    for problem, names in files.items():
        named = ", ".join(names[:shown])
        if len(names) > shown:
            named += f" and {len(names) - shown} more"
        lines.append(f"{named}: {problem}")
    return lines


def group_errors(errors: Iterable) -> list[str]:
    """:func:`group_problems` of recoverable input errors (each with ``path`` and ``message``,
    :class:`annotate_rgbd.errors.InputError`), in the order of their files."""
    return group_problems(sorted((str(error.path), error.message) for error in errors))

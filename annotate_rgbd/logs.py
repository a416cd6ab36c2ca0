"""Warnings of one scene among several: a batch names the scene in front of each."""

from __future__ import annotations

import logging
from contextlib import contextmanager
from typing import Iterator

LOGGER = "annotate_rgbd"


@contextmanager
def scene_warnings(name: str | None) -> Iterator[None]:
    """Put ``name: `` in front of every message the package logs inside the block.

    Parameters
    ----------
    name : str or None
        The scene's name; None leaves the messages as they are (a run of one scene).
    """
    if name is None:
        yield
        return

    def prefix(record: logging.LogRecord) -> bool:
        record.msg, record.args = f"{name}: {record.getMessage()}", ()
        return True

    logger = logging.getLogger(LOGGER)
    logger.addFilter(prefix)
    try:
        yield
    finally:
        logger.removeFilter(prefix)

"""The exception types the command line turns into a one-line message."""

from __future__ import annotations

from pathlib import Path


class InputError(Exception):
    """A problem with one of the user's inputs, worded for the user.

    Parameters
    ----------
    path : str or Path or None
        The file (or folder) the problem is in; ``None`` when it concerns no single file.
    message : str
        What is wrong, in one line, without the path.
    """

    def __init__(self, path: str | Path | None, message: str):
        self.path = None if path is None else Path(path)
        self.message = message
        super().__init__(str(self))

    def __str__(self) -> str:
        return self.message if self.path is None else f"{self.path}: {self.message}"

    def __reduce__(self):
        # Errors raised in worker processes travel back pickled: rebuild them from both fields.
        return (self.__class__, (self.path, self.message))


class OutputError(InputError):
    """An output file cannot be written (permissions, full disk): fatal for the run.

    Unlike a problem with one input frame, it would recur on every frame, so a run stops at the
    first one. ``path`` is the file that could not be written.
    """

"""What the depth-to-RGB association (:func:`annotate_rgbd.io.sequence.associate`) leaves out, in
the user's words: one warning line for the depth frames without an RGB frame near them, and an
error when none of the frames a command would process has one (every frame would be skipped).

Kept apart from :mod:`annotate_rgbd.io.sequence`, whose code is part of every mask's fingerprint
(:data:`annotate_rgbd.pipeline.resume.MASK_CODE`): the wording of a warning changes no mask.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from annotate_rgbd.errors import InputError
from annotate_rgbd.logs import group_problems


def unmatched_frames(root: Path, depth_files: Sequence[str], time_diff: np.ndarray, matched: np.ndarray,
                     max_time_diff: float, considered: np.ndarray | None = None, which: str = "") -> list[str]:
    """The warnings of the depth frames without an RGB frame within ``max_time_diff`` (grouped:
    one line names a few of them and counts the rest), or an error when none has one.

    Parameters
    ----------
    root : Path
        The sequence folder.
    depth_files : sequence of str
        Every depth frame's file, relative to ``root``.
    time_diff, matched : ndarray, shape (N,)
        Of :func:`annotate_rgbd.io.sequence.associate`.
    max_time_diff : float
    considered : ndarray of int, optional
        Indices of the frames the command would process (default: all).
    which : str
        Those frames in words, for the error when they are not all of them (``"of the annotated
        stretch (RGB frames 9 to 18)"``).

    Returns
    -------
    list of str
        ``"<file>, <file>, <file> and 57 more: no RGB frame within 0.02 s; skipped"``; empty when
        every considered frame has its RGB frame.

    Raises
    ------
    InputError
        Frames were considered and none has an RGB frame within ``max_time_diff``. The message
        gives the gaps there are, so the user can pick a limit.
    """
    considered = np.arange(len(depth_files)) if considered is None else np.asarray(considered, dtype=np.intp)
    missing = considered[~matched[considered]]
    if len(considered) and len(missing) == len(considered):
        gaps = np.abs(time_diff[considered])
        frames = f"depth frame {which}" if which else "depth frame"
        raise InputError(root, f"no {frames} has an RGB frame within {max_time_diff:g} s (sequence.max_time_diff): "
                               f"each is {gaps.min():.4g} to {gaps.max():.4g} s from the nearest (median "
                               f"{float(np.median(gaps)):.4g} s)")
    problem = f"no RGB frame within {max_time_diff:g} s; skipped"
    return group_problems((str(root / depth_files[i]), problem) for i in missing.tolist())

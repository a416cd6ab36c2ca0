"""Which tracks last long enough to be proposed: a plane found on one frame only is a flicker.

Linking gives every detection a track (:mod:`.link`). A track found on fewer than ``min_frames``
processed frames is not proposed: real surfaces stay in view, while a detection that comes and
goes is a fragment of a plane the detector cut differently on that frame, or noise. Whether a
track reaches ``min_frames`` is known once it has (it is *confirmed*) or once no later frame can
continue it (its last detection lies more than ``max_gap`` processed frames back: it *ended*).
:class:`PersistenceFilter` holds each frame until the fate of all its tracks is known and then
hands the frames back in order, with the tracks that stay numbered 1, 2, ... in order of first
appearance (the numbering a labeller sees: no gaps for the tracks left out).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Decided:
    """A frame whose tracks' fates are all known.

    Attributes
    ----------
    position : int
        The frame's position among the processed frames.
    payload : object
        What the caller gave with it.
    keep : ndarray of bool, shape (K,)
        Which of the frame's planes are proposed.
    ids : ndarray of int64, shape (K,)
        Proposed track id of each plane (1, 2, ... in order of first appearance), 0 where not kept.
    """

    position: int
    payload: Any
    keep: np.ndarray
    ids: np.ndarray


class PersistenceFilter:
    """Holds frames until their tracks are confirmed or ended (see the module notes).

    Parameters
    ----------
    min_frames : int
        Processed frames a track must be found on to be proposed (>= 1; 1 keeps every track
        and holds no frame back).
    max_gap : int
        The linker's ``max_gap``: a track last found at position ``p`` may be continued up to
        position ``p + max_gap + 1``.
    """

    def __init__(self, min_frames: int, max_gap: int):
        if min_frames < 1 or max_gap < 0:
            raise ValueError("min_frames must be >= 1 and max_gap >= 0")
        self.min_frames = int(min_frames)
        self.max_gap = int(max_gap)
        self.found: dict[int, int] = {}  # track -> frames found on so far
        self.last: dict[int, int] = {}  # track -> position last found
        self.pending: list[tuple[int, Any, np.ndarray]] = []
        self.output: dict[int, int] = {}  # linker track -> proposed id
        self.next_id = 1

    def add(self, position: int, tracks: np.ndarray, payload: Any) -> list[Decided]:
        """Take the next frame (positions increasing) and return the frames now decided.

        Parameters
        ----------
        position : int
        tracks : ndarray of int, shape (K,)
            The linker's track of each of the frame's planes (none for a failed frame).
        payload : object

        Returns
        -------
        list of Decided
            In position order; possibly empty.
        """
        tracks = np.asarray(tracks, dtype=np.int64)
        for track in tracks.tolist():
            self.found[track] = self.found.get(track, 0) + 1
            self.last[track] = position
        self.pending.append((position, payload, tracks))
        return self._flush(position, final=False)

    def finish(self) -> list[Decided]:
        """Every frame still held (no later frame will come), decided."""
        return self._flush(None, final=True)

    def _settled(self, track: int, position: int | None) -> bool:
        return (self.found[track] >= self.min_frames or position is None
                or position - self.last[track] > self.max_gap)

    def _flush(self, position: int | None, final: bool) -> list[Decided]:
        done = []
        while self.pending:
            where, payload, tracks = self.pending[0]
            if not all(self._settled(t, None if final else position) for t in tracks.tolist()):
                break
            self.pending.pop(0)
            keep = np.array([self.found[t] >= self.min_frames for t in tracks.tolist()], dtype=bool)
            ids = np.zeros(len(tracks), dtype=np.int64)
            for k in np.flatnonzero(keep).tolist():
                track = int(tracks[k])
                if track not in self.output:
                    self.output[track] = self.next_id
                    self.next_id += 1
                ids[k] = self.output[track]
            done.append(Decided(where, payload, keep, ids))
        # Forget the tracks of the frames handed back that no held frame refers to.
        held = {t for _, _, tracks in self.pending for t in tracks.tolist()}
        if not final and position is not None:
            for track in [t for t, p in self.last.items() if position - p > self.max_gap and t not in held]:
                del self.found[track], self.last[track]
        return done

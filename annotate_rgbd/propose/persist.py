"""Which tracks are planes worth proposing: seen on more than one frame, and large somewhere.

Linking gives every detection a track (:mod:`.link`). A track found on fewer than ``min_frames``
processed frames is not proposed: real surfaces stay in view, while a detection that comes and
goes is a fragment of a plane the detector cut differently on that frame, or noise. Nor is a
track whose largest detection covers less than ``min_size`` (square metres of surface): a box
top or a book cover is not a plane of the scene. Whether a track passes is known once it has
(it is *confirmed*) or once no later frame can continue it (its last detection lies more than
``max_gap`` processed frames back: it *ended*).
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
    reasons : list of str or None
        Why each plane is not kept ("flicker": found on too few frames; "small_surface": the
        track's largest detection is too small), None where kept.
    """

    position: int
    payload: Any
    keep: np.ndarray
    ids: np.ndarray
    reasons: list


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
    min_size : float or sequence of float
        Largest detection a track needs, in the units of the sizes given to :meth:`add`, one
        per measure of size (e.g. surface area and share of the image); 0: any.
    reasons : sequence of str
        Why a track too small is not proposed, one per measure (default ``"small_surface"``).
    """

    def __init__(self, min_frames: int, max_gap: int, min_size=0.0, reasons=("small_surface",)):
        min_size = np.atleast_1d(np.asarray(min_size, dtype=np.float64))
        if min_frames < 1 or max_gap < 0 or not (min_size >= 0).all() or len(reasons) < len(min_size):
            raise ValueError("min_frames must be >= 1, max_gap and min_size >= 0, a reason per size")
        self.min_frames = int(min_frames)
        self.max_gap = int(max_gap)
        self.min_size = min_size
        self.size_reasons = tuple(reasons)
        self.largest: dict[int, np.ndarray] = {}  # track -> its largest detection so far, per measure
        self.found: dict[int, int] = {}  # track -> frames found on so far
        self.last: dict[int, int] = {}  # track -> position last found
        self.pending: list[tuple[int, Any, np.ndarray]] = []
        self.output: dict[int, int] = {}  # linker track -> proposed id
        self.next_id = 1

    def add(self, position: int, tracks: np.ndarray, payload: Any, sizes: np.ndarray | None = None) -> list[Decided]:
        """Take the next frame (positions increasing) and return the frames now decided.

        Parameters
        ----------
        position : int
        tracks : ndarray of int, shape (K,)
            The linker's track of each of the frame's planes (none for a failed frame).
        payload : object
        sizes : ndarray of float, shape (K,) or (K, M), optional
            Size of each plane, per measure of ``min_size`` (default: all pass).

        Returns
        -------
        list of Decided
            In position order; possibly empty.
        """
        tracks = np.asarray(tracks, dtype=np.int64)
        measures = len(self.min_size)
        sizes = (np.full((len(tracks), measures), np.inf) if sizes is None
                 else np.asarray(sizes, dtype=np.float64).reshape(len(tracks), measures))
        for track, size in zip(tracks.tolist(), sizes):
            self.found[track] = self.found.get(track, 0) + 1
            self.largest[track] = np.maximum(self.largest.get(track, 0.0), size)
            self.last[track] = position
        self.pending.append((position, payload, tracks))
        return self._flush(position, final=False)

    def finish(self) -> list[Decided]:
        """Every frame still held (no later frame will come), decided."""
        return self._flush(None, final=True)

    def _passes(self, track: int) -> bool:
        return self.found[track] >= self.min_frames and bool((self.largest[track] >= self.min_size).all())

    def _reason(self, track: int) -> str:
        if self.found[track] < self.min_frames:
            return "flicker"
        return self.size_reasons[int(np.argmax(self.largest[track] < self.min_size))]

    def _settled(self, track: int, position: int | None) -> bool:
        return self._passes(track) or position is None or position - self.last[track] > self.max_gap

    def _flush(self, position: int | None, final: bool) -> list[Decided]:
        done = []
        while self.pending:
            where, payload, tracks = self.pending[0]
            if not all(self._settled(t, None if final else position) for t in tracks.tolist()):
                break
            self.pending.pop(0)
            keep = np.array([self._passes(t) for t in tracks.tolist()], dtype=bool)
            ids = np.zeros(len(tracks), dtype=np.int64)
            for k in np.flatnonzero(keep).tolist():
                track = int(tracks[k])
                if track not in self.output:
                    self.output[track] = self.next_id
                    self.next_id += 1
                ids[k] = self.output[track]
            reasons = [None if k else self._reason(t) for t, k in zip(tracks.tolist(), keep.tolist())]
            done.append(Decided(where, payload, keep, ids, reasons))
        # Forget the tracks of the frames handed back that no held frame refers to.
        held = {t for _, _, tracks in self.pending for t in tracks.tolist()}
        if not final and position is not None:
            for track in [t for t, p in self.last.items() if position - p > self.max_gap and t not in held]:
                del self.found[track], self.last[track], self.largest[track]
        return done

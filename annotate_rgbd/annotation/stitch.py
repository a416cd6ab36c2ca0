"""One global plane id per physical plane across annotation parts.

Tracks of consecutive parts are matched on the frames the parts share (or, without overlap, on
the last frame of one part and the first of the next) by the IoU of their depth-refined masks
(measured by :mod:`annotate_rgbd.pipeline.part_overlap`; this module only matches), with an optimal one-to-one assignment (Hungarian) and a minimum IoU. Unmatched tracks become new
planes; a plane that leaves view in one part and returns in a later one stays a new plane unless
a manual entry says otherwise. Manual entries (``[[matches]]`` in the configuration) override
the automatic matching.

A track that carries a plane id (the :data:`~annotate_rgbd.annotation.model.PLANE_ID` attribute
that ``propose`` and ``export-cvat`` write) keeps it, ahead of the automatic matching: a correction
round in CVAT keeps every plane's id and colour. Two tracks of one part that carry the same id
are one plane when they are never visible on the same frame (CVAT's "split" gives both halves the
attribute); otherwise the first keeps it and the other is a new plane (a copied shape keeps its
attributes too).

Other plane ids are given in order of first appearance: part by part (in sequence order), new
tracks by ascending track id, starting above the largest id any track carries, so that a track
the labeller added never takes the id (and colour) of a plane of an earlier round; without
carried ids, the ids of earlier parts never depend on later ones.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from annotate_rgbd.config.annotation import MatchConfig
from annotate_rgbd.errors import InputError
from annotate_rgbd.io.limits import MAX_PLANES
from .model import PLANE_ID, Track
from .parts import Part, part_name

#: How a track got its plane, as written to ``tracks.csv``.
FIRST_PART = "first"
AUTOMATIC = "auto"
MANUAL = "manual"
NEW = "new"
CARRIED = PLANE_ID  # the track's plane_id attribute


@dataclass(frozen=True)
class PartTracks:
    """The tracks of one part, for matching: names and ids only.

    Parameters
    ----------
    name : str
        The part's file name.
    track_ids : list of int
        Its CVAT track ids, ascending.
    labels : list of str
        The CVAT label of each track.
    plane_ids : tuple of (int or None)
        The plane id each track carries (:func:`carried_plane_ids`); empty: none.
    problems : tuple of str
        The carried ids left unused, one line each (the run's warnings).
    """

    name: str
    track_ids: list[int]
    labels: list[str]
    plane_ids: tuple[int | None, ...] = ()
    problems: tuple[str, ...] = ()

    @classmethod
    def of(cls, part: Part) -> "PartTracks":
        """The tracks of a placed part, by track id, with the plane ids they carry."""
        tracks = part.tracks_by_id
        plane_ids, problems = carried_plane_ids(tracks, part.name)
        return cls(part.name, [t.track_id for t in tracks], [t.label for t in tracks], tuple(plane_ids), tuple(problems))

    def carried(self, t: int) -> int | None:
        """The plane id the ``t``-th track carries, if any."""
        return self.plane_ids[t] if t < len(self.plane_ids) else None


def carried_plane_ids(tracks: Sequence[Track], part: str) -> tuple[list[int | None], list[str]]:
    """The plane id each track carries (:data:`~annotate_rgbd.annotation.model.PLANE_ID`), and
    one line per attribute left unused.

    A value that is no plane id (an integer 1..MAX_PLANES) is not used. Of two tracks that carry
    the same id and are visible on a common frame, the later one (by position) does not keep it.

    Parameters
    ----------
    tracks : sequence of Track
        One part's tracks, by track id.
    part : str
        The part's name, for the lines.

    Returns
    -------
    plane_ids : list of int or None
        One per track.
    problems : list of str
    """
    plane_ids: list[int | None] = []
    problems: list[str] = []
    holders: dict[int, list[Track]] = {}
    for track in tracks:
        text = track.attributes.get(PLANE_ID)
        if text is None or text == "":
            plane_ids.append(None)
            continue
        value = int(text) if text.isascii() and text.isdigit() and len(text) <= 6 else 0
        if not 1 <= value <= MAX_PLANES:
            problems.append(f"{part} track {track.track_id}: {PLANE_ID} {text[:20]!r} is no plane id "
                            f"(1 to {MAX_PLANES}): the track is matched as if it carried none")
            plane_ids.append(None)
            continue
        clash = next((other for other in holders.get(value, []) if other.shapes.keys() & track.shapes.keys()), None)
        if clash is not None:
            common = min(clash.shapes.keys() & track.shapes.keys())
            problems.append(f"{part} tracks {clash.track_id} and {track.track_id} both carry {PLANE_ID} {value} and are "
                            f"both visible on frame {common}: track {track.track_id} is matched as if it carried none "
                            f"(a copied shape keeps its attributes: clear {PLANE_ID} on a new plane's track)")
            plane_ids.append(None)
            continue
        holders.setdefault(value, []).append(track)
        plane_ids.append(value)
    return plane_ids, problems


@dataclass(frozen=True)
class TrackPlane:
    """Which global plane one track is, and why (a row of ``tracks.csv``)."""

    part: str
    track: int
    label: str
    plane: int
    how: str
    iou: float | None = None
    matched_part: str | None = None
    matched_track: int | None = None


def track_ious(first: np.ndarray, second: np.ndarray, n_first: int, n_second: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel intersections and unions of every pair of tracks on one frame.

    Parameters
    ----------
    first, second : ndarray of int, shape (H, W)
        Refined masks of the two parts' tracks on the frame: local track numbers 1..n, 0 = none.
    n_first, n_second : int
        Number of tracks of each part.

    Returns
    -------
    intersection, union : ndarray of int64, shape (n_first, n_second)
        Summable over frames; IoU = intersection / union.
    """
    pairs = np.bincount(
        first.ravel().astype(np.int64) * (n_second + 1) + second.ravel(), minlength=(n_first + 1) * (n_second + 1)
    ).reshape(n_first + 1, n_second + 1)
    intersection = pairs[1:, 1:]
    area_first = pairs[1:, :].sum(axis=1)
    area_second = pairs[:, 1:].sum(axis=0)
    union = area_first[:, None] + area_second[None, :] - intersection
    return intersection, union


def match_tracks(iou: np.ndarray, min_iou: float) -> list[tuple[int, int, float]]:
    """Optimal one-to-one matching of two parts' tracks by IoU.

    Parameters
    ----------
    iou : ndarray, shape (n_first, n_second)
    min_iou : float
        Pairs below this IoU are not matched.

    Returns
    -------
    list of (int, int, float)
        ``(row, column, iou)`` of every matched pair, by row.
    """
    if iou.size == 0:
        return []
    # Imported here: scipy.optimize takes a third of a second to import, and only runs of several
    # annotation parts match tracks.
    from scipy.optimize import linear_sum_assignment

    rows, cols = linear_sum_assignment(iou, maximize=True)
    return [(int(r), int(c), float(iou[r, c])) for r, c in zip(rows, cols) if iou[r, c] >= min_iou]


def assign_planes(
    parts: Sequence[PartTracks],
    pair_iou: Sequence[np.ndarray],
    manual: Sequence[MatchConfig],
    min_iou: float,
    config_origin: str | None = None,
) -> list[TrackPlane]:
    """Give every track of every part a global plane id.

    Parameters
    ----------
    parts : sequence of PartTracks
        In sequence order.
    pair_iou : sequence of ndarray
        ``pair_iou[k]``: IoU of part k's tracks (rows) with part k+1's tracks (columns).
    manual : sequence of MatchConfig
        Manual corrections.
    min_iou : float
        Smallest IoU of an automatic match.
    config_origin : str, optional
        Where the manual entries come from, for error messages.

    Returns
    -------
    list of TrackPlane
        One per track, part by part, by track id.

    Raises
    ------
    InputError
        A manual entry names an unknown part or track, a plane id that no earlier part has, or
        gives not exactly one of ``plane``, ``with_part``/``with_track``, ``new``.
    """
    index_of = {part.name: k for k, part in enumerate(parts)}
    pins = _manual_pins(parts, index_of, manual, config_origin)
    result: dict[tuple[int, int], TrackPlane] = {}
    # Fresh ids start above every carried one: none can take a plane of an earlier round.
    next_plane = 1 + max((p for part in parts for p in part.plane_ids if p is not None), default=0)
    known: set[int] = set()  # the planes given so far
    for k, part in enumerate(parts):
        claimed: dict[int, TrackPlane] = {}
        # Manual entries first: they take their tracks out of the automatic matching.
        for t, track in enumerate(part.track_ids):
            pin = pins.get((k, track))
            if pin is None:
                continue
            if pin == "new":
                claimed[t] = TrackPlane(part.name, track, part.labels[t], next_plane, MANUAL)
                next_plane += 1
            elif isinstance(pin, int):
                if pin not in known:
                    raise InputError(config_origin, f"[[matches]] {part.name} track {track}: no earlier part has plane {pin}")
                claimed[t] = TrackPlane(part.name, track, part.labels[t], pin, MANUAL)
            else:
                other = result[pin]
                claimed[t] = TrackPlane(
                    part.name, track, part.labels[t], other.plane, MANUAL, None, other.part, other.track
                )
            known.add(claimed[t].plane)
        # Then the plane ids the tracks carry.
        for t, track in enumerate(part.track_ids):
            carried = part.carried(t)
            if t not in claimed and carried is not None:
                claimed[t] = TrackPlane(part.name, track, part.labels[t], carried, CARRIED)
        automatic: dict[int, tuple[int, float]] = {}
        if k > 0:
            previous = parts[k - 1]
            taken = {p.plane for p in claimed.values()}
            iou = np.array(pair_iou[k - 1], dtype=np.float64, copy=True)
            for r, prev_track in enumerate(previous.track_ids):
                if result[(k - 1, prev_track)].plane in taken:
                    iou[r, :] = 0.0
            iou[:, list(claimed)] = 0.0
            automatic = {c: (r, value) for r, c, value in match_tracks(iou, min_iou)}
        for t, track in enumerate(part.track_ids):
            if t in claimed:
                result[(k, track)] = claimed[t]
            elif t in automatic:
                r, value = automatic[t]
                other = result[(k - 1, parts[k - 1].track_ids[r])]
                result[(k, track)] = TrackPlane(
                    part.name, track, part.labels[t], other.plane, AUTOMATIC, round(value, 6), other.part, other.track
                )
            else:
                result[(k, track)] = TrackPlane(part.name, track, part.labels[t], next_plane, FIRST_PART if k == 0 else NEW)
                next_plane += 1
            known.add(result[(k, track)].plane)
    return list(result.values())


def _manual_pins(
    parts: Sequence[PartTracks], index_of: dict[str, int], manual: Sequence[MatchConfig], origin: str | None
) -> dict[tuple[int, int], int | str | tuple[int, int]]:
    """(part index, track) -> plane id, ``"new"`` or the earlier (part index, track) it equals."""
    pins: dict[tuple[int, int], int | str | tuple[int, int]] = {}
    for number, entry in enumerate(manual, start=1):
        where = f"[[matches]] entry {number}"
        given = [entry.plane is not None, entry.with_part is not None or entry.with_track is not None, entry.new]
        if sum(given) != 1 or (given[1] and (entry.with_part is None or entry.with_track is None)):
            raise InputError(origin, f"{where}: give exactly one of 'plane', 'with_part' + 'with_track', or 'new = true'")
        key = _track_key(parts, index_of, entry.part, entry.track, where, origin)
        if entry.plane is not None:
            if entry.plane < 1:
                raise InputError(origin, f"{where}: plane ids start at 1")
            pins[key] = entry.plane
        elif entry.new:
            pins[key] = "new"
        else:
            other = _track_key(parts, index_of, entry.with_part, entry.with_track, where, origin)
            if other[0] == key[0]:
                raise InputError(origin, f"{where}: both tracks are in {entry.part}; match tracks of different parts")
            later, earlier = (key, other) if key[0] > other[0] else (other, key)
            pins[later] = earlier
    return pins


def _track_key(parts, index_of, name: str, track: int, where: str, origin) -> tuple[int, int]:
    k = index_of.get(part_name(name))
    if k is None:
        raise InputError(origin, f"{where}: unknown part {name!r} (parts: {', '.join(index_of)})")
    if track not in parts[k].track_ids:
        raise InputError(origin, f"{where}: {name} has no track {track} (tracks: {', '.join(map(str, parts[k].track_ids))})")
    return k, track


def plane_origins(tracks: list[TrackPlane]) -> dict[int, TrackPlane]:
    """Plane id -> its first track (the one that introduced the plane)."""
    first: dict[int, TrackPlane] = {}
    for track in tracks:
        first.setdefault(track.plane, track)
    return first


def label_conflicts(tracks: list[TrackPlane]) -> list[str]:
    """One line per track whose CVAT label differs from its plane's first track (a likely wrong match)."""
    origins = plane_origins(tracks)
    return [
        f"plane {t.plane} is labelled {origins[t.plane].label!r} in {origins[t.plane].part} "
        f"(track {origins[t.plane].track}) but {t.label!r} in {t.part} (track {t.track})"
        for t in tracks
        if t.label != origins[t.plane].label
    ]

"""Annotation parts: where each CVAT export lies in the RGB sequence, and which part owns a frame.

A long sequence is annotated in parts, each a CVAT task (or job) over a consecutive slice of the
RGB images, whose frame numbers restart at 0. A part's frame ``f`` is RGB index ``offset + f``.
The offset comes from, in this order of preference:

1. the image names of a "CVAT for images 1.1" export (exact; no offset needed);
2. an explicit offset: ``--part FILE:OFFSET`` or a ``[[parts]]`` entry of the configuration;
3. the original EVOPS tooling's file names, ``<first>-<anything>.xml`` (``950-1900.xml``), where
   ``<first>`` is the RGB index of the export's first frame;
4. a single export alone: offset 0 (CVAT frame numbers are RGB indices).

Where parts overlap, **the later part wins from its first frame on**: a frame belongs to the
part with the largest start among those that contain it. The shared frames are where the
tracks of consecutive parts are matched (:mod:`annotate_rgbd.annotation.stitch`).
"""

from __future__ import annotations

import re
from bisect import bisect_right
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Mapping, Sequence

from .model import Annotation, Track
from annotate_rgbd.errors import InputError
from .frames import rgb_indices
from annotate_rgbd.io.sequence import FrameList

#: ``<offset>-<anything>.xml``, the original tooling's naming of part exports.
PART_NAME = re.compile(r"^(\d+)-(\d+)?")


@dataclass(frozen=True)
class Part:
    """One annotation export placed in the sequence.

    Parameters
    ----------
    name : str
        File name, used in reports and in the configuration's ``[[parts]]`` / ``[[matches]]``.
    annotation : Annotation
    rgb_of_frame : dict of int to int
        CVAT frame number -> RGB index, for the part's frames that are in the sequence.
    offset : int
        RGB index of the part's frame 0 (0 for parts placed by image names).
    offset_source : str
        How the part was placed: ``image names``, ``explicit``, ``file name`` or ``single export``.
    """

    name: str
    annotation: Annotation
    rgb_of_frame: dict[int, int]
    offset: int
    offset_source: str

    @property
    def first(self) -> int:
        """RGB index of the part's first frame."""
        return min(self.rgb_of_frame.values())

    @cached_property
    def frame_of_rgb(self) -> dict[int, int]:
        """RGB index -> CVAT frame number, for the part's frames in the sequence (built once:
        planning looks up every depth frame)."""
        return {rgb: frame for frame, rgb in self.rgb_of_frame.items()}

    @cached_property
    def tracks_by_id(self) -> list[Track]:
        """The part's tracks in ascending track id (the order of plane matching)."""
        return sorted(self.annotation.tracks, key=lambda t: t.track_id)

    @property
    def last(self) -> int:
        """RGB index of the part's last frame."""
        return max(self.rgb_of_frame.values())


def part_name(path: str | Path) -> str:
    """The name a part goes by: its file name."""
    return Path(path).name


def place_parts(
    annotations: Sequence[Annotation], rgb: FrameList, offsets: Mapping[str, int]
) -> tuple[list[Part], list[str]]:
    """Place every export in the RGB sequence and order the parts by where they start.

    Parameters
    ----------
    annotations : sequence of Annotation
        The exports, in command-line order.
    rgb : FrameList
        The sequence's RGB frames.
    offsets : mapping of str to int
        Explicit offsets by file name (or path as given).

    Returns
    -------
    parts : list of Part
        Ordered by their first RGB index.
    warnings : list of str
        Frames of a part that are not in the sequence, one line each.

    Raises
    ------
    InputError
        Two parts with one name, a video export without any way to place it among several,
        a file name whose frame range contradicts the export, parts that coincide or lie one
        inside another, or a part none of whose frames is in the sequence.
    """
    names = [part_name(a.path) for a in annotations]
    for name in set(names):
        if names.count(name) > 1:
            raise InputError(name, "two annotation parts have this file name; rename one so each part has its own")
    unknown = [key for key in offsets if part_name(key) not in names]
    if unknown:
        raise InputError(unknown[0], f"offset given for a file that is not among the annotation parts ({', '.join(names)})")
    by_name = {part_name(key): value for key, value in offsets.items()}
    parts, warnings = [], []
    for annotation, name in zip(annotations, names):
        offset, source = _offset(annotation, name, by_name, several=len(annotations) > 1)
        mapping, missing = rgb_indices(annotation, rgb, offset)
        if missing and len(annotations) > 1 and source != "image names":
            raise InputError(annotation.path, f"part does not fit in the sequence: {missing[0]} (check its offset)")
        warnings.extend(f"{annotation.path}: {line}; skipped" for line in missing)
        if source == "single export" and mapping:
            warnings.extend(_partial_cover(annotation, name, mapping, len(rgb.timestamps)))
        parts.append(Part(name, annotation, mapping, offset, source))
    parts.sort(key=lambda p: (p.first, p.last))
    for earlier, later in zip(parts, parts[1:]):
        if later.first == earlier.first or later.last <= earlier.last:
            raise InputError(
                later.annotation.path,
                f"part covers RGB frames {later.first}-{later.last}, which lie within {earlier.name} "
                f"({earlier.first}-{earlier.last}): check the offsets",
            )
    return parts, warnings


def frame_owners(parts: Sequence[Part]) -> dict[int, int]:
    """RGB index -> index (in ``parts``) of the part whose annotation is used on that frame.

    The later part wins from its first frame on: a frame belongs to the part with the largest
    start at or before it (``parts`` ordered by start), if that part annotates it.
    """
    starts = [part.first for part in parts]
    owners: dict[int, int] = {}
    for index, part in enumerate(parts):
        for rgb in part.rgb_of_frame.values():
            owner = bisect_right(starts, rgb) - 1
            if owner == index:
                owners[rgb] = index
    return owners


def _partial_cover(annotation: Annotation, name: str, mapping: Mapping[int, int], total: int) -> list[str]:
    """A warning when one export placed at frame 0 spans only part of the RGB frames: the rest get
    no mask, and an export of another (shorter) sequence, or a job of a longer one, looks so."""
    first, last = min(mapping.values()), max(mapping.values())
    if last - first + 1 >= total:
        return []
    if annotation.frames and annotation.frames[0] > 0:
        # Its frame numbers start where its task starts in the video (start_frame): already placed.
        return [f"{annotation.path}: its frames are RGB frames {first}-{last} of the sequence's {total} (its task "
                f"starts at frame {annotation.frames[0]}): the others get no mask"]
    return [f"{annotation.path}: its frames are RGB frames {first}-{last} of the sequence's {total}: the others get "
            f"no mask (an export of another sequence? a part of this one: give its offset, --part {name}:OFFSET)"]


def _offset(annotation: Annotation, name: str, explicit: Mapping[str, int], several: bool) -> tuple[int, str]:
    if annotation.image_names:
        return 0, "image names"
    if name in explicit:
        return explicit[name], "explicit"
    match = PART_NAME.match(name)
    if match:
        # The name gives the RGB index of the export's first frame: 0 for a task export, and the
        # task-absolute start for a job export (whose frames do not restart at 0).
        offset = int(match.group(1)) - annotation.frames[0]
        if match.group(2) is not None:
            _check_name_range(annotation, name, offset, int(match.group(2)))
        return offset, "file name"
    if several:
        raise InputError(
            annotation.path,
            "cannot tell where this part starts in the sequence: give --part "
            f"{name}:OFFSET (the RGB index of its frame 0), a [[parts]] entry in the config, "
            "or name the file <offset>-<end>.xml",
        )
    return 0, "single export"


def _check_name_range(annotation: Annotation, name: str, offset: int, end: int) -> None:
    """A ``<offset>-<end>.xml`` name must agree with the export's frame count."""
    last = offset + annotation.frames[-1]
    if end not in (last, last + 1):
        raise InputError(
            annotation.path,
            f"file name says RGB frames {offset}-{end}, but the export's frames "
            f"{annotation.frames[0]}-{annotation.frames[-1]} put it at {offset + annotation.frames[0]}-{last}",
        )

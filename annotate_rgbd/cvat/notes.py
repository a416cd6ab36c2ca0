"""What reading an export noticed: skipped shapes, ignored kinds, the label filter.

The tallies become the annotation's ``notes`` (one line each) for the run's report.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from .format import IGNORED_KINDS


#: How the line of skipped shapes begins (:meth:`Notes.lines`): a shape the labeller drew that
#: makes no mask is a warning of the run, not a note.
SKIPPED = "skipped "


class Notes:
    """Notes in order of first occurrence; skipped shapes are counted per reason."""

    def __init__(self) -> None:
        self._entries: dict[tuple[str, str], list] = {}  # (kind, text) -> [count, first place]

    def add(self, text: str) -> None:
        self._entries.setdefault(("note", text), [0, ""])[0] += 1

    def skip(self, reason: str, where: str) -> None:
        self._entries.setdefault(("skip", reason), [0, where])[0] += 1

    def count(self, what: str, where: str) -> None:
        """Count a remarkable but usable shape."""
        self._entries.setdefault(("count", what), [0, where])[0] += 1

    def lines(self) -> list[str]:
        lines = []
        for (kind, text), (count, where) in self._entries.items():
            if kind == "note":
                lines.append(text)
            elif kind == "count":
                lines.append(f"{text}: {count} (first at {where})")
            else:
                noun = "shape" if count == 1 else "shapes"
                lines.append(f"{SKIPPED}{count} {noun}: {text} (first at {where})")
        return lines


@dataclass
class ReadContext:
    """The input being read and the tallies that become the annotation's notes."""

    path: Path
    labels: frozenset[str] | None
    notes: Notes = field(default_factory=Notes)
    ignored: Counter = field(default_factory=Counter)
    dropped_by_filter: int = 0
    labels_seen: set[str] = field(default_factory=set)
    mask_pixels: int = 0  # decoded so far, against MAX_MASK_PIXELS_TOTAL
    vertex_frames: int = 0  # polygon interpolation so far, against MAX_INTERPOLATED_VERTICES

    def keep_label(self, label: str, shape_count: int) -> bool:
        self.labels_seen.add(label)
        if self.labels is None or label in self.labels:
            return True
        self.dropped_by_filter += shape_count
        return False

    def summary(self) -> list[str]:
        lines = []
        for kind, count in self.ignored.items():
            plural = "s" if count > 1 else ""
            if kind not in IGNORED_KINDS:
                lines.append(f"ignored {count} <{kind}> element{plural} (unknown shape kind)")
            else:
                noun = kind if kind == "tag" else f"{kind} shape"
                lines.append(f"ignored {count} {noun}{plural} ({IGNORED_KINDS[kind]})")
        lines += self.notes.lines()
        if self.labels is not None:
            if self.dropped_by_filter:
                lines.append(
                    f"label filter dropped {self.dropped_by_filter} shapes with other labels"
                )
            for label in sorted(self.labels - self.labels_seen):
                lines.append(f"label filter: no shape has the label {label!r}")
        return lines

"""``<meta>``: the task's frame range, frame step and image size."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from lxml import etree

from annotate_rgbd.errors import InputError

from .format import MAX_TASK_FRAMES
from .xmlstream import int_text


@dataclass
class Meta:
    """What ``<meta>`` says about the frames; ``None`` where it says nothing."""

    start_frame: int | None = None
    stop_frame: int | None = None
    step: int = 1
    original_size: tuple[int, int] | None = None
    task_count: int = 1

    def frames(self) -> list[int] | None:
        if self.start_frame is None or self.stop_frame is None:
            return None
        return list(range(self.start_frame, self.stop_frame + 1, self.step))

    def frame_problem(self, frame: int) -> str | None:
        """Why ``frame`` is not a task frame, or ``None`` when it is (or the range is unknown)."""
        if self.start_frame is None or self.stop_frame is None:
            return None
        if not self.start_frame <= frame <= self.stop_frame:
            return f"frame outside the task range {self.start_frame}-{self.stop_frame}"
        if (frame - self.start_frame) % self.step:
            return f"frame off the task's step grid (step {self.step})"
        return None


def read_meta(meta: etree._Element, path: Path) -> Meta:
    """Frame range and image size of a task, job or single-task project export."""
    sources = [meta.find("task"), meta.find("job")]
    sources = [s for s in sources if s is not None] + meta.findall("project/tasks/task")
    result = Meta(task_count=max(len(sources), 1))
    if len(sources) != 1:
        return result
    source = sources[0]
    start = source.find("start_frame")
    stop = source.find("stop_frame")
    if start is not None and stop is not None:
        result.start_frame = int_text(start, path)
        result.stop_frame = int_text(stop, path)
        if result.stop_frame < result.start_frame:
            raise InputError(
                path,
                f"<stop_frame> at line {stop.sourceline}: {result.stop_frame} is before "
                f"start_frame {result.start_frame}",
            )
    frame_filter = source.find("frame_filter")
    if frame_filter is not None:
        result.step = _step(frame_filter, path)
    if result.start_frame is not None:
        count = (result.stop_frame - result.start_frame) // result.step + 1
        if count > MAX_TASK_FRAMES:
            raise InputError(
                path,
                f"<stop_frame> at line {stop.sourceline}: a task of {count} frames "
                f"({result.start_frame}-{result.stop_frame}, step {result.step}); at most "
                f"{MAX_TASK_FRAMES} are read: export a task or job of the sequence",
            )
    size = source.find("original_size")
    if size is None:
        size = meta.find("original_size")
    if size is not None and size.find("width") is not None and size.find("height") is not None:
        result.original_size = (
            int_text(size.find("width"), path),
            int_text(size.find("height"), path),
        )
    return result


def _step(frame_filter: etree._Element, path: Path) -> int:
    text = (frame_filter.text or "").strip()
    if not text:
        return 1
    key, _, value = text.partition("=")
    if key.strip() == "step" and value.strip().isdigit() and int(value) >= 1:
        return int(value)
    raise InputError(
        path, f"<frame_filter> at line {frame_filter.sourceline}: unsupported filter {text!r}"
    )

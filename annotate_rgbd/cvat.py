"""Read and write CVAT XML exports: "CVAT for video 1.1" and "CVAT for images 1.1".

This is the only module that sees XML. :func:`read_cvat` turns an export (task, job or project)
into the format-neutral :class:`~annotate_rgbd.annotation.Annotation`; the writers produce
exports for fixtures, sample data and tests.

Rules the reader follows (checked against CVAT's exporter and interpolation code):

- **Frames** are absolute CVAT frame numbers, ``start_frame + i * step`` up to ``stop_frame``
  (``<meta>``, ``frame_filter`` ``step=N``). For a video export they index the RGB image list.
- **Video tracks** list every frame where the object is visible. A file export already holds
  every frame (interpolated ones with ``keyframe="0"``); an API export holds keyframes only and
  the frames between them are filled as CVAT does (:mod:`annotate_rgbd.interpolate`). A shape
  with ``outside="1"`` hides the track until its next keyframe; the last visible shape persists
  to ``stop_frame``. Only task frames are filled. Masks are repeated, not interpolated.
- **Images identity**: CVAT's images export writes no track id (not even for shapes that came
  from tracks), so one object across images is identified by its ``group_id`` (with its label)
  when non-zero, otherwise by its label (one plane per label). Two shapes of one identity on one
  image stay separate tracks (the second, third ... of each image form their own tracks) and a
  note says so. Tracks are numbered 0, 1, ... in order of first appearance.
- Rotated boxes become 4-vertex polygons; masks are decoded into bitmaps. Polylines, points,
  ellipses, cuboids, skeletons and tags carry no usable area and are counted in the notes.
- Shapes that cannot be used (too few points, NaN, infinite or absurdly large coordinates,
  all vertices on one line, inverted box, bad RLE, a mask larger than the image, frame off the
  task grid) are skipped with a note; a broken file raises
  :class:`~annotate_rgbd.errors.InputError`. A self-intersecting polygon is used as drawn
  (filled by the even-odd rule); those a labeller drew (not CVAT's interpolated frames) are
  counted in a note, so that they can be fixed.

The file is parsed incrementally with entity expansion, DTD loading and network access
disabled; a document that declares a DTD is refused. Memory stays bounded whatever the file
says: at most :data:`MAX_TASK_FRAMES` task frames, :data:`MAX_SHAPES` shapes after filling in
the frames of tracks, and :data:`MAX_MASK_PIXELS_TOTAL` decoded mask pixels.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Collection, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from lxml import etree

from annotate_rgbd.annotation import AREA_KINDS, Annotation, Shape, Track
from annotate_rgbd.errors import InputError
from annotate_rgbd.interpolate import (
    interpolate_angle,
    interpolate_box,
    interpolate_polygon_series,
)

#: The CVAT XML version this reader understands.
SUPPORTED_VERSION = "1.1"

#: Bounds that keep a hostile or broken export from exhausting memory. A TUM or ICL-NUIM
#: sequence has at most a few thousand frames and a few dozen planes, far below them.
#: Frames of one task (``start_frame`` to ``stop_frame``).
MAX_TASK_FRAMES = 200_000
#: Shapes of a video export once its tracks are expanded to one shape per visible frame.
MAX_SHAPES = 2_000_000
#: Pixels of one mask's box when the export states no image size (4096 x 4096).
MAX_MASK_PIXELS = 1 << 24
#: Decoded mask pixels of the whole export (1 GiB of bitmaps).
MAX_MASK_PIXELS_TOTAL = 1 << 30
#: Coordinates farther than this from the image origin, in pixels, are a broken shape.
MAX_COORDINATE = 1e6

#: "x,y;x,y;..." (the numbers themselves are checked by float()).
_POINTS = re.compile(r"[^,;]+,[^,;]+(?:;[^,;]+,[^,;]+)*")

#: Shape kinds that are read past, with the reason given in the note.
IGNORED_KINDS = {
    "polyline": "no area",
    "points": "no area",
    "ellipse": "not supported, draw planes as polygons",
    "cuboid": "not supported",
    "skeleton": "not supported",
    "tag": "no geometry",
}


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def read_cvat(path: str | Path, labels: Collection[str] | None = None) -> Annotation:
    """Read a "CVAT for video 1.1" or "CVAT for images 1.1" XML export.

    Parameters
    ----------
    path : str or Path
        The ``annotations.xml`` of a task, job or project export.
    labels : collection of str, optional
        Keep only shapes with these labels; by default all labels are kept.

    Returns
    -------
    Annotation
        Tracks with a shape on every frame where they are visible, the task's frames and the
        notes on what was skipped or ignored (see the module docstring for the rules).

    Raises
    ------
    InputError
        The file is missing, unreadable, not well-formed (or cut short), not a CVAT 1.1
        export, declares a DTD, lacks a required attribute or number, repeats a track or image
        id, is a video export without a frame range, or exceeds one of the memory bounds.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(path, "file not found")
    if not path.is_file():
        raise InputError(path, "not a file")
    if path.stat().st_size == 0:
        raise InputError(path, "the file is empty")
    context = _ReadContext(path, None if labels is None else frozenset(labels))
    version = None
    meta = _Meta()
    raw_tracks: list[_RawTrack] = []
    images: list[_RawImage] = []
    track_lines: dict[int, int] = {}
    image_lines: dict[int, int] = {}

    for element in _top_level_elements(path):
        tag = element.tag
        if tag == "version":
            version = (element.text or "").strip()
            if version != SUPPORTED_VERSION:
                raise InputError(
                    path, f"unsupported CVAT XML version {version!r} (expected {SUPPORTED_VERSION})"
                )
        elif tag == "meta":
            meta = _read_meta(element, path)
        elif tag == "track":
            track = _read_track(element, context, meta.original_size)
            if track.track_id in track_lines:
                raise InputError(
                    path,
                    f"<track> at line {element.sourceline}: duplicate track id {track.track_id} "
                    f"(first at line {track_lines[track.track_id]})",
                )
            track_lines[track.track_id] = element.sourceline
            raw_tracks.append(track)
        elif tag == "image":
            image = _read_image(element, context)
            if image.frame in image_lines:
                raise InputError(
                    path,
                    f"<image> at line {element.sourceline}: duplicate image id {image.frame} "
                    f"(first at line {image_lines[image.frame]}); a project export with several "
                    "tasks must be exported per task or job",
                )
            image_lines[image.frame] = element.sourceline
            images.append(image)
        elif tag in IGNORED_KINDS:
            context.ignored[tag] += 1

    if version is None:
        context.notes.add(f"no <version> element: read as CVAT XML {SUPPORTED_VERSION}")
    if raw_tracks and images:
        raise InputError(path, "the export holds both <track> and <image> elements")

    if images:
        annotation = _assemble_images(images, meta, context)
    else:
        annotation = _assemble_video(raw_tracks, meta, context)
    annotation.notes = context.summary()
    return annotation


@dataclass
class _Meta:
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


@dataclass
class _Keyframe:
    """One shape element as written in the file, before interpolation."""

    frame: int
    kind: str
    points: np.ndarray  # polygon (N, 2); box [[xtl, ytl], [xbr, ybr]]; mask [[left, top]]
    line: int
    outside: bool = False
    rotation: float = 0.0
    z_order: int = 0
    occluded: bool = False
    bitmap: np.ndarray | None = None
    usable: bool = True  # False for an outside shape whose geometry has no area


@dataclass
class _RawTrack:
    track_id: int
    label: str
    keyframes: list[_Keyframe]
    line: int


@dataclass
class _RawImage:
    frame: int
    name: str | None
    size: tuple[int, int] | None
    # (identity, label, shape) in file order; identity as described in the module docstring
    shapes: list[tuple[tuple, str, _Keyframe]]
    line: int


class _Notes:
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
                lines.append(f"skipped {count} {noun}: {text} (first at {where})")
        return lines


@dataclass
class _ReadContext:
    """The input being read and the tallies that become the annotation's notes."""

    path: Path
    labels: frozenset[str] | None
    notes: _Notes = field(default_factory=_Notes)
    ignored: Counter = field(default_factory=Counter)
    dropped_by_filter: int = 0
    labels_seen: set[str] = field(default_factory=set)
    mask_pixels: int = 0  # decoded so far, against MAX_MASK_PIXELS_TOTAL

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


def _top_level_elements(path: Path) -> Iterator[etree._Element]:
    """Yield each complete child of the root ``<annotations>`` and free it afterwards."""
    events = etree.iterparse(
        str(path),
        events=("start", "end"),
        resolve_entities=False,
        no_network=True,
        load_dtd=False,
        dtd_validation=False,
        huge_tree=False,
        remove_comments=True,
        remove_pis=True,
    )
    depth = 0
    started = False  # whether the root element began (else a syntax error is no truncation)
    root = None  # checked at the next event, so that a file cut inside its root tag reads as cut
    try:
        for event, element in events:
            if root is not None:
                _check_root(root, path)
                root = None
            if event == "start":
                depth += 1
                if depth == 1:
                    root, started = element, True
                continue
            depth -= 1
            if depth == 1:
                yield element
                # Drop what was read so a large export never builds up in memory.
                element.clear(keep_tail=False)
                parent = element.getparent()
                while element.getprevious() is not None:
                    del parent[0]
    except etree.XMLSyntaxError as error:
        raise InputError(path, _syntax_message(error, path, started)) from None
    except OSError as error:
        raise InputError(path, f"cannot read the file: {error.strerror or error}") from None


def _syntax_message(error: etree.XMLSyntaxError, path: Path, started: bool) -> str:
    """libxml2's complaint, reworded where its own words mislead the user.

    An error on the last line of a document whose root began but that does not end with
    ``</annotations>`` is reported as a cut-off file, whatever libxml2 stumbled on there.
    """
    line = max(error.lineno or 1, 1)
    message = re.sub(r", line \d+, column \d+$", "", (error.msg or "not well-formed").strip())
    message = " ".join(message.split())  # libxml2 may end a message with a newline
    if message.startswith("Excessive depth in document"):
        # libxml2's limit without XML_PARSE_HUGE; CVAT exports nest about 6 levels deep.
        return f"malformed XML at line {line}: elements nested more than 256 levels deep"
    last_line, ending = _last_line(path) if started else (0, b"")
    if started and line >= last_line and not ending.endswith(b"</annotations>"):
        return (
            f"the file ends at line {last_line} before </annotations> (a truncated export or "
            f"download?): {message}"
        )
    return f"malformed XML at line {line}: {message}"


def _last_line(path: Path) -> tuple[int, bytes]:
    """Number of the last non-blank line and the file's last bytes, whitespace stripped."""
    newlines, tail = 0, b""
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            newlines += chunk.count(b"\n")
            tail = (tail + chunk)[-4096:]
    stripped = tail.rstrip()
    return newlines + 1 - tail[len(stripped):].count(b"\n"), stripped


def _check_root(root: etree._Element, path: Path) -> None:
    if root.getroottree().docinfo.doctype:
        raise InputError(
            path, "the file declares a DTD (<!DOCTYPE>), which CVAT exports never do: refused"
        )
    if root.tag != "annotations":
        raise InputError(
            path, f"not a CVAT XML export: the root element is <{root.tag}>, not <annotations>"
        )


def _read_meta(meta: etree._Element, path: Path) -> _Meta:
    """Frame range and image size of a task, job or single-task project export."""
    sources = [meta.find("task"), meta.find("job")]
    sources = [s for s in sources if s is not None] + meta.findall("project/tasks/task")
    result = _Meta(task_count=max(len(sources), 1))
    if len(sources) != 1:
        return result
    source = sources[0]
    start = source.find("start_frame")
    stop = source.find("stop_frame")
    if start is not None and stop is not None:
        result.start_frame = _int_text(start, path)
        result.stop_frame = _int_text(stop, path)
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
            _int_text(size.find("width"), path),
            _int_text(size.find("height"), path),
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


def _read_track(
    element: etree._Element, context: _ReadContext, image_size: tuple[int, int] | None
) -> _RawTrack:
    path = context.path
    track_id = _int_attr(element, "id", path)
    label = _attr(element, "label", path)
    children = [child for child in element if child.tag != "attribute"]
    track = _RawTrack(track_id, label, [], element.sourceline)
    if not context.keep_label(label, len(children)):
        return track
    for child in children:
        if child.tag not in AREA_KINDS:
            context.ignored[child.tag] += 1
            continue
        outside = _flag(child, "outside")
        frame = _int_attr(child, "frame", path)
        keyframe = _read_shape(child, frame, context, image_size, check=not outside)
        if keyframe is not None:
            keyframe.outside = outside
            track.keyframes.append(keyframe)
    return track


def _read_image(element: etree._Element, context: _ReadContext) -> _RawImage:
    path = context.path
    frame = _int_attr(element, "id", path)
    size = None
    if element.get("width") is not None and element.get("height") is not None:
        size = (_int_attr(element, "width", path), _int_attr(element, "height", path))
    image = _RawImage(frame, element.get("name"), size, [], element.sourceline)
    for child in element:
        if child.tag not in AREA_KINDS and child.tag not in IGNORED_KINDS:
            context.ignored[child.tag] += 1  # a kind this reader does not know
            continue
        label = _attr(child, "label", path)
        if not context.keep_label(label, 1):
            continue
        if child.tag in IGNORED_KINDS:
            context.ignored[child.tag] += 1
            continue
        keyframe = _read_shape(child, frame, context, size, check=True)
        if keyframe is None:
            continue
        group = _int_attr(child, "group_id", path, default=0)
        identity = ("group", group, label) if group else ("label", label)
        image.shapes.append((identity, label, keyframe))
    return image


def _read_shape(
    element: etree._Element,
    frame: int,
    context: _ReadContext,
    image_size: tuple[int, int] | None,
    *,
    check: bool,
) -> _Keyframe | None:
    """Read one polygon, box or mask; ``None`` (with a note) when it has no usable area.

    ``check=False`` reads the geometry without judging it (an ``outside`` shape only marks
    where a track ends). ``image_size`` (width, height), where known, bounds a mask's box.
    """
    path = context.path
    kind = element.tag
    line = element.sourceline
    shape = _Keyframe(
        frame=frame,
        kind=kind,
        points=np.empty((0, 2)),
        line=line,
        z_order=_int_attr(element, "z_order", path, default=0),
        occluded=_flag(element, "occluded"),
    )
    if kind == "polygon":
        shape.points = _points_attr(element, path)
        problem = _polygon_problem(shape.points)
        # Checked on the shapes a labeller drew, not on the frames CVAT interpolated from them.
        drawn = element.get("keyframe") != "0"
        if problem is None and check and drawn and _crosses_itself(shape.points):
            context.notes.count(
                "self-intersecting polygons, used as drawn (filled by the even-odd rule)",
                f"line {line}",
            )
    elif kind == "box":
        corners = [_float_attr(element, name, path) for name in ("xtl", "ytl", "xbr", "ybr")]
        shape.points = np.array(corners, dtype=np.float64).reshape(2, 2)
        shape.rotation = _float_attr(element, "rotation", path, default=0.0)
        problem = _box_problem(shape.points, shape.rotation)
    else:  # mask
        left, top, width, height = (
            _int_attr(element, name, path) for name in ("left", "top", "width", "height")
        )
        runs = _runs_attr(element, path)
        shape.points = np.array([[left, top]], dtype=np.float64)
        problem = _mask_problem(runs, width, height, image_size)
        if problem is None:
            context.mask_pixels += width * height
            if context.mask_pixels > MAX_MASK_PIXELS_TOTAL:
                raise InputError(
                    path,
                    f"{_where(element)}: the masks decode to more than {MAX_MASK_PIXELS_TOTAL} "
                    "pixels: export a shorter task or job",
                )
            shape.bitmap = decode_rle(runs, width, height)
    if problem is not None and check:
        context.notes.skip(problem, f"line {line}")
        return None
    shape.usable = problem is None
    return shape


def _polygon_problem(points: np.ndarray) -> str | None:
    if len(points) < 3:
        return "polygon with fewer than 3 points"
    problem = _coordinate_problem(points)
    if problem is not None:
        return problem
    # Zero area: every triangle of the fan from the first vertex is flat, so the polygon covers
    # nothing. (Its signed area is no test: the lobes of a figure of eight cancel out.)
    d = points[1:] - points[0]
    if np.abs(d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]).sum() < 1e-9:
        return "polygon with zero area"
    return None


def _crosses_itself(points: np.ndarray) -> bool:
    """Whether two edges of the closed polygon properly cross (not merely touch).

    Edges i and j cross when the ends of each lie strictly on opposite sides of the other;
    neighbouring edges share a vertex, which lies on neither side, so they never count. All
    pairs are tested at once, in blocks of rows to bound memory.
    """
    if len(points) < 4:
        return False
    start = points
    end = np.concatenate([points[1:], points[:1]])
    along = end - start
    for first in range(0, len(points), 512):
        block = slice(first, first + 512)
        # Ends of every edge against the block's edges, and the block's ends against every edge.
        others_straddle = _straddles(start[block], along[block], start, end)
        block_straddles = _straddles(start, along, start[block], end[block]).T
        if (others_straddle & block_straddles).any():
            return True
    return False


def _straddles(
    origin: np.ndarray, along: np.ndarray, first: np.ndarray, second: np.ndarray
) -> np.ndarray:
    """``[i, j]``: points ``first[j]`` and ``second[j]`` lie strictly on opposite sides of the
    line through ``origin[i]`` along ``along[i]``."""
    def side(points: np.ndarray) -> np.ndarray:
        dx = points[None, :, 0] - origin[:, None, 0]
        dy = points[None, :, 1] - origin[:, None, 1]
        return along[:, None, 0] * dy - along[:, None, 1] * dx

    return side(first) * side(second) < 0


def _coordinate_problem(points: np.ndarray) -> str | None:
    largest = np.abs(points).max()
    if not np.isfinite(largest):
        return "non-finite coordinates"
    if largest > MAX_COORDINATE:
        return f"coordinates beyond {MAX_COORDINATE:.0f} pixels"
    return None


def _mask_problem(
    runs: np.ndarray, width: int, height: int, image_size: tuple[int, int] | None
) -> str | None:
    if width < 1 or height < 1 or np.any(runs < 0) or runs.sum() != width * height:
        return "mask RLE runs do not add up to width x height"
    if image_size is not None and (width > image_size[0] or height > image_size[1]):
        return "mask larger than the image"
    if image_size is None and width * height > MAX_MASK_PIXELS:
        return f"mask larger than {MAX_MASK_PIXELS} pixels"
    return None


def _box_problem(corners: np.ndarray, rotation: float) -> str | None:
    problem = _coordinate_problem(corners)
    if problem is not None:
        return problem
    if not np.isfinite(rotation):
        return "non-finite coordinates"
    (xtl, ytl), (xbr, ybr) = corners
    if xbr <= xtl or ybr <= ytl:
        return "box with xbr <= xtl or ybr <= ytl"
    return None


def _assemble_video(raw_tracks: list[_RawTrack], meta: _Meta, context: _ReadContext) -> Annotation:
    path = context.path
    if meta.task_count > 1:
        raise InputError(
            path, f"a project export with {meta.task_count} tasks: export one task or job instead"
        )
    frames = meta.frames()
    if frames is None:
        raise InputError(path, "video export without <start_frame>/<stop_frame> in <meta>")
    tracks = []
    total = 0
    for raw in raw_tracks:
        if not raw.keyframes:
            continue  # filtered out, or only shapes without area
        keyframes = _task_keyframes(raw, meta, context.notes)
        shapes = _track_shapes(keyframes, meta.stop_frame, meta.step, context.notes, raw.track_id)
        total += len(shapes)
        if total > MAX_SHAPES:
            raise InputError(
                path,
                f"<track> at line {raw.line}: the tracks fill more than {MAX_SHAPES} frames in "
                "all (one shape per track and frame): export a shorter task or job",
            )
        if shapes:
            tracks.append(Track(raw.track_id, raw.label, shapes))
        else:
            context.notes.add(f"track {raw.track_id} (line {raw.line}) is never visible: dropped")
    image_size = {}
    if meta.original_size is not None:
        image_size = dict.fromkeys(frames, meta.original_size)
    return Annotation(str(path), "video", tracks, frames, image_size=image_size)


def _task_keyframes(raw: _RawTrack, meta: _Meta, notes: _Notes) -> list[_Keyframe]:
    """The track's shapes on task frames, sorted by frame, one per frame."""
    keyframes = []
    seen = set()
    for keyframe in sorted(raw.keyframes, key=lambda k: k.frame):
        problem = meta.frame_problem(keyframe.frame)
        if problem is None and keyframe.frame in seen:
            problem = "second shape on the same frame of one track"
        if problem is not None:
            notes.skip(problem, f"line {keyframe.line}")
            continue
        seen.add(keyframe.frame)
        keyframes.append(keyframe)
    return keyframes


def _track_shapes(
    keyframes: list[_Keyframe], stop_frame: int, step: int, notes: _Notes, track_id: int
) -> dict[int, Shape]:
    """Expand a track's sorted shapes into one shape per visible task frame, as CVAT does.

    Frames between two shapes are interpolated from the first towards the second (even when the
    second is ``outside``); after an ``outside`` shape the track is hidden until its next shape;
    the last visible shape persists to ``stop_frame``.
    """
    shapes: dict[int, Shape] = {}
    for current, following in zip(keyframes, keyframes[1:] + [None]):
        if current.outside:
            continue
        shapes[current.frame] = _to_shape(current)
        end = stop_frame + step if following is None else following.frame
        between = range(current.frame + step, end, step)
        if len(between) == 0:
            continue
        if following is None or current.kind == "mask" or not following.usable:
            # Nothing to move towards (or nothing CVAT would interpolate): repeat the shape.
            shapes.update(dict.fromkeys(between, shapes[current.frame]))
            continue
        if following.kind != current.kind:
            notes.add(
                f"track {track_id}: a {current.kind} keyframe is followed by a {following.kind}"
                f" on frame {following.frame}: the {current.kind} is repeated in between"
            )
            shapes.update(dict.fromkeys(between, shapes[current.frame]))
            continue
        span = following.frame - current.frame
        ts = [(frame - current.frame) / span for frame in between]
        for frame, shape in zip(between, _interpolate(current, following, ts)):
            if shape is None:
                notes.skip(
                    "interpolated polygon with fewer than 3 vertices",
                    f"track {track_id}, frame {frame}",
                )
            else:
                shapes[frame] = shape
    return shapes


def _interpolate(k0: _Keyframe, k1: _Keyframe, ts: list[float]) -> list[Shape | None]:
    """Shapes between two keyframes of the same kind (polygon or box) at positions ``ts``."""
    if k0.kind == "polygon":
        outlines = interpolate_polygon_series(k0.points, k1.points, ts)
        return [
            Shape("polygon", outline, k0.z_order, k0.occluded) if len(outline) >= 3 else None
            for outline in outlines
        ]
    shapes = []
    for t in ts:
        corners = interpolate_box(k0.points, k1.points, t)
        rotation = interpolate_angle(k0.rotation, k1.rotation, t)
        shapes.append(_box_shape(corners, rotation, k0.z_order, k0.occluded))
    return shapes


def _to_shape(keyframe: _Keyframe) -> Shape:
    if keyframe.kind == "box":
        return _box_shape(keyframe.points, keyframe.rotation, keyframe.z_order, keyframe.occluded)
    return Shape(
        keyframe.kind, keyframe.points, keyframe.z_order, keyframe.occluded, keyframe.bitmap
    )


def _box_shape(corners: np.ndarray, rotation: float, z_order: int, occluded: bool) -> Shape:
    if rotation % 360.0 == 0.0:
        return Shape("box", np.asarray(corners, dtype=np.float64), z_order, occluded)
    return Shape("polygon", rotated_box_corners(corners, rotation), z_order, occluded)


def _assemble_images(images: list[_RawImage], meta: _Meta, context: _ReadContext) -> Annotation:
    """Group the shapes of all images into tracks by identity (see the module docstring)."""
    tracks: dict[tuple, Track] = {}
    frames = []
    image_names = {}
    image_size = {}
    repeated = 0  # images with two shapes of one identity
    for image in sorted(images, key=lambda i: i.frame):
        problem = meta.frame_problem(image.frame) if meta.task_count == 1 else None
        if problem is not None:
            for _ in image.shapes:
                context.notes.skip(problem, f"line {image.line}")
            continue
        frames.append(image.frame)
        if image.name is not None:
            image_names[image.frame] = image.name
        if image.size is not None:
            image_size[image.frame] = image.size
        occurrences: Counter = Counter()
        for identity, label, keyframe in image.shapes:
            key = (identity, occurrences[identity])
            occurrences[identity] += 1
            track = tracks.setdefault(key, Track(len(tracks), label))
            track.shapes[image.frame] = _to_shape(keyframe)
        repeated += any(count > 1 for count in occurrences.values())
    if repeated:
        context.notes.add(
            f"{repeated} images hold two or more shapes of one label (or group): each extra shape "
            "became a track of its own; give such planes distinct group ids"
        )
    return Annotation(
        str(context.path),
        "images",
        list(tracks.values()),
        frames,
        image_names=image_names,
        image_size=image_size,
    )


# --------------------------------------------------------------------------------------------
# Attribute parsing: every failure names the element, its line and the attribute.
# --------------------------------------------------------------------------------------------


def _where(element: etree._Element) -> str:
    return f"<{element.tag}> at line {element.sourceline}"


def _attr(element: etree._Element, name: str, path: Path) -> str:
    value = element.get(name)
    if value is None:
        raise InputError(path, f"{_where(element)}: attribute {name!r} is missing")
    return value


def _int_attr(element: etree._Element, name: str, path: Path, default: int | None = None) -> int:
    return _number_attr(element, name, path, int, "an integer", default)


def _float_attr(
    element: etree._Element, name: str, path: Path, default: float | None = None
) -> float:
    return _number_attr(element, name, path, float, "a number", default)


def _number_attr(element, name, path, parse, kind, default):
    """Attribute ``name`` parsed by ``parse``; ``default`` when absent (if given)."""
    value = element.get(name)
    if value is None and default is not None:
        return default
    value = _attr(element, name, path)
    try:
        return parse(value)
    except ValueError:
        raise InputError(path, f"{_where(element)}: attribute {name}={value!r} is not {kind}") from None


def _points_attr(element: etree._Element, path: Path) -> np.ndarray:
    """``points="x,y;x,y;..."`` as an (N, 2) array."""
    text = _attr(element, "points", path).strip().strip(";")
    if not _POINTS.fullmatch(text):
        raise InputError(path, f"{_where(element)}: attribute 'points' is not a list of x,y pairs")
    values = text.replace(";", ",").split(",")
    try:
        points = np.fromiter(map(float, values), dtype=np.float64, count=len(values))
    except ValueError:
        raise InputError(
            path, f"{_where(element)}: attribute 'points' holds a non-number"
        ) from None
    return points.reshape(-1, 2)


def _runs_attr(element: etree._Element, path: Path) -> np.ndarray:
    text = _attr(element, "rle", path)
    try:
        return np.array([run for run in text.split(",") if run.strip()], dtype=np.int64)
    except ValueError:
        raise InputError(path, f"{_where(element)}: attribute 'rle' holds a non-integer") from None


def _flag(element: etree._Element, name: str) -> bool:
    return element.get(name) in ("1", "true", "True")


def _int_text(element: etree._Element, path: Path) -> int:
    text = (element.text or "").strip()
    try:
        return int(text)
    except ValueError:
        raise InputError(path, f"{_where(element)}: {text!r} is not an integer") from None


# --------------------------------------------------------------------------------------------
# Geometry helpers
# --------------------------------------------------------------------------------------------


def rotated_box_corners(corners: np.ndarray, rotation: float) -> np.ndarray:
    """The four corners of a CVAT box turned by ``rotation`` degrees about its centre.

    Parameters
    ----------
    corners : ndarray, shape (2, 2)
        ``[[xtl, ytl], [xbr, ybr]]`` before rotation.
    rotation : float
        Degrees, clockwise on screen (image y points down), as CVAT stores it.

    Returns
    -------
    ndarray of float64, shape (4, 2)
        Top-left, top-right, bottom-right, bottom-left corners after rotation.
    """
    (x0, y0), (x1, y1) = np.asarray(corners, dtype=np.float64)
    box = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    centre = box.mean(axis=0)
    angle = np.radians(rotation)
    turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    return (box - centre) @ turn.T + centre


def decode_rle(runs: np.ndarray, width: int, height: int) -> np.ndarray:
    """Decode CVAT's mask RLE into a bitmap.

    Parameters
    ----------
    runs : ndarray of int
        Run lengths over the ``width x height`` box in row-major order, alternating and
        starting with unset pixels; they must add up to ``width * height``.
    width, height : int
        Size of the mask's box.

    Returns
    -------
    ndarray of bool, shape (height, width)
    """
    runs = np.asarray(runs, dtype=np.int64)
    if np.any(runs < 0) or runs.sum() != width * height:
        raise ValueError(f"RLE runs add up to {runs.sum()}, not {width} x {height}")
    values = np.arange(len(runs)) % 2 == 1
    return np.repeat(values, runs).reshape(height, width)


def encode_rle(bitmap: np.ndarray) -> np.ndarray:
    """Encode a bitmap as CVAT's mask RLE (inverse of :func:`decode_rle`).

    Parameters
    ----------
    bitmap : ndarray of bool, shape (height, width)

    Returns
    -------
    ndarray of int64
        Run lengths in row-major order, starting with unset pixels (possibly a zero run).
    """
    flat = np.asarray(bitmap, dtype=bool).ravel()
    changes = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    runs = np.diff(np.concatenate([[0], changes, [flat.size]]))
    if flat.size and flat[0]:
        runs = np.concatenate([[0], runs])
    return runs.astype(np.int64)


# --------------------------------------------------------------------------------------------
# Writing (fixtures, sample data, tests)
# --------------------------------------------------------------------------------------------


def write_cvat_video(
    annotation: Annotation,
    path: str | Path,
    *,
    width: int,
    height: int,
    keyframe_step: int = 1,
    keyframes_only: bool = False,
) -> None:
    """Write a "CVAT for video 1.1" task export, as CVAT writes it.

    Within each run of consecutive task frames of a track, every ``keyframe_step``-th shape and
    the run's last one are keyframes; a run that ends before the task does is closed by an
    ``outside="1"`` keyframe on the next task frame.

    Parameters
    ----------
    annotation : Annotation
        What to write; ``annotation.frames`` must be evenly spaced (they give ``start_frame``,
        ``stop_frame`` and the ``step`` of ``frame_filter``).
    path : str or Path
        The XML file to create.
    width, height : int
        The video's frame size (``<original_size>``).
    keyframe_step : int
        Distance, in task frames, between keyframes inside a run.
    keyframes_only : bool
        Leave out the ``keyframe="0"`` shapes, as an export through the CVAT API does.
    """
    if keyframe_step < 1:
        raise ValueError("keyframe_step must be at least 1")
    frames = annotation.frames
    step = _uniform_step(frames)
    with _export_file(path) as xml:
        meta = _meta_element(annotation, "interpolation", step)
        size = etree.SubElement(meta[0], "original_size")
        etree.SubElement(size, "width").text = str(width)
        etree.SubElement(size, "height").text = str(height)
        xml.write(meta, pretty_print=True)
        index = {frame: i for i, frame in enumerate(frames)}  # built once, not per track
        for track in annotation.tracks:
            element = _track_element(track, frames, index, keyframe_step, keyframes_only)
            xml.write(element, pretty_print=True)


def write_cvat_images(annotation: Annotation, path: str | Path, *, width: int, height: int) -> None:
    """Write a "CVAT for images 1.1" task export, one ``<image>`` per frame.

    Each track's shapes carry ``group_id = position of the track + 1``, the identity
    :func:`read_cvat` uses, so reading the file back gives the same tracks (numbered in order
    of first appearance).

    Parameters
    ----------
    annotation : Annotation
        What to write; ``annotation.frames`` must be evenly spaced.
    path : str or Path
        The XML file to create.
    width, height : int
        Image size, where ``annotation.image_size`` does not give one.
    """
    frames = annotation.frames
    step = _uniform_step(frames)
    with _export_file(path) as xml:
        xml.write(_meta_element(annotation, "annotation", step), pretty_print=True)
        for frame in frames:
            image_width, image_height = annotation.image_size.get(frame, (width, height))
            image = etree.Element(
                "image",
                id=str(frame),
                name=annotation.image_names.get(frame, f"frame_{frame:06d}"),
                width=str(image_width),
                height=str(image_height),
            )
            for group, track in enumerate(annotation.tracks, start=1):
                shape = track.shapes.get(frame)
                if shape is not None:
                    attributes = {"label": track.label, "source": "manual"}
                    attributes["occluded"] = str(int(shape.occluded))
                    attributes.update(_geometry_attributes(shape))
                    attributes["z_order"] = str(shape.z_order)
                    attributes["group_id"] = str(group)
                    etree.SubElement(image, _xml_kind(shape), attributes)
            xml.write(image, pretty_print=True)


@contextmanager
def _export_file(path: str | Path) -> Iterator[etree.xmlfile]:
    """An export being written: the XML declaration, ``<annotations>`` and its ``<version>``."""
    with etree.xmlfile(str(path), encoding="utf-8") as xml:
        xml.write_declaration()
        with xml.element("annotations"):
            xml.write(_text_element("version", SUPPORTED_VERSION), pretty_print=True)
            yield xml


def _track_element(
    track: Track, frames: list[int], index: dict[int, int], keyframe_step: int, keyframes_only: bool
) -> etree._Element:
    """One ``<track>`` as CVAT's file (or API) export writes it (``index``: frame -> position)."""
    element = etree.Element("track", id=str(track.track_id), label=track.label, source="manual")
    for run in _runs_of_frames(sorted(track.shapes), index):
        for k, frame in enumerate(run):
            keyframe = k % keyframe_step == 0 or k == len(run) - 1
            if keyframe or not keyframes_only:
                element.append(_video_shape(track.shapes[frame], frame, keyframe, outside=False))
        following = index[run[-1]] + 1
        if following < len(frames):  # the run ends before the task does
            last = track.shapes[run[-1]]
            element.append(_video_shape(last, frames[following], True, outside=True))
    return element


def _uniform_step(frames: list[int]) -> int:
    if not frames:
        raise ValueError("the annotation has no frames")
    steps = set(np.diff(frames).tolist())
    if len(steps) > 1 or any(s < 1 for s in steps):
        raise ValueError("annotation frames must be increasing and evenly spaced")
    return steps.pop() if steps else 1


def _runs_of_frames(track_frames: list[int], index: dict[int, int]) -> list[list[int]]:
    """Split a track's frames into runs of consecutive task frames."""
    missing = [frame for frame in track_frames if frame not in index]
    if missing:
        raise ValueError(f"track frames {missing[:3]} are not annotation frames")
    runs: list[list[int]] = []
    for frame in track_frames:
        if runs and index[frame] == index[runs[-1][-1]] + 1:
            runs[-1].append(frame)
        else:
            runs.append([frame])
    return runs


def _text_element(tag: str, text: str) -> etree._Element:
    element = etree.Element(tag)
    element.text = text
    return element


def _meta_element(annotation: Annotation, mode: str, step: int) -> etree._Element:
    meta = etree.Element("meta")
    task = etree.SubElement(meta, "task")
    fields = {
        "id": "1",
        "name": Path(annotation.path).stem or "annotate-rgbd",
        "size": str(len(annotation.frames)),
        "mode": mode,
        "overlap": "0",
        "start_frame": str(annotation.frames[0]),
        "stop_frame": str(annotation.frames[-1]),
        "frame_filter": f"step={step}" if step > 1 else "",
    }
    for tag, text in fields.items():
        etree.SubElement(task, tag).text = text
    labels = etree.SubElement(task, "labels")
    for name in dict.fromkeys(track.label for track in annotation.tracks):
        label = etree.SubElement(labels, "label")
        etree.SubElement(label, "name").text = name
        etree.SubElement(label, "attributes")
    return meta


def _video_shape(shape: Shape, frame: int, keyframe: bool, *, outside: bool) -> etree._Element:
    attributes = {
        "frame": str(frame),
        "keyframe": str(int(keyframe)),
        "outside": str(int(outside)),
        "occluded": str(int(shape.occluded)),
    }
    attributes.update(_geometry_attributes(shape))
    attributes["z_order"] = str(shape.z_order)
    return etree.Element(_xml_kind(shape), attributes)


def _xml_kind(shape: Shape) -> str:
    if shape.kind not in AREA_KINDS:
        raise ValueError(f"cannot write a {shape.kind!r} shape")
    return shape.kind


def _geometry_attributes(shape: Shape) -> dict[str, str]:
    """Geometry attributes with CVAT's formatting (2 decimals for coordinates)."""
    if shape.kind == "polygon":
        return {"points": ";".join(f"{x:.2f},{y:.2f}" for x, y in shape.points.tolist())}
    if shape.kind == "box":
        (xtl, ytl), (xbr, ybr) = shape.points.tolist()
        return {"xtl": f"{xtl:.2f}", "ytl": f"{ytl:.2f}", "xbr": f"{xbr:.2f}", "ybr": f"{ybr:.2f}"}
    left, top = shape.points[0]
    mask_height, mask_width = shape.bitmap.shape
    return {
        "rle": ", ".join(str(run) for run in encode_rle(shape.bitmap)),
        "left": str(int(left)),
        "top": str(int(top)),
        "width": str(mask_width),
        "height": str(mask_height),
    }

"""Read a CVAT XML export (task, job or project) into the format-neutral annotation model.

The rules are those of the package docstring (:mod:`annotate_rgbd.cvat`).
"""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path

import numpy as np
from lxml import etree

from annotate_rgbd.annotation.model import AREA_KINDS, PLANE_ID, Annotation
from annotate_rgbd.errors import InputError

from .archive import xml_source
from .codecs import decode_rle
from .format import IGNORED_KINDS, MAX_MASK_PIXELS_TOTAL, SUPPORTED_VERSION
from .geometry import box_problem, crosses_itself, mask_problem, polygon_problem
from .meta import Meta, read_meta
from .notes import ReadContext
from .tracks import Keyframe, RawImage, RawTrack, assemble_images, assemble_video
from .xmlstream import attr, flag, float_attr, int_attr, points_attr, runs_attr, top_level_elements, where


def read_cvat(path: str | Path, labels: Collection[str] | None = None) -> Annotation:
    """Read a "CVAT for video 1.1" or "CVAT for images 1.1" XML export.

    Parameters
    ----------
    path : str or Path
        The ``annotations.xml`` of a task, job or project export, or the zip archive CVAT
        downloads, which holds it (read in place: see :mod:`~annotate_rgbd.cvat.archive`).
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
        export (a COCO or other export, zipped or not, is named as such), a zip archive without
        a CVAT XML or whose XML unpacks beyond the bound, declares a DTD, lacks a required attribute or number, repeats a track or image
        id, is a video export without a frame range, or exceeds one of the memory bounds.
    """
    given = Path(path)
    if not given.exists():
        raise InputError(given, "file not found")
    if not given.is_file():
        raise InputError(given, "not a file")
    if given.stat().st_size == 0:
        raise InputError(given, "the file is empty")
    source = xml_source(given)
    path = source.path  # what messages name: the file, or archive.zip/annotations.xml
    context = ReadContext(path, None if labels is None else frozenset(labels))
    version = None
    meta = Meta()
    raw_tracks: list[RawTrack] = []
    images: list[RawImage] = []
    track_lines: dict[int, int] = {}
    image_lines: dict[int, int] = {}

    for element in top_level_elements(source):
        tag = element.tag
        if tag == "version":
            version = (element.text or "").strip()
            if version != SUPPORTED_VERSION:
                raise InputError(
                    path, f"unsupported CVAT XML version {version!r} (expected {SUPPORTED_VERSION})"
                )
        elif tag == "meta":
            meta = read_meta(element, path)
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
        annotation = assemble_images(images, meta, context)
    else:
        annotation = assemble_video(raw_tracks, meta, context)
    annotation.path = str(given)  # a part is known by the file the user gave
    annotation.notes = context.summary()
    annotation.labels = tuple(sorted(context.labels_seen))
    return annotation


def _read_track(
    element: etree._Element, context: ReadContext, image_size: tuple[int, int] | None
) -> RawTrack:
    path = context.path
    track_id = int_attr(element, "id", path)
    label = attr(element, "label", path)
    children = [child for child in element if child.tag != "attribute"]
    track = RawTrack(track_id, label, [], element.sourceline)
    if not context.keep_label(label, len(children)):
        return track
    for child in children:
        if child.tag not in AREA_KINDS:
            context.ignored[child.tag] += 1
            continue
        outside = flag(child, "outside")
        frame = int_attr(child, "frame", path)
        keyframe = _read_shape(child, frame, context, image_size, check=not outside)
        if keyframe is not None:
            keyframe.outside = outside
            track.keyframes.append(keyframe)
        _read_attributes(child, track, context)
    return track


def _read_attributes(element: etree._Element, track: RawTrack, context: ReadContext) -> None:
    """Add a shape's ``<attribute name="...">`` values to its track's attributes (CVAT writes a
    track's attributes into every shape of it; the first value of a name is kept, and a
    :data:`~annotate_rgbd.annotation.model.PLANE_ID` that changes along the track gets a note)."""
    for child in element:
        if child.tag != "attribute":
            continue
        name, value = child.get("name"), (child.text or "").strip()
        if name is None:
            continue
        first = track.attributes.setdefault(name, value)
        if name == PLANE_ID and first != value:
            context.notes.count(
                f"tracks whose {PLANE_ID} attribute changes along the track: the first value is used",
                f"line {child.sourceline}",
            )


def _read_image(element: etree._Element, context: ReadContext) -> RawImage:
    path = context.path
    frame = int_attr(element, "id", path)
    size = None
    if element.get("width") is not None and element.get("height") is not None:
        size = (int_attr(element, "width", path), int_attr(element, "height", path))
    image = RawImage(frame, element.get("name"), size, [], element.sourceline)
    for child in element:
        if child.tag not in AREA_KINDS and child.tag not in IGNORED_KINDS:
            context.ignored[child.tag] += 1  # a kind this reader does not know
            continue
        label = attr(child, "label", path)
        if not context.keep_label(label, 1):
            continue
        if child.tag in IGNORED_KINDS:
            context.ignored[child.tag] += 1
            continue
        keyframe = _read_shape(child, frame, context, size, check=True)
        if keyframe is None:
            continue
        group = int_attr(child, "group_id", path, default=0)
        plane = _plane_id_of(child)
        identity = ("plane", plane) if plane else ("group", group, label) if group else ("label", label)
        image.shapes.append((identity, label, keyframe))
    return image


def _plane_id_of(element: etree._Element) -> str | None:
    """A shape's :data:`~annotate_rgbd.annotation.model.PLANE_ID` attribute text (CVAT writes a
    track's attributes into each of its shapes, also in an images export), None without one."""
    for child in element:
        if child.tag == "attribute" and child.get("name") == PLANE_ID:
            return (child.text or "").strip() or None
    return None


def _read_shape(
    element: etree._Element,
    frame: int,
    context: ReadContext,
    image_size: tuple[int, int] | None,
    *,
    check: bool,
) -> Keyframe | None:
    """Read one polygon, box or mask; ``None`` (with a note) when it has no usable area.

    ``check=False`` reads the geometry without judging it (an ``outside`` shape only marks
    where a track ends). ``image_size`` (width, height), where known, bounds a mask's box.
    """
    path = context.path
    kind = element.tag
    line = element.sourceline
    shape = Keyframe(
        frame=frame,
        kind=kind,
        points=np.empty((0, 2)),
        line=line,
        z_order=int_attr(element, "z_order", path, default=0),
        occluded=flag(element, "occluded"),
        drawn=element.get("keyframe") != "0",
    )
    if kind == "polygon":
        shape.points = points_attr(element, path)
        problem = polygon_problem(shape.points)
        # Checked on the shapes a labeller drew, not on the frames CVAT interpolated from them.
        if problem is None and check and shape.drawn and crosses_itself(shape.points):
            context.notes.count(
                "self-intersecting polygons, used as drawn (filled by the even-odd rule)",
                f"line {line}",
            )
    elif kind == "box":
        corners = [float_attr(element, name, path) for name in ("xtl", "ytl", "xbr", "ybr")]
        shape.points = np.array(corners, dtype=np.float64).reshape(2, 2)
        shape.rotation = float_attr(element, "rotation", path, default=0.0)
        problem = box_problem(shape.points, shape.rotation)
    else:  # mask
        left, top, width, height = (
            int_attr(element, name, path) for name in ("left", "top", "width", "height")
        )
        runs = runs_attr(element, path)
        shape.points = np.array([[left, top]], dtype=np.float64)
        problem = mask_problem(runs, width, height, image_size)
        if problem is None:
            context.mask_pixels += width * height
            if context.mask_pixels > MAX_MASK_PIXELS_TOTAL:
                raise InputError(
                    path,
                    f"{where(element)}: the masks decode to more than {MAX_MASK_PIXELS_TOTAL} "
                    "pixels: export a shorter task or job",
                )
            shape.bitmap = decode_rle(runs, width, height)
    if problem is not None and check:
        context.notes.skip(problem, f"line {line}")
        return None
    shape.usable = problem is None
    return shape

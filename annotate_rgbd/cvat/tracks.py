"""CVAT's track semantics, on shapes already read (no XML).

Video tracks list every frame where the object is visible. A file export already holds every
frame (interpolated ones with ``keyframe="0"``); an API export holds keyframes only and the
frames between them are filled as CVAT does (:mod:`annotate_rgbd.cvat.interpolate`). A shape with
``outside="1"`` hides the track until its next keyframe; the last visible shape persists to
``stop_frame``. Only task frames are filled. Masks are repeated, not interpolated. Images
exports group the shapes of all images into tracks by identity: the ``plane_id`` attribute (which
CVAT keeps on every shape of a track, also when it exports images), else the group id, else the
label.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from annotate_rgbd.annotation.model import PLANE_ID, Annotation, Shape, Track
from annotate_rgbd.errors import InputError
from annotate_rgbd.cvat.interpolate import (
    interpolate_angle,
    interpolate_box,
    interpolate_polygon_series,
)

from .codecs import rotated_box_corners
from .format import MAX_INTERPOLATED_VERTICES, MAX_SHAPES
from .meta import Meta
from .notes import Notes, ReadContext


@dataclass
class Keyframe:
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
    drawn: bool = True  # False for a shape CVAT interpolated (keyframe="0" in a file export)


@dataclass
class RawTrack:
    track_id: int
    label: str
    keyframes: list[Keyframe]
    line: int
    attributes: dict[str, str] = field(default_factory=dict)  # CVAT attributes, first value of each name


@dataclass
class RawImage:
    frame: int
    name: str | None
    size: tuple[int, int] | None
    # (identity, label, shape) in file order; identity as described in the module docstring
    shapes: list[tuple[tuple, str, Keyframe]]
    line: int


def assemble_video(raw_tracks: list[RawTrack], meta: Meta, context: ReadContext) -> Annotation:
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
        shapes = _track_shapes(keyframes, meta.stop_frame, meta.step, context, raw)
        total += len(shapes)
        if total > MAX_SHAPES:
            raise InputError(
                path,
                f"<track> at line {raw.line}: the tracks fill more than {MAX_SHAPES} frames in "
                "all (one shape per track and frame): export a shorter task or job",
            )
        if shapes:
            drawn = frozenset(k.frame for k in keyframes if k.drawn and not k.outside and k.frame in shapes)
            tracks.append(Track(raw.track_id, raw.label, shapes, keyframes=drawn, attributes=dict(raw.attributes)))
        else:
            context.notes.add(f"track {raw.track_id} (line {raw.line}) is never visible: dropped")
    image_size = {}
    if meta.original_size is not None:
        image_size = dict.fromkeys(frames, meta.original_size)
    return Annotation(str(path), "video", tracks, frames, image_size=image_size)


def _task_keyframes(raw: RawTrack, meta: Meta, notes: Notes) -> list[Keyframe]:
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
    keyframes: list[Keyframe], stop_frame: int, step: int, context: ReadContext, raw: RawTrack
) -> dict[int, Shape]:
    """Expand a track's sorted shapes into one shape per visible task frame, as CVAT does.

    Frames between two shapes are interpolated from the first towards the second (even when the
    second is ``outside``); after an ``outside`` shape the track is hidden until its next shape;
    the last visible shape persists to ``stop_frame``.
    """
    notes, track_id = context.notes, raw.track_id
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
        if current.kind == "polygon":
            _charge_interpolation(context, raw, current, following, len(between))
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


def _charge_interpolation(
    context: ReadContext, raw: RawTrack, k0: Keyframe, k1: Keyframe, frames: int
) -> None:
    """Count a polygon span's vertex-frames against :data:`MAX_INTERPOLATED_VERTICES`."""
    context.vertex_frames += (len(k0.points) + len(k1.points)) * frames
    if context.vertex_frames > MAX_INTERPOLATED_VERTICES:
        raise InputError(
            context.path,
            f"<track> at line {raw.line}: interpolating polygons of {len(k0.points)} and "
            f"{len(k1.points)} vertices over the {frames} frames between frames {k0.frame} and "
            f"{k1.frame} takes the export's interpolation past {MAX_INTERPOLATED_VERTICES} "
            "vertex-frames (vertices x frames, all tracks): simplify the polygons or export a "
            "shorter task or job",
        )


def _interpolate(k0: Keyframe, k1: Keyframe, ts: list[float]) -> list[Shape | None]:
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


def _to_shape(keyframe: Keyframe) -> Shape:
    if keyframe.kind == "box":
        return _box_shape(keyframe.points, keyframe.rotation, keyframe.z_order, keyframe.occluded)
    return Shape(
        keyframe.kind, keyframe.points, keyframe.z_order, keyframe.occluded, keyframe.bitmap
    )


def _box_shape(corners: np.ndarray, rotation: float, z_order: int, occluded: bool) -> Shape:
    if rotation % 360.0 == 0.0:
        return Shape("box", np.asarray(corners, dtype=np.float64), z_order, occluded)
    return Shape("polygon", rotated_box_corners(corners, rotation), z_order, occluded)


def assemble_images(images: list[RawImage], meta: Meta, context: ReadContext) -> Annotation:
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
            if identity[0] == "plane":
                track.attributes.setdefault(PLANE_ID, identity[1])
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

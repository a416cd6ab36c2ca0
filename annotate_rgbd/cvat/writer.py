"""Write "CVAT for video 1.1" and "CVAT for images 1.1" exports (fixtures, sample data, tests)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

import numpy as np
from lxml import etree

from annotate_rgbd.annotation.model import AREA_KINDS, Annotation, Shape, Track

from .codecs import encode_rle
from .format import SUPPORTED_VERSION


def write_cvat_video(
    annotation: Annotation,
    path: str | Path | IO[bytes],
    *,
    width: int,
    height: int,
    keyframe_step: int = 1,
    keyframes_only: bool = False,
    sampled_frames: list[int] | None = None,
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
    path : str or Path or binary file object
        The XML file to create, or an open binary stream to write it to.
    width, height : int
        The video's frame size (``<original_size>``).
    keyframe_step : int
        Distance, in task frames, between keyframes inside a run.
    keyframes_only : bool
        Leave out the ``keyframe="0"`` shapes, as an export through the CVAT API does.
    sampled_frames : list of int, optional
        The task frames that were looked at (e.g. every N-th frame, proposals): a track's
        shapes on consecutive sampled frames form one run, all of them keyframes, which CVAT
        interpolates between; a run that ends before the last sampled frame is closed by an
        ``outside="1"`` keyframe on the next sampled frame. Default: every task frame.

    Track attributes (:attr:`Track.attributes`) are written into every shape of the track as
    ``<attribute name="...">`` elements, as CVAT exports them, and declared as text attributes
    of the label in ``<meta>``.
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
        runs_over = frames if sampled_frames is None else sorted(sampled_frames)
        if not set(runs_over) <= set(frames):
            raise ValueError("sampled frames must be annotation frames")
        index = {frame: i for i, frame in enumerate(runs_over)}  # built once, not per track
        for track in annotation.tracks:
            element = _track_element(track, runs_over, index, keyframe_step, keyframes_only)
            xml.write(element, pretty_print=True)


def write_cvat_images(annotation: Annotation, path: str | Path, *, width: int, height: int) -> None:
    """Write a "CVAT for images 1.1" task export, one ``<image>`` per frame.

    Each track's shapes carry ``group_id = position of the track + 1`` and the track's
    attributes, as CVAT exports a track's shapes: the identity :func:`read_cvat` uses (the
    ``plane_id`` attribute, else the group id), so reading the file back gives the same tracks
    (numbered in order of first appearance).

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
                    element = etree.SubElement(image, _xml_kind(shape), attributes)
                    for name, value in track.attributes.items():  # as CVAT exports a track's shapes
                        etree.SubElement(element, "attribute", name=name).text = value
            xml.write(image, pretty_print=True)


@contextmanager
def _export_file(path: str | Path | IO[bytes]) -> Iterator[etree.xmlfile]:
    """An export being written (to a path or an open binary stream): the XML declaration,
    ``<annotations>`` and its ``<version>``."""
    with etree.xmlfile(str(path) if isinstance(path, (str, Path)) else path, encoding="utf-8") as xml:
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
    for shape in element:
        for name, value in track.attributes.items():
            etree.SubElement(shape, "attribute", name=name).text = value
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
    attribute_names: dict[str, dict[str, None]] = {}
    for track in annotation.tracks:
        attribute_names.setdefault(track.label, {}).update(dict.fromkeys(track.attributes))
    for name, names in attribute_names.items():
        label = etree.SubElement(labels, "label")
        etree.SubElement(label, "name").text = name
        attributes = etree.SubElement(label, "attributes")
        for attribute_name in names:  # as CVAT declares a text attribute
            spec = etree.SubElement(attributes, "attribute")
            for tag, text in (("name", attribute_name), ("mutable", "False"), ("input_type", "text"),
                              ("default_value", ""), ("values", "")):
                etree.SubElement(spec, tag).text = text
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

"""What ``propose`` and ``export-cvat`` write: polygon tracks as a CVAT video export, colour
masks, the report's entries. The CVAT XML itself is :mod:`annotate_rgbd.cvat`'s job."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from annotate_rgbd.annotation.model import Annotation, Shape, Track
from annotate_rgbd.config.settings import Config
from annotate_rgbd.cvat import write_cvat_video
from annotate_rgbd.geometry.registration import clip_to_image, polygon_on_colour_image
from annotate_rgbd.report.palette import colour_hex, colourize, plane_colours
from annotate_rgbd.io.writer import is_stream, open_output, write_png


@dataclass
class TrackShapes:
    """The polygons of one track (one plane) on the CVAT frames where it was found.

    Parameters
    ----------
    track : int
        Track (plane) id, > 0: its colour in the masks and its CVAT track id.
    label : str
        CVAT label.
    shapes : dict of int to Shape
        RGB frame index -> polygon.
    attributes : dict of str to str
        CVAT track attributes.
    """

    track: int
    label: str
    shapes: dict[int, Shape] = field(default_factory=dict)
    attributes: dict[str, str] = field(default_factory=dict)


def write_polygon_tracks(
    tracks: list[TrackShapes],
    path: Path,
    *,
    n_frames: int,
    sampled_frames: list[int],
    width: int,
    height: int,
) -> None:
    """Write polygon tracks as a "CVAT for video 1.1" export of a task of ``n_frames`` RGB frames,
    atomically.

    Every shape is a keyframe; CVAT interpolates between the sampled frames of a track's run, and
    a track absent on a sampled frame gets ``outside="1"`` there. Where the sampled frames stop
    well before the task does (a tail longer than any gap between them: a run whose masks end
    early), every track still open ends on the frame after the last sampled one, instead of CVAT
    carrying its last polygon to the end of the task.

    Parameters
    ----------
    tracks : list of TrackShapes
        Written in this order (CVAT track ids are the ``track`` values).
    path : Path
    n_frames : int
        Frames of the CVAT task: the RGB images 0..n_frames-1.
    sampled_frames : list of int
        The RGB frames that were looked at (every shape lies on one of them).
    width, height : int
        Image size.

    Raises
    ------
    OutputError
        The file cannot be written (:func:`annotate_rgbd.io.writer.open_output`).
    """
    annotation = Annotation(
        # The CVAT task's name: the file's, none for a stream (then the writer's default name).
        path="" if is_stream(path) else str(path.stem), format="video",
        tracks=[Track(t.track, t.label, dict(sorted(t.shapes.items())), attributes=dict(t.attributes)) for t in tracks],
        frames=list(range(n_frames)),
    )
    sampled = sorted(set(sampled_frames))
    if sampled and n_frames - 1 - sampled[-1] > max(np.diff(sampled), default=1):
        sampled.append(sampled[-1] + 1)  # looked at up to here, not beyond: the tracks end
    with open_output(path) as handle:  # atomically; a stream (``-``, /dev/stdout, a FIFO) as it is
        write_cvat_video(annotation, handle, width=width, height=height, sampled_frames=sampled)


def write_colour_mask(path: Path, labels: np.ndarray, ids: np.ndarray) -> None:
    """Write a colour mask: label ``k`` of ``labels`` in the palette colour of ``ids[k - 1]``.

    Parameters
    ----------
    path : Path
    labels : ndarray of int, shape (H, W)
        0 = black, else 1..K.
    ids : ndarray of int, shape (K,)
        Plane (track) id of each label, > 0.
    """
    palette = plane_colours(int(ids.max(initial=0)))
    write_png(path, colourize(labels, palette[np.asarray(ids, dtype=np.intp) - 1]))


def track_colour(track: int) -> str:
    """``#rrggbb`` of a plane id."""
    return colour_hex(plane_colours(track)[track - 1])


def equation_text(equation: np.ndarray) -> str:
    """A plane ``(a, b, c, d)`` as CVAT attribute text: ``a b c d``, 6 decimals."""
    return " ".join(f"{float(v):.6f}" for v in equation)


#: Depth (m) of a polygon vertex whose ray misses its plane, when the plane has no mean distance.
FALLBACK_DEPTH_M = 2.0


def colour_image_polygons(outlines: list, planes, distances, config: Config) -> list:
    """Polygons traced on the depth grid, on the image the labeller draws on: as they are when
    colour and depth share one grid, else on the colour image of ``[colour_camera]``
    (:func:`annotate_rgbd.geometry.registration.polygon_on_colour_image`, through each polygon's
    plane).

    Parameters
    ----------
    outlines : list of ndarray, shape (V, 2)
        CVAT coordinates on the depth image.
    planes : sequence of ndarray, shape (4,)
        Each polygon's plane ``(a, b, c, d)``, depth camera frame (None: unknown).
    distances : sequence of float
        Each plane's mean distance (m), the depth of a vertex whose ray misses the plane.
    config : Config
        ``camera`` and ``colour_camera``.

    Returns
    -------
    list of (ndarray, shape (V, 2), or None)
        On the colour image, clipped to it (None: the polygon lies outside it).
    """
    colour = config.colour_camera
    if colour is None:
        return list(outlines)
    mapped = []
    for outline, plane, distance in zip(outlines, planes, distances):
        fallback = float(distance) if distance is not None and np.isfinite(distance) and distance > 0 else FALLBACK_DEPTH_M
        if plane is None:  # no plane: every vertex at the fallback depth
            plane = np.array([0.0, 0.0, 1.0, -fallback])
        polygon = polygon_on_colour_image(outline, np.asarray(plane, dtype=np.float64), config.camera, colour, fallback)
        polygon = clip_to_image(polygon, colour.width, colour.height)
        mapped.append(polygon if len(polygon) >= 3 else None)
    return mapped

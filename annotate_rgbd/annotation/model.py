"""Format-neutral annotation model.

The CVAT reader (:mod:`annotate_rgbd.cvat`) turns an export into these dataclasses; every later
stage works on them and never sees XML.

Coordinates are CVAT image coordinates: x to the right, y down, in pixels, with the image's
top-left *corner* at (0, 0), so pixel ``(col, row)`` covers ``[col, col + 1) x [row, row + 1)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Shape kinds that carry an area and become plane masks.
AREA_KINDS = ("polygon", "box", "mask")

#: The track attribute that carries a plane's id through CVAT: ``propose`` and ``export-cvat``
#: write it into every track (CVAT renumbers track ids on upload, but keeps the attributes its
#: labels declare), and ``cvat2mask`` gives a track that carries it that plane id, and so its
#: colour (:func:`annotate_rgbd.annotation.stitch.assign_planes`).
PLANE_ID = "plane_id"


@dataclass(frozen=True)
class Shape:
    """One plane outline on one frame.

    Parameters
    ----------
    kind : {"polygon", "box", "mask"}
        The CVAT shape type.
    points : ndarray of float64, shape (N, 2)
        ``polygon``: the N >= 3 vertices (x, y), not repeated at the end.
        ``box``: two rows, ``[[xtl, ytl], [xbr, ybr]]``.
        ``mask``: one row, ``[[left, top]]``: where ``bitmap`` sits in the image.
    z_order : int
        CVAT drawing order: a higher value is drawn on top.
    occluded : bool
        CVAT's "occluded" flag, kept for reports; it does not change the mask.
    bitmap : ndarray of bool, shape (height, width), optional
        Only for ``mask`` shapes: the decoded RLE, ``True`` where the mask is set.
    """

    kind: str
    points: np.ndarray
    z_order: int = 0
    occluded: bool = False
    bitmap: np.ndarray | None = None


@dataclass
class Track:
    """One annotated object (one plane) over the frames where it is visible.

    Parameters
    ----------
    track_id : int
        The id in the export: a CVAT track id for video 1.1; for images 1.1 the identity
        described in :func:`annotate_rgbd.cvat.read_cvat`.
    label : str
        The CVAT label name.
    shapes : dict of int to Shape
        Frame number -> outline on that frame, for every frame where the track is visible:
        interpolated frames are filled in and ``outside`` frames are absent.
    keyframes : frozenset of int, optional
        The frames whose shape the labeller drew (CVAT's keyframes); the others were filled in
        by interpolation. None: every shape was drawn (an images export, a rendered sequence).
    attributes : dict of str to str
        CVAT attributes of the track (name -> text value), e.g. a proposed plane's equation or
        its :data:`PLANE_ID`; written by :func:`annotate_rgbd.cvat.write_cvat_video` into every
        shape, and read back from a video export (the first value of each name along the track).
    """

    track_id: int
    label: str
    shapes: dict[int, Shape] = field(default_factory=dict)
    keyframes: frozenset[int] | None = None
    attributes: dict[str, str] = field(default_factory=dict)


@dataclass
class Annotation:
    """Everything read from one CVAT export (one annotation part).

    Parameters
    ----------
    path : str
        The file it was read from, for messages.
    format : {"video", "images"}
        "CVAT for video 1.1" or "CVAT for images 1.1".
    tracks : list of Track
        In export order (CVAT's track order decides drawing order at equal ``z_order``).
    frames : list of int
        Every frame number of the task in ascending order (``start_frame + i * step`` up to
        ``stop_frame``), whether or not it carries shapes.
    image_names : dict of int to str
        Frame number -> image name, for images 1.1 exports (where the name identifies the RGB
        file). Empty for video exports, whose frame number is the RGB index.
    image_size : dict of int to (int, int)
        Frame number -> (width, height) of the annotated image, where the export states it.
    notes : list of str
        What was read but not used (polylines, points, unknown shapes, filtered labels), one
        line each, for the report.
    labels : tuple of str
        Every label the export's tracks and shapes carry, whether or not a label filter kept it.
    """

    path: str
    format: str
    tracks: list[Track]
    frames: list[int]
    image_names: dict[int, str] = field(default_factory=dict)
    image_size: dict[int, tuple[int, int]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    labels: tuple[str, ...] = ()

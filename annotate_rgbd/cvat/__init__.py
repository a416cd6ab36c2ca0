"""Read and write CVAT XML exports: "CVAT for video 1.1" and "CVAT for images 1.1".

This package is the only code that sees XML. :func:`read_cvat` turns an export (task, job or
project) into the format-neutral :class:`~annotate_rgbd.annotation.model.Annotation`; the writers
produce exports for fixtures, sample data, proposals and tests. One job per module:

- :mod:`~annotate_rgbd.cvat.format`: the format's constants and the reader's bounds;
- :mod:`~annotate_rgbd.cvat.archive`: the XML in CVAT's zip download; other exports (COCO ...) named;
- :mod:`~annotate_rgbd.cvat.xmlstream`: safe incremental parsing, attribute parsing, error wording;
- :mod:`~annotate_rgbd.cvat.meta`: ``<meta>`` (frame range, step, image size);
- :mod:`~annotate_rgbd.cvat.reader`: :func:`read_cvat`, the shape elements;
- :mod:`~annotate_rgbd.cvat.geometry`: whether a shape's geometry is usable (pure);
- :mod:`~annotate_rgbd.cvat.codecs`: mask RLE and rotated boxes (pure);
- :mod:`~annotate_rgbd.cvat.tracks`: track semantics, keyframes, interpolation (no XML);
- :mod:`~annotate_rgbd.cvat.notes`: what reading noticed, for the report;
- :mod:`~annotate_rgbd.cvat.writer`: :func:`write_cvat_video`, :func:`write_cvat_images`;
- :mod:`~annotate_rgbd.cvat.from_masks`: label masks -> the polygons and drawing order written for CVAT;
- :mod:`~annotate_rgbd.cvat.pieces`: a mask's pieces, their boxes, the corridors joining them;
- :mod:`~annotate_rgbd.cvat.rings`: simple polygons from traced outlines, under a vertex budget.

Rules the reader follows (checked against CVAT's exporter and interpolation code):

- **Frames** are absolute CVAT frame numbers, ``start_frame + i * step`` up to ``stop_frame``
  (``<meta>``, ``frame_filter`` ``step=N``). For a video export they index the RGB image list.
- **Video tracks** list every frame where the object is visible. A file export already holds
  every frame (interpolated ones with ``keyframe="0"``); an API export holds keyframes only and
  the frames between them are filled as CVAT does (:mod:`annotate_rgbd.cvat.interpolate`). A shape
  with ``outside="1"`` hides the track until its next keyframe; the last visible shape persists
  to ``stop_frame``. Only task frames are filled. Masks are repeated, not interpolated.
- **Images identity**: CVAT's images export writes no track id (not even for shapes that came
  from tracks), so one object across images is identified by its ``group_id`` (with its label)
  when non-zero, otherwise by its label (one plane per label). Two shapes of one identity on one
  image stay separate tracks (the second, third ... of each image form their own tracks) and a
  note says so. Tracks are numbered 0, 1, ... in order of first appearance.
- Rotated boxes become 4-vertex polygons; masks are decoded into bitmaps. Polylines, points,
  ellipses, cuboids, skeletons and tags carry no usable area and are counted in the notes.
- Shapes that cannot be used (too few or too many points, NaN, infinite or absurdly large coordinates,
  all vertices on one line, inverted box, bad RLE, a mask larger than the image, frame off the
  task grid) are skipped with a note; a broken file raises
  :class:`~annotate_rgbd.errors.InputError`. A self-intersecting polygon is used as drawn
  (filled by the even-odd rule); those a labeller drew (not CVAT's interpolated frames) are
  counted in a note, so that they can be fixed.
- **Track attributes** (``<attribute>`` children of a video track's shapes, as CVAT writes them)
  become :attr:`~annotate_rgbd.annotation.model.Track.attributes`, the first value of each name;
  a ``plane_id`` carries a plane's id through a correction round.

A zip archive (CVAT's download) is read in place: its top-level ``annotations.xml`` (or its one
``.xml``), streamed and never extracted, at most :data:`MAX_ARCHIVE_XML_BYTES` unpacked. A COCO,
Datumaro or other export, zipped or not, is refused in one line that says what to export.

The file is parsed incrementally with entity expansion, DTD loading and network access
disabled; a document that declares a DTD is refused. Memory stays bounded whatever the file
says: at most :data:`MAX_TASK_FRAMES` task frames, :data:`MAX_SHAPES` shapes after filling in
the frames of tracks, :data:`MAX_MASK_PIXELS_TOTAL` decoded mask pixels,
:data:`MAX_POLYGON_VERTICES` vertices per polygon (more: the shape is skipped) and
:data:`MAX_INTERPOLATED_VERTICES` vertex-frames of polygon interpolation.
"""

from .codecs import decode_rle, encode_rle, rotated_box_corners
from .format import (
    IGNORED_KINDS, MAX_ARCHIVE_MEMBERS, MAX_ARCHIVE_XML_BYTES, MAX_COORDINATE, MAX_INTERPOLATED_VERTICES,
    MAX_MASK_PIXELS, MAX_MASK_PIXELS_TOTAL, MAX_POLYGON_VERTICES, MAX_SHAPES, MAX_TASK_FRAMES, SUPPORTED_VERSION,
)
from .reader import read_cvat
from .writer import write_cvat_images, write_cvat_video

__all__ = [
    "IGNORED_KINDS", "MAX_ARCHIVE_MEMBERS", "MAX_ARCHIVE_XML_BYTES", "MAX_COORDINATE", "MAX_INTERPOLATED_VERTICES",
    "MAX_MASK_PIXELS", "MAX_MASK_PIXELS_TOTAL", "MAX_POLYGON_VERTICES", "MAX_SHAPES", "MAX_TASK_FRAMES",
    "SUPPORTED_VERSION", "decode_rle", "encode_rle", "read_cvat", "rotated_box_corners", "write_cvat_images",
    "write_cvat_video",
]

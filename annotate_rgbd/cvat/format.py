"""The CVAT XML format's constants and the reader's bounds (no code, no XML)."""

from __future__ import annotations

import re


#: The CVAT XML version this reader understands.
SUPPORTED_VERSION = "1.1"


#: Bounds that keep a hostile or broken export from exhausting memory. A TUM or ICL-NUIM
#: sequence has at most a few thousand frames and a few dozen planes, far below them.
#: Frames of one task (``start_frame`` to ``stop_frame``).
MAX_TASK_FRAMES = 200_000


#: Shapes of a video export once its tracks are expanded to one shape per visible frame.
MAX_SHAPES = 2_000_000


#: Vertex-frames of polygon interpolation in one export: the vertices of the two keyframes of
#: each interpolated span (N + M) times the frames between them, summed over the tracks. It
#: bounds the reader's time and the memory of the filled-in outlines (some 10 to 16 bytes per
#: vertex-frame: about 1.5 GB at the bound). 30 planes of 200 vertices over 5000 frames take
#: 60 million; two 100k-vertex keyframes 5000 frames apart would take a billion.
MAX_INTERPOLATED_VERTICES = 100_000_000


#: Pixels of one mask's box when the export states no image size (4096 x 4096).
MAX_MASK_PIXELS = 1 << 24


#: Decoded mask pixels of the whole export (1 GiB of bitmaps).
MAX_MASK_PIXELS_TOTAL = 1 << 30


#: Vertices of one polygon; a polygon with more is skipped. CVAT's own mask-to-polygon and a
#: labeller's clicks rarely exceed a few thousand; the reader's work on a polygon (the
#: self-crossing check, matching two keyframes for interpolation) and the memory of its
#: interpolated frames grow with the vertex count.
MAX_POLYGON_VERTICES = 100_000


#: Unpacked bytes of the XML read from a zip archive. The XML is parsed as a stream, so this
#: bounds the time a zip bomb can take, not memory; a CVAT export of a sequence's planes is
#: a few megabytes, of a long task with large polygons at most some hundreds.
MAX_ARCHIVE_XML_BYTES = 4 << 30


#: Files in a zip archive: an export with images holds one per frame (at most
#: :data:`MAX_TASK_FRAMES`) and a few more; the archive's directory is read whole.
MAX_ARCHIVE_MEMBERS = 250_000


#: Coordinates farther than this from the image origin, in pixels, are a broken shape.
MAX_COORDINATE = 1e6


#: "x,y;x,y;..." (the numbers themselves are checked by float()).
POINTS = re.compile(r"[^,;]+,[^,;]+(?:;[^,;]+,[^,;]+)*")


#: Shape kinds that are read past, with the reason given in the note.
IGNORED_KINDS = {
    "polyline": "no area",
    "points": "no area",
    "ellipse": "not supported, draw planes as polygons",
    "cuboid": "not supported",
    "skeleton": "not supported",
    "tag": "no geometry",
}

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


#: Pixels of one mask's box when the export states no image size (4096 x 4096).
MAX_MASK_PIXELS = 1 << 24


#: Decoded mask pixels of the whole export (1 GiB of bitmaps).
MAX_MASK_PIXELS_TOTAL = 1 << 30


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

"""Measuring how the tracks of two consecutive annotation parts overlap, for stitching.

The matching itself (:mod:`annotate_rgbd.annotation.stitch`) is pure: it takes IoU matrices. This module
makes them, by reading the depth frames two parts share and segmenting each part's shapes on
them.
"""

from __future__ import annotations

import numpy as np

from annotate_rgbd.config.settings import Config
from annotate_rgbd.segment.filters import label_histogram
from annotate_rgbd.annotation.parts import Part
from annotate_rgbd.segment.frame import segment_frame
from annotate_rgbd.io.sequence import Sequence, read_depth
from annotate_rgbd.annotation.stitch import track_ious

#: At most this many shared frames of two parts are segmented to match their tracks.
MAX_MATCH_FRAMES = 10


def part_pair_iou(
    sequence: Sequence, depth_of_rgb: dict[int, int], a: Part, b: Part, config: Config, max_frames: int = MAX_MATCH_FRAMES
) -> np.ndarray:
    """IoU of part ``a``'s tracks (rows) with part ``b``'s (columns), on their refined masks
    (on the shapes as drawn for tracks that the depth checks drop on those frames).

    On the frames both parts annotate (up to ``max_frames``, evenly spread); without shared
    frames, ``a``'s last frame against ``b``'s first.

    Parameters
    ----------
    sequence : annotate_rgbd.io.sequence.Sequence
    depth_of_rgb : dict of int to int
        RGB index -> the depth frame that shows it.
    a, b : Part
        Consecutive parts.
    config : Config
        Segmentation settings (the same as for the masks).
    max_frames : int
        Most shared frames to segment.

    Returns
    -------
    ndarray of float64, shape (tracks of a, tracks of b)
    """
    tracks_a, tracks_b = a.tracks_by_id, b.tracks_by_id
    shared = sorted(set(a.rgb_of_frame.values()) & set(b.rgb_of_frame.values()) & set(depth_of_rgb))
    if shared:
        picks = np.unique(np.linspace(0, len(shared) - 1, min(len(shared), max_frames)).round().astype(int))
        pairs = [(shared[i], shared[i]) for i in picks]
    else:
        pairs = [(a.last, b.first)] if a.last in depth_of_rgb and b.first in depth_of_rgb else []
    shape = (len(tracks_a), len(tracks_b))
    sums = {kind: [np.zeros(shape, np.int64), np.zeros(shape, np.int64)] for kind in ("labels", "drawn")}
    kept_a, kept_b = np.zeros(shape[0], bool), np.zeros(shape[1], bool)
    for rgb_a, rgb_b in pairs:
        depth = {rgb: read_depth(sequence.root / sequence.depth.files[depth_of_rgb[rgb]]) for rgb in {rgb_a, rgb_b}}
        results = []
        for part, tracks, rgb in ((a, tracks_a, rgb_a), (b, tracks_b, rgb_b)):
            frame = part.frame_of_rgb[rgb]
            shapes = [(i + 1, t.shapes[frame]) for i, t in enumerate(tracks) if frame in t.shapes]
            results.append(segment_frame(depth[rgb], shapes, config))
        for kind, (intersection, union) in sums.items():
            inter, uni = track_ious(getattr(results[0], kind), getattr(results[1], kind), *shape)
            intersection += inter
            union += uni
        kept_a |= label_histogram(results[0].labels, shape[0] + 1)[1:] > 0
        kept_b |= label_histogram(results[1].labels, shape[1] + 1)[1:] > 0
    iou = {kind: np.where(u > 0, i / np.maximum(u, 1), 0.0) for kind, (i, u) in sums.items()}
    # Planes the depth checks drop on these frames (too far, glass) have no refined pixels:
    # they are matched on their shapes as drawn instead.
    return np.where(kept_a[:, None] & kept_b[None, :], iou["labels"], iou["drawn"])

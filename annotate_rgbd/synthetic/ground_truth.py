"""The expected fate of each plane in ``planes.json``: an oracle for the tests, not the pipeline.

:func:`make_sequence <annotate_rgbd.synthetic.sequence.make_sequence>` states for every plane
whether ``cvat2mask`` is expected to keep it or drop it (and why). The tests compare the
pipeline's masks and report with that statement, so it is computed here on purpose from other
data than :mod:`annotate_rgbd.segment.filters` uses, and decided more coarsely. Its thresholds and rule
order are those of the pipeline (the defaults of :class:`annotate_rgbd.config.FilterConfig`;
``invalid_depth`` is checked before ``too_far``, both with a strict ``>``), but it differs from
:func:`annotate_rgbd.segment.filters.plane_statistics` and :func:`annotate_rgbd.segment.filters.drop_reasons`
in exactly these points:

1. **Distance: z depth, not the distance along the ray.** The oracle averages the depth image
   value (z, metres); the pipeline averages the Euclidean distance from the camera centre, the
   depth times the pixel's ray length, which is larger off the image centre (by up to 26 % in
   the corners of a 640 x 480, f = 525 image). A plane whose mean z depth is a little below
   3.5 m but which is seen off-centre can be ``"kept"`` here and dropped as ``too_far`` by
   the pipeline.
2. **No ``too_few_points`` rule.** A plane with fewer than ``min_valid_pixels`` valid pixels in
   a frame is dropped from that frame by the pipeline; the oracle never gives that reason.
3. **One decision per plane for the whole sequence, not one per frame.** The invalid ratio and
   the mean depth pool the pixels of every frame in which the plane is annotated (weighted by
   pixel count); the pipeline decides every frame on that frame's pixels alone. A plane close
   to a threshold can be kept in some frames and dropped in others; ``planes.json`` cannot say
   which.
4. **Pixels counted: what is visible of the plane, not what its polygon covers.** The oracle
   counts the pixels where the renderer sees the plane itself. The pipeline counts the pixels
   of the labeller's polygon that are on top after z-order, including the clutter and nearer
   objects the polygon runs over (table legs inside the floor polygon), whose depth is theirs.
5. **Frames pooled: every rendered depth frame**, including the ones whose RGB frame is
   missing (``dropped_rgb_frames``), which the pipeline skips for lack of an annotation.

What it means for users of ``planes.json``: ``expected`` and ``reason`` label each plane as
"should be in the masks" or "should never be in a mask" under the default filter settings
(a configuration's ``[filter]`` section may change them), not as a per-frame prediction of the
report's ``dropped`` lists; ``invalid_ratio`` and ``mean_depth_m`` are the pooled z-depth
statistics above and differ from the per-frame ``invalid_ratio`` and ``mean_distance`` of
``report.json``. The room of :func:`room_scene <annotate_rgbd.synthetic.scene.room_scene>` keeps
every plane far from the thresholds (the corridor wall 4.4 m away on average, the window 90 %
without depth, every other plane nearer than 2.7 m on average and at most 11 % without depth),
so that the differences do not show there: on the committed sample, the benchmark scene and
the tests' sequence, the per-frame rules of :mod:`annotate_rgbd.segment.filters`, applied to the
labeller's polygons, give every plane the oracle's fate in every frame. A scene of your own
with a plane near a threshold needs its own check.
"""

from __future__ import annotations

import numpy as np

from annotate_rgbd.config.settings import FilterConfig
from annotate_rgbd.segment.filters import INVALID_DEPTH, TOO_FAR
from .frame import Frame

#: The pipeline's default thresholds (EVOPS paper; see :class:`annotate_rgbd.config.FilterConfig`).
MAX_MEAN_DISTANCE = FilterConfig().max_mean_distance
MAX_INVALID_RATIO = FilterConfig().max_invalid_ratio


def depth_statistics(frame: Frame, n_planes: int, depth_scale: float) -> np.ndarray:
    """Depth statistics of the planes annotated in one frame, to be summed over a sequence.

    Parameters
    ----------
    frame : Frame
        Its ``visible`` object index says which plane a pixel shows, ``polygons`` which planes
        are annotated, ``depth_raw`` which pixels have depth.
    n_planes : int
        Number of planes of the scene.
    depth_scale : float
        Raw depth units per metre.

    Returns
    -------
    ndarray of float64, shape (3, n_planes)
        Per plane (zero for planes not annotated in the frame): visible pixels, those of them
        without depth, and the sum of the z depth in metres of the others.
    """
    seen = frame.visible.ravel()
    on = np.isin(seen, list(frame.polygons))
    has_depth = frame.depth_raw.ravel() > 0
    metres = frame.depth_raw.ravel() / depth_scale
    return np.stack([
        np.bincount(seen[on], minlength=n_planes)[:n_planes],
        np.bincount(seen[on & ~has_depth], minlength=n_planes)[:n_planes],
        np.bincount(seen[on & has_depth], weights=metres[on & has_depth], minlength=n_planes)[:n_planes],
    ]).astype(np.float64)


def plane_record(
    track_id: int, label: str, n_frames: int, visible: float, invalid: float, depth_sum: float
) -> dict:
    """The ``planes.json`` entry of one plane, with its expected fate (see the module notes).

    Parameters
    ----------
    track_id : int
        The plane's CVAT track id (its ground-truth value is ``track_id + 1``).
    label : str
    n_frames : int
        Annotation frames that have a polygon of the plane.
    visible, invalid, depth_sum : float
        The plane's column of :func:`depth_statistics` summed over the sequence.

    Returns
    -------
    dict
        ``track_id``, ``gt_value``, ``label``, ``expected`` ("kept" or "dropped"), ``reason``
        (None, "invalid_depth" or "too_far"), ``annotated_frames``, ``visible_pixels``,
        ``invalid_ratio`` and ``mean_depth_m`` (z depth; None when no pixel has depth).
    """
    invalid_ratio = invalid / visible
    mean_depth = depth_sum / (visible - invalid) if visible > invalid else float("nan")
    reason = None
    if invalid_ratio > MAX_INVALID_RATIO:
        reason = INVALID_DEPTH
    elif mean_depth > MAX_MEAN_DISTANCE:
        reason = TOO_FAR
    return {
        "track_id": track_id,
        "gt_value": track_id + 1,
        "label": label,
        "expected": "kept" if reason is None else "dropped",
        "reason": reason,
        "annotated_frames": n_frames,
        "visible_pixels": int(visible),
        "invalid_ratio": round(invalid_ratio, 4),
        "mean_depth_m": round(mean_depth, 4) if np.isfinite(mean_depth) else None,
    }

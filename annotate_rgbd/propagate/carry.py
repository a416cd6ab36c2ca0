"""Pose-guided propagation: a plane drawn on a few keyframes, carried to every frame by the poses.

With camera poses (``--poses``, a TUM trajectory), each keyframe shape of a track is **lifted**
onto its plane: the plane is fitted (as refinement fits it, noise-aware) to the shape's depth
on the depth frame nearest the keyframe, taken to world coordinates with that depth frame's
pose, and the outline's vertex rays from the RGB camera at the keyframe's own time are
intersected with it: a 3-D polygon. On every depth frame of the track's life (CVAT semantics:
the frames where the track is visible) the lifted polygons of its keyframes (on a keyframe,
its own; elsewhere all of them: each outlines the part of the plane in view when it was drawn)
are projected with the depth frame's own pose and drawn in place of the 2-D interpolation; refinement then keeps only the
pixels whose depth lies on the plane in that frame, so occluders (nearer than the plane) fall
out. The lifted planes of one track must agree: a track whose keyframes disagree (two surfaces
under one track, or wrong poses) is listed for review.

With a colour camera of its own (``[colour_camera]``), the trajectory gives the depth camera's
poses: outlines are lifted and projected with the colour camera's intrinsics and its pose
(:func:`annotate_rgbd.propagate.lift.rgb_view`), so that carried shapes stay in colour image
coordinates like drawn ones.

The steps: :mod:`annotate_rgbd.propagate.keyframes` fits the keyframe planes on their depth
frames (the only I/O), :mod:`annotate_rgbd.propagate.timing` estimates the trajectory's time
offset from them, :mod:`annotate_rgbd.propagate.lift` lifts the keyframes onto their planes with
the poses, and this module carries them to a frame (:func:`carried_layers`, pure) and says how
much the keyframes on either side of it agree there (:func:`keyframe_agreement`: the review list).
"""

from __future__ import annotations

from bisect import bisect_right

import cv2
import numpy as np

from annotate_rgbd.config.settings import Config
from annotate_rgbd.geometry.lift import NEAR, plane_to_camera, project_polygons
from .lift import LiftedKeyframe, TrackLift, rgb_view


def carried_layers(
    lift: TrackLift, frame: int, config: Config, pose: tuple[np.ndarray, np.ndarray], disagree: bool = False,
) -> tuple[tuple[tuple[int, np.ndarray], ...], tuple[np.ndarray, ...]]:
    """What a track's lifted keyframes say about its plane on a frame it was not drawn on.

    Every keyframe outlines the part of the plane in view when it was drawn, and (with
    ``[propagate] exclude``) what touched the plane there and was left out. Projected with the
    frame's pose, they are layers for :func:`annotate_rgbd.segment.rasterize.paint_layers`,
    the farthest keyframe (in frames) first: where keyframes disagree about a pixel, the nearest
    one that saw it decides; a pixel no keyframe saw is the plane where any outline holds it.
    Where the keyframes on either side of the frame disagree about the plane there
    (``disagree``: their :func:`keyframe_agreement` is below
    :data:`annotate_rgbd.propagate.DISAGREE_BELOW`), every outline goes over every exclusion: what
    any of them outlined is the plane's, and the frame's own depth decides (refinement), as it
    does under a drawn outline. One of them left out a part of the plane the other drew, and on
    real frames that is more often an outline stopped short (a labeller's, or one that followed
    a gap of the depth) than a surface proud of the plane: on TUM fr1_rpy
    (docs/propagation.md) mean IoU rose at every keyframe spacing, the desk most.

    Parameters
    ----------
    lift : TrackLift
    frame : int
        The CVAT frame (of the track's part) the depth frame shows.
    config : Config
        For the camera.
    pose : (ndarray (3, 3), ndarray (3,))
        The depth frame's camera-to-world pose.
    disagree : bool
        Every keyframe's outline over every keyframe's exclusions (the keyframes on either side
        disagree here).

    Returns
    -------
    layers : tuple of (int, ndarray of shape (V, 2))
        ``(+1, outline)`` or ``(-1, excluded outline)`` in CVAT image coordinates, farthest
        keyframe first; empty when nothing projects into the image.
    beyond : list of ndarray, shape (V, 2)
        Where a keyframe's view ended, the plane went on: drawn below every other shape
        (:data:`annotate_rgbd.segment.rasterize.BOTTOM_Z_ORDER`), so that these only take pixels
        no other shape claims and no keyframe excluded (and refinement keeps the plane's own).
    """
    # Several keyframes, not the two nearest: each outlines the part of the plane in view when
    # it was drawn, and their union is the plane as the labeller saw it (measured on
    # benchmarks/bench_propagate.py, keyframe every 30th frame: mean IoU 0.71 with the two
    # neighbouring keyframes, 0.87 with all).
    nearest = nearest_keyframes(lift.keyframes, frame, config.propagate.keyframes_each_side)
    farthest_first = sorted(nearest, key=lambda k: (-abs(k.frame - frame), k.frame))
    excluded = [[(-1, world) for world in keyframe.excluded] for keyframe in farthest_first]
    outlines = [(1, keyframe.world) for keyframe in farthest_first]
    if disagree:  # every exclusion, then every outline
        signed = [layer for group in excluded for layer in group] + outlines
    else:  # keyframe by keyframe, each one's outline over its own exclusions
        signed = [layer for group, outline in zip(excluded, outlines) for layer in (*group, outline)]
    quads = [quad for keyframe in nearest for quad in keyframe.beyond]
    camera, pose = rgb_view(config, pose)
    projected = project_polygons([world for _, world in signed] + quads, camera, *pose)
    usable = [len(polygon) >= 3 and np.isfinite(polygon).all() for polygon in projected]
    layers = [(sign, polygon) for (sign, _), polygon, ok in zip(signed, projected, usable) if ok]
    beyond = [polygon for polygon, ok in zip(projected[len(signed):], usable[len(signed):]) if ok]
    return tuple(layers), tuple(beyond)


#: Spacing (px) of the pixels :func:`keyframe_agreement` compares the keyframes' regions at, in
#: rows and columns (one near the middle of every such square): far below the size of a plane
#: worth a polygon (1 % of a 640 x 480 image is 48 of them). On TUM fr1_rpy at a keyframe every
#: 10th frame, every 4th pixel ranked the carried planes that went wrong no better (AUC 0.845
#: against 0.847, commit 33daa9a) at 1.5 times the time.
AGREEMENT_STRIDE = 8
#: A disagreement needs evidence: the share is taken as if this many more pixels compared had
#: agreed, so that a score resting on a handful of pixels (two keyframes that saw only a corner
#: of the frame in common) is no alarm, while one on hundreds hardly moves. 12 (768 px of the
#: image): on TUM fr1_rpy with poses (docs/propagation.md) it took the carried planes listed at a
#: keyframe every 30th frame from 33 % to 24 % with 40 % of those that went wrong instead of 46 %
#: (at every 10th: 12 % holding 62 % either way); 48 listed fewer still, holding fewer of them.
PRIOR_SAMPLES = 12
#: Sub-pixel bits of the vertices given to OpenCV's polygon fill.
_SHIFT = 4
#: Vertices are clamped to this many pixels around the image: far enough that no filled pixel of
#: the image moves (a polygon's edges inside the image change only when a vertex lies farther out
#: than this), near enough that OpenCV's fixed-point coordinates do not overflow.
_REACH = 1 << 20


def keyframe_agreement(
    lift: TrackLift, frame: int, config: Config, pose: tuple[np.ndarray, np.ndarray],
    image_size: tuple[int, int] | None = None,
) -> float | None:
    """How much the nearest keyframe before a frame and the nearest one after it agree about where
    their plane is on it, where both could see it.

    Each keyframe's region is its outline, projected with the frame's pose. Only the part of the
    frame both keyframes saw is compared: a pixel of the two regions' union counts when its point
    on the plane (the nearer keyframe's) lies inside both keyframe images (``view``); the camera
    moving on, so that the later keyframe outlines a part of the plane the earlier one could not
    see, is no disagreement. The agreement is the share of the pixels compared that both regions
    hold (as if :data:`PRIOR_SAMPLES` more had), on every :data:`AGREEMENT_STRIDE`-th pixel of
    every :data:`AGREEMENT_STRIDE`-th row. A keyframe whose image size is not known (``view``
    None) limits nothing. Where the keyframes that bracket a frame disagree (the labeller drew
    the plane differently, or another surface; or the poses are off), what is carried there is
    least certain.

    Parameters
    ----------
    lift : TrackLift
    frame : int
        The CVAT frame (of the track's part) the depth frame shows.
    config : Config
        For the camera.
    pose : (ndarray (3, 3), ndarray (3,))
        The depth frame's camera-to-world pose.
    image_size : (int, int), optional
        (width, height) of the annotated image, px; default: the keyframes' (``view``).

    Returns
    -------
    float or None
        The agreement, in [0, 1]; None when the frame has a keyframe on one side only, no
        pixel of either region in the image was seen by both keyframes, or the image's size is
        not known.
    """
    keyframes = lift.keyframes  # in frame order
    i = bisect_right(keyframes, frame, key=lambda k: k.frame)
    if i == 0 or i == len(keyframes):
        return None
    pair = (keyframes[i - 1], keyframes[i])
    camera, (rotation, translation) = rgb_view(config, pose)
    if image_size is None:
        image_size = next((k.view[2] for k in pair if k.view is not None), None)
        if image_size is None:
            return None
    shape = (int(image_size[1]), int(image_size[0]))
    outlines = project_polygons([k.world for k in pair], camera, rotation, translation)
    sample = (slice(AGREEMENT_STRIDE // 2, None, AGREEMENT_STRIDE),) * 2  # the pixels compared
    first, second = (_filled(outline, shape)[sample] for outline in outlines)
    rows, cols = np.nonzero(first | second)
    if rows.size == 0:
        return None
    # Those pixels' points on the nearer keyframe's plane, in the frame's camera.
    rays = np.stack([(cols * AGREEMENT_STRIDE + AGREEMENT_STRIDE // 2 - camera.cx) / camera.fx,
                     (rows * AGREEMENT_STRIDE + AGREEMENT_STRIDE // 2 - camera.cy) / camera.fy, np.ones(rows.size)], axis=1)
    nearer = min(pair, key=lambda k: (abs(k.frame - frame), k.frame))
    plane = plane_to_camera(nearer.plane, rotation, translation)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = -plane[3] / (rays @ plane[:3])
    seen = np.isfinite(depth) & (depth > NEAR)  # a ray along the plane meets it nowhere
    points = rays * np.where(seen, depth, 0.0)[:, None]
    for keyframe in pair:
        if keyframe.view is not None:
            seen &= _in_view(points, rotation, translation, keyframe.view, camera)
    compared = np.count_nonzero(seen)
    if compared == 0:
        return None
    both = np.count_nonzero(seen & first[rows, cols] & second[rows, cols])
    return float((both + PRIOR_SAMPLES) / (compared + PRIOR_SAMPLES))


def _in_view(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray, view: tuple, camera) -> np.ndarray:
    """Which points (N, 3) of a camera posed ``rotation``, ``translation`` a keyframe's camera
    (``view``: its pose and image size) saw: in front of it and inside its image."""
    own_rotation, own_translation, (width, height) = view
    to_own = own_rotation.T @ rotation
    in_camera = points @ to_own.T + own_rotation.T @ (translation - own_translation)
    ahead = in_camera[:, 2] > NEAR
    z = np.where(ahead, in_camera[:, 2], 1.0)
    u = in_camera[:, 0] * camera.fx / z + camera.cx + 0.5  # CVAT coordinates
    v = in_camera[:, 1] * camera.fy / z + camera.cy + 0.5
    return ahead & (u >= 0) & (u < width) & (v >= 0) & (v < height)


def _filled(polygon: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A projected outline (CVAT image coordinates) filled on the image's pixels (bool,
    ``shape``); nothing for one that did not project. As
    :func:`annotate_rgbd.segment.rasterize.fill_window` fills, with the vertices clamped: an
    outline carried by the poses may reach far past the image."""
    region = np.zeros(shape, dtype=np.uint8)
    if len(polygon) >= 3 and np.isfinite(polygon).all():
        # CVAT coordinates count from a pixel's corner, OpenCV's from its centre.
        pixels = np.clip((polygon - 0.5) * (1 << _SHIFT), -_REACH << _SHIFT, (_REACH + max(shape)) << _SHIFT)
        cv2.fillPoly(region, [np.round(pixels).astype(np.int32)], 1, shift=_SHIFT)
    return region.view(bool)


def nearest_keyframes(keyframes: list[LiftedKeyframe], frame: int, each_side: int) -> list[LiftedKeyframe]:
    """The ``each_side`` keyframes nearest a frame before it and after it (fewer where there are
    fewer), in frame order."""
    before = [k for k in keyframes if k.frame <= frame][-each_side:] if each_side > 0 else []
    after = [k for k in keyframes if k.frame > frame][:each_side] if each_side > 0 else []
    return before + after

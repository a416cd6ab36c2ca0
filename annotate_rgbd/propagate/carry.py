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
the poses, and this module carries them to a frame (:func:`carried_layers`, pure).
"""

from __future__ import annotations

import numpy as np

from annotate_rgbd.config.settings import Config
from annotate_rgbd.geometry.lift import project_polygons
from .lift import LiftedKeyframe, TrackLift, rgb_view


def carried_layers(
    lift: TrackLift, frame: int, config: Config, pose: tuple[np.ndarray, np.ndarray]
) -> tuple[tuple[tuple[int, np.ndarray], ...], tuple[np.ndarray, ...]]:
    """What a track's lifted keyframes say about its plane on a frame it was not drawn on.

    Every keyframe outlines the part of the plane in view when it was drawn, and (with
    ``[propagate] exclude``) what touched the plane there and was left out. Projected with the
    frame's pose, they are layers for :func:`annotate_rgbd.segment.rasterize.paint_layers`,
    the farthest keyframe (in frames) first: where keyframes disagree about a pixel, the nearest
    one that saw it decides; a pixel no keyframe saw is the plane where any outline holds it.

    Parameters
    ----------
    lift : TrackLift
    frame : int
        The CVAT frame (of the track's part) the depth frame shows.
    config : Config
        For the camera.
    pose : (ndarray (3, 3), ndarray (3,))
        The depth frame's camera-to-world pose.

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
    signs, worlds = [], []
    for keyframe in sorted(nearest, key=lambda k: (-abs(k.frame - frame), k.frame)):
        for world in keyframe.excluded:
            signs.append(-1)
            worlds.append(world)
        signs.append(1)
        worlds.append(keyframe.world)
    quads = [quad for keyframe in nearest for quad in keyframe.beyond]
    camera, pose = rgb_view(config, pose)
    projected = project_polygons(worlds + quads, camera, *pose)
    usable = [len(polygon) >= 3 and np.isfinite(polygon).all() for polygon in projected]
    layers = [(sign, polygon) for sign, polygon, ok in zip(signs, projected, usable) if ok]
    beyond = [polygon for polygon, ok in zip(projected[len(worlds):], usable[len(worlds):]) if ok]
    return tuple(layers), tuple(beyond)


def nearest_keyframes(keyframes: list[LiftedKeyframe], frame: int, each_side: int) -> list[LiftedKeyframe]:
    """The ``each_side`` keyframes nearest a frame before it and after it (fewer where there are
    fewer), in frame order."""
    before = [k for k in keyframes if k.frame <= frame][-each_side:] if each_side > 0 else []
    after = [k for k in keyframes if k.frame > frame][:each_side] if each_side > 0 else []
    return before + after

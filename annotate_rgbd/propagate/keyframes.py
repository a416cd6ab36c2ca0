"""Keyframe planes fitted on their depth frames: the first step of pose-guided propagation.

Every keyframe shape of a track (the frames where it was drawn, :func:`keyframe_frames`) gets the
plane under it fitted, as refinement fits it (noise-aware), to the shape's depth on the depth
frame nearest the keyframe, in that depth frame's camera frame: no pose is needed yet
(:func:`fit_keyframes`; reading those depth frames is the only I/O of propagation). The fits
give the trajectory's time offset its samples (:func:`time_samples`,
:mod:`annotate_rgbd.propagate.timing`), then :mod:`annotate_rgbd.propagate.lift` takes them to
the world with the poses and :mod:`annotate_rgbd.propagate.carry` carries them to every frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from annotate_rgbd.annotation.model import Shape, Track
from annotate_rgbd.geometry.camera import backproject, depth_to_metres
from annotate_rgbd.config.settings import Config
from annotate_rgbd.errors import InputError
from annotate_rgbd.segment.rasterize import draw_on_depth_grid
from annotate_rgbd.segment.ransac import fit_plane
from annotate_rgbd.segment.refine import grid_pixels, spans_a_plane
from annotate_rgbd.io.sequence import read_depth
from annotate_rgbd.pool import HelperPool, run_jobs
from .evidence import excluded_regions, region_outlines
from .timing import KeyframeSample


def keyframe_frames(track: Track) -> list[int]:
    """The frames where a track's shape was drawn (CVAT's keyframes; every shape of an images
    export), in order."""
    if track.keyframes is None:
        return sorted(track.shapes)
    return sorted(f for f in track.keyframes if f in track.shapes)


def keyframe_planes(
    shapes: list[tuple[int, Shape]],
    wanted: list[int],
    depth_path: Path,
    config: Config,
) -> tuple[dict[int, tuple[np.ndarray, int] | str], tuple[int, int]]:
    """Fit the planes under the keyframe shapes of one frame, in its camera frame.

    The frame's shapes are drawn in ``z_order`` as refinement draws them, so that each plane is
    fitted to the pixels where its shape is on top (a floor drawn under a table is fitted to the
    floor, not to the table).

    Parameters
    ----------
    shapes : list of (int, Shape)
        Every shape of the frame, with a key, in track order.
    wanted : list of int
        The keys of the keyframe shapes to fit (polygons or boxes).
    depth_path : Path
        The depth frame nearest the keyframe.
    config : Config
        Camera, filter (``min_valid_pixels``), the noise-aware fit of refinement and
        ``[propagate]``: what a shape excluded reaches ``noise.cap`` off its plane (the widest
        band any frame's refinement uses: a surface that close is inside some frame's band).

    Returns
    -------
    planes : dict of int to ((ndarray (4,), int, list of ndarray, ndarray) or str)
        For each wanted key: the camera-frame plane, the number of valid depth pixels it was
        fitted to, the outlines (V, 2) of what the shape excluded
        (:func:`annotate_rgbd.propagate.evidence.excluded_regions`, with ``[propagate]
        exclude``) and the fit's inliers among its grid points (camera frame, m: at most about
        ``ransac.max_points``), or why there is none.
    size : (int, int)
        (width, height) of the keyframe image: the depth frame's, or the colour camera's.

    Raises
    ------
    InputError
        The depth frame is unreadable.
    """
    depth_m = depth_to_metres(read_depth(depth_path), config.camera.depth_scale)
    drawn, grid = draw_on_depth_grid(shapes, depth_m, config.camera, config.colour_camera)
    on_valid = np.where(np.isfinite(depth_m), drawn, 0)
    shape_of = dict(shapes)
    settings = config.propagate
    planes: dict[int, tuple[np.ndarray, int, list[np.ndarray]] | str] = {}
    for key in wanted:
        valid = int(np.count_nonzero(on_valid == key))
        if valid < config.filter.min_valid_pixels:
            planes[key] = f"too little valid depth where the shape is on top ({valid} pixels)"
            continue
        rows, cols = grid_pixels(on_valid, key, valid, config.ransac.max_points)
        band = config.inlier_band()
        points = backproject(cols, rows, depth_m[rows, cols], config.camera)
        fit = fit_plane(points, config.ransac, band) if spans_a_plane(rows, cols) else None
        if fit is None or not fit.inliers.any():  # one pixel row or column, or one line in space
            planes[key] = "no plane in the shape's depth (on one pixel row or column, or on one line in space)"
            continue
        on_plane = points[fit.inliers]
        excluded = []
        if settings.exclude:
            own, _ = draw_on_depth_grid([(1, shape_of[key])], depth_m, config.camera, config.colour_camera)
            own = own > 0
            region = excluded_regions(own, depth_m, fit.equation, config.camera, band.scaled(fit.noise_scale),
                                      band.cap, settings.exclude_margin)
            if grid is not None:  # outlines in colour image coordinates, like the shapes
                region = _on_colour_grid(region, grid, config.colour_camera.width, config.colour_camera.height)
            excluded = region_outlines(region, config.filter.min_valid_pixels, settings.outline_tolerance)
        planes[key] = (fit.equation, valid, excluded, on_plane)
    colour = config.colour_camera
    return planes, (depth_m.shape[1], depth_m.shape[0]) if colour is None else (colour.width, colour.height)


def _on_colour_grid(region: np.ndarray, grid: tuple[np.ndarray, np.ndarray], width: int, height: int) -> np.ndarray:
    """A depth-grid pixel set on the colour grid: the colour pixels the set's depth pixels land
    on (``grid``: each depth pixel's colour position, :func:`draw_on_depth_grid`'s)."""
    map_x, map_y = grid
    u = np.rint(map_x[region]).astype(np.int64)
    v = np.rint(map_y[region]).astype(np.int64)
    inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    out = np.zeros((height, width), dtype=bool)
    out[v[inside], u[inside]] = True
    return out


def outline_of(shape: Shape) -> np.ndarray | None:
    """A shape's outline as polygon vertices (a box's four corners); None for a mask."""
    if shape.kind == "mask":
        return None
    if shape.kind == "box":
        (x0, y0), (x1, y1) = shape.points
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)
    return shape.points


#: Why a keyframe on an RGB frame that no depth frame takes (each depth frame takes the RGB frame
#: nearest to it in time, within ``sequence.max_time_diff``; a neighbour may be nearer) is not lifted.
NO_DEPTH_FRAME = "no depth frame is matched to its RGB frame"


@dataclass
class FittedTrack:
    """A track's keyframe planes as their depth frames saw them (camera frames), before poses.

    Parameters
    ----------
    part : str
    track : Track
    plane : int
        Its global plane id.
    keyframes : list of (int, ndarray, int, (ndarray, int) or str)
        Per keyframe with an outline: its CVAT frame, the outline (V, 2) px, the depth frame
        nearest it (-1: none), and the camera-frame plane with the number of valid depth pixels
        it was fitted to and the outlines of what it excluded (:func:`keyframe_planes`), or why
        there is none.
    failed : list of (int, str)
        Keyframes that cannot be lifted whatever the poses (mask shapes).
    sizes : dict of int to (int, int)
        CVAT frame -> (width, height) of the image the keyframe's shapes are drawn on: the colour
        camera's (``[colour_camera]``), or else the keyframe's depth frame's.
    """

    part: str
    track: Track
    plane: int
    keyframes: list = field(default_factory=list)
    failed: list = field(default_factory=list)
    sizes: dict = field(default_factory=dict)


def fit_keyframes(
    parts: list[tuple[str, list[Track], list[int], dict[int, int]]],
    depth_of_rgb: dict[int, int],
    depth_files: list[Path],
    config: Config,
    helpers: HelperPool | None = None,
) -> list[FittedTrack]:
    """Fit the plane under every keyframe shape on its depth frame (reads those depth frames).

    Parameters
    ----------
    parts : list of (str, list of Track, list of int, dict of int to int)
        Each annotation part: its name, its tracks in export order, their global plane ids and
        its CVAT frame -> RGB index map (the frames of the sequence: a keyframe on a frame
        without an RGB index is none of the sequence's, neither fitted nor failed).
    depth_of_rgb : dict of int to int
        RGB index -> the depth frame that shows it.
    depth_files : list of Path
        The sequence's depth files, in depth order.
    config : Config
    helpers : HelperPool, optional
        Helper processes that fit keyframe frames too (:func:`annotate_rgbd.pool.run_jobs`);
        None: this process fits them all. The fits are the same either way.

    Returns
    -------
    list of FittedTrack
        Part by part, in track order; a track drawn on every frame of its life (nothing to carry
        anywhere) has no keyframes.
    """
    # First what to fit (one job per keyframe frame), then the fits (in the helper processes
    # too, when given), then each track's keyframes in frame order, as fitting frame by frame.
    fitted_tracks: list[FittedTrack] = []
    frames = []  # (the part's tracks, frame, depth index, its job or None, [(track, outline, why not)])
    jobs = []
    for part, tracks, plane_ids, rgb_of_frame in parts:
        part_tracks = [FittedTrack(part, track, plane) for track, plane in zip(tracks, plane_ids)]
        fitted_tracks += part_tracks
        keyframes_at: dict[int, list[int]] = {}
        for i, track in enumerate(tracks):
            drawn = keyframe_frames(track)
            if len(drawn) == len(track.shapes):
                continue  # drawn on every frame of its life: nothing to carry
            for frame in drawn:
                keyframes_at.setdefault(frame, []).append(i)
        for frame in sorted(keyframes_at):
            rgb = rgb_of_frame.get(frame)
            if rgb is None:
                continue  # not a frame of the sequence (said once when the part was placed): no keyframe of it
            depth = depth_of_rgb.get(rgb, -1)
            keyframe_shapes = []
            for i in keyframes_at[frame]:
                outline = outline_of(tracks[i].shapes[frame])
                why = ("mask shapes are not propagated" if outline is None
                       else NO_DEPTH_FRAME if depth < 0 else None)
                keyframe_shapes.append((i, outline, why))
            wanted = [i + 1 for i, _, why in keyframe_shapes if why is None]
            job = None
            if wanted:
                job = len(jobs)
                shapes = [(i + 1, t.shapes[frame]) for i, t in enumerate(tracks) if frame in t.shapes]
                jobs.append((shapes, wanted, depth_files[depth], config))
            frames.append((part_tracks, frame, depth, job, keyframe_shapes))
    fits: list = [None] * len(jobs)
    for outcome in run_jobs(jobs, keyframe_job, helpers):
        fits[outcome.index] = outcome.value if outcome.error is None else outcome.error
    for part_tracks, frame, depth, job, keyframe_shapes in frames:
        fit = fits[job] if job is not None else ({}, None)
        if isinstance(fit, InputError):
            fit = ({i + 1: f"unreadable depth ({fit.message})" for i, _, why in keyframe_shapes if why is None}, None)
        planes, size = fit
        for i, outline, why in keyframe_shapes:
            if outline is None:
                part_tracks[i].failed.append((frame, why))
                continue
            part_tracks[i].keyframes.append((frame, outline, depth, why or planes[i + 1]))
            if size is not None:  # fitted (a frame without depth has no fit, so no size)
                part_tracks[i].sizes[frame] = size
    return fitted_tracks


def keyframe_job(job: tuple) -> tuple[dict, tuple[int, int]]:
    """:func:`keyframe_planes` of one job ``(shapes, wanted, depth_path, config)``: the function
    :func:`fit_keyframes` gives :func:`annotate_rgbd.pool.run_jobs`."""
    return keyframe_planes(*job)


def keyframe_depths(fitted: list[FittedTrack]) -> list[int]:
    """The depth frames of every track's fitted keyframes (those with a plane), in order."""
    return sorted({depth for track in fitted for _, _, depth, result in track.keyframes
                   if depth >= 0 and not isinstance(result, str)})


def time_samples(fitted: list[FittedTrack], depth_timestamps: np.ndarray, config: Config) -> list[KeyframeSample]:
    """Every fitted keyframe as a :class:`~annotate_rgbd.propagate.timing.KeyframeSample`: its
    plane and points of it where the depth supports it, in its camera frame (one group per
    track)."""
    samples = []
    for group, track in enumerate(fitted):
        for frame, outline, depth, result in track.keyframes:
            if isinstance(result, str):
                continue
            if len(result[3]) >= 3:
                samples.append(KeyframeSample(group, float(depth_timestamps[depth]), result[3], result[0]))
    return samples

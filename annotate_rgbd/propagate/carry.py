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
(:func:`rgb_view`), so that carried shapes stay in colour image coordinates like drawn ones.

Reading depth for the fits is the only I/O here (:func:`lift_tracks`); projecting is pure
(:func:`carried_layers`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from annotate_rgbd.annotation.model import Shape, Track
from annotate_rgbd.geometry.camera import Camera, backproject, depth_to_metres
from annotate_rgbd.config.settings import Config, PropagateConfig
from annotate_rgbd.errors import InputError
from annotate_rgbd.geometry.lift import lift_polygon, plane_agreement, plane_to_camera, plane_to_world, project_polygons
from annotate_rgbd.geometry.registration import colour_pose
from annotate_rgbd.io.poses import FramePoses
from annotate_rgbd.segment.rasterize import draw_on_depth_grid
from annotate_rgbd.segment.ransac import fit_plane
from annotate_rgbd.segment.refine import grid_pixels
from annotate_rgbd.io.sequence import read_depth
from .evidence import excluded_regions, region_outlines
from .timing import KeyframeSample

@dataclass(frozen=True)
class LiftedKeyframe:
    """One keyframe shape lifted onto its plane.

    Parameters
    ----------
    frame : int
        The keyframe's CVAT frame (of its part).
    world : ndarray of float64, shape (V, 3)
        The outline in world coordinates (m).
    plane : ndarray of float64, shape (4,)
        The fitted plane in world coordinates.
    z_order : int
        The shape's drawing order.
    beyond : tuple of ndarray, shape (4, 3)
        World quads that carry the outline past the keyframe image's border, where it was cut by
        the edge of the view rather than by the plane's end (:func:`beyond_the_border`).
    excluded : tuple of ndarray, shape (V, 3)
        World outlines of what the keyframe's labeller saw touching the plane and left out
        (:mod:`annotate_rgbd.propagate.evidence`).
    """

    frame: int
    world: np.ndarray
    plane: np.ndarray
    z_order: int
    beyond: tuple = ()
    excluded: tuple = ()


@dataclass
class TrackLift:
    """A track's keyframes lifted onto their planes.

    Parameters
    ----------
    part : str
        The annotation part's file name.
    track : int
        The CVAT track id.
    plane : int
        Its global plane id.
    keyframes : list of LiftedKeyframe
        In frame order.
    failed : list of (int, str)
        Keyframes that could not be lifted: CVAT frame and why.
    off_plane : list of int
        Keyframes whose own plane disagreed with the track's consensus plane (lifted onto the
        consensus plane instead).
    substantial : list of int
        Those of them that hold a good share of the track's depth (``propagate.min_keyframe_weight``):
        the track needs review.
    angle, offset : float
        The largest disagreement of those with the consensus plane (degrees, metres).
    """

    part: str
    track: int
    plane: int
    keyframes: list[LiftedKeyframe] = field(default_factory=list)
    failed: list[tuple[int, str]] = field(default_factory=list)
    off_plane: list[int] = field(default_factory=list)
    substantial: list[int] = field(default_factory=list)
    angle: float = 0.0
    offset: float = 0.0

    @property
    def consistent(self) -> bool:
        """Whether every substantial keyframe's own plane agrees with the track's consensus plane
        (within ``propagate.same_surface_angle`` and ``same_surface_offset``)."""
        return not self.substantial

    def to_json(self) -> dict:
        """The report's entry for the track."""
        return {
            "part": self.part,
            "track": self.track,
            "plane": self.plane,
            "keyframes_lifted": [k.frame for k in self.keyframes],
            "keyframes_failed": [{"frame": frame, "reason": reason} for frame, reason in self.failed],
            "keyframes_off_plane": self.off_plane,
            "keyframes_in_conflict": self.substantial,
            "angle_deg": round(self.angle, 3),
            "offset_m": round(self.offset, 4),
            "consistent": self.consistent,
        }


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
        fit = fit_plane(points, config.ransac, band)
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


def rgb_view(config: Config, pose: tuple[np.ndarray, np.ndarray]) -> tuple[Camera, tuple[np.ndarray, np.ndarray]]:
    """The camera the labeller's shapes are drawn in, and its pose, for a depth camera pose.

    Parameters
    ----------
    config : Config
    pose : (ndarray (3, 3), ndarray (3,))
        The depth camera's camera-to-world pose.

    Returns
    -------
    camera : Camera
        ``config.camera`` when colour and depth are registered, else the colour intrinsics.
    pose : (ndarray (3, 3), ndarray (3,))
        The colour camera's camera-to-world pose (:func:`annotate_rgbd.geometry.registration.colour_pose`).
    """
    colour = config.colour_camera
    if colour is None:
        return config.camera, pose
    return colour.intrinsics, colour_pose(*pose, colour)


def outline_of(shape: Shape) -> np.ndarray | None:
    """A shape's outline as polygon vertices (a box's four corners); None for a mask."""
    if shape.kind == "mask":
        return None
    if shape.kind == "box":
        (x0, y0), (x1, y1) = shape.points
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)
    return shape.points


def consensus_plane(
    planes: list[np.ndarray], outlines: list[np.ndarray], weights: list[float] | None = None,
    propagate: PropagateConfig = PropagateConfig(),
) -> tuple[np.ndarray, list[bool]]:
    """The plane most of a track's keyframes agree on, and which of them agree with it.

    Each fitted plane is a candidate; it is supported by the keyframes whose plane lies within
    ``propagate.same_surface_angle`` and ``same_surface_offset`` of it (offset
    measured at that keyframe's outline centroid), each with its weight; the best supported wins
    (ties: the earliest).

    Parameters
    ----------
    planes : list of ndarray, shape (4,)
        World planes, one per keyframe.
    outlines : list of ndarray, shape (V, 3)
        The keyframes' outlines lifted onto their own planes (for the centroids).
    weights : list of float, optional
        How much each keyframe counts (the valid depth pixels it was fitted to); default 1 each.
    propagate : PropagateConfig
        The same-surface tolerances.

    Returns
    -------
    plane : ndarray, shape (4,)
    agree : list of bool
    """
    centroids = np.array([outline.mean(axis=0) for outline in outlines])
    stacked = np.array(planes, dtype=np.float64)
    support = []
    for candidate in planes:
        angle, offset = plane_agreement(candidate, stacked, at=centroids)
        support.append([bool(ok) for ok in (angle <= propagate.same_surface_angle) & (offset <= propagate.same_surface_offset)])
    weights = [1.0] * len(planes) if weights is None else weights
    best = max(range(len(planes)), key=lambda i: (sum(w for w, ok in zip(weights, support[i]) if ok), -i))
    return planes[best], support[best]


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


def beyond_the_border(
    outline: np.ndarray, image_size: tuple[int, int], margin: float = PropagateConfig.border_margin,
    reach: float = PropagateConfig.beyond_reach,
) -> list[np.ndarray]:
    """Quads that extend an outline's edges lying on the image border outward, off the image.

    Parameters
    ----------
    outline : ndarray, shape (V, 2)
        Polygon in CVAT image coordinates.
    image_size : (int, int)
        (width, height) of the keyframe image.
    margin : float
        Vertices this close to the image's edge (px) lie on it (``propagate.border_margin``).
    reach : float
        How far past the border an outline is carried, as a share of the image's size
        (``propagate.beyond_reach``).

    Returns
    -------
    list of ndarray, shape (4, 2)
        For every edge whose two ends lie within ``margin`` of the same image side: the edge
        and its copy moved ``reach`` of the image's size straight out.
    """
    width, height = image_size
    outline = np.asarray(outline, dtype=np.float64)
    following = np.roll(outline, -1, axis=0)
    sides = (
        (lambda p: p[:, 0] <= margin, (-reach * width, 0.0)),
        (lambda p: p[:, 0] >= width - margin, (reach * width, 0.0)),
        (lambda p: p[:, 1] <= margin, (0.0, -reach * height)),
        (lambda p: p[:, 1] >= height - margin, (0.0, reach * height)),
    )
    quads = []
    for on_side, out in sides:
        along = on_side(outline) & on_side(following)
        for start, end in zip(outline[along], following[along]):
            if np.hypot(*(end - start)) >= 1.0:
                quads.append(np.array([start, end, end + out, start + out]))
    return quads


def _lift_beyond(outline: np.ndarray, image_size, plane_camera: np.ndarray, pose, config: Config) -> tuple:
    """:func:`beyond_the_border` lifted onto the plane: each quad shortened (halved, a few times)
    until its far corners meet the plane in front of the camera within the distance rule."""
    farthest = 1.5 * config.filter.max_mean_distance
    lifted = []
    camera = rgb_view(config, pose)[0]
    settings = config.propagate
    for quad in beyond_the_border(outline, image_size, settings.border_margin, settings.beyond_reach):
        for _ in range(4):
            world = lift_polygon(quad, plane_camera, camera, *pose)
            depth = (world.world - pose[1]) @ pose[0][:, 2] if world.ok else None
            if world.ok and (depth <= farthest).all():
                lifted.append(world.world)
                break
            quad = np.array([quad[0], quad[1], (quad[1] + quad[2]) / 2, (quad[0] + quad[3]) / 2])
    return tuple(lifted)


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
        CVAT frame -> (width, height) of the keyframe's depth frame.
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
) -> list[FittedTrack]:
    """Fit the plane under every keyframe shape on its depth frame (reads those depth frames).

    Parameters
    ----------
    parts : list of (str, list of Track, list of int, dict of int to int)
        Each annotation part: its name, its tracks in export order, their global plane ids and
        its CVAT frame -> RGB index map.
    depth_of_rgb : dict of int to int
        RGB index -> the depth frame that shows it.
    depth_files : list of Path
        The sequence's depth files, in depth order.
    config : Config

    Returns
    -------
    list of FittedTrack
        Part by part, in track order; a track drawn on every frame of its life (nothing to carry
        anywhere) has no keyframes.
    """
    fitted_tracks = []
    for part, tracks, plane_ids, rgb_of_frame in parts:
        part_tracks = [FittedTrack(part, track, plane) for track, plane in zip(tracks, plane_ids)]
        keyframes_at: dict[int, list[int]] = {}
        for i, track in enumerate(tracks):
            drawn = keyframe_frames(track)
            if len(drawn) == len(track.shapes):
                continue  # drawn on every frame of its life: nothing to carry
            for frame in drawn:
                keyframes_at.setdefault(frame, []).append(i)
        for frame in sorted(keyframes_at):
            wanted = []
            rgb = rgb_of_frame.get(frame)
            depth = depth_of_rgb.get(rgb, -1) if rgb is not None else -1
            for i in keyframes_at[frame]:
                outline = outline_of(tracks[i].shapes[frame])
                if outline is None:
                    part_tracks[i].failed.append((frame, "mask shapes are not propagated"))
                elif depth < 0:
                    part_tracks[i].keyframes.append((frame, outline, depth, "no depth frame near the keyframe"))
                else:
                    wanted.append(i)
            if not wanted:
                continue
            shapes = [(i + 1, t.shapes[frame]) for i, t in enumerate(tracks) if frame in t.shapes]
            try:
                planes, size = keyframe_planes(shapes, [i + 1 for i in wanted], depth_files[depth], config)
            except InputError as exc:
                planes, size = {i + 1: f"unreadable depth ({exc.message})" for i in wanted}, None
            for i in wanted:
                part_tracks[i].keyframes.append((frame, outline_of(tracks[i].shapes[frame]), depth, planes[i + 1]))
                if size is not None:
                    part_tracks[i].sizes[frame] = size
        fitted_tracks += part_tracks
    return fitted_tracks


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


def lift_tracks(fitted: list[FittedTrack], depth_poses: FramePoses, config: Config) -> list[TrackLift]:
    """Lift the fitted keyframes of every track onto their planes, in world coordinates.

    Each keyframe's plane (:func:`fit_keyframes`) is taken to the world and its outline lifted
    onto it with the pose of the depth frame it was fitted on: on its own keyframe a shape is
    used as drawn on that depth frame (:mod:`annotate_rgbd.pipeline.plan`), so it is that frame's
    view the outline stands for. A plane is rigid and static, so a keyframe whose plane
    disagrees with the one the track's keyframes agree on (:func:`consensus_plane`, weighted
    by their depth pixels: the shape lay mostly over clutter or another surface) is lifted onto
    that consensus plane instead, and listed; the track is flagged (``consistent`` False) when
    such a keyframe holds a good share of the track's depth (``propagate.min_keyframe_weight``).

    Parameters
    ----------
    fitted : list of FittedTrack
    depth_poses : FramePoses
        The pose of every depth frame.
    config : Config

    Returns
    -------
    list of TrackLift
        In the order of ``fitted``.
    """
    lifts = []
    for track in fitted:
        lift = TrackLift(track.part, track.track.track_id, track.plane, failed=list(track.failed))
        posed = []
        for frame, outline, depth, result in track.keyframes:
            if depth < 0 or not depth_poses.ok[depth]:
                why = result if depth < 0 else f"no pose ({depth_poses.reasons[depth]})"
                lift.failed.append((frame, why))
                continue
            pose = (depth_poses.rotations[depth], depth_poses.translations[depth])
            if not isinstance(result, str):
                result = (plane_to_world(result[0], *pose), *result[1:])
            posed.append((frame, outline, rgb_view(config, pose)[1], result))
        _lift_onto_planes(lift, track.track, posed, config, track.sizes)
        lift.failed.sort()
        lifts.append(lift)
    return lifts


def _lift_onto_planes(lift: TrackLift, track: Track, fitted: list, config: Config, sizes: dict) -> None:
    """Lift a track's fitted keyframes onto their own plane, or the track's consensus plane
    (``sizes``: CVAT frame -> (width, height) of the keyframe image, to carry outlines past it)."""
    camera = rgb_view(config, (np.eye(3), np.zeros(3)))[0]  # the camera the outlines were drawn in
    own = [(frame, outline, pose, result) for frame, outline, pose, result in fitted if not isinstance(result, str)]
    lifted_own = [lift_polygon(o, plane_to_camera(r[0], *p), camera, *p) for _, o, p, r in own]
    usable = [(entry, lifted) for entry, lifted in zip(own, lifted_own) if lifted.ok]
    consensus, agree = None, []
    if usable:
        consensus, agree = consensus_plane([e[3][0] for e, _ in usable], [lifted.world for _, lifted in usable],
                                           [e[3][1] for e, _ in usable], config.propagate)
    agrees = {e[0]: ok for (e, _), ok in zip(usable, agree)}
    weight = {frame: result[1] for frame, _, _, result in own}
    largest = max(weight.values(), default=0)
    for frame, outline, pose, result in fitted:
        plane = None if isinstance(result, str) else result[0]
        target = plane if plane is not None and agrees.get(frame, False) else consensus
        if target is None:
            lift.failed.append((frame, result if isinstance(result, str) else "the outline cannot be lifted onto its plane"))
            continue
        lifted = lift_polygon(outline, plane_to_camera(target, *pose), camera, *pose)
        if not lifted.ok:
            lift.failed.append((frame, f"the outline cannot be lifted onto its plane ({lifted.reason})"))
            continue
        beyond = _lift_beyond(outline, sizes[frame], plane_to_camera(target, *pose), pose, config) if frame in sizes else ()
        excluded = ()
        if target is plane:  # what the outline left out, judged against its own plane
            found = [lift_polygon(o, plane_to_camera(target, *pose), camera, *pose) for o in result[2]]
            excluded = tuple(f.world for f in found if f.ok)
        lift.keyframes.append(LiftedKeyframe(frame, lifted.world, target, track.shapes[frame].z_order, beyond,
                                             excluded))
        if plane is not None and target is consensus and not agrees.get(frame, False):
            lift.off_plane.append(frame)
            if weight[frame] >= config.propagate.min_keyframe_weight * largest:
                angle, offset = plane_agreement(consensus, plane, at=lifted.world.mean(axis=0))
                lift.angle, lift.offset = max(lift.angle, angle), max(lift.offset, offset)
                lift.substantial.append(frame)
    lift.keyframes.sort(key=lambda k: k.frame)

"""Keyframes lifted onto their planes in world coordinates, with the camera poses.

Each keyframe plane fitted on its depth frame (:mod:`annotate_rgbd.propagate.keyframes`) is taken
to world coordinates with that depth frame's pose, and the outline's vertex rays from the RGB
camera at the keyframe's own time are intersected with it: a 3-D polygon (:func:`lift_tracks`).
The lifted planes of one track must agree: a keyframe off the plane the others agree on
(:func:`consensus_plane`) is lifted onto that plane instead, and a track whose keyframes
disagree (two surfaces under one track, or wrong poses) is listed for review. Where an outline
was cut by the image's border rather than by the plane's end, quads carry it past the border
(:func:`beyond_the_border`). With a colour camera of its own, outlines are lifted with the
colour camera's intrinsics and pose (:func:`rgb_view`). Pure: no file is read.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from annotate_rgbd.annotation.model import Track
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.config.settings import Config, PropagateConfig
from annotate_rgbd.geometry.lift import lift_polygon, plane_agreement, plane_to_camera, plane_to_world
from annotate_rgbd.geometry.registration import colour_pose
from annotate_rgbd.io.poses import FramePoses
from .keyframes import FittedTrack


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
    view : (ndarray (3, 3), ndarray (3,), (int, int)), optional
        The camera-to-world pose of the camera the shape was drawn in and the keyframe image's
        (width, height) (the colour camera's, or the keyframe's depth frame's): what part of the
        plane the labeller could see. None where that size is not known (the keyframe's depth
        frame could not be read, and its shape was lifted onto the plane the track's other
        keyframes agree on).
    """

    frame: int
    world: np.ndarray
    plane: np.ndarray
    z_order: int
    beyond: tuple = ()
    excluded: tuple = ()
    view: tuple | None = None


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


def lift_tracks(fitted: list[FittedTrack], depth_poses: FramePoses, config: Config) -> list[TrackLift]:
    """Lift the fitted keyframes of every track onto their planes, in world coordinates.

    Each keyframe's plane (:func:`annotate_rgbd.propagate.keyframes.fit_keyframes`) is taken to the world and its outline lifted
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
        view = (pose[0], pose[1], tuple(sizes[frame])) if frame in sizes else None
        lift.keyframes.append(LiftedKeyframe(frame, lifted.world, target, track.shapes[frame].z_order, beyond,
                                             excluded, view))
        if plane is not None and target is consensus and not agrees.get(frame, False):
            lift.off_plane.append(frame)
            if weight[frame] >= config.propagate.min_keyframe_weight * largest:
                angle, offset = plane_agreement(consensus, plane, at=lifted.world.mean(axis=0))
                lift.angle, lift.offset = max(lift.angle, angle), max(lift.offset, offset)
                lift.substantial.append(frame)
    lift.keyframes.sort(key=lambda k: k.frame)

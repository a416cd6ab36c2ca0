"""Pose-guided propagation: a plane drawn on a few keyframes, carried to every frame by the poses.

With camera poses (``--poses``, a TUM trajectory), each keyframe shape of a track is **lifted**
onto its plane: the plane is fitted (as refinement fits it, noise-aware) to the shape's depth
on the depth frame nearest the keyframe, taken to world coordinates with that depth frame's
pose, and the outline's vertex rays from the RGB camera at the keyframe's own time are
intersected with it: a 3-D polygon. On every depth frame of the track's life (CVAT semantics:
the frames where the track is visible) the lifted polygons of the neighbouring keyframes (the
last one at or before the frame and the first one after it) are projected with the depth
frame's own pose and drawn in place of the 2-D interpolation; refinement then keeps only the
pixels whose depth lies on the plane in that frame, so occluders (nearer than the plane) fall
out. The lifted planes of one track must agree: a track whose keyframes disagree (two surfaces
under one track, or wrong poses) is listed for review.

Reading depth for the fits is the only I/O here (:func:`lift_tracks`); projecting is pure
(:func:`propagated_shapes`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .annotation import Shape, Track
from .camera import backproject, depth_to_metres
from .config import Config
from .errors import InputError
from .lift import lift_polygon, plane_agreement, plane_to_camera, plane_to_world, project_polygon
from .poses import FramePoses
from .rasterize import rasterize_frame
from .refine import fit_plane
from .sequence import read_depth

#: Largest angle (degrees) and offset (m, at the keyframes' centroid) between the planes lifted
#: from two keyframes of one track for them to be one surface. Real poses reproject depth with
#: errors of 0.4-2 cm over tens of frames (7-Scenes, TUM fr1_rpy), and a plane fitted to a few
#: thousand pixels has an orientation error of a fraction of a degree: 5 degrees and 5 cm are
#: well above both and well below two surfaces a labeller might confuse (a table top and the
#: floor: 0.7 m; a wall and the door in it: a few cm, flagged when the poses are good).
MAX_KEYFRAME_ANGLE = 5.0
MAX_KEYFRAME_OFFSET = 0.05


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
    """

    frame: int
    world: np.ndarray
    plane: np.ndarray
    z_order: int


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
    angle, offset : float
        The largest disagreement between two of its lifted planes (degrees, metres); 0 with
        fewer than two.
    """

    part: str
    track: int
    plane: int
    keyframes: list[LiftedKeyframe] = field(default_factory=list)
    failed: list[tuple[int, str]] = field(default_factory=list)
    angle: float = 0.0
    offset: float = 0.0

    @property
    def consistent(self) -> bool:
        """Whether all lifted planes agree within :data:`MAX_KEYFRAME_ANGLE` and :data:`MAX_KEYFRAME_OFFSET`."""
        return self.angle <= MAX_KEYFRAME_ANGLE and self.offset <= MAX_KEYFRAME_OFFSET

    def to_json(self) -> dict:
        """The report's entry for the track."""
        return {
            "part": self.part,
            "track": self.track,
            "plane": self.plane,
            "keyframes_lifted": [k.frame for k in self.keyframes],
            "keyframes_failed": [{"frame": frame, "reason": reason} for frame, reason in self.failed],
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


def lift_keyframe(
    shape: Shape,
    depth_path: Path,
    depth_pose: tuple[np.ndarray, np.ndarray],
    rgb_pose: tuple[np.ndarray, np.ndarray],
    config: Config,
) -> tuple[np.ndarray, np.ndarray] | str:
    """Fit the plane under one keyframe shape and lift its outline.

    Parameters
    ----------
    shape : Shape
        A polygon or box (masks cannot be lifted).
    depth_path : Path
        The depth frame nearest the keyframe.
    depth_pose, rgb_pose : (ndarray (3, 3), ndarray (3,))
        Camera-to-world poses of that depth frame and of the keyframe's RGB frame.
    config : Config
        Camera, filter (``min_valid_pixels``) and the noise-aware fit of refinement.

    Returns
    -------
    (ndarray (V, 3), ndarray (4,)) or str
        The world outline and world plane, or why the keyframe cannot be lifted.

    Raises
    ------
    InputError
        The depth frame is unreadable.
    """
    if shape.kind == "mask":
        return "mask shapes are not propagated"
    outline = shape.points
    if shape.kind == "box":
        (x0, y0), (x1, y1) = shape.points
        outline = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)
    depth_raw = read_depth(depth_path)
    depth_m = depth_to_metres(depth_raw, config.camera.depth_scale)
    drawn = rasterize_frame([(1, shape)], *depth_m.shape)
    rows, cols = np.nonzero((drawn == 1) & np.isfinite(depth_m))
    if rows.size < config.filter.min_valid_pixels:
        return f"too little valid depth under the shape ({rows.size} pixels)"
    step = max(1, int(np.ceil(np.sqrt(rows.size / config.ransac.max_points)))) if config.ransac.max_points else 1
    pick = (rows % step == 0) & (cols % step == 0)
    if np.count_nonzero(pick) >= 3:
        rows, cols = rows[pick], cols[pick]
    fit = fit_plane(backproject(cols, rows, depth_m[rows, cols], config.camera), config.ransac, config.inlier_band())
    plane = plane_to_world(fit.equation, *depth_pose)
    lifted = lift_polygon(outline, plane_to_camera(plane, *rgb_pose), config.camera, *rgb_pose)
    if not lifted.ok:
        return f"the outline cannot be lifted onto its plane ({lifted.reason})"
    return lifted.world, plane


def check_agreement(lift: TrackLift) -> None:
    """Set ``lift.angle`` and ``lift.offset``: the worst disagreement of its lifted planes with
    the first one, measured at the centroid of the keyframes' outlines."""
    if len(lift.keyframes) < 2:
        return
    centroid = np.mean([k.world.mean(axis=0) for k in lift.keyframes], axis=0)
    first = lift.keyframes[0].plane
    worst = [plane_agreement(first, k.plane, at=centroid) for k in lift.keyframes[1:]]
    lift.angle = max(a for a, _ in worst)
    lift.offset = max(o for _, o in worst)


def propagated_shapes(lift: TrackLift, frame: int, config: Config, pose: tuple[np.ndarray, np.ndarray]) -> list[Shape]:
    """The shapes a track gets on one frame from its neighbouring lifted keyframes.

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
    list of Shape
        One or two polygons (the keyframes at or before and after ``frame``), drawn as one
        plane; empty when neither projects into the image.
    """
    before = [k for k in lift.keyframes if k.frame <= frame]
    after = [k for k in lift.keyframes if k.frame > frame]
    shapes = []
    for keyframe in ([before[-1]] if before else []) + ([after[0]] if after else []):
        polygon = project_polygon(keyframe.world, config.camera, *pose)
        if len(polygon) >= 3 and np.isfinite(polygon).all():
            shapes.append(Shape("polygon", polygon, z_order=keyframe.z_order))
    return shapes


def lift_tracks(
    tracks: list[tuple[str, Track, int, dict[int, int]]],
    depth_of_rgb: dict[int, int],
    depth_files: list[Path],
    depth_poses: FramePoses,
    rgb_poses: FramePoses,
    config: Config,
) -> list[TrackLift]:
    """Lift the keyframes of every track (reads the depth frames nearest the keyframes).

    Parameters
    ----------
    tracks : list of (str, Track, int, dict of int to int)
        Each track with its part's name, its global plane id and its part's CVAT frame -> RGB
        index map.
    depth_of_rgb : dict of int to int
        RGB index -> the depth frame that shows it.
    depth_files : list of Path
        The sequence's depth files, in depth order.
    depth_poses, rgb_poses : FramePoses
        The poses of every depth and every RGB frame.
    config : Config

    Returns
    -------
    list of TrackLift
        In the order of ``tracks``.
    """
    lifts = []
    for part, track, plane, rgb_of_frame in tracks:
        lift = TrackLift(part, track.track_id, plane)
        for frame in keyframe_frames(track):
            rgb = rgb_of_frame.get(frame)
            depth = depth_of_rgb.get(rgb) if rgb is not None else None
            if depth is None:
                lift.failed.append((frame, "no depth frame near the keyframe"))
                continue
            if not depth_poses.ok[depth]:
                lift.failed.append((frame, f"no pose for its depth frame ({depth_poses.reasons[depth]})"))
                continue
            depth_pose = (depth_poses.rotations[depth], depth_poses.translations[depth])
            rgb_pose = (rgb_poses.rotations[rgb], rgb_poses.translations[rgb]) if rgb_poses.ok[rgb] else depth_pose
            try:
                result = lift_keyframe(track.shapes[frame], depth_files[depth], depth_pose, rgb_pose, config)
            except InputError as exc:
                result = f"unreadable depth ({exc.message})"
            if isinstance(result, str):
                lift.failed.append((frame, result))
            else:
                lift.keyframes.append(LiftedKeyframe(frame, result[0], result[1], track.shapes[frame].z_order))
        check_agreement(lift)
        lifts.append(lift)
    return lifts

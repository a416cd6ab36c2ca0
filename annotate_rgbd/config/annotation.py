"""The sections about the input: how depth frames meet RGB frames and poses (``[sequence]``),
which CVAT shapes are planes (``[annotation]``), and how the tracks of annotation parts become one
plane each (``[stitch]``, ``[[parts]]``, ``[[matches]]``)."""

from __future__ import annotations

from dataclasses import dataclass

from annotate_rgbd.io.poses import DEFAULT_MAX_POSE_GAP


@dataclass(frozen=True)
class SequenceConfig:
    """How depth frames are matched to RGB frames.

    Parameters
    ----------
    max_time_diff : float
        Largest |t_depth - t_rgb| in seconds for a depth frame to use an RGB frame's
        annotation. 0.02 s is the default of TUM RGB-D's ``associate.py``.
    poses : str
        A camera trajectory in TUM format (``timestamp tx ty tz qx qy qz qw``, camera to world):
        keyframe shapes are then carried to every frame by the poses
        (:mod:`annotate_rgbd.propagate.carry`). Relative to the configuration file's folder. Empty:
        no poses (shapes between keyframes are interpolated in 2-D, as CVAT does).
    max_pose_gap : float
        A frame gets a pose only when trajectory samples on both sides lie within this many
        seconds (:data:`annotate_rgbd.io.poses.DEFAULT_MAX_POSE_GAP`: TUM's motion capture runs at
        100 Hz and has drop-outs).
    """

    max_time_diff: float = 0.02
    poses: str = ""
    max_pose_gap: float = DEFAULT_MAX_POSE_GAP


@dataclass(frozen=True)
class AnnotationConfig:
    """Which CVAT shapes become planes.

    Parameters
    ----------
    labels : tuple of str
        CVAT labels to use; empty means every label.
    """

    labels: tuple[str, ...] = ()


@dataclass(frozen=True)
class StitchConfig:
    """How tracks of consecutive annotation parts are matched into one plane.

    Parameters
    ----------
    min_iou : float
        Smallest IoU of two tracks' depth-refined masks on the frames the parts share (or on the
        last frame of one part and the first of the next) for them to be the same plane. 0.5 is
        the usual threshold for "the same object" (PASCAL VOC) and the one CVAT uses to merge
        overlapping job segments.
    """

    min_iou: float = 0.5


@dataclass(frozen=True)
class PartConfig:
    """Where one annotation part starts in the RGB sequence (``[[parts]]`` in a config file).

    Parameters
    ----------
    file : str
        The export's file name (as given on the command line, or its base name).
    offset : int
        RGB index of the part's frame 0.
    """

    file: str
    offset: int


@dataclass(frozen=True)
class MatchConfig:
    """A manual correction of the automatic track matching (``[[matches]]`` in a config file).

    Exactly one of ``plane``, ``with_part`` + ``with_track`` or ``new`` is given.

    Parameters
    ----------
    part : str
        File name of the part the track is in.
    track : int
        The CVAT track id in that part.
    plane : int, optional
        Pin the track to this global plane id (a plane that an earlier part introduced).
    with_part, with_track : str and int, optional
        The track is the same plane as this track of another part.
    new : bool
        The track is a new plane, whatever the automatic matching says.
    """

    part: str
    track: int
    plane: int | None = None
    with_part: str | None = None
    with_track: int | None = None
    new: bool = False

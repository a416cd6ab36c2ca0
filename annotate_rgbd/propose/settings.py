"""Every tunable of ``propose`` beyond the detector's, with its default and the reason for it.

The detector's own settings, among them the smallest plane proposed
(``DetectorConfig.min_area_fraction``, 1 % of the image), live in
:class:`annotate_rgbd.detect.DetectorConfig`; the drop rules (invalid depth, distance) are the
``[filter]`` section of the run's configuration, as for ``cvat2mask``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from annotate_rgbd.detect import DetectorConfig

#: CVAT label of the proposed tracks.
DEFAULT_LABEL = "plane"


@dataclass(frozen=True)
class LinkConfig:
    """How detections on successive processed frames are linked into tracks.

    Two detections can be one plane when their planes agree within the noise band (plus what
    the camera may have moved between the two frames, when no poses are given) and their
    masks overlap; among those, an optimal one-to-one assignment maximises the overlap.

    Parameters
    ----------
    min_iou : float
        Smallest IoU of the two masks (without poses: after the 2-D shift that overlaps them
        best among those the camera motion limits below allow; with poses: the earlier outline
        reprojected into the later frame). 0.3: a plane seen at 30 Hz overlaps itself on the
        next frame with IoU > 0.8, at every 10th frame of TUM fr1 still > 0.5; two different
        planes that touch overlap by a few boundary pixels only. Without the shift, a narrow
        plane (a cabinet side seen at a grazing angle) falls below 0.3 across a missed frame
        while the camera pans.
    angle_deg : float
        Largest angle between the two planes' normals from estimation noise alone: the
        detector's own tolerance for coplanar patches (``DetectorConfig.min_angle_deg``).
    max_speed : float
        Without poses: the largest camera speed, m/s, allowed for between the two frames (the
        planes' distances from the camera may differ by ``max_speed * dt`` more, and their
        masks may be shifted by what such a move does to the image). 0.5 m/s:
        TUM RGB-D's hand-held sequences stay below about 0.4 m/s (Sturm et al. 2012, Table 1).
    max_turn_deg : float
        Without poses: the largest camera rotation rate, degrees per second (normals may differ
        by ``max_turn_deg * dt`` more, masks may be shifted by ``f tan(max_turn_deg * dt)``
        pixels more). 60 deg/s: above the hand-held TUM fr1 sequences' mean rates (fr1_rpy:
        ~50 deg/s).
    pose_error : float
        With poses: metres added to the offset tolerance for trajectory error (TUM's
        motion-capture ground truth: ~1 cm; SLAM trajectories: a few cm).
    max_gap : int
        A track may skip this many processed frames and still be continued (a plane the
        detector missed once keeps its track and colour).
    """

    min_iou: float = 0.3
    angle_deg: float = DetectorConfig().min_angle_deg
    max_speed: float = 0.5
    max_turn_deg: float = 60.0
    pose_error: float = 0.02
    max_gap: int = 2


@dataclass(frozen=True)
class ProposeConfig:
    """Settings of :func:`annotate_rgbd.propose.run_propose`.

    Parameters
    ----------
    detector : DetectorConfig
        The plane detector; ``detector.min_area_fraction`` is the smallest plane proposed.
    link : LinkConfig
    label : str
        CVAT label of every proposed track.
    every : int
        Process every N-th depth frame (keyframes); 1: all.
    merge_excess : float
        Two detected planes that do not touch (a floor on both sides of a table, a wall behind
        a cabinet, the near and far ends of a desk the sensor bends) are one plane when fitting
        one plane to both raises the mean squared residual by at most ``merge_excess * (s *
        sigma(z))**2`` over their own fits (``s``: the pieces' measured noise scale, 1 where they
        are as noisy as the model). ``(band_k / 2)**2`` = 2.25: two parallel planes of equal
        size merge when their offset is within the noise band, ``band_k * s * sigma``.
    piece_fraction : float
        The detector keeps pieces down to this fraction of the smallest plane, for the merge
        (0.5: a floor cut in two by a table adds up; 0.25 found nothing more on the rendered
        room and made detection a third slower); what is smaller than the smallest plane after
        merging is not proposed.
    outline_tolerance_px : float
        Douglas-Peucker tolerance of the polygons (``plane_outlines``): a pixel or two of error.
    widen_to_noise : bool
        Give each plane the pixels inside its outline that lie within its own noise band, the
        model's noise scaled by the plane's residuals as ``cvat2mask`` scales it
        (:mod:`annotate_rgbd.propose.extent`): real sensors are noisier than their published
        noise, and a desk cut at the model's band comes out speckled and frayed.
    seam_min_px : int
        Two detected planes that meet along at least this many pixels, with normals within
        ``detector.min_angle_deg`` and each one's seam pixels on the other's plane within the
        noise band, are pieces of one gently bent surface and are joined
        (:mod:`annotate_rgbd.propose.seams`: real depth sensors bend large flat surfaces by a
        centimetre or more). 20: the detector's cell side, the shortest stretch it tests a plane on.
    seam_reach_px : int
        Pixels between two planes that still meet: the detector leaves a pixel or two unassigned
        along a bend where the noise takes it off both bands. 2.
    object_height : float
        A plane parallel to a larger one (within ``detector.min_angle_deg``), in front of it by at
        most this many metres and mostly inside its polygon is an object on it, not proposed
        (:mod:`annotate_rgbd.propose.objects`). 0.10 m: what lies or hangs on a plane (papers,
        books, keyboards, frames, whiteboards, racks: 0.1-6 cm) stands less off it, the planes a
        labeller draws apart (a seat or shelf over the floor, a monitor before a wall, a table
        top: 20 cm and more) stand more.
    object_inside : float
        The larger plane holds the smaller one when this share of the smaller one's pixels lie
        inside its polygon (holes filled), or of the planes' pixels around it are its: a
        majority, 0.5.
    object_ring_px : int
        Width of the ring around a plane whose planes surround it, pixels: 10, half the
        detector's cell, wider than the unlabelled rims of a few-centimetre object seen at an
        angle from a metre or more.
    min_track_frames : int
        A plane is proposed only when its track is found on at least this many processed frames
        (all of them when fewer are processed): a plane that flickers for one frame is a fragment
        or noise, not a surface (issue 26). 2: the least that tells a surface that stays in view
        from a one-frame flicker at any ``every``.
    min_surface_m2 : float
        A track is proposed only when the surface its largest detection covers reaches this
        many square metres: ScanNet-style plane ground truth keeps only mesh planes of 0.1 m2
        (and at least 0.2 m across) or more, the real-data ground truth of issue 26 0.15 m2;
        0.1, as the largest part of a plane a track sees may be less than the whole.
    """

    detector: DetectorConfig = field(default_factory=DetectorConfig)
    link: LinkConfig = field(default_factory=LinkConfig)
    label: str = DEFAULT_LABEL
    every: int = 1
    merge_excess: float = (DetectorConfig().band_k / 2) ** 2
    piece_fraction: float = 0.5
    outline_tolerance_px: float = 1.5
    widen_to_noise: bool = True
    seam_min_px: int = 20
    seam_reach_px: int = 2
    object_height: float = 0.10
    object_inside: float = 0.5
    object_ring_px: int = 10
    min_track_frames: int = 2
    min_surface_m2: float = 0.1

    def __post_init__(self):
        if not isinstance(self.every, int) or self.every < 1:
            raise ValueError(f"every must be an integer >= 1, got {self.every!r}")
        if not (self.object_height >= 0 and 0 <= self.object_inside <= 1):
            raise ValueError("object_height must be >= 0 and object_inside in [0, 1]")
        if not self.min_surface_m2 >= 0:
            raise ValueError(f"min_surface_m2 must be >= 0, got {self.min_surface_m2!r}")
        if not isinstance(self.min_track_frames, int) or self.min_track_frames < 1:
            raise ValueError(f"min_track_frames must be an integer >= 1, got {self.min_track_frames!r}")
        if not self.label.strip():
            raise ValueError("the label must not be empty")

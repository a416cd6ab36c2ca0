"""The ``[detect]``, ``[propose]`` and ``[link]`` sections: every tunable of ``propose``, with its
default and the reason for it.

``propose`` also reads ``[camera]``, ``[sequence]`` (RGB association), ``[filter]`` (the drop rules,
as ``cvat2mask`` applies them), ``[noise]`` (the sensor's ``sigma(z)``, which the detector's
bands and tests are multiples of) and, with poses, ``propagate.time_offset`` (the trajectory's
clock offset, added to every frame's timestamp as ``cvat2mask`` adds it). Each section checks itself when it is made: a bad value is a
``ValueError`` of one line naming ``section.key`` (:func:`annotate_rgbd.config.rules.check_section`).
"""

from __future__ import annotations

from dataclasses import dataclass

from .rules import check_section

#: CVAT label of the proposed tracks.
DEFAULT_LABEL = "plane"

#: ``export-cvat``'s polygons (``--tolerance``, ``--max-vertices``): a run's refined masks are
#: what the labeller approved, so their outlines are kept closer than proposals' (0.5 px: on the
#: 320x240 sample the run read back scores within 0.002 mean IoU of the original against the
#: ground truth; 1.0 px: 0.014 lower, one boundary pixel in eight moves at that size), under a
#: larger vertex budget: the sample run (0.9958 mean IoU against its ground truth, polygons of a
#: median 206 vertices at 0.5 px) reads back at 0.9925 without a budget, 0.9904 at 200 vertices,
#: 0.9836 at 100.
EXPORT_TOLERANCE_PX = 0.5
EXPORT_MAX_VERTICES = 200


@dataclass(frozen=True)
class DetectorConfig:
    """The ``[detect]`` section: settings of :func:`annotate_rgbd.detect.detect_planes`.

    Lengths are in metres, image sizes in pixels of the depth image. The noise standard deviation
    ``sigma(z)`` is the ``[noise]`` model's.

    Parameters
    ----------
    cell_px : int
        Side of the square cells whose planarity is tested. 20 px at 640 x 480 is CAPE's
        recommendation (Proenca & Gao 2018): large enough for a stable plane fit under Kinect
        noise, small enough to follow plane boundaries before pixel refinement.
    min_valid_fraction : float
        Share of a cell's pixels that must have depth for the cell to be tested (CAPE: half).
    planar_k : float
        A cell is planar when the RMS distance of its points to their best plane is at most
        ``planar_k * sigma(z)`` at the cell's mean depth. Pure sensor noise gives an RMS of
        about ``sigma``; 3 leaves room for depth quantisation and lens distortion on real
        Kinect frames while a cell across a 90-degree corner or a depth step stays far above.
    band_k : float
        Width of the band around a plane, in noise standard deviations: a cell joins a
        region, and a pixel a plane, when it lies within ``band_k * sigma(z)`` of the plane
        (3 sigma holds 99.7 % of Gaussian noise).
    band_behind : float
        A pixel is given to a plane within ``band_behind`` times that band behind the plane (away
        from the camera), as ``cvat2mask``'s ``refine.behind_band``: nothing seen stands just
        behind a surface, and a real sensor's error has longer tails than its sigma. 1.5: on TUM
        fr1_rpy ``propose``'s precision/recall at IoU 0.8 went 0.682/0.650 -> 0.695/0.661, its leak
        8.7 -> 9.1 % (2: 0.686/0.658); on the rendered scenes of ``bench_propose.py`` precision and
        recall held or rose, and colour consistency (contact 0.568 -> 0.604, wall objects 0.562 ->
        0.606); mean IoU room 0.848 unchanged, contact 0.768 -> 0.767, wall objects 0.749 -> 0.751.
    min_angle_deg, max_angle_deg : float
        Two normals agree when their angle is at most the tilt the noise band allows across
        the less certain patch, ``atan(band_k * sigma / half_width)`` (half_width: half the
        patch's extent across its narrower in-plane direction), clipped to these bounds. The
        tilt bound, not a standard error, because real depth noise is correlated over a
        cell (RealSense stereo ripples tilt neighbouring 20-pixel cells of a flat screen by
        15 degrees at 0.7 m). The floor (10 degrees) covers the low-frequency distortion of
        real sensors on large segments; the ceiling (25 degrees, about CAPE's merge angle)
        keeps far, noisy cells from bridging creases. The band tests on the points do the
        finer work.
    merge_gap_cells : int
        Coplanar segments are merged when at most this many cells separate them on the cell
        grid (1: touching or one non-planar cell in between, e.g. a seam or a cable).
    min_area_fraction : float
        Smallest plane kept (and proposed), as a share of the image's pixels. 1 % (3072 px at
        640 x 480) is the smallest plane EVOPS-style annotations keep.
    """

    cell_px: int = 20
    min_valid_fraction: float = 0.5
    planar_k: float = 3.0
    band_k: float = 3.0
    band_behind: float = 1.5
    min_angle_deg: float = 10.0
    max_angle_deg: float = 25.0
    merge_gap_cells: int = 1
    min_area_fraction: float = 0.01

    def __post_init__(self):
        check_section("detect", self, [
            ("cell_px", lambda v: v >= 2, "must be an integer >= 2"),
            ("min_valid_fraction", lambda v: 0 < v <= 1, "must be in (0, 1]"),
            ("planar_k", lambda v: v > 0, "must be > 0"),
            ("band_k", lambda v: v > 0, "must be > 0"),
            ("band_behind", lambda v: 1 <= v <= 10, "must be in [1, 10]"),
            ("min_angle_deg", lambda v: 0 < v <= self.max_angle_deg, "must be > 0 and at most detect.max_angle_deg"),
            ("max_angle_deg", lambda v: v < 90, "must be < 90"),
            ("merge_gap_cells", lambda v: v >= 0, "must be >= 0"),
            ("min_area_fraction", lambda v: 0 < v <= 1, "must be in (0, 1]"),
        ])


@dataclass(frozen=True)
class LinkConfig:
    """The ``[link]`` section: how ``propose`` links detections on successive processed frames
    into tracks.

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
        detector's own tolerance for coplanar patches (``[detect]``'s default ``min_angle_deg``).
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
    angle_deg: float = DetectorConfig.min_angle_deg
    max_speed: float = 0.5
    max_turn_deg: float = 60.0
    pose_error: float = 0.02
    max_gap: int = 2

    def __post_init__(self):
        check_section("link", self, [
            ("min_iou", lambda v: 0 < v <= 1, "must be in (0, 1]"),
            ("angle_deg", lambda v: 0 <= v <= 90, "must be in [0, 90]"),
            ("max_speed", lambda v: v >= 0, "must be >= 0"),
            ("max_turn_deg", lambda v: v >= 0, "must be >= 0"),
            ("pose_error", lambda v: v >= 0, "must be >= 0"),
            ("max_gap", lambda v: v >= 0, "must be >= 0"),
        ])


@dataclass(frozen=True)
class ProposeConfig:
    """The ``[propose]`` section: settings of :func:`annotate_rgbd.propose.run_propose` beyond the
    detector's and the linker's.

    Parameters
    ----------
    label : str
        CVAT label of every proposed track (``--label``).
    every : int
        Process every N-th depth frame (keyframes); 1: all (``--every``).
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
        Largest distance, pixels, of a polygon's edges from the traced outline of its plane's
        pixels (Douglas-Peucker, :func:`annotate_rgbd.cvat.from_masks.outline_planes`): a pixel
        or two of error, which ``cvat2mask``'s refinement takes back.
    max_vertices : int
        Vertex budget of each polygon, what a labeller drags in CVAT (0: none, the tolerance
        alone): past it the tolerance is raised until the polygon fits; it stays simple either
        way. 120: on TUM fr1_rpy (every 10th of its 722 frames) the polygons' median falls from
        242 vertices (largest 970) to 118, their mean IoU with the planes' pixels from 0.969 to
        0.945; on 40 rendered room frames ``cvat2mask`` on the proposals keeps its precision and
        recall at IoU 0.8 (mean IoU 0.8602 -> 0.8596), while 100 vertices cost both 0.01. The
        report gives each plane's ``polygon_iou`` and ``budget_iou_cost``, and their summary.
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
        along a bend where the noise takes it off both bands. 2. 0: planes never meet at a seam
        (none are joined).
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
    object_band_share : float
        An object whose pixels lie within its plane's noise band (``widen_to_noise``'s scaled
        band, the one ``cvat2mask`` keeps a pixel by) for at least this share is part of the plane:
        its pixels join the plane's instead of being dropped (a strip of desk the sensor's bend
        lifts a centimetre, a mouse pad: a polygon over both would keep them in ``cvat2mask``).
        A majority, 0.5; above 1: never.
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
    min_track_share : float
        A track is proposed only when its largest detection covers at least this share of the
        image, too (with ``min_surface_m2``, both must hold): a plane
        a labeller annotates is seen large at least once in a sequence, while what is never seen
        larger than a few per cent of the image is a far or small surface that plane ground truth
        leaves out (ScanNet-style GT keeps mesh planes of 0.1-0.15 m2 and more, the EVOPS rules
        drop planes past 3.5 m). 0.03: on TUM fr1_rpy against the independent ground truth of
        issue 26 precision at IoU 0.8 went from 0.63 to 0.74 at the same recall; 0: any.
    """

    label: str = DEFAULT_LABEL
    every: int = 1
    merge_excess: float = (DetectorConfig().band_k / 2) ** 2
    piece_fraction: float = 0.5
    outline_tolerance_px: float = 1.5
    max_vertices: int = 120
    widen_to_noise: bool = True
    seam_min_px: int = 20
    seam_reach_px: int = 2
    object_height: float = 0.10
    object_inside: float = 0.5
    object_ring_px: int = 10
    object_band_share: float = 0.5
    min_track_frames: int = 2
    min_surface_m2: float = 0.1
    min_track_share: float = 0.03

    def __post_init__(self):
        check_section("propose", self, [
            ("label", lambda v: label_problem(v) is None, "must be a CVAT label: visible text without control characters"),
            ("every", lambda v: v >= 1, "must be an integer >= 1"),
            ("merge_excess", lambda v: v > 0, "must be > 0"),
            ("piece_fraction", lambda v: 0 < v <= 1, "must be in (0, 1]"),
            ("outline_tolerance_px", lambda v: v >= 0, "must be >= 0"),
            ("max_vertices", lambda v: v == 0 or v >= 3, "must be 0 (no budget) or an integer >= 3"),
            ("seam_min_px", lambda v: v >= 1, "must be an integer >= 1"),
            ("seam_reach_px", lambda v: v >= 0, "must be an integer >= 0"),
            ("object_height", lambda v: v >= 0, "must be >= 0"),
            ("object_inside", lambda v: 0 <= v <= 1, "must be in [0, 1]"),
            ("object_ring_px", lambda v: v >= 1, "must be an integer >= 1"),
            ("object_band_share", lambda v: v >= 0, "must be >= 0"),
            ("min_track_frames", lambda v: v >= 1, "must be an integer >= 1"),
            ("min_surface_m2", lambda v: v >= 0, "must be >= 0"),
            ("min_track_share", lambda v: 0 <= v <= 1, "must be in [0, 1]"),
        ])


def label_problem(label: str) -> str | None:
    """Why a text cannot be a CVAT label (``"is empty"``, ``"holds the control character
    U+0001"``), or None when it can.

    A CVAT label is a name shown in menus and written into XML: it has a visible character, and
    no control character (XML 1.0 has none of C0 but tab and line breaks, which a label cannot
    hold either).
    """
    if not label.strip():
        return "is empty"
    control = next((c for c in label if ord(c) < 0x20 or 0x7F <= ord(c) < 0xA0), None)
    if control is not None:
        return f"holds the control character U+{ord(control):04X}"
    try:
        label.encode("utf-8")
    except UnicodeEncodeError:
        return "is not Unicode text (a lone surrogate)"
    return None

"""The configuration sections that change how a mask is made: ``[filter]``, ``[ransac]``,
``[refine]`` and ``[propagate]`` (with ``[camera]`` and ``[noise]``, the settings a mask's
fingerprint keys on, :func:`annotate_rgbd.pipeline.resume.fingerprint`).

Each default is given with its source: a paper, a sensor's datasheet, or a measurement of this
project (which benchmark). :mod:`annotate_rgbd.config.settings` assembles them into
:class:`~annotate_rgbd.config.settings.Config` and reads them from TOML and ``--set``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class FilterConfig:
    """When a plane is dropped from a frame before refinement.

    Parameters
    ----------
    max_invalid_ratio : float
        Drop a plane whose share of pixels without valid depth exceeds this (EVOPS paper: 0.8;
        0.75 for fr2_pioneer_slam in the original annotation).
    max_mean_distance : float
        Drop a plane whose valid pixels lie farther than this from the camera on average, in
        metres (EVOPS paper: 3.5 m, where Kinect depth noise grows beyond a few centimetres).
    min_valid_pixels : int
        Drop a plane with fewer valid pixels than this: RANSAC needs 3 points, and a patch
        smaller than about 7x7 pixels says nothing reliable about a plane (this project's choice).
    """

    max_invalid_ratio: float = 0.8
    max_mean_distance: float = 3.5
    min_valid_pixels: int = 50


@dataclass(frozen=True)
class RansacConfig:
    """RANSAC settings (:func:`annotate_rgbd.segment.ransac.ransac_plane`) and the exhaustive search
    of pose-carried shapes (:class:`annotate_rgbd.segment.ransac.RansacSearch` taken on through
    every hypothesis).

    Parameters
    ----------
    distance_threshold : float
        A fixed inlier band: the largest point-to-plane distance of an inlier, in metres, at
        every depth (EVOPS set it by hand per sequence: 0.02 m for TUM long_office; 0.005 m for
        ICL-NUIM, 0.01 m fr1_desk, 0.03 m fr2_pioneer_slam). 0 (the default): the band follows
        the sensor's noise, ``[noise]`` (:class:`annotate_rgbd.geometry.noise.NoiseSettings`). A value
        > 0 replaces the noise model, whatever ``[noise]`` says.
    num_iterations : int
        RANSAC iterations (it stops earlier once the inlier set is certain, by Open3D's
        ``segment_plane`` rule; the exhaustive search tries them all), at most 1,000,000
        (``config.settings.MAX_RANSAC_ITERATIONS``).
    seed : int
        Seed of RANSAC's random generator (numpy's), set before every fit, so that a re-run gives
        identical masks (with the same numpy version).
    max_points : int
        RANSAC looks for the plane among at most this many of a plane's points, spread evenly
        over it (a regular pixel grid); every pixel is then tested against that plane. On the
        benchmark sequence (benchmarks/bench_cvat2mask.py) 1,000 points change 0.04 % of the
        mask pixels against a search among all points, at a third of the time. 0: every point.
    band_share : float
        RANSAC's distance threshold, as a share of the inlier band at the points' median depth
        (k = 3 sigma: 1.5 sigma). With the full band a plane tilted between two surfaces a few
        sigma apart (a whiteboard on a wall, books on a table) can gather more points than
        either surface's own plane; within 1.5 sigma the dominant surface wins. Measured on
        benchmarks/bench_refine.py: the wall behind a whiteboard went from mean IoU 0.86 to 0.94
        (0.34 of the band gave the same).
    exhaustive_below : float
        For a shape carried by camera poses, RANSAC goes on through all its iterations
        (every hypothesis scored, as :func:`annotate_rgbd.segment.ransac.every_hypothesis`) when
        its plane holds under this share of the points (a wall half covered by a whiteboard:
        RANSAC stops early on a plane leaning between two surfaces of about half each). This
        project's choice, between those halves and a plane that clearly dominates.
    min_noise_scale, max_noise_scale : float
        Real sensors are noisier than their published axial noise (depth distortion on TUM fr1,
        stereo ripples on RealSense, lateral noise on tilted planes). Each plane's own residuals
        tell by how much (``1.4826 median(|d| / sigma(z))`` of its fit's inliers, the MAD
        estimate of a standard deviation); the noise is scaled by that factor when it exceeds
        ``min_noise_scale`` (below, it is within the spread of the estimate: a median of about
        a thousand points varies by a few per cent) and by at most ``max_noise_scale``
        (measured: the planes of TUM fr1_rpy and of the RealSense office frames are about 1.5
        sigma of the published models; renders with the model's exact noise stay about 1).
    behind_share, min_behind_points, max_behind_depth, max_behind : float, int, float, int
        A surface behind RANSAC's plane (beyond its band) that holds at least ``behind_share``
        of the plane's inliers and ``min_behind_points`` points (a few stray points always
        make a plane), that lies at most ``max_behind_depth`` metres behind it (an object
        standing on a plane is rarely taller: the carton on the benchmark's floor is 0.3 m; a
        surface farther behind is seen through an opening, a doorway, which labellers do draw
        over), and that the plane's points lie in front of, replaces it, at most ``max_behind``
        times in a row (:func:`annotate_rgbd.segment.ransac.fit_plane`; this project's choices,
        checked on the rendered scenes of tests/segment/test_rims_and_behind.py). ``max_behind = 0``:
        never.
    """

    distance_threshold: float = 0.0
    num_iterations: int = 1000
    seed: int = 0
    max_points: int = 1000
    band_share: float = 0.5
    exhaustive_below: float = 0.6
    min_noise_scale: float = 1.15
    max_noise_scale: float = 2.5
    behind_share: float = 0.3
    min_behind_points: int = 10
    max_behind_depth: float = 0.5
    max_behind: int = 2


@dataclass(frozen=True)
class RefineConfig:
    """What refinement does besides the inlier test.

    Parameters
    ----------
    grow_pixels : int
        Grow each kept plane by up to this many pixels beyond its drawn shape, into pixels
        whose depth lies on the plane and that no other plane's shape or inliers claim
        (:func:`annotate_rgbd.segment.grow.grow_planes`): a labeller's outline is a pixel or two off the
        real edge (this project's measurement on rendered scenes: +-2 px). 0: no growing.
    rim_pixels : int
        Drop a plane's pixels this close to a surface standing in front of it inside its shape
        (:func:`annotate_rgbd.segment.rims.near_surfaces_in_front`; ``docs/refinement.md`` for
        the measurement behind 2). 0: keep them.
    coherence_window : int
        Side (px, odd) of the window in which a plane's residuals (in noise units) are averaged
        to find surfaces that stand off it by less than the inlier band (a whiteboard on a
        wall, a book on a table): each pixel's residual is within the noise, but they share a
        sign over an area (:func:`annotate_rgbd.segment.refine.window_scores`). 7 px covers a
        few Kinect v1 correlation windows (this project's choice). 0: no window test.
    coherence_limit : float
        How many spreads of a plane's window scores (a standard deviation where the noise is
        independent) mark a window's centre pixel as lying on another surface; also the limit
        of growing beyond keyframes (:func:`annotate_rgbd.segment.grow.grow_connected`). 5:
        far in the tail of a normal distribution, so a true plane loses almost nothing.
    min_window_inliers : int
        Fewest inliers in a window for its score to count: the score is normalised for any
        number, and a surface just beyond the band leaves only scattered inliers.
    min_inlier_density : float
        Inliers whose window holds fewer inliers than this share of its labelled pixels are
        dropped: a plane pixel's window holds about 99 % (a 3 sigma band), 57 % on an
        occluder's straight edge (4 of 7 columns), 33 % in a right-angled corner (16 of 49); a
        surface a little beyond the band, whose noise puts only scattered pixels inside it,
        5-40 %.
    core_score, core_refits : float, int
        Each plane is re-fitted (at most ``core_refits`` times) to its core: the pixels whose
        window score lies within ``core_score`` standard normal deviations of the plane's centre
        (on real sensors, whose noise is correlated, fewer than 95 % of the plane, but all of
        them on its dominant surface).
    bend_rounds, bend_cell : int
        The final inlier test is against each plane's bent surface: a quadratic disparity error
        over the image, fitted robustly to the median distances of its inliers in
        ``bend_cell`` x ``bend_cell`` px cells, ``bend_rounds`` times at most
        (:mod:`annotate_rgbd.segment.bend`; Kinect v1 bows a desk 1 m away by millimetres). 0
        rounds: a flat plane. This project's measurement (``docs/refinement.md``): on TUM
        fr1_rpy's dense labelling mean IoU 0.932 -> 0.935 with the leak unchanged, rendered
        planes unchanged; 16 px cells hold a few Kinect correlation windows each.
    behind_band : float
        The inlier band behind a plane (away from the camera), as a multiple of the band in
        front of it (>= 1). Nothing a camera sees stands a few centimetres behind the surface it
        sees (that surface hides it), so behind a plane the band holds the sensor's own error,
        whose real tails reach past ``k`` sigma (Kinect v1's disparity steps, what the bend leaves);
        in front of it stand the objects touching it, which the band must keep out. This
        project's measurement (``docs/refinement.md``): 1.5 took TUM fr1_rpy's dense labelling from
        mean IoU 0.935 to 0.942 with the leak unchanged (1.2 %) and the rendered scenes' clutter
        from 0.0782 to 0.0779 %; ``propose`` takes each plane's pixels with the same band
        (precision/recall 0.672/0.637 -> 0.682/0.650 there). 1: a symmetric band.
    """

    grow_pixels: int = 3
    rim_pixels: int = 2
    coherence_window: int = 7
    coherence_limit: float = 5.0
    min_window_inliers: int = 4
    min_inlier_density: float = 0.3
    core_score: float = 2.0
    core_refits: int = 2
    bend_rounds: int = 3
    bend_cell: int = 16
    behind_band: float = 1.5


@dataclass(frozen=True)
class PropagateConfig:
    """Pose-guided propagation (:mod:`annotate_rgbd.propagate`), with ``sequence.poses``.

    Parameters
    ----------
    same_surface_angle, same_surface_offset : float
        Largest angle (degrees) and offset (m, at a point of the surface) between two planes for
        them to be one surface seen through camera poses: a track's keyframe planes, and a
        surface behind RANSAC's plane against where the poses put it. Real poses reproject
        depth with errors of 0.4-2 cm over tens of frames (7-Scenes, TUM fr1_rpy), and a plane
        fitted to a few thousand pixels has an orientation error of a fraction of a degree: 5
        degrees and 5 cm are well above both and well below two surfaces a labeller might
        confuse (a table top and the floor: 0.7 m). The offset also bounds how far most points
        of a carried plane's fit may lie from where the poses put the plane
        (:func:`annotate_rgbd.segment.ransac.on_expected_plane`).
    min_keyframe_weight : float
        A keyframe off its track's agreed plane flags the track for review only when its shape
        holds at least this share of the valid depth pixels of the track's largest keyframe (a
        sliver of a plane leaving the view is mostly another surface). This project's choice.
    border_margin : float
        Outline vertices this close to the keyframe image's edge (px) lie on it (CVAT clamps
        drawn vertices to the image; a labeller's few pixels of slack).
    beyond_reach : float
        How far past a keyframe image's border an outline that the border cut is carried, at
        most, as a share of the image's size (:func:`annotate_rgbd.propagate.lift.beyond_the_border`).
    time_offset : float
        Seconds added to every frame's timestamp before the trajectory is read, when known
        (TUM freiburg1: about -0.02 s, the offset that makes its fused surfaces sharpest).
    time_offset_search : float
        Estimate a further offset within +-this many seconds from the keyframes' planes
        (:func:`annotate_rgbd.propagate.timing.estimate_time_offset`): motion-capture clocks
        are off from camera clocks by tens of milliseconds (TUM freiburg1_rpy: 0.02 s, found by
        the sharpest fusion of its depth; 0.1 s covers five times that). 0: no estimate.
    time_offset_step : float
        The grid of that search (s); it is refined to a tenth of it around the best point. At
        70 degrees per second (TUM fr1's hand-held sweeps) 5 ms is 0.35 degrees, 3 px at fx 517.
        At least 1 ms (refined to 0.1 ms, far below a frame's 33 ms): a finer grid takes memory
        in proportion (1e-5 s took a gigabyte on 120 frames) and finds nothing more.
    keyframes_each_side : int
        A frame between keyframes gets what the nearest this many keyframes before it and after
        it say about each plane (the nearest one that saw a pixel decides it, but where the two
        nearest disagree every outline counts:
        :func:`annotate_rgbd.propagate.carry.carried_layers`): each outlines the part of the
        plane in view when it was drawn, and farther ones add only what the nearer ones did not
        see. On benchmarks/bench_propagate.py's walk ... (measured in the README).
    exclude : bool
        Carry what each keyframe's outline left out as well as what it holds
        (:mod:`annotate_rgbd.propagate.evidence`): the surfaces touching the plane, within
        ``noise.cap`` of it, that the labeller saw and did not draw are not the plane on other
        frames either.
    exclude_margin : int
        Pixels next to a keyframe's outline that are never excluded (0: what the outline left
        out starts at the outline). A labeller's outline is up to 2 px off the real edge and the
        poses put it another 1-2 px off, but the outline and what it left out are carried
        together, with one pose: a margin only hands the carried plane a strip of what touches
        it. Measured 2026-11-27, 4 px -> 0: TUM fr1_rpy (benchmarks/bench_real.py, strict
        ground truth) a keyframe every 10th frame 0.898 -> 0.904 mean IoU, leak 3.0 -> 2.4 %
        (2 px: 0.902, 2.7 %), every 30th 0.874 -> 0.877, leak 4.0 -> 3.5 % (leak: the share of
        the ground truth's "no plane" pixels given a plane, docs/benchmarks.md); the rendered
        walk (benchmarks/bench_propagate.py) every 10th 0.967 -> 0.974, every 30th 0.962 ->
        0.964, but its variant with near-coplanar wall objects and noisy poses every 30th 0.929
        -> 0.926 (every 10th 0.935 -> 0.941).
    outline_tolerance : float
        Largest distance (px) of a carried exclusion outline from the traced one.
    align_rounds : int
        Rounds of aligning every keyframe's pose to its neighbouring keyframes' depth before
        every other frame's pose is aligned to its keyframes' (:mod:`annotate_rgbd.propagate.align`);
        0: the trajectory's poses as they are. Measured on TUM fr1_rpy (docs/benchmarks.md).
    align_neighbours : int
        The keyframes on each side a keyframe is aligned to (a frame between keyframes: its
        ``keyframes_each_side``, those whose outlines it takes). On TUM fr1_rpy at a keyframe
        every 100th frame 2 scored 0.887, 1 0.881 (docs/benchmarks.md).
    align_step : int
        A frame is aligned on its depth at every this many pixels both ways (at most 16: at 64
        a 640 x 480 frame has too few points to pair).
    align_max_shift, align_max_turn : float
        A larger correction of a pose (m, degrees; a keyframe's, over all rounds) is not
        believed and the trajectory's pose is kept: real trajectories are off by a few
        centimetres and degrees (TUM fr1_rpy's motion capture against poses registered to its
        fused depth: 95th percentile 4.2 cm, 3.0 degrees), and ICP that pairs the wrong
        surfaces moves poses farther.
    """

    same_surface_angle: float = 5.0
    same_surface_offset: float = 0.05
    min_keyframe_weight: float = 0.25
    border_margin: float = 4.0
    beyond_reach: float = 0.5
    time_offset: float = 0.0
    time_offset_search: float = 0.1
    time_offset_step: float = 0.005
    keyframes_each_side: int = 3
    exclude: bool = True
    exclude_margin: int = 0
    outline_tolerance: float = 1.0
    align_rounds: int = 3
    align_neighbours: int = 2
    align_step: int = 8
    align_max_shift: float = 0.05
    align_max_turn: float = 3.0


def range_checks(config: Any) -> list[tuple[str, bool, str]]:
    """The ``(key, holds, rule)`` checks of the tunables of these sections that
    :func:`annotate_rgbd.config.settings.load_config` makes (one line each in the error:
    ``'refine.coherence_window' must be ...``), besides the finite-number and integer-size
    checks of every key and the checks of the keys listed in ``settings``.

    Parameters
    ----------
    config : Config

    Returns
    -------
    list of (str, bool, str)
    """
    ransac, refine, propagate = config.ransac, config.refine, config.propagate
    return [
        ("ransac.band_share", 0 < ransac.band_share <= 1, "must be in (0, 1]"),
        ("ransac.exhaustive_below", 0 <= ransac.exhaustive_below <= 1, "must be in [0, 1]"),
        ("ransac.min_noise_scale", ransac.min_noise_scale >= 1, "must be >= 1"),
        ("ransac.max_noise_scale", ransac.max_noise_scale >= 1, "must be >= 1 (1: never scale the noise)"),
        ("ransac.behind_share", ransac.behind_share > 0, "must be > 0"),
        ("ransac.min_behind_points", ransac.min_behind_points >= 3, "must be >= 3"),
        ("ransac.max_behind_depth", ransac.max_behind_depth > 0, "must be > 0"),
        ("ransac.max_behind", 0 <= ransac.max_behind <= 10, "must be in [0, 10]"),
        ("refine.coherence_window", refine.coherence_window == 0
         or (3 <= refine.coherence_window <= 51 and refine.coherence_window % 2 == 1),
         "must be 0 (no window test) or odd in [3, 51]"),
        ("refine.coherence_limit", 0 < refine.coherence_limit <= 100, "must be in (0, 100]"),
        ("refine.min_window_inliers", 1 <= refine.min_window_inliers, "must be >= 1"),
        ("refine.min_inlier_density", 0 <= refine.min_inlier_density <= 1, "must be in [0, 1]"),
        ("refine.core_score", 0 < refine.core_score <= 100, "must be in (0, 100]"),
        ("refine.core_refits", 0 <= refine.core_refits <= 20, "must be in [0, 20]"),
        ("refine.bend_rounds", 0 <= refine.bend_rounds <= 20, "must be in [0, 20]"),
        ("refine.bend_cell", 4 <= refine.bend_cell <= 256, "must be in [4, 256]"),
        ("propagate.same_surface_angle", 0 <= propagate.same_surface_angle <= 90, "must be in [0, 90] (degrees)"),
        ("propagate.same_surface_offset", propagate.same_surface_offset >= 0, "must be >= 0"),
        ("propagate.min_keyframe_weight", 0 <= propagate.min_keyframe_weight <= 1, "must be in [0, 1]"),
        ("propagate.border_margin", propagate.border_margin >= 0, "must be >= 0"),
        ("propagate.beyond_reach", 0 <= propagate.beyond_reach <= 10, "must be in [0, 10]"),
        ("propagate.time_offset_search", 0 <= propagate.time_offset_search <= 1, "must be in [0, 1] s"),
        ("propagate.time_offset_step", 0.001 <= propagate.time_offset_step <= 1,
         "must be in [0.001, 1] s (refined to a tenth of it; a finer grid costs memory for nothing)"),
        ("propagate.keyframes_each_side", 1 <= propagate.keyframes_each_side <= 1000, "must be in [1, 1000]"),
        ("propagate.exclude_margin", 0 <= propagate.exclude_margin <= 50, "must be in [0, 50]"),
        ("propagate.outline_tolerance", propagate.outline_tolerance > 0, "must be > 0"),
        ("propagate.align_rounds", 0 <= propagate.align_rounds <= 20, "must be in [0, 20] (0: no alignment)"),
        ("propagate.align_neighbours", 1 <= propagate.align_neighbours <= 8,
         "must be in [1, 8] (each keyframe's depth is held in memory while a frame is aligned to it)"),
        ("propagate.align_step", 1 <= propagate.align_step <= 16, "must be in [1, 16] (px)"),
        ("propagate.align_max_shift", propagate.align_max_shift >= 0, "must be >= 0"),
        ("propagate.align_max_turn", 0 <= propagate.align_max_turn <= 180, "must be in [0, 180] (degrees)"),
    ]

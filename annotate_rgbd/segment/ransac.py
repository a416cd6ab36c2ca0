"""Finding one plane among a shape's 3-D points: RANSAC with hypotheses scored in blocks
(:func:`ransac_plane`, a :class:`RansacSearch` that can go on where it stopped; through all its
iterations, :func:`every_hypothesis`), the surface behind it, the weighted re-fit and the plane's
own noise scale (:func:`fit_plane`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from annotate_rgbd.config.settings import PropagateConfig, RansacConfig
from annotate_rgbd.geometry.lift import plane_agreement
from annotate_rgbd.geometry.noise import NoiseSettings, noise_scale
from annotate_rgbd.geometry.planes import refit_plane, weighted_plane_fit
from annotate_rgbd.geometry.statistics import median


#: Least-squares re-fits of a RANSAC plane to its inliers (the second settles the inlier set).
REFITS = 2
#: Planes tried among the points behind, largest first.
BEHIND_CANDIDATES = 3
#: Confidence at which RANSAC stops early (:func:`ransac_plane`; Open3D's default).
DEFAULT_PROBABILITY = 0.99999999
#: Hypotheses in RANSAC's first block: as many as a plane that holds 76 % of the points needs at
#: :data:`DEFAULT_PROBABILITY` (a plane that dominates its shape, the common case, stops there).
FIRST_BLOCK = 32
#: Hypotheses drawn at a time: the memory RANSAC takes stays small whatever ``num_iterations``.
TRIPLES_DRAWN = 1000
#: The share of a plane's points that may lie behind a plane that replaces it (noise, edges).
IN_FRONT_SLACK = 0.02
#: Point-to-plane distances computed at once by :meth:`RansacSearch.score` (1 MiB of float64): a block
#: of hypotheses is this many distances over the number of points, at most 100.
DISTANCES_PER_BLOCK = 2**17


@dataclass(frozen=True)
class PlaneFit:
    """The result of fitting one plane.

    Parameters
    ----------
    equation : ndarray of float64, shape (4,)
        ``(a, b, c, d)`` with ``a x + b y + c z + d = 0`` in the camera frame (metres), unit
        normal, oriented towards the camera (``d > 0``); all NaN when the points span no plane
        (all on one line), and then no point is an inlier.
    inliers : ndarray of bool, shape (N,)
        For each input point, whether it lies within the inlier band of the plane at its depth.
    band : float
        The inlier band (m) at the median depth of the inliers.
    rms_sigma : float
        Root mean square distance of the inliers to the plane, in units of the noise the band
        stands for (``band / k``); about 1 when the noise model fits the sensor. NaN without
        inliers.
    inliers_ransac, inliers_refit : int
        Inliers among the input points of RANSAC's plane (or of the surface behind that replaced
        it) and of the re-fitted plane.
    noise_scale : float
        How much noisier than the model the plane's points are (``config.max_noise_scale``);
        the band, the re-fit's weights and the inlier test use the scaled noise.
    surface_behind : bool
        Whether a surface behind RANSAC's plane replaced it (:func:`_surface_behind`).
    """

    equation: np.ndarray
    inliers: np.ndarray
    band: float = float("nan")
    rms_sigma: float = float("nan")
    inliers_ransac: int = 0
    inliers_refit: int = 0
    noise_scale: float = 1.0
    surface_behind: bool = False


def fit_plane(
    points: np.ndarray, config: RansacConfig, noise: NoiseSettings, look_behind: bool = True,
    expected: np.ndarray | None = None, propagate: PropagateConfig = PropagateConfig(),
) -> PlaneFit:
    """Find a plane among 3-D points with RANSAC (:func:`ransac_plane`), then re-fit it to its inliers.

    RANSAC searches for the plane among at most ``config.max_points`` of the points, taken
    evenly through the input (for a plane's pixels in row-major order: a regular grid over the
    plane), with half the inlier band of the noise model at the points' median depth as its one
    distance threshold (``config.band_share``). A 3-point RANSAC plane is noisier than the data, so the plane is then
    re-fitted by least squares to its inliers, each weighted by ``1 / sigma(z)^2``
    (:func:`annotate_rgbd.geometry.planes.refit_plane`: every point tested against the band at its own
    depth). RANSAC's generator is seeded (``config.seed``) before every call: a re-run gives
    identical planes.

    With ``look_behind``, a large surface behind RANSAC's plane that the plane's points lie in
    front of takes its place (:func:`_surface_behind`): the points are a labeller's drawn shape,
    which runs over what stands on the plane but not over what lies behind it.

    Parameters
    ----------
    points : ndarray of float64, shape (N, 3)
        N >= 3 points in metres.
    config : RansacConfig
    noise : NoiseSettings
        The inlier band (:meth:`annotate_rgbd.config.Config.noise_settings`).
    look_behind : bool
        False for points of a shape no labeller drew on this frame (projected from keyframes on
        other frames, which may run past the plane's edge onto a surface behind it), unless
        ``expected`` says which plane it is.
    expected : ndarray, shape (4,), optional
        Where camera poses put the plane in this frame (a track's keyframe plane): a surface
        behind replaces RANSAC's plane only when it is that one (within
        ``propagate.same_surface_angle`` and ``same_surface_offset``); and when RANSAC's plane
        holds under ``config.exhaustive_below`` of the points, RANSAC goes on through all its
        iterations (as :func:`every_hypothesis`; the plane with more inliers is kept).
    propagate : PropagateConfig
        The same-surface tolerances.

    Returns
    -------
    PlaneFit
        Without a plane (NaN equation, no inliers) when no three of the points span one (all
        on one line).
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    sample = points
    if config.max_points and len(points) > config.max_points:
        sample = points[:: -(-len(points) // config.max_points)]
        if len(sample) < 3:  # a stride over very few points (max_points = 3) can leave two
            sample = points[: max(config.max_points, 3)]
    threshold = config.band_share * float(noise.band(median(sample[:, 2])))
    search = _search(sample, threshold, config)
    equation, inliers = search.best()
    if inliers == 0:  # the points lie on one line: no plane to find (nor behind it, nor to re-fit)
        return PlaneFit(np.full(4, np.nan), np.zeros(len(points), dtype=bool))
    if expected is not None and inliers < config.exhaustive_below * len(sample):
        # RANSAC stops searching once its plane is likely the best given the share of points it
        # holds; with two surfaces of about half each it can stop on a plane leaning between them.
        # The search goes on through every hypothesis (as every_hypothesis, without scoring the
        # first ones again); a plane with more inliers replaces the first one.
        search.score(probability=1.0)
        if search.best_count > inliers:
            equation, inliers = search.best()
    band = noise.band(sample[:, 2])
    behind = False
    for _ in range(config.max_behind if look_behind or expected is not None else 0):
        found = _surface_behind(sample, band, equation, inliers, threshold, config, expected, propagate)
        if found is None:
            break
        (equation, inliers), behind = found, True
    refit = refit_plane(points, equation, noise, iterations=REFITS, fit_points=0)
    rms_sigma, before, scale = refit.rms_sigma, refit.inliers_before, 1.0
    for _ in range(2):  # the first estimate sees a band truncated at the model's k sigma
        found = noise_scale(points, refit.equation, noise.scaled(scale))
        if found < (config.min_noise_scale if scale == 1.0 else 1.02):
            break
        scale = min(scale * found, config.max_noise_scale)
        refit = refit_plane(points, refit.equation, noise.scaled(scale), iterations=1, fit_points=0)
    equation = refit.equation / np.linalg.norm(refit.equation[:3])
    if equation[3] < 0:
        equation = -equation
    return PlaneFit(equation, refit.inliers, refit.band_at_median, rms_sigma, before, refit.inliers_after, scale,
                    surface_behind=behind)


def _surface_behind(
    sample: np.ndarray, band: np.ndarray, equation: np.ndarray, inliers: int, threshold: float, config: RansacConfig,
    expected: np.ndarray | None = None, propagate: PropagateConfig = PropagateConfig(),
) -> tuple[np.ndarray, int] | None:
    """A plane behind ``equation`` that the polygon was drawn for, or None.

    A polygon is drawn over what lies on its plane and in front of it, never over a surface
    behind it (but for a pixel or two along its edges, and openings such as a doorway). When
    the points behind RANSAC's plane (beyond the band, within ``config.max_behind_depth``) hold
    a plane with at least ``config.behind_share`` of its ``inliers`` (and
    ``config.min_behind_points``),
    and the plane's own points lie in front of that one, RANSAC took an object for the plane: the
    top of a carton on a floor that it mostly hides, a picture on a sliver of wall. Planes
    behind that the plane's points are not in front of (a carton's side seen behind its top:
    the top is behind the side, too) are set aside, and the next one tried; so are planes other
    than the ``expected`` one, when given.
    """
    on_plane = np.abs(sample @ equation[:3] + equation[3]) <= threshold
    behind = sample @ equation[:3] + equation[3] < -band
    for _ in range(BEHIND_CANDIDATES):
        if np.count_nonzero(behind) < max(config.behind_share * inliers, config.min_behind_points):
            return None
        candidate, found = _search(sample[behind], threshold, config).best()
        if found < max(config.behind_share * inliers, config.min_behind_points):
            return None
        signed = sample @ candidate[:3] + candidate[3]
        on_candidate = np.abs(signed) <= threshold
        in_front = np.count_nonzero(on_plane & (signed < -band)) <= IN_FRONT_SLACK * np.count_nonzero(on_plane)
        near = -median(sample[on_candidate] @ equation[:3] + equation[3]) <= config.max_behind_depth
        if in_front and near and (
            expected is None or same_surface(candidate, expected, sample[on_candidate], propagate)
        ):
            return candidate, found
        behind &= np.abs(signed) > threshold  # set that plane aside
    return None


def same_surface(plane: np.ndarray, expected: np.ndarray, points: np.ndarray, propagate: PropagateConfig) -> bool:
    """Whether ``plane`` is the ``expected`` one, compared at the centre of its ``points`` (at
    the origin when there are none), within ``propagate.same_surface_angle`` and ``_offset``."""
    at = points.mean(axis=0) if len(points) else None
    angle, offset = plane_agreement(expected, plane, at=at)
    return angle <= propagate.same_surface_angle and offset <= propagate.same_surface_offset


#: Share of a fit's points that must lie within ``propagate.same_surface_offset`` of the plane the
#: poses expect (:func:`on_expected_plane`): most of them, a few stray points aside.
ON_EXPECTED_SHARE = 0.9


def on_expected_plane(points: np.ndarray, expected: np.ndarray, propagate: PropagateConfig) -> bool:
    """Whether a fit's points lie where the poses put the plane: at least
    :data:`ON_EXPECTED_SHARE` of them within ``propagate.same_surface_offset`` of ``expected``.

    The points, not the fitted plane's angle, decide: a real sensor's depth distortion tilts the
    planes fitted on different views of one surface by several degrees (TUM fr1_rpy's floor and
    desk: 5-8 degrees between views, their points within 2-4 cm of each other's plane), while
    another surface the shape landed on (a wall beside the floor, a box on the desk) lies off the
    expected plane by more than the offset over most of its points.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        The fit's inliers, camera frame (m).
    expected : ndarray, shape (4,)
        The plane the poses put there (unit normal).
    propagate : PropagateConfig

    Returns
    -------
    bool
        False when there are no points.
    """
    if len(points) == 0:
        return False
    distance = np.abs(points @ np.asarray(expected[:3], dtype=np.float64) + float(expected[3]))
    return bool(np.count_nonzero(distance <= propagate.same_surface_offset) >= ON_EXPECTED_SHARE * len(points))


def _search(sample: np.ndarray, threshold: float, config: RansacConfig) -> RansacSearch:
    """RANSAC's search through ``sample`` with the configured iterations and seed, scored until
    its plane is likely the best (:data:`DEFAULT_PROBABILITY`): ``best()`` gives that plane (unit
    normal towards the camera) and its inliers within ``threshold``, ``score(1.0)`` takes the
    search on through every hypothesis."""
    search = RansacSearch(sample, threshold, config.num_iterations, config.seed)
    search.score()
    return search


def every_hypothesis(points: np.ndarray, threshold: float, iterations: int, seed: int) -> tuple[np.ndarray, int]:
    """RANSAC through all its ``iterations``, never stopping early: :func:`ransac_plane` with
    ``probability = 1`` (the same hypotheses, a superset of those an early stop scores). What
    :func:`fit_plane` ends with when it takes a stopped :class:`RansacSearch` on, without scoring
    the first hypotheses twice (the tests hold the two equal)."""
    return ransac_plane(points, threshold, iterations, seed, probability=1.0)


def ransac_plane(
    points: np.ndarray, threshold: float, iterations: int, seed: int, probability: float = DEFAULT_PROBABILITY,
) -> tuple[np.ndarray, int]:
    """RANSAC's plane: the plane through three of the points with the most points within
    ``threshold`` (the first of equals), re-fitted by least squares to those points.
    Equal counts are not told apart by the inliers' distances, as Open3D's ``segment_plane``
    does (its smaller root mean square wins): the first hypothesis drawn keeps its place.

    The hypotheses are scored a block at a time, each block one product of arrays (Open3D's
    ``segment_plane`` scores them one by one, a pass over the points each). After each block the
    search stops, as Open3D's does, once enough hypotheses were tried to have drawn three inliers
    of the best plane with the given ``probability``: ``log(1 - p) / log(1 - w^3)`` of them, ``w``
    the best plane's share of the points (15 for a plane that holds 90 % of them, 138 for half).
    The first block is :data:`FIRST_BLOCK` hypotheses, as many as a plane that dominates needs.
    Each hypothesis is three distinct points, drawn :data:`TRIPLES_DRAWN` at a time (all of them
    at once for the default 1,000 iterations), so a search that stops early scored the first of
    the hypotheses a full search scores (:class:`RansacSearch` goes on from there). Degenerate
    hypotheses (three collinear points) hold no points.

    Parameters
    ----------
    points : ndarray of float64, shape (N, 3)
        Finite points (m), N >= 3.
    threshold : float
        Largest distance (m) of an inlier, exclusive (as Open3D's).
    iterations : int
        Most hypotheses tried (at least 1).
    seed : int
        Seed of the hypotheses' generator (numpy's).
    probability : float
        Confidence at which the search stops early, in (0, 1]; 1: never (every hypothesis).

    Returns
    -------
    equation : ndarray of float64, shape (4,)
        Unit normal towards the camera (``d >= 0``); the best hypothesis itself when its inliers
        lie on one line; all NaN when no hypothesis holds 3 points (the points lie on one line):
        no point is within any distance of it.
    inliers : int
        Points within ``threshold`` of the best hypothesis.
    """
    search = RansacSearch(points, threshold, iterations, seed)
    search.score(probability)
    return search.best()


class RansacSearch:
    """A RANSAC search that can go on where it stopped: :func:`ransac_plane` is one search
    scored once, :func:`fit_plane` takes one on through every hypothesis.

    A search stopped early at some probability and then taken on with ``probability = 1``
    scores every hypothesis, each once, and ends where :func:`every_hypothesis` does (the first
    of the hypotheses with the most inliers): the hypotheses are drawn in chunks of
    :data:`TRIPLES_DRAWN` from the search's own generator, whatever the blocks scored, so the
    ``i``-th hypothesis is the same however the search was stopped and taken on.

    Parameters
    ----------
    points : ndarray of float64, shape (N, 3)
        Finite points (m), N >= 3.
    threshold : float
        Largest distance (m) of an inlier, exclusive.
    iterations : int
        Most hypotheses tried (at least 1).
    seed : int
        Seed of the hypotheses' generator (numpy's).

    Attributes
    ----------
    done : int
        Hypotheses scored so far.
    best_count : int
        Points within ``threshold`` of the best hypothesis so far (0 before any).
    """

    def __init__(self, points: np.ndarray, threshold: float, iterations: int, seed: int):
        self.points = np.asarray(points, dtype=np.float64)
        self.coords = np.ascontiguousarray(self.points.T)
        self.threshold = threshold
        self.iterations, self.rng = max(int(iterations), 1), np.random.default_rng(seed)
        self.drawn, self.drawn_from = np.zeros((0, 3), dtype=np.int64), 0  # the hypotheses drawn, from the drawn_from-th
        self.per_block = int(np.clip(DISTANCES_PER_BLOCK // max(len(self.points), 1), 1, 100))
        self.best_plane, self.best_count, self.done = np.zeros(4), 0, 0

    def score(self, probability: float = DEFAULT_PROBABILITY) -> None:
        """Score the next hypotheses, a block at a time, until the best plane is likely found
        (:func:`ransac_plane`'s rule) or every hypothesis is scored.

        Parameters
        ----------
        probability : float
            Confidence at which the search stops, in (0, 1]; 1: not before every hypothesis is
            scored.
        """
        if not 0 < probability <= 1:
            raise ValueError(f"RANSAC's probability must be in (0, 1], not {probability}")
        points, needed = self.points, self.iterations
        size = min(FIRST_BLOCK, self.per_block) if probability < 1 and self.done == 0 else self.per_block
        while self.done < needed:
            done, drawn_from = self.done, self.drawn_from
            if done == drawn_from + len(self.drawn):
                self.drawn = _distinct_triples(len(points), min(TRIPLES_DRAWN, self.iterations - done), self.rng)
                self.drawn_from = drawn_from = done
            corners = points[self.drawn[done - drawn_from:min(done + size, needed) - drawn_from]]
            normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
            length = np.sqrt(np.einsum("ij,ij->i", normals, normals))
            usable = length > 0
            normals[usable] /= length[usable, None]
            offsets = -np.einsum("ij,ij->i", normals, corners[:, 0])
            # einsum, not ``@``: no BLAS threads (geometry.planes._fit says why).
            distance = np.einsum("ij,jn->in", normals, self.coords)
            distance += offsets[:, None]
            np.abs(distance, out=distance)
            counts = np.count_nonzero(distance < self.threshold, axis=1)
            counts[~usable] = 0
            winner = int(np.argmax(counts))  # the first of equals
            if counts[winner] > self.best_count:
                self.best_plane, self.best_count = np.append(normals[winner], offsets[winner]), int(counts[winner])
            self.done += len(corners)
            size = self.per_block
            share = self.best_count / len(points)
            if probability < 1 and share > 0:
                needed = self.done if share >= 1 else min(needed, int(np.ceil(np.log1p(-probability) / np.log1p(-share**3))))

    def best(self) -> tuple[np.ndarray, int]:
        """The best hypothesis so far, re-fitted by least squares to its inliers.

        Returns
        -------
        equation : ndarray of float64, shape (4,)
            As :func:`ransac_plane`'s (all NaN when no hypothesis holds 3 points).
        inliers : int
            Points within ``threshold`` of the best hypothesis (0 with a NaN equation).
        """
        if self.best_count < 3:  # no usable hypothesis (its own three points are its inliers)
            return np.full(4, np.nan), 0
        plane, points = self.best_plane, self.points
        try:
            plane = weighted_plane_fit(points[np.abs(points @ plane[:3] + plane[3]) < self.threshold])
        except ValueError:  # inliers on one line (three nearly collinear points, a tiny threshold)
            pass
        return (-plane if plane[3] < 0 else plane), self.best_count


def _distinct_triples(count: int, triples: int, rng: np.random.Generator) -> np.ndarray:
    """``triples`` rows of three distinct indices below ``count`` (>= 3), uniformly drawn.

    Returns
    -------
    ndarray of int64, shape (triples, 3)
    """
    first = rng.integers(0, count, triples)
    second = rng.integers(0, count - 1, triples)
    second += second >= first  # skip the first
    third = rng.integers(0, count - 2, triples)
    low, high = np.minimum(first, second), np.maximum(first, second)
    third += third >= low  # skip both, the lower first
    third += third >= high
    return np.stack([first, second, third], axis=1)

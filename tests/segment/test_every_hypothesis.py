"""RANSAC scored in blocks (segment.ransac.ransac_plane; through all its iterations,
every_hypothesis), against a plain loop over the same hypotheses and Open3D's stopping rule."""

import numpy as np
import pytest

from annotate_rgbd.segment import ransac
from annotate_rgbd.segment.ransac import _distinct_triples, every_hypothesis, ransac_plane


def _two_surfaces(rng, near=400, far=600, gap=0.02, noise=0.003):
    """A table top 2 m away (``far`` points) and papers ``gap`` in front of it (``near`` points)."""
    far_points = np.c_[rng.uniform(-1, 1, (far, 2)), 2.0 + rng.normal(0, noise, far)]
    near_points = np.c_[rng.uniform(-1, 1, (near, 2)), 2.0 - gap + rng.normal(0, noise, near)]
    return rng.permutation(np.r_[far_points, near_points])


def _loop_reference(sample, threshold, iterations, seed, scored=None):
    """One hypothesis at a time: its plane from the 3 points' cross product, its inliers counted
    point by point (strictly within the threshold); the first best one wins, re-fitted by SVD
    to its inliers. Of the ``iterations`` hypotheses drawn, the first ``scored`` (all)."""
    corners = _distinct_triples(len(sample), iterations, np.random.default_rng(seed))[:scored]
    best, best_count = None, -1
    for a, b, c in corners:
        normal = np.cross(sample[b] - sample[a], sample[c] - sample[a])
        if not np.linalg.norm(normal) > 0:
            continue
        normal = normal / np.linalg.norm(normal)
        offset = -float(sample[a] @ normal)
        count = sum(abs(float(p @ normal) + offset) < threshold for p in sample)
        if count > best_count:
            best, best_count = (normal, offset), count
    normal, offset = best
    inliers = sample[np.abs(sample @ normal + offset) < threshold]
    centre = inliers.mean(axis=0)
    normal = np.linalg.svd(inliers - centre)[2][2]
    plane = np.append(normal, -normal @ centre)
    return (-plane if plane[3] < 0 else plane), best_count


@pytest.mark.parametrize("iterations", [1, 100, 101, 237])
def test_the_plane_and_its_count_are_the_plain_loop_s(iterations, monkeypatch):
    rng = np.random.default_rng(iterations)
    sample = _two_surfaces(rng, near=120, far=180)
    threshold = 0.004
    # Blocks of 100 hypotheses: 1, 100, 101 and 237 end inside the first, at its end, one into
    # the second and inside a third.
    monkeypatch.setattr(ransac, "DISTANCES_PER_BLOCK", 100 * len(sample))
    equation, count = every_hypothesis(sample, threshold, iterations, seed=7)
    expected, expected_count = _loop_reference(sample, threshold, iterations, seed=7)
    assert count == expected_count
    assert np.allclose(equation, expected, atol=1e-9)
    assert equation[3] >= 0 and np.linalg.norm(equation[:3]) == pytest.approx(1.0)


def test_it_finds_the_surface_with_more_points():
    rng = np.random.default_rng(3)
    sample = _two_surfaces(rng, near=400, far=600)
    equation, count = every_hypothesis(sample, 0.004, 1000, seed=0)
    assert abs(equation[2]) == pytest.approx(1.0, abs=1e-3)
    assert equation[3] == pytest.approx(2.0, abs=0.003)  # the table, not the papers at 1.98 m
    assert 500 <= count <= 600
    # Another seed draws other hypotheses and finds the same surface.
    other, _ = every_hypothesis(sample, 0.004, 1000, seed=1)
    assert other[3] == pytest.approx(2.0, abs=0.003)
    # The same seed gives the same plane.
    again, again_count = every_hypothesis(sample, 0.004, 1000, seed=0)
    assert np.array_equal(again, equation) and again_count == count
    # Whatever the seed, the table wins with about as many points.
    for seed in range(2, 12):
        plane, found = every_hypothesis(sample, 0.004, 1000, seed=seed)
        assert plane[3] == pytest.approx(2.0, abs=0.003) and abs(found - count) <= 0.05 * count


def test_a_point_at_the_threshold_is_not_an_inlier_and_the_first_of_equals_wins():
    # A triangle on z = 2 m and a point exactly a quarter metre above its centroid (all exact in
    # binary, and so is the triangle's plane). The triangle's plane holds 3 points, the one
    # above lying exactly on the threshold; a plane through the point above and two corners
    # misses the third corner by more: every hypothesis holds 3 points, and the first one wins.
    sample = np.array([[0.0, 0.0, 2.0], [3.0, 0.0, 2.0], [0.0, 3.0, 2.0], [1.0, 1.0, 2.25]])
    winners = set()
    for seed in range(12):
        equation, count = every_hypothesis(sample, 0.25, 6, seed=seed)
        expected, expected_count = _loop_reference(sample, 0.25, 6, seed=seed)
        assert count == expected_count == 3
        assert np.allclose(equation, expected, atol=1e-12)
        winners.add(tuple(equation.round(6)))
    assert len(winners) > 1  # which three points come first decides


def test_triples_are_three_distinct_points_drawn_evenly():
    rng = np.random.default_rng(5)
    triples = _distinct_triples(7, 70_000, rng)
    assert triples.shape == (70_000, 3) and triples.min() == 0 and triples.max() == 6
    assert np.all((triples[:, 0] != triples[:, 1]) & (triples[:, 0] != triples[:, 2]) & (triples[:, 1] != triples[:, 2]))
    for column in triples.T:  # each index about a seventh of the time in every position
        assert np.allclose(np.bincount(column, minlength=7) / len(column), 1 / 7, atol=0.01)
    assert len(np.unique(np.sort(triples, axis=1), axis=0)) == 35  # every 3-subset of 7 occurs
    assert np.all(np.sort(_distinct_triples(3, 20, rng), axis=1) == [0, 1, 2])


def test_degenerate_samples_hold_no_points():
    on_a_line = np.c_[np.linspace(0, 1, 20), np.zeros(20), np.full(20, 2.0)]
    equation, count = every_hypothesis(on_a_line, 0.01, 50, seed=0)
    assert count == 0 and np.isnan(equation).all()  # no point lies within any distance of it
    # Nearly collinear (1e-12 m off the line): a hypothesis holds points, but its inliers admit no
    # least-squares plane; the hypothesis itself comes back, normal towards the camera.
    rng = np.random.default_rng(2)
    almost = on_a_line + rng.normal(0, 1e-12, on_a_line.shape)
    equation, count = every_hypothesis(almost, 0.01, 50, seed=0)
    assert count >= 3 and np.linalg.norm(equation[:3]) == pytest.approx(1.0) and equation[3] >= 0


def _hypotheses_needed(share, probability=ransac.DEFAULT_PROBABILITY):
    """Open3D's stopping rule: enough triples to have drawn three of the best plane's inliers."""
    return np.log(1 - probability) / np.log(1 - share**3)


@pytest.mark.parametrize("plane_share", [0.95, 0.6, 0.35])
def test_an_early_stop_scores_the_blocks_its_confidence_needs(plane_share, monkeypatch):
    # A wall holding plane_share of 300 points, the rest scattered in front of and behind it.
    rng = np.random.default_rng(11)
    on_wall = int(plane_share * 300)
    sample = rng.permutation(np.r_[
        np.c_[rng.uniform(-1, 1, (on_wall, 2)), 2.0 + rng.normal(0, 0.002, on_wall)],
        np.c_[rng.uniform(-1, 1, (300 - on_wall, 2)), rng.uniform(1.0, 3.0, 300 - on_wall)],
    ])
    monkeypatch.setattr(ransac, "DISTANCES_PER_BLOCK", 50 * len(sample))  # blocks: 32, then 50 each
    iterations, threshold = 1000, 0.004
    # The blocks' ends, and the loop's best plane after each: the search stops after the first
    # block whose best plane's share says that enough hypotheses were drawn.
    first = ransac.FIRST_BLOCK
    ends = [first + 50 * i for i in range(20) if first + 50 * i <= iterations]
    for end in ends:
        expected, expected_count = _loop_reference(sample, threshold, iterations, seed=3, scored=end)
        if end >= _hypotheses_needed(expected_count / len(sample)):
            break
    else:
        pytest.fail("no block's end is enough for the loop's best plane: the scene does not test an early stop")
    equation, count = ransac_plane(sample, threshold, iterations, seed=3)
    assert count == expected_count and np.allclose(equation, expected, atol=1e-9)
    assert end < iterations  # it did stop early
    # The first block is as many hypotheses as a plane holding 76 % of the points needs.
    assert _hypotheses_needed(0.76) <= first < _hypotheses_needed(0.75)
    assert (end == first) == (plane_share > 0.76)
    assert equation[3] == pytest.approx(2.0, abs=0.003)  # the wall
    # Never stopping scores every hypothesis: at least as many points, and the same plane as the loop.
    full, full_count = ransac_plane(sample, threshold, iterations, seed=3, probability=1.0)
    loop, loop_count = _loop_reference(sample, threshold, iterations, seed=3)
    assert full_count == loop_count >= count and np.allclose(full, loop, atol=1e-9)


def test_hypotheses_are_drawn_a_chunk_at_a_time(monkeypatch):
    # A huge num_iterations costs no memory up front: the first chunk is the default 1,000
    # hypotheses, and a dominant plane stops the search inside it.
    rng = np.random.default_rng(4)
    sample = np.c_[rng.uniform(-1, 1, (500, 2)), 2.0 + rng.normal(0, 0.002, 500)]
    assert np.array_equal(ransac_plane(sample, 0.004, 10**12, seed=5)[0], ransac_plane(sample, 0.004, 1000, seed=5)[0])
    # Never stopping, chunks of 7: every hypothesis of the chunks is scored, in order.
    sample = _two_surfaces(rng, near=60, far=90)
    chunks = np.random.default_rng(9)
    triples = np.concatenate([_distinct_triples(len(sample), n, chunks) for n in (7,) * 5 + (2,)])
    best = max(range(len(triples)), key=lambda i: (_count(sample, triples[i], 0.004), -i))
    monkeypatch.setattr(ransac, "TRIPLES_DRAWN", 7)
    plane, count = ransac_plane(sample, 0.004, 37, seed=9, probability=1.0)
    assert count == _count(sample, triples[best], 0.004)
    # The plane is that hypothesis's, re-fitted to its inliers.
    a, b, c = sample[triples[best]]
    normal = np.cross(b - a, c - a)
    normal /= np.linalg.norm(normal)
    inliers = sample[np.abs((sample - a) @ normal) < 0.004]
    centre = inliers.mean(axis=0)
    refitted = np.linalg.svd(inliers - centre)[2][2]
    expected = np.append(refitted, -refitted @ centre)
    assert np.allclose(plane, -expected if expected[3] < 0 else expected, atol=1e-9)


def _count(sample, triple, threshold):
    a, b, c = sample[triple]
    normal = np.cross(b - a, c - a)
    normal /= np.linalg.norm(normal)
    return int(np.count_nonzero(np.abs((sample - a) @ normal) < threshold))


@pytest.mark.parametrize("probability", [0.0, -0.5, 1.5, float("nan")])
def test_a_probability_outside_0_to_1_is_refused(probability):
    sample = np.c_[np.random.default_rng(0).uniform(-1, 1, (50, 2)), np.full(50, 2.0)]
    with pytest.raises(ValueError, match="probability must be in"):
        ransac_plane(sample, 0.004, 100, seed=0, probability=probability)


def test_fit_plane_on_points_of_one_line_finds_no_plane():
    # Exact depth on one pixel row of a wall facing the camera: the points lie on one line in space, which no plane
    # (nor any other RANSAC plane) holds. The fit has no inliers and no equation, rather than
    # every point on a plane of zeros.
    from annotate_rgbd.config.masks import RansacConfig
    from annotate_rgbd.geometry.noise import NoiseSettings

    on_a_line = np.c_[np.linspace(-0.5, 0.5, 200), np.full(200, 0.1), np.full(200, 2.0)]
    fit = ransac.fit_plane(on_a_line, RansacConfig(), NoiseSettings())
    assert not fit.inliers.any() and len(fit.inliers) == 200
    assert np.isnan(fit.equation).all() and fit.inliers_refit == 0


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("triples_drawn", [1000, 7])
def test_a_stopped_search_taken_on_ends_where_every_hypothesis_does(seed, triples_drawn, monkeypatch):
    # fit_plane takes an early-stopped search on through every hypothesis (a carried shape whose
    # plane holds few of its points): the plane and count of every_hypothesis, with the
    # hypotheses drawn in one chunk or in many, and each hypothesis scored once.
    monkeypatch.setattr(ransac, "TRIPLES_DRAWN", triples_drawn)
    monkeypatch.setattr(ransac, "DISTANCES_PER_BLOCK", 30 * 300)  # blocks of 30 after the first
    rng = np.random.default_rng(seed)
    sample = _two_surfaces(rng, near=130, far=170)
    search = ransac.RansacSearch(sample, 0.004, 400, seed)
    search.score()
    early_plane, early_count = search.best()
    plain_plane, plain_count = ransac_plane(sample, 0.004, 400, seed)
    assert early_count == plain_count and np.array_equal(early_plane, plain_plane)
    stopped_at = search.done
    assert stopped_at < 400  # it stopped early: there is something to take on
    search.score(probability=1.0)
    assert search.done == 400
    plane, count = search.best()
    expected, expected_count = every_hypothesis(sample, 0.004, 400, seed)
    assert count == expected_count >= early_count
    assert np.array_equal(plane, expected)
    if triples_drawn >= 400:  # the loop draws its hypotheses in one chunk
        reference, reference_count = _loop_reference(sample, 0.004, 400, seed)
        assert count == reference_count and np.allclose(plane, reference, atol=1e-9)


def test_fit_plane_takes_its_own_search_on_to_every_hypothesis_s_plane(monkeypatch):
    # A carried shape (an expected plane) whose RANSAC plane holds under exhaustive_below of its
    # points: the search fit_plane started (on its sample, with the configured iterations and
    # seed) is taken on to the last hypothesis, and the plane re-fitted to the points is
    # every_hypothesis's on that sample. Without an expected plane the early stop stands.
    from annotate_rgbd.config.settings import RansacConfig
    from annotate_rgbd.geometry.noise import SENSOR_MODELS, NoiseSettings

    rng = np.random.default_rng(5)
    points = _two_surfaces(rng, near=450, far=550, gap=0.015, noise=0.002)
    config = RansacConfig(max_points=400, exhaustive_below=1.01, num_iterations=600, seed=11, max_behind=0)
    noise = NoiseSettings(SENSOR_MODELS["kinect_v1"])
    sample = points[:: -(-len(points) // config.max_points)]
    threshold = config.band_share * float(noise.band(np.median(sample[:, 2])))
    searches, refitted = [], []
    real_search, real_refit = ransac.RansacSearch, ransac.refit_plane

    class Recorded(real_search):
        def __init__(self, *args):
            super().__init__(*args)
            searches.append(self)

    def refit(points_, equation, *args, **kwargs):
        refitted.append(np.array(equation))
        return real_refit(points_, equation, *args, **kwargs)

    monkeypatch.setattr(ransac, "RansacSearch", Recorded)
    monkeypatch.setattr(ransac, "refit_plane", refit)
    ransac.fit_plane(points, config, noise, look_behind=False, expected=np.array([0.0, 0.0, -1.0, 2.0]))
    search, = searches
    assert np.array_equal(search.points, sample) and search.threshold == threshold
    assert search.done == config.num_iterations
    expected, _ = every_hypothesis(sample, threshold, config.num_iterations, config.seed)
    assert np.array_equal(refitted[0], expected)
    # A drawn shape: the early stop, where ransac_plane stops.
    searches.clear(), refitted.clear()
    ransac.fit_plane(points, config, noise, look_behind=False)
    early, _ = ransac_plane(sample, threshold, config.num_iterations, config.seed)
    assert searches[0].done < config.num_iterations and np.array_equal(refitted[0], early)


def test_a_search_stopped_inside_a_chunk_of_hypotheses_goes_on_with_the_same_ones(monkeypatch):
    # Hypotheses are drawn 7 at a time here; an early stop after, say, 10 of them leaves the
    # chunk of 7 to 13 drawn and 3 of it unscored: taking the search on must score those 3 and
    # draw the next chunks as a search that never stopped does (chunks by the search's length,
    # not by where the stop fell).
    monkeypatch.setattr(ransac, "TRIPLES_DRAWN", 7)
    stops = set()
    for seed in range(20):
        rng = np.random.default_rng(seed)
        sample = rng.uniform(-1, 1, (300, 3))
        search = ransac.RansacSearch(sample, 0.5, 101, seed)
        search.score()
        stops.add(search.done % 7)
        search.score(probability=1.0)
        plane, count = search.best()
        expected, expected_count = every_hypothesis(sample, 0.5, 101, seed)
        assert count == expected_count and np.array_equal(plane, expected), seed
    assert stops - {0}  # some searches stopped inside a chunk

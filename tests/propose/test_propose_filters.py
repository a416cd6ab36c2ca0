"""What ``propose`` leaves out: tracks that flicker for a frame (the persistence filter)."""

from __future__ import annotations

import numpy as np
import pytest

from annotate_rgbd.propose.persist import PersistenceFilter


def run_filter(sequence, min_frames, max_gap):
    """Feed a sequence of per-frame track lists; return {position: (keep, ids, handed back at)}."""
    gate = PersistenceFilter(min_frames, max_gap)
    out = {}
    for position, tracks in enumerate(sequence):
        for d in gate.add(position, np.array(tracks, dtype=np.int64), f"frame {position}"):
            assert d.payload == f"frame {d.position}"
            out[d.position] = (d.keep.tolist(), d.ids.tolist(), position)
    for d in gate.finish():
        out[d.position] = (d.keep.tolist(), d.ids.tolist(), len(sequence))
    return out


def test_a_track_found_once_is_left_out_and_the_others_numbered_in_order():
    sequence = [[1, 2], [1], [1, 3], [], [3]]
    out = run_filter(sequence, min_frames=2, max_gap=1)
    assert [out[p][:2] for p in range(5)] == [
        ([True, False], [1, 0]), ([True], [1]), ([True, True], [1, 2]), ([], []), ([True], [2])]
    # Frame 0 waits until track 2 can no longer be continued (position 2), frame 2 until
    # track 3 is found again (position 4).
    assert [out[p][2] for p in range(5)] == [2, 2, 4, 4, 4]


def test_min_frames_one_holds_nothing_back():
    out = run_filter([[5, 7], [7], [9]], min_frames=1, max_gap=2)
    assert out == {0: ([True, True], [1, 2], 0), 1: ([True], [2], 1), 2: ([True], [3], 2)}


def reference(sequence, min_frames):
    """Keep and ids from the whole sequence at once: a track is kept when found on at least
    ``min_frames`` frames; kept tracks numbered by first appearance."""
    found = {}
    for tracks in sequence:
        for t in tracks:
            found[t] = found.get(t, 0) + 1
    ids, result = {}, []
    for tracks in sequence:
        keep = [found[t] >= min_frames for t in tracks]
        for t, k in zip(tracks, keep):
            if k and t not in ids:
                ids[t] = len(ids) + 1
        result.append((keep, [ids[t] if k else 0 for t, k in zip(tracks, keep)]))
    return result


@pytest.mark.parametrize("min_frames, max_gap", [(2, 0), (2, 2), (3, 1), (4, 2)])
def test_streaming_decisions_equal_the_whole_sequence_ones(min_frames, max_gap):
    rng = np.random.default_rng(min_frames * 10 + max_gap)
    for _ in range(20):
        # Tracks as a linker makes them: each found on runs of frames at most max_gap + 1 apart.
        sequence = [[] for _ in range(40)]
        next_track, position = 1, 0
        for track in range(1, 30):
            position = int(rng.integers(0, 40))
            for _ in range(int(rng.integers(1, 6))):
                if position >= 40:
                    break
                sequence[position].append(track)
                position += int(rng.integers(1, max_gap + 2))
        out = run_filter(sequence, min_frames, max_gap)
        assert [out[p][:2] for p in range(40)] == reference(sequence, min_frames)
        # A frame is handed back once its tracks are decided: at the latest when each has had
        # min_frames chances (max_gap + 1 positions apart) or can no longer be continued.
        for p in range(40):
            assert out[p][2] <= p + min_frames * (max_gap + 1)


def test_a_track_must_be_large_somewhere_by_every_measure():
    # Sizes per plane: (surface m2, share of the image). Track 1 is large on frame 1 by both,
    # track 2 has the surface but is never more than 2 % of the image, track 3 the reverse.
    gate = PersistenceFilter(1, 0, (0.1, 0.03), ("small_surface", "small_in_view"))
    sizes = [np.array([[0.05, 0.02], [0.3, 0.02], [0.05, 0.2]]), np.array([[0.2, 0.05]])]
    tracks = [[1, 2, 3], [1]]
    out = [d for position, (t, s) in enumerate(zip(tracks, sizes))
           for d in gate.add(position, np.array(t), position, s)] + gate.finish()
    first = next(d for d in out if d.position == 0)
    assert first.keep.tolist() == [True, False, False]
    assert first.reasons == [None, "small_in_view", "small_surface"]
    assert next(d for d in out if d.position == 1).keep.tolist() == [True]


def test_bad_settings_are_refused():
    with pytest.raises(ValueError):
        PersistenceFilter(0, 2)
    with pytest.raises(ValueError):
        PersistenceFilter(2, -1)
    with pytest.raises(ValueError):
        PersistenceFilter(2, 1, (0.1, 0.03), ("small_surface",))  # a reason per measure


# Objects on planes ------------------------------------------------------------------------

from annotate_rgbd.config.settings import FilterConfig  # noqa: E402
from annotate_rgbd.geometry.camera import Camera  # noqa: E402
from annotate_rgbd.geometry.noise import NoiseSettings  # noqa: E402
from annotate_rgbd.config.propose import DetectorConfig, ProposeConfig  # noqa: E402
from annotate_rgbd.propose.detect_job import propose_planes  # noqa: E402
from annotate_rgbd.cvat.pieces import label_boxes  # noqa: E402
from annotate_rgbd.propose.objects import object_hosts  # noqa: E402

CAMERA = Camera(fx=525.0, fy=525.0, cx=319.5, cy=239.5, depth_scale=5000.0)


def wall_with_things(rng):
    """A wall 2 m away facing the camera, a picture 3 cm proud of it, a panel 25 cm before it,
    Kinect noise (computed here: sigma = 1.2 mm + 1.9 mm (z - 0.4)^2)."""
    depth = np.full((480, 640), 2.0)
    depth[150:300, 150:350] = 1.97   # picture: 3 cm proud, 5 sigma at 2 m
    depth[120:260, 430:600] = 1.75   # panel: 25 cm before the wall
    sigma = 0.0012 + 0.0019 * (depth - 0.4) ** 2
    return (depth + rng.normal(0, 1, depth.shape) * sigma).astype(np.float32)


def test_a_picture_on_a_wall_is_not_proposed_and_a_panel_before_it_is():
    depth = wall_with_things(np.random.default_rng(3))
    found = propose_planes(depth, CAMERA, DetectorConfig(), ProposeConfig(), NoiseSettings(), FilterConfig())
    z = np.array([c[2] for c in found.centroids])
    assert sorted(np.round(z, 1).tolist()) == [1.8, 2.0]  # the panel and the wall (its mean over the picture's hole)
    dropped = [d for d in found.dropped if d["reason"] == "on_plane"]
    assert len(dropped) == 1 and dropped[0]["area"] == pytest.approx(150 * 200, rel=0.1)
    assert dropped[0]["equation"][3] == pytest.approx(1.97, abs=0.01)
    # The picture's pixels are nobody's.
    assert np.count_nonzero(found.labels[160:290, 160:340]) < 0.02 * 130 * 180
    # Allowed 2 cm only, the picture is a plane of its own again.
    high = propose_planes(depth, CAMERA, DetectorConfig(), ProposeConfig(object_height=0.02), NoiseSettings(), FilterConfig())
    assert len(high.areas) == 3 and not high.dropped


def test_objects_rule_needs_every_condition():
    wall = [0.0, 0.0, -1.0, 2.0]
    planes = np.array([wall, [0.0, 0.0, -1.0, 1.95], wall])
    areas = np.array([10000, 1000, 500])
    centroids = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 1.95], [0.5, 0.0, 2.0]])
    coverage = np.array([[10000, 900, 0], [0, 1000, 0], [0, 0, 500]])  # [p, q]: q's pixels in p's polygon
    alone = np.zeros((3, 3))  # no plane next to another
    args = dict(max_height=0.1, min_inside=0.5, angle_deg=10.0)
    assert (object_hosts(planes, areas, centroids, coverage, alone, **args) >= 0).tolist() == [False, True, False]
    # Too far before the wall; behind it (a recess); not inside its polygon; tilted; larger.
    assert not (object_hosts(planes, areas, centroids, coverage, alone, **{**args, "max_height": 0.04}) >= 0)[1]
    behind = centroids.copy()
    behind[1, 2] = 2.05
    assert not (object_hosts(planes, areas, behind, coverage, alone, **args) >= 0)[1]
    outside = coverage.copy()
    outside[0, 1] = 400
    assert not (object_hosts(planes, areas, centroids, outside, alone, **args) >= 0)[1]
    # Not inside the wall's polygon but surrounded by the wall (at its edge): on it.
    surrounded = alone.copy()
    surrounded[1] = [0.7, 0.0, 0.3]
    assert (object_hosts(planes, areas, centroids, outside, surrounded, **args) >= 0)[1]
    tilted = planes.copy()
    tilted[1, :3] = [0.0, np.sin(np.radians(15)), -np.cos(np.radians(15))]
    assert not (object_hosts(tilted, areas, centroids, coverage, alone, **args) >= 0)[1]
    assert not (object_hosts(planes, np.array([10000, 20000, 500]), centroids, coverage, alone, **args) >= 0)[1]


def test_an_object_inside_its_planes_band_joins_the_plane():
    depth = wall_with_things(np.random.default_rng(3))
    # Every object joins its plane whatever its share in the band: the picture is no longer
    # dropped, and its pixels, 5 sigma off the wall, stay nobody's (the wall's band decides them).
    joined = propose_planes(depth, CAMERA, DetectorConfig(), ProposeConfig(object_band_share=0.0), NoiseSettings(),
                            FilterConfig())
    assert not [d for d in joined.dropped if d["reason"] == "on_plane"] and len(joined.areas) == 2
    assert np.count_nonzero(joined.labels[160:290, 160:340]) < 0.02 * 130 * 180
    # The default (a majority in the band) keeps it an object; widen_to_noise off: no band, no joining.
    for settings in (ProposeConfig(), ProposeConfig(object_band_share=0.0, widen_to_noise=False)):
        found = propose_planes(depth, CAMERA, DetectorConfig(), settings, NoiseSettings(), FilterConfig())
        assert [d["reason"] for d in found.dropped] == ["on_plane"]


def test_a_strip_at_the_image_border_inside_the_walls_band_joins_the_wall():
    # A wall 2 m away whose left 80 columns the sensor puts 6 sigma nearer (as Kinect v1's bend
    # lifts TUM fr1_rpy's desk at the image's border); cvat2mask's band is 9 sigma here, so the
    # strip lies in the wall's band, while the detector (3 sigma) finds it as a plane of its own,
    # parallel, surrounded by the wall: an object on it. No merging of coplanar pieces.
    rng = np.random.default_rng(3)
    depth = np.full((480, 640), 2.0)
    depth[:, :80] -= 6 * (0.0012 + 0.0019 * 1.6**2)
    depth = (depth + rng.normal(0, 1, depth.shape) * (0.0012 + 0.0019 * (depth - 0.4) ** 2)).astype(np.float32)
    wide = NoiseSettings(k=9.0)
    joined = propose_planes(depth, CAMERA, DetectorConfig(), ProposeConfig(merge_excess=0.5), wide, FilterConfig())
    assert not joined.dropped and len(joined.areas) == 1
    assert np.mean(joined.labels[:, :80] == 1) > 0.99 and np.mean(joined.labels[:, 80:] == 1) > 0.99
    # Never joining (a share above 1): the strip is an object, dropped, and its pixels nobody's.
    apart = propose_planes(depth, CAMERA, DetectorConfig(), ProposeConfig(merge_excess=0.5, object_band_share=2.0), wide,
                           FilterConfig())
    assert [d["reason"] for d in apart.dropped] == ["on_plane"] and apart.dropped[0]["area"] == pytest.approx(80 * 480, rel=0.02)
    assert not apart.labels[:, :80].any() and len(apart.areas) == 1


def test_object_hosts_and_their_band_shares():
    from annotate_rgbd.geometry.noise import ConstantNoise
    from annotate_rgbd.propose.objects import ends_on_object, join_table
    from annotate_rgbd.propose.objects import shares_in_band

    wall = [0.0, 0.0, -1.0, 2.0]
    planes = np.array([wall, [0.0, 0.0, -1.0, 1.99], [0.0, 0.0, -1.0, 1.99], [0.0, 0.0, -1.0, 2.01]])
    areas = np.array([10000, 1000, 500, 20000])
    centroids = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 1.99], [0.5, 0.0, 1.99], [0.0, 0.0, 2.01]])
    coverage = np.array([[10000, 900, 500, 0], [0, 1000, 0, 0], [0, 0, 500, 0], [0, 900, 0, 20000]])
    args = dict(max_height=0.1, min_inside=0.5, angle_deg=10.0)
    # Plane 2 is on the wall and on plane 4 (1 cm behind the wall): the larger host wins; 3 is on
    # the wall only (not inside plane 4's polygon); the wall is not inside plane 4's polygon either.
    hosts = object_hosts(planes, areas, centroids, coverage, np.zeros((4, 4)), **args)
    assert hosts.tolist() == [-1, 3, 0, -1]
    # Shares: the band is 3 x 5 mm = 15 mm; object 2's pixels 1 cm and 4 cm before plane 4
    # (z = 2.01), object 3's 1 cm and 3 cm before the wall.
    labels = np.zeros((4, 6), np.uint8)
    labels[0, :4] = 2
    labels[1, :2] = 3
    labels[2:, :] = 4
    z = np.full((4, 6), 2.01)
    z[0, :4] = [2.0, 2.0, 2.0, 1.97]
    z[1, :2] = [1.99, 1.97]
    points = np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=-1)
    noise = NoiseSettings(model=ConstantNoise(0.005), k=3.0, floor=0.0, cap=1.0)
    boxes = label_boxes(labels, 4)
    shares = shares_in_band(labels, points, planes, np.array([-1, 3, 0, -1]), np.ones(4), noise, boxes)
    expected_2 = np.mean(np.abs(np.array([2.0, 2.0, 2.0, 1.97]) - 2.01) <= 0.015)
    expected_3 = np.mean(np.abs(np.array([1.99, 1.97]) - 2.0) <= 0.015)
    assert shares.tolist() == pytest.approx([0.0, expected_2, expected_3, 0.0])
    assert (expected_2, expected_3) == (0.75, 0.5)
    # 2.5 times the noise of the model on the wall (band 3.75 cm): it holds object 3's 3 cm pixel too.
    wider = shares_in_band(labels, points, planes, np.array([-1, 3, 0, -1]), np.array([2.5, 1, 1, 1]), noise, boxes)
    assert wider[2] == 1.0
    # Joining follows a host that joins its own host: 2 -> 1 -> 4 puts 2 on 4.
    assert join_table(np.array([3, 0, -1, -1]), np.array([True, True, False, False])).tolist() == [0, 4, 4, 3, 4]
    # A plane whose chain of hosts ends on an object that does not join (and is dropped) is an
    # object too: 1 -> 2 -> 3, and 3 lies on the wall 0 without joining it; 4 -> 0 joins the wall.
    hosts, part = np.array([-1, 2, 3, 0, 0]), np.array([False, True, True, False, True])
    assert ends_on_object(hosts, part).tolist() == [False, True, True, False, False]
    assert not ends_on_object(hosts, part & (np.arange(5) == 4)).any()


def test_neighbour_shares_count_the_labelled_ring_only():
    from annotate_rgbd.propose.objects import neighbour_shares

    labels = np.zeros((60, 80), np.uint8)
    labels[:, :40] = 1               # a desk on the left
    labels[:, 40:] = 2               # the floor on the right
    labels[20:30, 25:40] = 3         # a book at the desk's edge, touching the floor
    labels[18:32, 23:42] = np.where(labels[18:32, 23:42] == 3, 3, 0)  # its unlabelled rims
    labels[20:30, 25:40] = 3
    shares = neighbour_shares(labels, 4)
    # Around the book within 4 px: rows 16..33, cols 21..43 minus the book and its rims.
    ring = np.zeros_like(labels, bool)
    ring[16:34, 21:44] = True
    ring[18:32, 23:42] = False
    expected_desk = np.count_nonzero(ring & (labels == 1)) / np.count_nonzero(ring & (labels > 0))
    assert shares[2, 0] == pytest.approx(expected_desk)
    assert shares[2, 1] == pytest.approx(1 - expected_desk)
    assert shares[2, 2] == 0


# Pieces of one bent surface ----------------------------------------------------------------

from annotate_rgbd.propose.seams import seam_groups, seam_pairs  # noqa: E402


def two_pieces(turn_deg, step, rng):
    """A wall 1.5 m away: the left half facing the camera, the right half turned by ``turn_deg``
    about the vertical line where they meet (x = 0) and moved ``step`` metres towards the camera;
    labels 1 (left) and 2 (right), depth with Kinect noise; the planes fitted here."""
    rows, cols = np.mgrid[0:480, 0:640].astype(np.float64)
    x, y = (cols - CAMERA.cx) / CAMERA.fx, (rows - CAMERA.cy) / CAMERA.fy
    turn = np.radians(turn_deg)
    normal_right = np.array([-np.sin(turn), 0.0, -np.cos(turn)])
    z_left = np.full(x.shape, 1.5)
    z_right = (1.5 - step) / (np.sin(turn) * x + np.cos(turn))  # n . X + d = 0 through (0, *, 1.5 - step)
    depth = np.where(cols < 320, z_left, z_right)
    depth = depth + rng.normal(0, 1, depth.shape) * (0.0012 + 0.0019 * (depth - 0.4) ** 2)
    labels = np.where(cols < 320, 1, 2).astype(np.uint8)
    planes = np.array([[0.0, 0.0, -1.0, 1.5], [*normal_right, (1.5 - step) * np.cos(turn)]])
    return labels, depth, planes


@pytest.mark.parametrize("turn_deg, step, joined", [(4.0, 0.0, True), (0.0, 0.0, True), (0.0, 0.03, False),
                                                     (30.0, 0.0, False), (4.0, 0.02, False)])
def test_pieces_meeting_without_step_or_crease_are_joined(turn_deg, step, joined):
    labels, depth, planes = two_pieces(turn_deg, step, np.random.default_rng(7))
    sigma = NoiseSettings().model.sigma
    groups = seam_groups(labels, depth, planes, CAMERA, sigma, band_k=3.0, angle_deg=10.0, min_seam=20, reach=2)
    assert bool(groups[1] == groups[0]) is joined


def test_seam_pairs_find_the_pixels_along_the_border_only():
    labels = np.zeros((10, 12), np.uint8)
    labels[:, :5] = 1
    labels[:, 7:] = 2          # two columns of nothing between them
    labels[8:, :] = 3          # a strip along the bottom touching both
    pairs = seam_pairs(labels, reach=2)
    assert set(pairs) == {(1, 3), (2, 3)}  # 1 and 2 are three pixels apart
    left, right = seam_pairs(labels, reach=3)[(1, 2)]
    np.testing.assert_array_equal(np.unravel_index(left, labels.shape)[1], np.full(8, 4))
    np.testing.assert_array_equal(np.unravel_index(right, labels.shape)[1], np.full(8, 7))


@pytest.mark.parametrize("reach", [0, 1, 2, 3])
def test_seam_pairs_match_a_pixel_by_pixel_search(reach):
    # Speckled labels (many short seams, borders at the image's edges) against a walk over
    # every pixel and its neighbours up to ``reach`` to the right and below (0: none, no seam;
    # propose.seam_reach_px = 0 raised in np.concatenate).
    rng = np.random.default_rng(reach)
    labels = rng.integers(0, 5, size=(23, 17)).astype(np.uint8)
    labels[rng.random(labels.shape) < 0.5] = 0
    expected: dict = {}
    height, width = labels.shape
    for r in range(height):
        for c in range(width):
            for dr, dc in [(0, s) for s in range(1, reach + 1)] + [(s, 0) for s in range(1, reach + 1)]:
                if r + dr >= height or c + dc >= width:
                    continue
                a, b = int(labels[r, c]), int(labels[r + dr, c + dc])
                if a and b and a != b:
                    low, high = ((r, c), (r + dr, c + dc)) if a < b else ((r + dr, c + dc), (r, c))
                    sides = expected.setdefault((min(a, b), max(a, b)), (set(), set()))
                    sides[0].add(low[0] * width + low[1])
                    sides[1].add(high[0] * width + high[1])
    pairs = seam_pairs(labels, reach)
    assert list(pairs) == sorted(expected)
    for key, (low, high) in pairs.items():
        assert low.tolist() == sorted(expected[key][0])
        assert high.tolist() == sorted(expected[key][1])


def test_plane_centroids_and_distances_are_the_sums_over_their_pixels():
    # Against np.bincount over the whole image (its sums run in raster order, as the job's over
    # the labelled pixels do): equal to the last bit.
    depth = wall_with_things(np.random.default_rng(5))
    depth[400:, :100] = np.nan
    found = propose_planes(depth, CAMERA, DetectorConfig(), ProposeConfig(), NoiseSettings(), FilterConfig())
    k = len(found.areas)
    assert k >= 2
    flat = found.labels.ravel()
    rays = (np.arange(640) - CAMERA.cx) / CAMERA.fx, (np.arange(480) - CAMERA.cy) / CAMERA.fy
    x = (rays[0].astype(np.float32)[None, :] * depth).ravel().astype(np.float64)
    y = (rays[1].astype(np.float32)[:, None] * depth).ravel().astype(np.float64)
    sums = [np.bincount(flat, weights=np.nan_to_num(v), minlength=k + 1)[1:] for v in (x, y, depth.ravel().astype(np.float64))]
    assert np.array_equal(found.centroids, np.stack(sums, axis=1) / found.areas[:, None])
    assert np.array_equal(found.areas, np.bincount(flat, minlength=k + 1)[1:])

"""Unit tests of plane proposals: merging pieces, draw order, track linking, the CVAT writer's
track attributes and sampled keyframes, and export-cvat's outlines."""

from __future__ import annotations

import numpy as np
import pytest
from lxml import etree

from annotate_rgbd.annotation.model import Annotation, Shape, Track
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.cvat import read_cvat, write_cvat_video
from annotate_rgbd.config.propose import LinkConfig, ProposeConfig
from annotate_rgbd.cvat.from_masks import draw_order, piece_outlines
from annotate_rgbd.geometry.noise import NoiseSettings
from annotate_rgbd.geometry.planes import Moments
from annotate_rgbd.propose import FrameProposal, link_proposals
from annotate_rgbd.propose.detect_job import paint
from annotate_rgbd.propose.merge import merge_groups
from annotate_rgbd.propose.link import shifted_iou
from annotate_rgbd.segment.rasterize import rasterize_frame, shape_mask

CAMERA = Camera(fx=525.0, fy=525.0, cx=319.5, cy=239.5, depth_scale=5000.0)
H, W = 480, 640
NOISE = NoiseSettings()


def label_moments(labels: np.ndarray, depth: np.ndarray, camera: Camera, stride: int = 2) -> Moments:
    """Moments of the back-projected valid pixels of every label 1..K, computed here from the
    pixels (the job takes the detector's own), every ``stride``-th pixel along rows and columns.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
    depth : ndarray of float, shape (H, W)
        Metres, NaN where invalid.
    camera : Camera
    stride : int

    Returns
    -------
    Moments
        ``count`` counts the sampled pixels.
    """
    n = int(labels.max(initial=0))
    sub_labels, sub_depth = labels[::stride, ::stride], depth[::stride, ::stride]
    rows, cols = np.nonzero((sub_labels > 0) & np.isfinite(sub_depth))
    z = sub_depth[rows, cols].astype(np.float64)
    which = sub_labels[rows, cols].astype(np.intp) - 1
    rows, cols = rows * stride, cols * stride
    points = np.stack([(cols - camera.cx) / camera.fx * z, (rows - camera.cy) / camera.fy * z, z], axis=1)
    count = np.bincount(which, minlength=n).astype(np.float64)[:n]
    total = np.stack([np.bincount(which, weights=points[:, i], minlength=n)[:n] for i in range(3)], axis=1)
    mean = total / np.maximum(count, 1)[:, None]
    centred = points - mean[which]
    scatter = np.empty((n, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            scatter[:, i, j] = scatter[:, j, i] = np.bincount(which, weights=centred[:, i] * centred[:, j], minlength=n)[:n]
    return Moments(count, mean, scatter)


def plane_depth(normal, d, shape=(H, W), camera=CAMERA):
    """z of each pixel's ray on the plane n . X + d = 0 (independent of the code under test)."""
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    x, y = (cols - camera.cx) / camera.fx, (rows - camera.cy) / camera.fy
    return -d / (normal[0] * x + normal[1] * y + normal[2])


def test_pieces_of_one_plane_merge_and_parallel_planes_do_not():
    rng = np.random.default_rng(0)
    floor = np.array([0.0, -0.8, -0.6])  # a floor seen from above at an angle
    floor /= np.linalg.norm(floor)
    depth = plane_depth(floor, 1.5)
    sigma = NOISE.model.sigma
    depth = (depth + rng.normal(0, 1, depth.shape) * sigma(depth)).astype(np.float32)
    labels = np.zeros((H, W), np.uint8)
    labels[300:400, 50:250] = 1   # left of a table
    labels[300:400, 400:600] = 2  # right of it: the same floor
    # 3: a parallel plane 8 sigma above the floor (a low step), beside the others.
    step = plane_depth(floor, 1.5 - 8 * float(sigma(np.array([2.0]))[0]))
    labels[420:470, 100:500] = 3
    depth[420:470, 100:500] = step[420:470, 100:500]
    moments = label_moments(labels, depth, CAMERA)
    groups = merge_groups(moments, sigma, ProposeConfig().merge_excess)
    assert groups[0] == groups[1]
    assert groups[2] != groups[0]


@pytest.mark.parametrize("seed", range(4))
def test_merge_groups_merges_as_recomputing_every_pair_each_round_does(seed):
    # Pieces of a few planes (several merges, chains of them) against the greedy merge that fits
    # every pair of the current groups again in each round.
    from annotate_rgbd.geometry.planes import fit_planes, merge_pairs, residual_ms

    rng = np.random.default_rng(seed)
    sigma, excess = NOISE.model.sigma, ProposeConfig().merge_excess
    normals = [np.array(v) / np.linalg.norm(v) for v in ([0.0, -0.8, -0.6], [0.3, 0.0, -1.0], [0.0, 0.0, -1.0])]
    labels, depth = np.zeros((H, W), np.uint8), np.full((H, W), np.nan)
    for k in range(1, 13):
        top, left = int(rng.integers(0, H - 60)), int(rng.integers(0, W - 80))
        plane = normals[k % 3], 1.2 + 0.6 * (k % 3) + (0.03 if k == 7 else 0.0)
        labels[top : top + 50, left : left + 70] = k
        z = plane_depth(*plane)[top : top + 50, left : left + 70]
        depth[top : top + 50, left : left + 70] = z + rng.normal(0, 1, z.shape) * sigma(z)
    moments = label_moments(labels, depth, CAMERA)
    scales = 1 + rng.random(len(moments.count)) * (seed % 2)
    expected = np.arange(len(moments.count))
    current = Moments(moments.count.copy(), moments.mean.copy(), moments.scatter.copy())
    scale2, alive = scales**2, moments.count > 0
    while alive.sum() > 1:
        idx = np.flatnonzero(alive)
        i, j = np.triu_indices(len(idx), 1)
        a, b = idx[i], idx[j]
        joint = merge_pairs(current, a, b)
        ms = [residual_ms(m.count, fit_planes(m.mean, m.scatter)[1]) for m in (joint, current.take(a), current.take(b))]
        added = ms[0] - (current.count[a] * ms[1] + current.count[b] * ms[2]) / joint.count
        pair = (current.count[a] * scale2[a] + current.count[b] * scale2[b]) / joint.count
        ratio = added / (excess * pair * sigma(joint.mean[:, 2]) ** 2)
        best = int(np.argmin(ratio))
        if ratio[best] > 1:
            break
        keep, gone = a[best], b[best]
        current.count[keep], current.mean[keep], current.scatter[keep] = joint.count[best], joint.mean[best], joint.scatter[best]
        scale2[keep], alive[gone] = pair[best], False
        expected[expected == gone] = keep
    assert len(np.unique(expected)) < len(expected) - 2  # several merges
    assert merge_groups(moments, sigma, excess, scales).tolist() == expected.tolist()


def test_draw_order_puts_the_plane_that_fills_an_overlap_on_top():
    labels = np.zeros((100, 120), np.uint8)
    labels[10:90, 10:110] = 1   # a wall
    labels[30:60, 40:80] = 2    # a picture on it: the wall's filled outline covers it
    labels[70:100, 0:40] = 3    # a box in front of the wall's lower left corner
    labels[70:90, 10:40] = 3
    polygons = {
        1: np.array([[10, 10], [110, 10], [110, 90], [10, 90]], float),
        2: np.array([[40, 30], [80, 30], [80, 60], [40, 60]], float),
        3: np.array([[0, 70], [40, 70], [40, 100], [0, 100]], float),
    }
    windows = [shape_mask(Shape("polygon", polygons[k]), *labels.shape) for k in (1, 2, 3)]
    # Distances that would put the picture and the box below the wall if used alone.
    z = draw_order(labels, windows, np.array([1.0, 2.0, 3.0]))
    assert z[1] > z[0] and z[2] > z[0]
    painted = paint(windows, z, labels.shape)
    assert np.array_equal(painted, labels)


def proposal(position, masks, planes, labels_shape=(H, W)):
    """A FrameProposal of rectangles ``masks`` (rows, cols slices) with these planes."""
    labels = np.zeros(labels_shape, np.uint8)
    outlines = []
    for k, (rows, cols) in enumerate(masks, start=1):
        labels[rows, cols] = k
        outlines.append(np.array([[cols.start, rows.start], [cols.stop, rows.start],
                                  [cols.stop, rows.stop], [cols.start, rows.stop]], float))
    planes = np.asarray(planes, float)
    centroids = []
    for (rows, cols), plane in zip(masks, planes):
        r, c = (rows.start + rows.stop - 1) / 2, (cols.start + cols.stop - 1) / 2
        ray = np.array([(c - CAMERA.cx) / CAMERA.fx, (r - CAMERA.cy) / CAMERA.fy, 1.0])
        centroids.append(ray * (-plane[3] / (plane[:3] @ ray)))
    areas = np.bincount(labels.ravel(), minlength=len(masks) + 1)[1:]
    return FrameProposal(position, labels, planes.reshape(-1, 4), areas, np.array(centroids).reshape(-1, 3),
                         np.ones(len(masks)), np.ones(len(masks)), outlines, np.arange(len(masks)), [])


WALL = [0.0, 0.0, -1.0, 2.0]  # z = 2 m, facing the camera


def test_linking_without_poses_follows_overlap_and_plane():
    first = proposal(0, [(slice(100, 300), slice(100, 300)), (slice(300, 400), slice(0, 640))],
                     [WALL, [0.0, -1.0, 0.0, 1.0]])
    # Moved a little; a third plane 20 cm behind the wall overlaps the wall's old place.
    second = proposal(1, [(slice(110, 310), slice(110, 310)), (slice(305, 400), slice(0, 640)),
                          (slice(100, 200), slice(300, 400))],
                      [WALL, [0.0, -1.0, 0.0, 1.0], [0.0, 0.0, -1.0, 2.2]])
    ids = link_proposals([first, second], np.array([0.0, 1 / 30]), LinkConfig(), NOISE, CAMERA)
    assert ids[0].tolist() == [1, 2]
    assert ids[1].tolist() == [1, 2, 3]
    # The same frames 1 s apart: the allowed camera motion (0.5 m) now covers the 20 cm, but
    # the new plane still overlaps the wall's old mask far less than the wall itself.
    ids = link_proposals([first, second], np.array([0.0, 1.0]), LinkConfig(), NOISE, CAMERA)
    assert ids[1].tolist() == [1, 2, 3]


def test_plane_far_off_the_tracked_one_starts_a_new_track():
    first = proposal(0, [(slice(100, 300), slice(100, 300))], [WALL])
    second = proposal(1, [(slice(100, 300), slice(100, 300))], [[0.0, 0.0, -1.0, 2.3]])
    ids = link_proposals([first, second], np.array([0.0, 1 / 30]), LinkConfig(), NOISE, CAMERA)
    assert ids[1].tolist() == [2]


def test_linking_with_poses_uses_the_reprojected_outline():
    # The camera moves 0.4 m to the right: the wall's image moves 105 px left.
    shift = int(round(CAMERA.fx * 0.4 / 2.0))
    first = proposal(0, [(slice(100, 300), slice(200, 350))], [WALL])
    second = proposal(1, [(slice(100, 300), slice(200 - shift, 350 - shift))], [WALL])
    times = np.array([0.0, 1 / 30])
    eye = np.eye(3)
    poses = [(eye, np.zeros(3)), (eye, np.array([0.4, 0.0, 0.0]))]
    config = LinkConfig(min_iou=0.5)
    assert link_proposals([first, second], times, config, NOISE, CAMERA, poses)[1].tolist() == [1]
    # Without poses the masks overlap too little (IoU ~0.17): a new track.
    assert link_proposals([first, second], times, config, NOISE, CAMERA)[1].tolist() == [2]


def test_tracks_continue_over_a_missed_frame_only_within_max_gap():
    wall = [(slice(100, 300), slice(100, 300))]
    frames = [proposal(0, wall, [WALL]), proposal(1, [], np.zeros((0, 4))), proposal(2, wall, [WALL])]
    times = np.arange(3) / 30
    assert link_proposals(frames, times, LinkConfig(max_gap=1), NOISE, CAMERA)[2].tolist() == [1]
    assert link_proposals(frames, times, LinkConfig(max_gap=0), NOISE, CAMERA)[2].tolist() == [2]


SIDE = [1.0, 0.0, 0.0, 0.5]  # a cabinet side 0.5 m to the left, seen edge-on: a narrow strip


def strip(position, left, width=32):
    return proposal(position, [(slice(150, 350), slice(left, left + width))], [SIDE])


def test_narrow_plane_panning_past_keeps_its_track_over_a_missed_frame():
    # The camera pans: the strip moves 20 px a frame, and the detector misses it on frame 1.
    # Its masks on frames 0 and 2 are 40 px apart and do not overlap at all (IoU 0); shifted
    # back by what a camera turning 60 deg/s moves the image in 2/30 s (~45 px), they coincide.
    frames = [strip(0, 300), proposal(1, [], np.zeros((0, 4))), strip(2, 340)]
    ids = link_proposals(frames, np.arange(3) / 30, LinkConfig(), NOISE, CAMERA)
    assert ids[2].tolist() == [1]


def test_shift_search_stays_within_the_camera_motion_limits():
    # 160 px in 1/30 s is far beyond 60 deg/s and 0.5 m/s: a different strip, a new track.
    frames = [strip(0, 200), strip(1, 360)]
    assert link_proposals(frames, np.arange(2) / 30, LinkConfig(), NOISE, CAMERA)[1].tolist() == [2]
    # The same 160 px over 1/3 s (every 10th frame) is within them.
    assert link_proposals(frames, np.arange(2) / 3, LinkConfig(), NOISE, CAMERA)[1].tolist() == [1]


def test_shifted_iou_is_the_best_overlap_over_the_allowed_shifts():
    rng = np.random.default_rng(4)
    for _ in range(20):
        first = np.zeros((30, 40), bool)
        second = np.zeros((30, 40), bool)
        r, c = rng.integers(0, 20, 2)
        first[r : r + rng.integers(2, 10), c : c + rng.integers(2, 15)] = True
        second[rng.random((30, 40)) < 0.05] = True
        second[r + 3 : r + 9, c - 2 + rng.integers(0, 4) : c + 12] = True
        reach = int(rng.integers(0, 6))
        best = 0.0
        for dy in range(-reach, reach + 1):
            for dx in range(-reach, reach + 1):
                moved = np.zeros_like(second)  # second[p + (dy, dx)] laid over first[p]
                moved[max(-dy, 0) : 30 - max(dy, 0), max(-dx, 0) : 40 - max(dx, 0)] = \
                    second[max(dy, 0) : 30 - max(-dy, 0), max(dx, 0) : 40 - max(-dx, 0)]
                inter = np.count_nonzero(first & moved)
                best = max(best, inter / (first.sum() + second.sum() - inter))
        assert shifted_iou(first, second, reach) == pytest.approx(best, abs=1e-9)
    assert shifted_iou(first, np.zeros_like(first), 3) == 0.0


def test_video_writer_track_attributes_and_sampled_keyframes(tmp_path):
    square = np.array([[10, 10], [50, 10], [50, 50], [10, 50]], float)
    moved = square + [20, 0]
    track = Track(7, "plane", {0: Shape("polygon", square), 5: Shape("polygon", moved)},
                  attributes={"equation": "0 0 -1 2"})
    annotation = Annotation("p", "video", [track], list(range(12)))
    path = tmp_path / "p.xml"
    write_cvat_video(annotation, path, width=64, height=64, sampled_frames=[0, 5, 10])
    root = etree.parse(str(path)).getroot()
    shapes = root.findall("track/polygon")
    assert [(s.get("frame"), s.get("keyframe"), s.get("outside")) for s in shapes] == [
        ("0", "1", "0"), ("5", "1", "0"), ("10", "1", "1")]
    assert all(s.find("attribute").get("name") == "equation" and s.find("attribute").text == "0 0 -1 2"
               for s in shapes)
    assert root.find("meta/task/labels/label/attributes/attribute/name").text == "equation"
    read = read_cvat(path).tracks[0]
    assert sorted(read.shapes) == list(range(10))  # interpolated 1..4 and 6..9, outside from 10
    assert np.allclose(read.shapes[3].points, square + [12, 0])


def test_piece_outlines_cover_every_piece():
    labels = np.zeros((60, 90), np.int32)
    labels[5:25, 5:30] = 1
    labels[30:55, 50:85] = 1  # the same plane, apart (a floor on both sides of a table)
    labels[35:50, 10:40] = 2
    outlines = piece_outlines(labels, tolerance_px=0.0)
    drawn = rasterize_frame([(k, Shape("polygon", outlines[k])) for k in (1, 2)], *labels.shape)
    # Plane 1's pieces are joined by a one-pixel corridor between their nearest corners, pixels
    # (29, 24) and (50, 30): a 4-connected path of |dx| + |dy| - 1 pixels outside both.
    extra = (drawn == 1) & (labels == 0)
    assert np.array_equal(drawn[labels > 0], labels[labels > 0])
    assert np.count_nonzero(extra) == (50 - 29) + (30 - 24) - 1
    assert not (drawn[labels == 0] == 2).any()


@pytest.mark.parametrize("shape", [(40, 40), (33, 57)])
def test_piece_outlines_of_one_piece_equal_a_filled_region(shape):
    rng = np.random.default_rng(shape[1])
    labels = (rng.random(shape) < 0.0).astype(np.int32)
    labels[5:-5, 4:-6] = 1
    labels[10:15, 10:20] = 0  # a hole: filled by the outline
    drawn = rasterize_frame([(1, Shape("polygon", piece_outlines(labels, 0.0)[1]))], *shape)
    expected = labels.copy()
    expected[10:15, 10:20] = 1
    assert np.array_equal(drawn, expected)


def test_piece_on_an_island_stays_covered():
    labels = np.zeros((60, 60), np.int32)
    labels[5:55, 5:55] = 1
    labels[15:45, 15:45] = 2   # another plane in a hole of plane 1 ...
    labels[25:35, 25:35] = 1   # ... with a piece of plane 1 on it
    outlines = piece_outlines(labels, tolerance_px=0.0)
    drawn = rasterize_frame([(1, Shape("polygon", outlines[1]))], *labels.shape)
    assert drawn[25:35, 25:35].all() and drawn[5:55, 5:55].all()


def test_tracks_end_where_the_sampled_frames_stop_not_at_the_end_of_the_task(tmp_path):
    import numpy as np

    from annotate_rgbd.annotation.model import Shape
    from annotate_rgbd.cvat import read_cvat
    from annotate_rgbd.propose.output import TrackShapes, write_polygon_tracks

    square = np.array([[10.0, 10.0], [30.0, 10.0], [30.0, 30.0], [10.0, 30.0]])

    def written(sampled, n_frames):
        track = TrackShapes(1, "plane", shapes={f: Shape("polygon", square) for f in sampled})
        path = tmp_path / f"t{len(sampled)}_{n_frames}.xml"
        write_polygon_tracks([track], path, n_frames=n_frames, sampled_frames=sampled, width=64, height=48)
        return sorted(read_cvat(path).tracks[0].shapes)

    # A run whose masks stop at frame 9 of a 30-frame task (frames skipped, a part cut short):
    # the track ends there instead of CVAT carrying its polygon over frames 10-29.
    assert written(list(range(10)), 30) == list(range(10))
    # Every 10th frame looked at (propose --every 10): the last shape holds to the task's end, as
    # between samples.
    assert written([0, 10, 20], 22) == list(range(22))

"""Plane detector (annotate_rgbd.detect) against depth frames rendered here with exact ground truth.

Scenes are ray-cast analytically (bounded planes, nearest hit), the depth gets Kinect-like axial
noise sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2 (Nguyen et al. 2012) and random holes. IoU is
measured on pixels with valid depth, the only ones a depth-based detector can label.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest
from conftest import reference_data
from scipy import ndimage

from annotate_rgbd.geometry.camera import Camera, backproject, depth_to_metres
from annotate_rgbd.config.propose import DetectorConfig
from annotate_rgbd.cvat.from_masks import plane_outlines
from annotate_rgbd.detect import detect_planes
from annotate_rgbd.detect.cells import cloud_cells
from annotate_rgbd.geometry.noise import SENSOR_MODELS
from annotate_rgbd.segment.rasterize import polygon_window

KINECT = Camera(525.0, 525.0, 319.5, 239.5, 5000.0)
ICL_LIKE = Camera(481.2, -480.0, 319.5, 239.5, 5000.0)  # fy < 0: y-up camera frame
SHAPE = (480, 640)
BIG = 1e3


def kinect_sigma(z):
    return 0.0012 + 0.0019 * (z - 0.4) ** 2


# --- rendering ---------------------------------------------------------------------------------


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """World -> camera rotation (rows: camera x right, y down, z forward, in world axes)."""
    forward = np.subtract(target, eye, dtype=float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    return np.stack([right, np.cross(forward, right), forward])


def render(faces, eye, target, camera=KINECT, shape=SHAPE):
    """Ray-cast bounded world planes ``(normal, d, low corner, high corner)``.

    Returns depth (z, 0 where nothing is hit), the index of the face seen at each pixel (-1
    for none) and each face's plane in the camera frame, unit normal towards the camera.
    """
    rotation = look_at(eye, target)
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    # Ray with camera z = 1 (so the hit parameter is the depth), in world axes.
    rays = backproject(cols.ravel(), rows.ravel(), np.ones(rows.size), camera) @ rotation
    eye = np.asarray(eye, dtype=float)
    depth = np.full(rows.size, np.inf)
    index = np.full(rows.size, -1)
    planes = []
    for k, (normal, d, low, high) in enumerate(faces):
        normal = np.asarray(normal, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -(normal @ eye + d) / (rays @ normal)
        hit = eye + t[:, None] * rays
        inside = (t > 0) & np.all((hit >= np.asarray(low) - 1e-9) & (hit <= np.asarray(high) + 1e-9), axis=1)
        closer = inside & (t < depth)
        depth[closer], index[closer] = t[closer], k
        # n.p_w + d = 0 with p_w = R^T p_c + eye  ->  (R n).p_c + (n.eye + d) = 0
        plane = np.append(rotation @ normal, normal @ eye + d)
        planes.append(plane if plane[3] > 0 else -plane)
    depth[index < 0] = 0
    return depth.reshape(shape), index.reshape(shape), np.array(planes)


def sensor(depth, seed=0, dropout=0.03, sigma=kinect_sigma):
    """Axial Gaussian noise and random holes; NaN where invalid."""
    rng = np.random.default_rng(seed)
    noisy = depth + rng.standard_normal(depth.shape) * sigma(depth)
    noisy[(depth <= 0) | (rng.random(depth.shape) < dropout)] = np.nan
    return noisy.astype(np.float32)


def room_corner():
    """Floor z = 0, walls x = 1.5 and y = 2.5, a 0.6 x 0.6 x 0.45 m box on the floor."""
    return [
        ((0, 0, 1), 0.0, (-BIG, -BIG, -1e-9), (1.5, 2.5, 1e-9)),
        ((1, 0, 0), -1.5, (1.5, -BIG, 0), (1.5, 2.5, 2.5)),
        ((0, 1, 0), -2.5, (-BIG, 2.5, 0), (1.5, 2.5, 2.5)),
        ((0, 0, 1), -0.45, (0.2, 1.0, 0.45), (0.8, 1.6, 0.45)),
        ((1, 0, 0), -0.2, (0.2, 1.0, 0), (0.2, 1.6, 0.45)),
        ((1, 0, 0), -0.8, (0.8, 1.0, 0), (0.8, 1.6, 0.45)),
        ((0, 1, 0), -1.0, (0.2, 1.0, 0), (0.8, 1.0, 0.45)),
        ((0, 1, 0), -1.6, (0.2, 1.6, 0), (0.8, 1.6, 0.45)),
    ]


ROOM_VIEW = dict(eye=(-0.4, -0.3, 1.3), target=(0.8, 1.5, 0.4))


def wall(distance, tilt_deg=10.0, step=None):
    """A wall facing the camera at ``distance`` m, turned by ``tilt_deg``; with ``step``, its
    right half (x > 0) is ``step`` m nearer the camera. World = camera axes here (y down)."""
    turn = np.deg2rad(tilt_deg)
    normal = (np.sin(turn), 0.0, -np.cos(turn))
    if step is None:
        return [(normal, distance, (-BIG,) * 3, (BIG,) * 3)]
    return [
        (normal, distance, (-BIG, -BIG, -BIG), (0.0, BIG, BIG)),
        (normal, distance - step, (0.0, -BIG, -BIG), (BIG, BIG, BIG)),
    ]


def render_facing(faces, camera=KINECT):
    """Render with the camera at the origin looking along +z, y down (world = camera axes)."""
    rows, cols = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]]
    rays = backproject(cols.ravel(), rows.ravel(), np.ones(rows.size), camera)
    depth = np.full(rows.size, np.inf)
    index = np.full(rows.size, -1)
    planes = []
    for k, (normal, d, low, high) in enumerate(faces):
        normal = np.asarray(normal, dtype=float)
        t = -d / (rays @ normal)
        hit = t[:, None] * rays
        inside = (t > 0) & np.all((hit >= np.asarray(low)) & (hit <= np.asarray(high)), axis=1)
        closer = inside & (t < depth)
        depth[closer], index[closer] = t[closer], k
        planes.append(np.append(normal, d))
    depth[index < 0] = 0
    return depth.reshape(SHAPE), index.reshape(SHAPE), np.array(planes)


# --- matching ----------------------------------------------------------------------------------


def match(detection, truth, valid, min_area):
    """IoU (on valid pixels) of each true plane of area >= min_area with its best detection.

    Returns ``{true index: (label, IoU)}`` and the detected labels that match no true plane
    with IoU >= 0.5.
    """
    found = {}
    matched = set()
    for k in range(int(truth.max()) + 1):
        true = (truth == k) & valid
        if np.count_nonzero(truth == k) < min_area:
            continue
        overlap = np.bincount(detection[true], minlength=detection.max() + 1)
        overlap[0] = 0
        label = int(np.argmax(overlap))
        iou = overlap[label] / np.count_nonzero(true | (detection == label)) if label else 0.0
        found[k] = (label, iou)
        if iou >= 0.5:
            matched.add(label)
    extra = sorted(set(range(1, int(detection.max()) + 1)) - matched)
    return found, extra


def plane_error(estimated, true):
    """Angle between normals in degrees and difference of offsets d in metres."""
    angle = np.degrees(np.arccos(np.clip(estimated[:3] @ true[:3], -1, 1)))
    return angle, abs(estimated[3] - true[3])


def iou(a, b):
    return np.count_nonzero(a & b) / np.count_nonzero(a | b)


@pytest.fixture(scope="module")
def room():
    depth, truth, planes = render(room_corner(), **ROOM_VIEW)
    measured = sensor(depth, seed=1)
    return measured, truth, planes, detect_planes(measured, KINECT)


# --- tests -------------------------------------------------------------------------------------


def test_room_corner_every_plane_found_with_its_equation(room):
    depth, truth, planes, detection = room
    valid = np.isfinite(depth)
    min_area = 0.01 * depth.size
    found, extra = match(detection.labels, truth, valid, min_area)
    assert len(found) == 6  # floor, two walls, box top and two box sides reach 1 %
    for k, (label, overlap) in found.items():
        assert overlap >= 0.9, f"true plane {k}: IoU {overlap:.3f}"
        angle, offset = plane_error(detection.planes[label - 1], planes[k])
        assert angle <= 2.0 and offset <= 0.01, f"true plane {k}: {angle:.2f} deg, {offset * 100:.2f} cm"
    assert extra == []
    assert detection.planes.shape == (len(found), 4)


def test_output_conventions(room):
    depth, _, _, detection = room
    labels, planes, areas = detection.labels, detection.planes, detection.areas
    assert labels.dtype == np.uint8 and labels.shape == depth.shape
    assert np.array_equal(areas, np.bincount(labels.ravel(), minlength=len(areas) + 1)[1:])
    assert np.all(np.diff(areas) <= 0)  # largest first
    assert np.allclose(np.linalg.norm(planes[:, :3], axis=1), 1) and np.all(planes[:, 3] > 0)
    assert not np.any(labels[~np.isfinite(depth)])  # only pixels with depth
    # Each plane is the least-squares fit to its pixels: an independent SVD fit agrees.
    rows, cols = np.nonzero(labels == 2)
    points = backproject(cols, rows, depth[rows, cols], KINECT)
    centre = points.mean(axis=0)
    normal = np.linalg.svd(points - centre, full_matrices=False)[2][-1]
    normal *= -np.sign(normal @ centre)
    assert np.allclose(planes[1], np.append(normal, -normal @ centre), atol=1e-6)
    # The moments the planes were fitted to come with them (for merging labels without a second pass).
    for k in range(1, len(areas) + 1):
        rows, cols = np.nonzero(labels == k)
        points = backproject(cols, rows, depth[rows, cols].astype(float), KINECT)
        centre = points.mean(axis=0)
        scatter = (points - centre).T @ (points - centre)
        assert np.allclose(detection.means[k - 1], centre, rtol=0, atol=1e-8)
        assert np.allclose(detection.scatters[k - 1], scatter, rtol=0, atol=1e-6 * np.abs(scatter).max())
    # Every labelled pixel lies within the band of its plane (refit moves it a little).
    for k in range(1, len(areas) + 1):
        rows, cols = np.nonzero(labels == k)
        z = depth[rows, cols].astype(float)
        distance = np.abs(backproject(cols, rows, z, KINECT) @ planes[k - 1, :3] + planes[k - 1, 3])
        assert np.mean(distance <= 3 * kinect_sigma(z)) >= 0.99


def test_camera_with_negative_fy():
    """ICL-NUIM intrinsics (fy < 0): the same scene, equations in that camera's frame."""
    depth, truth, planes = render(room_corner(), camera=ICL_LIKE, **ROOM_VIEW)
    measured = sensor(depth, seed=2)
    detection = detect_planes(measured, ICL_LIKE)
    found, extra = match(detection.labels, truth, np.isfinite(measured), 0.01 * depth.size)
    assert extra == [] and len(found) >= 5
    for k, (label, overlap) in found.items():
        assert overlap >= 0.9
        angle, offset = plane_error(detection.planes[label - 1], planes[k])
        assert angle <= 2.0 and offset <= 0.01


def test_deterministic(room):
    depth, _, _, first = room
    again = detect_planes(depth.copy(), KINECT)
    assert np.array_equal(first.labels, again.labels)
    assert np.array_equal(first.planes, again.planes)
    assert np.array_equal(first.areas, again.areas)


def test_a_merge_gap_beyond_the_grid_merges_as_the_whole_grid(room):
    # 640 x 480 at 20 px: a 24 x 32 grid. A gap of 1000 cells raised (the offsets sliced the grid
    # out of step); one of the grid's own size reaches every pair already.
    depth = room[0]
    whole = detect_planes(depth, KINECT, DetectorConfig(merge_gap_cells=32))
    beyond = detect_planes(depth, KINECT, DetectorConfig(merge_gap_cells=1000))
    np.testing.assert_array_equal(beyond.labels, whole.labels)
    np.testing.assert_array_equal(beyond.planes, whole.planes)


def test_far_noisy_wall_is_one_plane():
    """At 3.5 m the noise is 2 cm: a fixed millimetre threshold would shatter the wall."""
    depth, _, plane = render_facing(wall(3.5))
    measured = sensor(depth, seed=3)
    assert np.nanstd(measured - depth) > 0.015
    detection = detect_planes(measured, KINECT)
    assert detection.planes.shape[0] == 1
    assert iou(detection.labels == 1, np.isfinite(measured)) >= 0.9
    angle, offset = plane_error(detection.planes[0], plane[0])
    assert angle <= 2.0 and offset <= 0.01
    # The same frame judged with the noise of 1 m everywhere is no longer one plane.
    blind = detect_planes(measured, KINECT, noise=lambda z: np.full_like(z, kinect_sigma(1.0)))
    assert blind.planes.shape[0] != 1 or iou(blind.labels == 1, np.isfinite(measured)) < 0.9


def test_small_step_at_one_metre_splits_two_planes():
    """A 3 cm step at 1 m is 16 sigma: two planes, split at the step."""
    depth, truth, planes = render_facing(wall(1.0, step=0.03))
    measured = sensor(depth, seed=4)
    detection = detect_planes(measured, KINECT)
    found, extra = match(detection.labels, truth, np.isfinite(measured), 0.01 * depth.size)
    assert len(found) == 2 and extra == []
    for k, (label, overlap) in found.items():
        assert overlap >= 0.9
        angle, offset = plane_error(detection.planes[label - 1], planes[k])
        assert angle <= 2.0 and offset <= 0.01
    # With noise as large as the step the two are one plane: the split comes from the model.
    merged = detect_planes(measured, KINECT, noise=lambda z: np.full_like(z, 0.03))
    assert merged.planes.shape[0] == 1


def test_min_area_removes_small_planes():
    # A box face of about 0.5 % of the image in front of a wall.
    faces = wall(2.0, tilt_deg=0) + [((0, 0, -1), 1.5, (0.05, 0.05, 1.4), (0.2, 0.18, 1.6))]
    depth, truth, _ = render_facing(faces)
    share = np.mean(truth == 1)
    assert 0.003 < share < 0.01
    measured = sensor(depth, seed=5)
    default = detect_planes(measured, KINECT)
    assert default.planes.shape[0] == 1 and iou(default.labels == 1, (truth == 0) & np.isfinite(measured)) >= 0.9
    finer = detect_planes(measured, KINECT, DetectorConfig(min_area_fraction=0.002))
    assert finer.planes.shape[0] == 2
    assert iou(finer.labels == 2, (truth == 1) & np.isfinite(measured)) >= 0.8


def test_cell_planes_match_an_independent_fit(room):
    depth = room[0]
    config = DetectorConfig()
    cells = cloud_cells(depth, KINECT, 20, kinect_sigma, config.planar_k, config.min_valid_fraction)
    for index in (0, 137, 300, 517, 767):
        r, c = divmod(index, cells.grid[1])
        rows, cols = np.mgrid[r * 20 : r * 20 + 20, c * 20 : c * 20 + 20]
        z = depth[rows, cols]
        keep = np.isfinite(z)
        points = backproject(cols[keep], rows[keep], z[keep], KINECT)
        centre = points.mean(axis=0)
        _, singular, vt = np.linalg.svd(points - centre, full_matrices=False)
        assert cells.count[index] == keep.sum()
        assert np.allclose(cells.mean[index], centre, atol=1e-6)
        assert np.isclose(cells.mse[index], singular[-1] ** 2 / keep.sum(), rtol=1e-3)
        assert abs(abs(cells.normal[index] @ vt[-1]) - 1) < 1e-6
        assert cells.normal[index] @ centre < 0 and cells.offset[index] > 0


@pytest.mark.parametrize("seed", range(3))
def test_cell_segment_boxes_are_scipys_find_objects(seed):
    from annotate_rgbd.detect.refine import _boxes

    rng = np.random.default_rng(seed)
    grid = rng.integers(0, 9, size=(30, 40)) * (rng.random((30, 40)) < 0.1)
    grid[grid == 3] = 0
    assert _boxes(grid) == ndimage.find_objects(grid)
    assert _boxes(grid, 12) == ndimage.find_objects(grid, max_label=12)


def test_just_above_is_nextafter_towards_infinity():
    from annotate_rgbd.detect.refine import _just_above

    rng = np.random.default_rng(1)
    tiny, big = np.finfo(np.float32).smallest_subnormal, np.finfo(np.float32).max
    values = np.concatenate([rng.uniform(0, 0.1, 1000), rng.uniform(-5, 5, 100),
                             [0.0, -0.0, tiny, -tiny, big, -big, np.inf, -np.inf, np.nan]]).astype(np.float32)
    with np.errstate(over="ignore"):  # the largest float32 goes to infinity
        expected = np.nextafter(values, np.float32(np.inf))
    assert np.array_equal(_just_above(values).view(np.int32)[:-1], expected.view(np.int32)[:-1])
    assert np.isnan(_just_above(values)[-1])


def test_zero_and_negative_depths_are_invalid(room):
    depth = np.array(room[0], dtype=np.float32)
    holes = np.random.default_rng(2).random(depth.shape) < 0.2
    with_nan = depth.copy()
    with_nan[holes] = np.nan
    sigma = SENSOR_MODELS["kinect_v1"].sigma
    a = cloud_cells(with_nan, KINECT, 20, sigma, 3.0, 0.5)
    assert not np.shares_memory(a.depth, with_nan)
    for invalid in (0.0, -1.0):
        other = depth.copy()
        other[holes] = invalid
        b = cloud_cells(other, KINECT, 20, sigma, 3.0, 0.5)
        assert np.array_equal(a.depth, b.depth, equal_nan=True) and np.array_equal(a.scatter, b.scatter)


def test_no_depth_no_planes():
    detection = detect_planes(np.full(SHAPE, np.nan, dtype=np.float32), KINECT)
    assert detection.planes.shape == (0, 4) and not detection.labels.any()
    with pytest.raises(ValueError, match="2-D"):
        detect_planes(np.zeros(10), KINECT)


def test_config_rejects_bad_values():
    for bad in (dict(cell_px=1), dict(band_k=0), dict(min_area_fraction=2), dict(min_angle_deg=30)):
        with pytest.raises(ValueError):
            DetectorConfig(**bad)


# --- outlines ------------------------------------------------------------------------------------


def raster(polygon, shape=SHAPE):
    top, left, inside = polygon_window(polygon, *shape)
    mask = np.zeros(shape, dtype=bool)
    mask[top : top + inside.shape[0], left : left + inside.shape[1]] = inside
    return mask


def test_outline_of_a_rectangle_rasterises_back_exactly():
    labels = np.zeros((60, 80), dtype=np.uint8)
    labels[10:30, 5:45] = 3
    outlines = plane_outlines(labels)
    assert list(outlines) == [3] and len(outlines[3]) == 4
    assert np.array_equal(raster(outlines[3], labels.shape), labels == 3)


@pytest.mark.parametrize("shape", ["disc", "rotated", "triangle", "thin"])
def test_outlines_round_trip_compact_regions(shape):
    canvas = np.zeros(SHAPE, dtype=np.uint8)
    if shape == "disc":
        cv2.circle(canvas, (300, 200), 90, 1, -1)
    elif shape == "rotated":
        box = cv2.boxPoints(((320, 240), (260, 120), 27.0))
        cv2.fillPoly(canvas, [np.round(box).astype(np.int32)], 1)
    elif shape == "triangle":
        cv2.fillPoly(canvas, [np.array([[50, 400], [600, 420], [300, 30]], dtype=np.int32)], 1)
    else:
        canvas[100:104, 50:550] = 1  # 4 px wide band
    outline = plane_outlines(canvas, tolerance_px=1.5)[1]
    assert len(outline) < 60  # simplified
    assert iou(raster(outline), canvas == 1) >= 0.95


def test_outline_keeps_the_largest_piece_and_fills_holes():
    labels = np.zeros(SHAPE, dtype=np.uint16)
    labels[50:250, 50:350] = 7
    labels[100:150, 100:200] = 0  # hole
    labels[400:420, 400:420] = 7  # small second piece
    outline = plane_outlines(labels)[7]
    mask = raster(outline)
    assert np.array_equal(mask[:300], np.pad(np.ones((200, 300), bool), ((50, 50), (50, 290)))[:300])
    assert not mask[300:].any()


def test_outlines_of_detected_planes(room):
    labels = room[3].labels
    outlines = plane_outlines(labels)
    assert sorted(outlines) == list(range(1, labels.max() + 1))
    for k, outline in outlines.items():
        pieces, n = ndimage.label(labels == k, structure=np.ones((3, 3)))
        largest = pieces == 1 + np.argmax(np.bincount(pieces.ravel())[1:])
        assert iou(raster(outline), ndimage.binary_fill_holes(largest)) >= 0.95


# --- real frames ---------------------------------------------------------------------------------




REAL = {
    "tum_fr1_rpy": ("tum_fr1_rpy/depth", Camera(517.3, 516.5, 318.6, 255.3, 5000.0)),
    "icl_nuim": ("icl_nuim_depth", Camera(481.2, -480.0, 319.5, 239.5, 5000.0)),
    "realsense_d435": ("realsense_d435_office/depth", Camera(615.0, 615.0, 320.0, 240.0, 1000.0)),
}


@pytest.mark.parametrize("name", sorted(REAL))
def test_real_frame_sanity(name):
    folder, camera = REAL[name]
    files = sorted(reference_data(folder).glob("*.png"))
    depth = depth_to_metres(cv2.imread(str(files[0]), cv2.IMREAD_UNCHANGED), camera.depth_scale)
    start = time.perf_counter()
    detection = detect_planes(depth, camera)
    print(f"{name} {files[0].name}: {detection.planes.shape[0]} planes in {1e3 * (time.perf_counter() - start):.1f} ms")
    assert detection.planes.shape[0] >= 2
    assert np.all(detection.areas >= 0.01 * depth.size)
    for k in range(1, detection.planes.shape[0] + 1):
        rows, cols = np.nonzero(detection.labels == k)
        z = depth[rows, cols].astype(float)
        # Signed: > 0 on the camera's side; the band is 1.5 times wider behind the plane.
        signed = backproject(cols, rows, z, camera) @ detection.planes[k - 1, :3] + detection.planes[k - 1, 3]
        band = 3 * kinect_sigma(z)
        assert np.mean((signed <= band) & (signed >= -DetectorConfig().band_behind * band)) >= 0.9
    outlines = plane_outlines(detection.labels)
    assert len(outlines) == detection.planes.shape[0]


def test_pixels_are_given_to_a_plane_within_a_band_wider_behind_it():
    """A wall 2 m away (sigma 6.1 mm: a 3 sigma band of 18 mm), measured with 1 mm noise; a tenth
    of its pixels, scattered, lie 24 mm behind it, another tenth 24 mm in front."""
    rng = np.random.default_rng(4)
    depth = (2.0 + rng.normal(0, 0.001, (480, 640))).astype(np.float32)
    scatter = rng.random(depth.shape)
    front, behind = scatter < 0.1, scatter > 0.9
    step = np.float32(4 * kinect_sigma(2.0))  # 4 sigma: beyond the band, inside 1.5 times it
    depth[front] -= step
    depth[behind] += step
    taken = {k: detect_planes(depth, KINECT, DetectorConfig(band_behind=k)).labels > 0 for k in (1.0, 1.5)}
    inner = (slice(20, -20), slice(20, -20))
    assert taken[1.5][inner][behind[inner]].mean() > 0.99 and not taken[1.5][front].any()
    assert not taken[1.0][behind].any() and not taken[1.0][front].any()
    plain = ~front & ~behind
    assert all(taken[k][inner][plain[inner]].mean() > 0.99 for k in taken)

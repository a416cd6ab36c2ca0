"""Label masks -> simple polygons (annotate_rgbd.cvat.from_masks, annotate_rgbd.cvat.rings).

Validity is judged by shapely (a test tool only, ``pip install -e '.[test]'``), independent of
the package's own edge test; pixels by the package's rasteriser, which the CVAT reader tests pin.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from conftest import reference_data
from scipy import ndimage

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.config.settings import load_config
from annotate_rgbd.cvat import read_cvat
from annotate_rgbd.cvat.from_masks import outline_planes, plane_outlines
from annotate_rgbd.cvat.pieces import close_corners, kept_pieces, label_boxes, piece_corridors
from annotate_rgbd.cvat.rings import _Simplifier, meeting_edges, simplify_ring, sorted_unique
from annotate_rgbd.propose import run_propose
from annotate_rgbd.segment.rasterize import rasterize_frame

shapely = pytest.importorskip("shapely", reason="shapely (a test tool): pip install -e '.[test]'")


def is_simple(points: np.ndarray) -> bool:
    """A valid shapely polygon whose ring is simple and repeats no vertex."""
    ring = shapely.LinearRing(points)
    return bool(shapely.Polygon(points).is_valid and ring.is_simple and len(np.unique(points, axis=0)) == len(points))


def speckled(seed: int, shape=(120, 160), planes: int = 4) -> np.ndarray:
    """Planes of random blobs, holes and speckle: many pieces, pixels touching at corners."""
    rng = np.random.default_rng(seed)
    labels = np.zeros(shape, np.int32)
    for k in range(1, planes + 1):
        for _ in range(rng.integers(1, 4)):
            centre = (int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0])))
            axes = (int(rng.integers(5, 40)), int(rng.integers(5, 30)))
            cv2.ellipse(labels, centre, axes, float(rng.uniform(0, 180)), 0, 360, k, -1)
    noise = rng.random(shape)
    labels[noise < 0.15] = 0  # speckle and holes
    flip = (noise > 0.97) & (labels == 0)
    labels[flip] = rng.integers(1, planes + 1, size=np.count_nonzero(flip))
    return labels


@pytest.mark.parametrize("seed, planes", [(0, 4), (1, 1), (2, 90), (3, 300)])
def test_label_boxes_are_scipys_find_objects(seed, planes):
    # Few labels (one pass each) and many (one pass by label), absent labels among them.
    labels = speckled(seed, planes=planes).astype(np.uint16)
    labels[labels == 2] = 0
    assert label_boxes(labels) == ndimage.find_objects(labels)
    assert label_boxes(labels, planes + 5) == ndimage.find_objects(labels, max_label=planes + 5)
    assert label_boxes(labels[:, :1]) == ndimage.find_objects(labels[:, :1])
    assert label_boxes(np.zeros((0, 4), np.uint8)) == []


@pytest.mark.parametrize("seed", range(12))
@pytest.mark.parametrize("tolerance, budget", [(0.0, 0), (1.5, 0), (1.5, 24), (3.0, 8)])
def test_polygons_are_simple_and_within_budget(seed, tolerance, budget):
    labels = speckled(seed)
    outlines = outline_planes(labels, tolerance, budget)
    assert sorted(outlines) == [k for k in range(1, labels.max() + 1) if (labels == k).any()]
    for outline in outlines.values():
        assert is_simple(outline.points), outline.points.tolist()
        assert len(outline.points) >= 3
        if budget:
            assert len(outline.points) <= budget
            if outline.unlimited is not None:
                assert len(outline.unlimited) > budget and is_simple(outline.unlimited)
        else:
            assert outline.unlimited is None


@pytest.mark.parametrize("seed", range(6))
def test_exact_outlines_cover_the_large_pieces_and_little_else(seed):
    # At tolerance 0 a polygon holds every pixel of its plane's pieces of >= 20 pixels, the
    # holes between, and beyond those only its corridors and corner pixels.
    labels = speckled(seed)
    outlines = outline_planes(labels, 0.0)
    for k, outline in outlines.items():
        drawn = rasterize_frame([(1, Shape("polygon", outline.points))], *labels.shape) == 1
        pieces, n = ndimage.label(labels == k, structure=np.ones((3, 3)))
        sizes = np.bincount(pieces.ravel())[1:]
        large = np.isin(pieces, np.flatnonzero(sizes >= 20) + 1) if (sizes >= 20).any() else pieces == 1 + np.argmax(sizes)
        assert drawn[large].all()
        # Corridors are one pixel wide: few pixels beside the pieces and their holes.
        outside = np.count_nonzero(drawn & ~ndimage.binary_fill_holes(large))
        assert outside <= 0.25 * np.count_nonzero(large) + 2 * labels.shape[1]


def test_a_diagonal_touch_gets_no_self_touching_outline():
    labels = np.zeros((12, 12), np.int32)
    labels[2:6, 2:6] = 1
    labels[6:10, 6:10] = 1  # touches the first square at one corner only
    outline = plane_outlines(labels, 0.0)[1]
    assert is_simple(outline)
    drawn = rasterize_frame([(1, Shape("polygon", outline))], *labels.shape) == 1
    assert drawn[labels == 1].all() and np.count_nonzero(drawn & (labels == 0)) == 1  # one corner pixel


def test_the_budget_trades_vertices_for_iou():
    canvas = np.zeros((240, 320), np.uint8)
    cv2.circle(canvas, (160, 120), 100, 1, -1)
    ious = []
    for budget in (0, 48, 16, 8):
        outline = plane_outlines(canvas, 0.5, budget)[1]
        assert is_simple(outline) and (budget == 0 or len(outline) <= budget)
        drawn = rasterize_frame([(1, Shape("polygon", outline))], *canvas.shape) == 1
        ious.append(np.count_nonzero(drawn & (canvas == 1)) / np.count_nonzero(drawn | (canvas == 1)))
    assert ious[0] > 0.995 and ious[1] > 0.99 and ious[2] > 0.95 and ious[3] > 0.85
    assert ious == sorted(ious, reverse=True)


def test_simplify_ring_stays_within_the_tolerance_and_simple():
    rng = np.random.default_rng(5)
    angles = np.sort(rng.uniform(0, 2 * np.pi, 400))
    radius = 50 + 30 * rng.random(400)  # a spiky star: simplifying it naively crosses edges
    ring = np.round(np.stack([radius * np.cos(angles), radius * np.sin(angles)], axis=1) * 4) / 4
    keep = simplify_ring(ring, 6.0)
    polygon = shapely.Polygon(ring[keep])
    assert is_simple(ring[keep]) and len(keep) < len(ring)
    distances = shapely.distance(shapely.points(ring), polygon.exterior)
    assert distances.max() <= 6.0 + 1e-9


@pytest.mark.parametrize("seed", range(200))
def test_meeting_edges_agrees_with_shapely(seed):
    rng = np.random.default_rng(seed)
    points = rng.integers(0, 6, (int(rng.integers(3, 10)), 2)) / 2.0
    if len(np.unique(points, axis=0)) < len(points):
        assert len(meeting_edges(points)) > 0  # a repeated vertex is never simple
        return
    assert (len(meeting_edges(points)) == 0) == is_simple(points), points.tolist()


@pytest.mark.parametrize("seed", range(60))
def test_meeting_edges_lists_every_pair_shapely_finds(seed):
    # Every pair (i, j), i < j, in order: non-neighbouring edges that share a point, and
    # neighbours that overlap along a length (distinct vertices: shapely has no edge of no length).
    rng = np.random.default_rng(seed)
    points = rng.integers(0, 5, (int(rng.integers(3, 12)), 2)) / 2.0
    points = points[np.sort(np.unique(points, axis=0, return_index=True)[1])]
    m = len(points)
    if m < 3:
        assert len(meeting_edges(points)) == 0
        return
    edges = [shapely.LineString([points[i], points[(i + 1) % m]]) for i in range(m)]
    expected = []
    for i in range(m):
        for j in range(i + 1, m):
            if j - i == 1 or (i == 0 and j == m - 1):
                if edges[i].intersection(edges[j]).length > 0:
                    expected.append([i, j])
            elif edges[i].intersects(edges[j]):
                expected.append([i, j])
    assert meeting_edges(points).tolist() == expected


@pytest.mark.parametrize("seed, min_piece, most", [(0, 20, 0), (1, 20, 3), (2, None, 0), (3, 1, 0), (4, 20, 1)])
def test_kept_pieces_are_the_large_8_connected_pieces_largest_first(seed, min_piece, most):
    mask = speckled(seed) == 1
    region, pieces, kept = kept_pieces(mask, min_piece, most)
    found, n = ndimage.label(mask, structure=np.ones((3, 3)))
    sizes = np.bincount(found.ravel(), minlength=n + 1)[1:]
    large = np.flatnonzero(sizes >= (min_piece or 1)) if min_piece is not None else np.array([], int)
    chosen = large if len(large) else np.array([np.argmax(sizes)])
    if most and len(chosen) > most:  # the largest; the test's masks have no tie at the cut
        ranked = np.sort(sizes[chosen])[::-1]
        assert ranked[most - 1] > ranked[most]
        chosen = chosen[sizes[chosen] >= ranked[most - 1]]
    kept_sizes = [np.count_nonzero(pieces == p) for p in kept]
    assert kept_sizes == sorted(kept_sizes, reverse=True)  # largest first
    assert sorted(kept_sizes) == sorted(sizes[chosen].tolist())
    assert np.array_equal(region, np.isin(found, chosen + 1))
    for p in kept:  # every kept piece is one of ndimage's pieces, whole
        assert len(np.unique(found[pieces == p])) == 1 and np.array_equal(found == found[pieces == p][0], pieces == p)


@pytest.mark.parametrize("seed", range(8))
def test_piece_corridors_join_each_piece_to_the_nearest_joined_one(seed):
    # Prim's tree over the pieces' border pixels, against all pairwise distances: each corridor
    # starts at the first border pixel (raster order) of the piece nearest to those joined, and
    # ends at a border pixel of a joined piece at that distance.
    mask = speckled(seed, planes=6) >= 3
    region, pieces, kept = kept_pieces(mask, 20)
    if len(kept) < 3:
        pytest.skip("fewer than three pieces")
    border = region & ~ndimage.binary_erosion(region, structure=ndimage.generate_binary_structure(2, 1))
    ys, xs = np.nonzero(border)
    points = {k: np.stack([xs, ys], axis=1)[pieces[ys, xs] == k] for k in kept}
    joined, remaining = [kept[0]], list(kept[1:])
    for start, end in piece_corridors(region, pieces, kept):
        gaps = {k: min(np.sqrt(((points[k][:, None] - points[j][None]) ** 2).sum(-1)).min() for j in joined) for k in remaining}
        nearest = min(remaining, key=lambda k: (gaps[k], kept.index(k)))
        to_joined = np.concatenate([points[j] for j in joined])
        distances = np.sqrt(((points[nearest][:, None] - to_joined[None]) ** 2).sum(-1)).min(axis=1)
        assert start == tuple(points[nearest][np.argmax(distances <= gaps[nearest])].tolist())
        assert np.hypot(start[0] - end[0], start[1] - end[1]) == pytest.approx(gaps[nearest])
        assert any(tuple(p) == end for p in to_joined.tolist())
        joined.append(nearest)
        remaining.remove(nearest)
    assert not remaining


@pytest.mark.parametrize("seed", range(10))
def test_close_corners_fills_as_passes_over_the_whole_region_do(seed):
    # Pass after pass over every 2 x 2 block, each filling the upper right pixel of a falling
    # corner and the upper left of a rising one, until none is left (chains of diagonal pixels
    # need several passes).
    rng = np.random.default_rng(seed)
    region = rng.random((40, 50)) < (0.2 if seed % 2 else 0.5)
    region[5:25, 5:25] = np.eye(20, dtype=bool) | np.eye(20, dtype=bool)[::-1]  # long diagonals
    expected = region.copy()
    passes = 0
    while True:
        a, b, c, d = expected[:-1, :-1], expected[:-1, 1:], expected[1:, :-1], expected[1:, 1:]
        falling, rising = a & d & ~b & ~c, b & c & ~a & ~d
        if not (falling.any() or rising.any()):
            break
        expected[:-1, 1:] |= falling
        expected[:-1, :-1] |= rising
        passes += 1
    assert passes >= 2
    assert np.array_equal(close_corners(region), expected)
    assert np.array_equal(close_corners(region[:1]), region[:1]) and close_corners(region[:0]).shape == (0, 50)


def test_sorted_unique_is_numpys_unique_and_union():
    rng = np.random.default_rng(4)
    for size in (0, 1, 2, 7, 500):
        a, b = rng.integers(-20, 40, size), rng.integers(0, 9, (3, 4)).astype(np.intp)
        assert np.array_equal(sorted_unique(a), np.unique(a)) and sorted_unique(a).dtype == np.unique(a).dtype
        assert np.array_equal(sorted_unique(a, b), np.union1d(a, b))


def test_anchored_simplification_is_douglas_peucker_on_each_chain():
    # The vertices kept between anchors: approxPolyDP on every chain (ends included) at each
    # tolerance, chains of two vertices (an anchor next to an anchor) among them.
    rng = np.random.default_rng(11)
    angles = np.sort(rng.uniform(0, 2 * np.pi, 300))
    ring = np.round(np.stack([(60 + 20 * rng.random(300)) * np.cos(angles), 70 * np.sin(angles)], axis=1) * 4) / 4
    ring = ring[np.unique(ring, axis=0, return_index=True)[1]]
    ring = ring[np.argsort(np.arctan2(ring[:, 1], ring[:, 0]))]
    anchors = np.array([3, 4, 50, 51, 52, 120, 121, 150, 152, 200, len(ring) - 2, len(ring) - 1])
    assert len(ring) > 250
    simplify = _Simplifier(ring, anchors)
    points = (ring * 4).astype(np.int32)
    for tolerance in (0.3, 1.0, 2.5, 7.0):
        expected = set(anchors.tolist())
        bounds = anchors.tolist() + [anchors[0] + len(ring)]
        for a, b in zip(bounds[:-1], bounds[1:]):
            chain = np.array([points[i % len(ring)] for i in range(a, b + 1)], np.int32).reshape(-1, 1, 2)
            for x, y in cv2.approxPolyDP(chain, 4 * tolerance, closed=False).reshape(-1, 2).tolist():
                expected.add(int(np.flatnonzero((points[:, 0] == x) & (points[:, 1] == y))[0]))
        assert simplify(tolerance).tolist() == sorted(expected)
    for some in (anchors[:0], anchors[:1], anchors):  # counted without the vertices: as many
        counted = _Simplifier(ring, some)
        assert [counted.count(t) for t in (0.1, 0.6, 3.0, 40.0, 500.0)] == [len(counted(t)) for t in (0.1, 0.6, 3.0, 40.0, 500.0)]


def test_outlines_of_real_proposals_are_simple_and_small(tmp_path):
    """TUM fr1_rpy's proposals (propose on every 10th of its 30 frames): every polygon simple and
    within the budget, the budget's cost in IoU with the planes' pixels small on average."""
    sequence = reference_data("tum_fr1_rpy")
    out = tmp_path / "out"
    run_propose(sequence, out, load_config("fr1_desk", {"propose.every": 10}), workers=1)
    report = json.loads((out / "report.json").read_text())
    polygons = [t.shapes[f].points for t in read_cvat(out / "proposals.xml").tracks for f in sorted(t.keyframes)]
    assert polygons
    budget = load_config("fr1_desk").propose.max_vertices
    for points in polygons:
        assert is_simple(points) and len(points) <= budget
    summary = report["summary"]["polygons"]
    assert summary["polygons"] == len(polygons) and summary["mean_polygon_iou"] > 0.85
    assert summary["mean_budget_iou_cost"] < 0.06

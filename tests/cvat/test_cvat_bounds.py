"""The CVAT reader's work is bounded by vertices: self-crossing test, outline matching, budget."""

from __future__ import annotations

import numpy as np
import pytest

from annotate_rgbd.cvat import MAX_POLYGON_VERTICES, read_cvat, tracks
from annotate_rgbd.cvat.geometry import crosses_itself
from annotate_rgbd.errors import InputError
from annotate_rgbd.cvat.interpolate import match_outlines


def all_pairs_cross(points: np.ndarray) -> bool:
    """The former all-pairs test, as the reference: ends strictly on opposite sides both ways."""
    start = np.asarray(points, dtype=np.float64)
    end = np.roll(start, -1, axis=0)
    along = end - start

    def side(p):  # [i, j]: p[j] against the line of edge i
        return along[:, None, 0] * (p[None, :, 1] - start[:, None, 1]) - along[:, None, 1] * (p[None, :, 0] - start[:, None, 0])

    straddles = side(start) * side(end) < 0
    return bool((straddles & straddles.T).any())


def comb(teeth: int, height: int) -> np.ndarray:
    """A simple integer polygon (a mask outline's staircase): teeth with square-wave sides."""
    up = np.arange(0, height, 2)
    ys = np.stack([up, up, up + 1, up + 1], axis=1).ravel()
    xs = np.tile([0, 1, 1, 0], len(up))
    parts = []
    for tooth in range(teeth):
        x0 = 4 * tooth
        left = np.column_stack([x0 + xs, ys])
        right = np.column_stack([2 * x0 + 3 - left[::-1, 0], left[::-1, 1]])
        parts += [left, [[x0, height], [x0 + 3, height]], right]
    parts.append([[4 * teeth - 1, -1], [0, -1]])
    return np.concatenate(parts).astype(np.float64)


def random_polygons(rng, count):
    for trial in range(count):
        n = int(rng.integers(4, 40))
        kind = trial % 4
        if kind == 0:
            yield rng.random((n, 2)) * 100
        elif kind == 1:  # a small integer grid: touching, collinear and repeated vertices
            yield rng.integers(0, 5, (n, 2)).astype(np.float64)
        else:  # star-shaped (simple), in the second case with two vertices swapped
            angle = np.sort(rng.random(n)) * 2 * np.pi
            radius = 50 + rng.random(n) * 40
            points = np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])
            if kind == 3:
                k = int(rng.integers(0, n - 1))
                points[[k, k + 1]] = points[[k + 1, k]]
            yield points * rng.choice([1e-3, 1.0, 1e4])


def test_crosses_itself_agrees_with_all_pairs():
    rng = np.random.default_rng(7)
    answers = [(crosses_itself(p), all_pairs_cross(p)) for p in random_polygons(rng, 2000)]
    assert all(new == old for new, old in answers)
    assert 100 < sum(old for _, old in answers) < 1900  # both kinds of answer were tested
    # Exactly one crossing, at a random place and angle: the two edges' pieces fall into the
    # same or any neighbouring grid cell.
    rng = np.random.default_rng(5)
    for _ in range(3000):
        n = int(rng.integers(8, 30))
        angle = np.sort(rng.random(n)) * 2 * np.pi
        radius = 50 + rng.random(n) * 40
        points = np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])
        k = int(rng.integers(0, n - 1))
        points[[k, k + 1]] = points[[k + 1, k]]
        assert crosses_itself(points) == all_pairs_cross(points)
    # Touching is no crossing: a vertex on another edge, an edge doubling back along another.
    assert not crosses_itself(np.array([[0, 0], [4, 0], [4, 4], [2, 0], [0, 4]], dtype=float))
    assert not crosses_itself(np.array([[0, 0], [4, 0], [4, 1], [4, 0], [8, 0], [8, 4], [0, 4]], dtype=float))
    assert crosses_itself(np.array([[0, 0], [4, 4], [4, 0], [0, 4]], dtype=float))  # a bow tie


def test_crosses_itself_on_a_long_outline_in_bounded_memory():
    # 200k vertices: the all-pairs test held 512 x 200k blocks (several GiB) and 2e10 pairs.
    outline = comb(50, 1000)
    assert len(outline) > 200_000
    assert not crosses_itself(outline)
    crossed = outline.copy()
    crossed[[100_001, 100_002]] = crossed[[100_002, 100_001]]
    assert crosses_itself(crossed)
    # One long edge among many short ones is cut into pieces, and still found.
    assert all_pairs_cross(comb(3, 10)) is False
    chord = np.vstack([comb(3, 10), [[5.5, 12.0]]])  # the closing edge runs through the teeth
    assert crosses_itself(chord) and all_pairs_cross(chord)


def nearest_by_matrix(left, right):
    """The former n x m implementation of match_outlines, as the reference."""
    def offsets(points):
        cumulative = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
        return cumulative / cumulative[-1]

    distance = np.abs(offsets(left)[:, None] - offsets(right)[None, :])
    nearest = np.argmin(distance, axis=1)
    matching = [[j] for j in nearest.tolist()]
    chosen = np.zeros(len(right), dtype=bool)
    chosen[nearest] = True
    for j in np.flatnonzero(~chosen).tolist():
        matching[int(np.argmin(distance[:, j]))].append(j)
    return [sorted(m) for m in matching]


def test_match_outlines_agrees_with_the_distance_matrix():
    rng = np.random.default_rng(3)
    for trial in range(600):
        n, m = rng.integers(3, 40, 2)
        if trial % 3 == 0:  # repeated vertices and equal edges: many ties of arc-length position
            left, right = (rng.integers(0, 3, (k, 2)).astype(np.float64) for k in (n, m))
        elif trial % 3 == 1:  # regular polygons: offsets that coincide exactly
            left, right = (np.column_stack([np.cos(a), np.sin(a)]) for a in (np.arange(k) * 2 * np.pi / k for k in (n, m)))
        else:
            left, right = rng.random((n, 2)), rng.random((m, 2))
        left, right = np.vstack([left, left[:1]]), np.vstack([right, right[:1]])
        if np.all(left == left[0]) or np.all(right == right[0]):
            continue
        assert match_outlines(left, right) == nearest_by_matrix(left, right)


def test_match_outlines_of_large_outlines():
    # 300k x 200k: the distance matrix would take 480 GB.
    left, right = (np.column_stack([np.cos(a), np.sin(a)]) for a in (np.linspace(0, 2 * np.pi, k) for k in (300_001, 200_001)))
    matching = match_outlines(left, 2 * right)
    assert len(matching) == len(left) and all(matching)
    assert {j for m in matching for j in m} == set(range(len(right)))
    # Equal spacing: left vertex i sits at 2/3 of right vertex i's index, give or take a tie.
    first = np.array([m[0] for m in matching])
    assert np.abs(first - np.arange(len(left)) * 2 / 3).max() <= 0.5


def polygon(frame: int, points: np.ndarray) -> str:
    text = ";".join(f"{x:.2f},{y:.2f}" for x, y in points)
    return f'<polygon frame="{frame}" keyframe="1" outside="0" occluded="0" points="{text}" z_order="0"/>'


def video_export(path, stop: int, tracks_xml: list[str]):
    path.write_text(
        "<?xml version='1.0' encoding='utf-8'?>\n<annotations><version>1.1</version><meta><task>"
        f"<start_frame>0</start_frame><stop_frame>{stop}</stop_frame></task></meta>\n"
        + "\n".join(tracks_xml)
        + "\n</annotations>\n"
    )
    return path


def circle(count: int, shift: float = 0.0) -> np.ndarray:
    angle = np.arange(count) * 2 * np.pi / count
    return np.column_stack([300 + shift + 200 * np.cos(angle), 300 + 200 * np.sin(angle)])


def test_a_polygon_with_too_many_vertices_is_skipped(tmp_path):
    too_many = circle(MAX_POLYGON_VERTICES + 1)
    path = video_export(
        tmp_path / "a.xml",
        0,
        [
            f'<track id="0" label="wall">{polygon(0, circle(5))}</track>',  # line 3
            f'<track id="1" label="huge">{polygon(0, too_many)}</track>',  # line 4
        ],
    )
    annotation = read_cvat(path)
    assert [t.label for t in annotation.tracks] == ["wall"]
    assert f"skipped 1 shape: polygon with more than {MAX_POLYGON_VERTICES} vertices (first at line 4)" in annotation.notes
    # At the bound itself it is read.
    path = video_export(tmp_path / "b.xml", 0, [f'<track id="1" label="big">{polygon(0, circle(MAX_POLYGON_VERTICES))}</track>'])
    assert len(read_cvat(path).tracks[0].shapes[0].points) == MAX_POLYGON_VERTICES


def test_interpolation_beyond_the_budget_is_one_line(tmp_path, monkeypatch):
    monkeypatch.setattr(tracks, "MAX_INTERPOLATED_VERTICES", 10_000)
    # 10 + 15 vertices over 199 frames between keyframes 0 and 200: 4975 vertex-frames a track.
    track = '<track id="{}" label="plane">' + polygon(0, circle(10)) + polygon(200, circle(15, 30)) + "</track>"
    path = video_export(tmp_path / "a.xml", 200, [track.format(0), track.format(1)])
    annotation = read_cvat(path)  # 9950: within the budget
    assert len(annotation.tracks[1].shapes) == 201
    path = video_export(tmp_path / "b.xml", 200, [track.format(i) for i in range(3)])  # lines 3, 4, 5
    with pytest.raises(InputError) as caught:
        read_cvat(path)
    assert str(caught.value) == (
        f"{path}: <track> at line 5: interpolating polygons of 10 and 15 vertices over the 199 frames "
        "between frames 0 and 200 takes the export's interpolation past 10000 vertex-frames "
        "(vertices x frames, all tracks): simplify the polygons or export a shorter task or job"
    )


def test_the_budget_stops_work_before_it_is_done(tmp_path):
    # Two 100k-vertex keyframes 5000 frames apart: a billion vertex-frames (the matrix alone
    # once asked for 74.5 GiB); refused at once with the numbers.
    path = video_export(
        tmp_path / "a.xml",
        5000,
        [f'<track id="0" label="plane">{polygon(0, circle(100_000))}{polygon(5000, circle(100_000, 30))}</track>'],
    )
    with pytest.raises(InputError, match="interpolating polygons of 100000 and 100000 vertices over the 4999 frames"):
        read_cvat(path)

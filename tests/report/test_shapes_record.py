"""The shapes record: what every frame's job drew, written when a run finishes and read by review."""

from __future__ import annotations

import json

import numpy as np
import pytest

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.errors import InputError
from annotate_rgbd.io.outdir import SHAPES_RECORD
from annotate_rgbd.report.run_folder import SHAPES_FORMAT, points_from_json, read_drawn_shapes, write_drawn_shapes


def _frame(rng: np.random.Generator):
    bitmap = rng.random((5, 7)) > 0.5
    shapes = [
        (1, Shape("polygon", rng.uniform(-3, 700, (9, 2)), z_order=2)),
        (2, Shape("box", np.array([[0.1, 0.2], [300.3, 200.7]]))),
        (3, Shape("mask", np.array([[12.0, 30.0]]), z_order=-1, bitmap=bitmap)),
    ]
    carried = [(1, 4, 0, ((1, rng.uniform(-50, 700, (40, 2))), (-1, rng.uniform(0, 640, (7, 2)))),
                (rng.uniform(-900, 1500, (4, 2)),))]
    return shapes, carried


def test_the_record_gives_back_every_vertex_bit_for_bit(tmp_path):
    rng = np.random.default_rng(3)
    shapes, carried = _frame(rng)
    # Values whose decimal form is long, and the extremes of float64.
    shapes[0][1].points[0] = (1 / 3, np.nextafter(640.0, 0.0))
    carried[0][3][0][1][0] = (np.finfo(np.float64).tiny, -np.finfo(np.float64).max)
    write_drawn_shapes(tmp_path, [("masks/a.png", shapes, carried), ("masks/b.png", shapes[:1], [])])
    found = read_drawn_shapes(tmp_path, {"masks/a.png", "masks/b.png"})
    back = found["masks/a.png"]
    for (plane, shape), (plane_back, shape_back) in zip(shapes, back.shapes, strict=True):
        assert (plane, shape.kind, shape.z_order) == (plane_back, shape_back.kind, shape_back.z_order)
        assert shape_back.points.dtype == np.float64
        assert shape_back.points.tobytes() == np.asarray(shape.points, dtype=np.float64).tobytes()
        assert (shape.bitmap is None) == (shape_back.bitmap is None)
        if shape.bitmap is not None:
            assert np.array_equal(shape.bitmap, shape_back.bitmap)
    (position, plane, z, layers, beyond), = carried
    (position_back, plane_back, z_back, layers_back, beyond_back), = back.carried
    assert (position, plane, z) == (position_back, plane_back, z_back)
    assert [s for s, _ in layers] == [s for s, _ in layers_back]
    assert all(a.tobytes() == b.tobytes() for (_, a), (_, b) in zip(layers, layers_back, strict=True))
    assert all(a.tobytes() == b.tobytes() for a, b in zip(beyond, beyond_back, strict=True))
    assert found["masks/b.png"].carried == []


def test_a_version_2_record_with_numbers_is_still_read(tmp_path):
    points = [[1.5, 2.25], [10.0, 2.0], [4.0, 9.125]]
    lines = [{"format": SHAPES_FORMAT, "version": 2},
             {"mask": "masks/a.png", "shapes": [{"plane": 1, "kind": "polygon", "z_order": 0, "points": points}],
              "carried": [{"position": 0, "plane": 2, "z_order": 1, "layers": [[1, points]], "beyond": []}]}]
    (tmp_path / SHAPES_RECORD).write_text("".join(json.dumps(line) + "\n" for line in lines))
    frame = read_drawn_shapes(tmp_path, {"masks/a.png"})["masks/a.png"]
    assert np.array_equal(frame.shapes[0][1].points, points)
    assert np.array_equal(frame.carried[0][3][0][1], points)


@pytest.mark.parametrize("points, problem", [("not base64!", "not base64"), ("AAAA", "no whole")])
def test_damaged_points_name_the_line(tmp_path, points, problem):
    lines = [{"format": SHAPES_FORMAT, "version": 3},
             {"mask": "masks/a.png", "shapes": [{"plane": 1, "kind": "polygon", "points": points}]}]
    (tmp_path / SHAPES_RECORD).write_text("".join(json.dumps(line) + "\n" for line in lines))
    with pytest.raises(InputError, match=f"line 2: .*{problem}"):
        read_drawn_shapes(tmp_path, {"masks/a.png"})


def test_points_from_json_reads_pairs():
    assert points_from_json([]).shape == (0, 2)
    assert np.array_equal(points_from_json([[1, 2], [3, 4]]), [[1.0, 2.0], [3.0, 4.0]])

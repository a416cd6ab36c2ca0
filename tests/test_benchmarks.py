"""The real-data benchmark's arithmetic (benchmarks/bench_real.py), on made-up kit results."""

import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parent.parent / "benchmarks" / "bench_real.py"


@pytest.fixture(scope="module")
def bench_real():
    spec = importlib.util.spec_from_file_location("bench_real", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _result(planes: dict) -> dict:
    """A kit ``evaluate.py --json`` result holding only what the deficit reads."""
    return {"planes": {plane: {"name": name, "frames": frames, "mean_iou": iou}
                       for plane, (name, frames, iou) in planes.items()}}


DENSE = _result({"1": ("floor", 100, 0.90), "2": ("desk", 400, 0.95), "3": ("wall", 50, 0.80), "4": ("door", 10, 0.9)})
SPARSE = _result({"1": ("floor", 100, 0.70), "2": ("desk", 400, 0.85), "3": ("wall", 50, 0.85)})


def test_plane_deficits_weigh_each_plane_by_its_frames(bench_real):
    rows = bench_real.plane_deficits(SPARSE, DENSE)
    # Lost: floor 100 x 0.20 = 20, desk 400 x 0.10 = 40; the wall gained and the door is absent.
    assert [row[1] for row in rows] == ["desk", "floor"]
    assert rows[0][2:5] == (400, 0.95, 0.85)
    assert [row[5] for row in rows] == pytest.approx([40 / 60, 20 / 60])


def test_deficit_lines_compare_each_posed_row_with_the_dense_row(bench_real):
    results = {"full_pose": DENSE, "every10_pose": SPARSE, "every30_nopose": SPARSE}
    lines = bench_real.deficit_lines(results, top=1)
    assert lines == ["  every 10th frame: desk 67% (0.85 against 0.95 on 400 frames)"]
    assert bench_real.deficit_lines({"every10_pose": SPARSE}) == []  # no dense row: nothing to compare

"""EVOPS metrics: differential tests against vectors computed by the real evops 1.0.0, and properties."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from annotate_rgbd.evaluate.metrics import (
    METRIC_NAMES,
    FrameStatistics,
    frame_statistics,
    plane_index,
    plane_overlaps,
)

VECTORS = Path(__file__).parent / "evops" / "vectors.npz"
TOLERANCE = 1e-9
#: Statistics that do not depend on how planes are paired, so evops's are exact even for full < 0.5.
PAIRING_FREE = ("usr", "osr", "noise", "missed")


def _load_cases():
    with np.load(VECTORS) as stored:  # each access to an npz member decompresses it again
        data = dict(stored)
    columns = list(data["columns"])
    cases = []
    for i, name in enumerate(data["names"]):
        shape = tuple(data["shapes"][i])
        size = int(np.prod(shape))
        start = int(data["offsets"][i])
        gt = data["labels"][start : start + size].reshape(shape)
        pred = data["labels"][start + size : start + 2 * size].reshape(shape)
        case = {
            "gt": gt,
            "pred": pred,
            "full": float(data["full"][i]),
            "part": float(data["part"][i]),
            "expected": dict(zip(columns, data["expected"][i])),
            "error": str(data["evops_error"][i]),
            "order_dependent": bool(data["order_dependent"][i]),
        }
        cases.append(pytest.param(case, id=f"{i}-{name}-full{case['full']}-part{case['part']}"))
    return cases


CASES = _load_cases()


def test_vectors_cover_the_required_cases():
    data = np.load(VECTORS)
    names = " ".join(data["names"])
    assert str(data["evops_version"]) == "1.0.0"
    assert len(CASES) >= 300
    for needed in ("merge 6 planes", "split into 6", "noise", "all unsegmented", "no 0 in", "empty"):
        assert needed in names
    assert data["order_dependent"].any() and not data["order_dependent"].all()
    # Random cases spread over the range of every statistic, not all zeros or ones.
    expected = data["expected"][np.isfinite(data["expected"][:, 0])]
    assert (np.ptp(expected, axis=0) > 0.5).all()


@pytest.mark.parametrize("case", CASES)
def test_reproduces_evops(case):
    stats = frame_statistics(case["gt"], case["pred"], full=case["full"], part=case["part"])
    dice = frame_statistics(case["gt"], case["pred"], full=case["full"], part=case["part"], measure="dice")
    expected = case["expected"]
    if case["error"]:
        # evops asserts on zero-size inputs; here an empty frame scores 0 everywhere.
        assert case["gt"].size == 0
        assert stats == FrameStatistics(*[0.0] * len(METRIC_NAMES))
        return
    compared = PAIRING_FREE if case["order_dependent"] else METRIC_NAMES
    for name in compared:
        assert getattr(stats, name) == pytest.approx(expected[name], abs=TOLERANCE), name
    if case["order_dependent"]:
        # A maximum pairing never finds fewer true positives than evops's greedy one.
        assert stats.precision >= expected["precision"] - TOLERANCE
        assert stats.recall >= expected["recall"] - TOLERANCE
    else:
        assert dice.mean == pytest.approx(expected["mean_dice"], abs=TOLERANCE)
        assert dice.panoptic == pytest.approx(expected["panoptic_dice"], abs=TOLERANCE)


def test_low_full_threshold_does_not_depend_on_plane_numbering():
    # Ground-truth plane 1 is fully overlapped (IoU >= 0.3) by predictions 1 and 2, plane 2 only by
    # prediction 1. Greedy pairing in id order pairs 1-1 and leaves plane 2 unpaired; renumbering the
    # predictions changes its result. A maximum pairing finds both pairs whatever the numbering.
    gt = np.array([1, 1, 1, 1, 2, 2, 0, 0, 0, 0])
    pred = np.array([2, 2, 1, 1, 1, 1, 0, 0, 0, 0])
    renumbered = np.where(pred == 0, 0, 3 - pred)
    first = frame_statistics(gt, pred, full=0.3)
    second = frame_statistics(gt, renumbered, full=0.3)
    assert first == second
    assert first.precision == first.recall == 1.0


def test_full_match_of_permuted_labels():
    gt = np.repeat(np.arange(4), 25).reshape(10, 10)
    pred = np.array([0, 7, 3, 9])[gt]
    stats = frame_statistics(gt, pred)
    assert stats == FrameStatistics(1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0)


def test_merge_is_under_segmentation_and_split_over_segmentation():
    gt = np.repeat(np.arange(1, 4), 10)
    merged = np.ones_like(gt)
    stats = frame_statistics(gt, merged, full=0.75, part=0.2)
    assert stats.usr == 1.0 and stats.osr == 0.0 and stats.precision == 0.0
    stats = frame_statistics(merged, gt, full=0.75, part=0.2)
    assert stats.osr == 1.0 and stats.usr == 0.0 and stats.recall == 0.0


def test_iou_is_over_all_pixels():
    # The prediction covers the plane and as much unsegmented ground truth: IoU 0.5, not 1.
    gt = np.array([1, 1, 0, 0])
    overlaps = plane_overlaps(gt, np.ones(4, int))
    np.testing.assert_array_equal(overlaps.iou(), [0.5])
    np.testing.assert_allclose(overlaps.dice(), [2 / 3])


def test_plane_index_paths_agree():
    # Small non-negative ids are counted; negative or huge ones are sorted: same numbering.
    labels = np.array([[5, 0, 5], [2, 9, 0]])
    for shifted in (labels, np.where(labels == 0, 0, labels + 10**12), np.where(labels == 0, 0, -labels)):
        ids, index, sizes = plane_index(shifted)
        assert ids.size == 3 and 0 not in ids
        np.testing.assert_array_equal(index == 0, shifted.ravel() == 0)
        np.testing.assert_array_equal(ids[index[index > 0] - 1], shifted.ravel()[shifted.ravel() != 0])
        np.testing.assert_array_equal(np.sort(sizes), [1, 1, 2])


def test_bool_masks_are_one_plane():
    gt = np.zeros((4, 4), bool)
    gt[:2] = True
    assert frame_statistics(gt, gt).fScore == 1.0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"full": 0.0}, "full"), ({"part": 1.5}, "part"), ({"measure": "jaccard"}, "measure")],
)
def test_rejects_bad_parameters(kwargs, message):
    with pytest.raises(ValueError, match=message):
        frame_statistics(np.ones(3, int), np.ones(3, int), **kwargs)


def test_rejects_mismatched_or_float_labels():
    with pytest.raises(ValueError, match="shape"):
        frame_statistics(np.ones((2, 3), int), np.ones((3, 2), int))
    with pytest.raises(ValueError, match="integers"):
        frame_statistics(np.ones(3, int), np.ones(3, float))

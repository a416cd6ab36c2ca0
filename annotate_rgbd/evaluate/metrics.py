"""EVOPS plane segmentation metrics on label arrays, vectorised.

The definitions are those of the ``evops`` package, version 1.0.0 (``evops.metrics.full_statistics``
with ``tp_condition="iou"``), the metrics of the EVOPS benchmark paper. Per frame, on flattened
label arrays where ``0`` marks unsegmented pixels and every other value is one plane:

- The IoU (and Dice) of a predicted and a ground-truth plane is taken over all pixels, so a predicted
  plane that spills into unsegmented ground truth gets a larger union.
- A *full* overlap is IoU >= ``full``, a *partial* overlap IoU >= ``part``.
- True positives pair ground-truth and predicted planes that overlap fully, one to one.
  ``precision = TP / #predicted``, ``recall = TP / #ground truth``, ``fScore`` their harmonic mean;
  each is 0 when its denominator is.
- ``usr``: share of predicted planes that partially overlap two or more ground-truth planes;
  ``osr``: share of ground-truth planes partially overlapped by two or more predicted planes.
- ``noise``: share of predicted planes that partially overlap no ground-truth plane, or exactly one
  ground-truth plane G while overlapping none fully, G's only partial overlapper being that
  prediction. ``missed`` is the same over ground-truth planes.
- ``mean``: the IoU (or Dice) averaged over the predicted planes that fully overlap a ground-truth
  plane, each taken with that plane; ``panoptic = mean * fScore``.

Everything is computed from one sparse contingency table (pixel counts per pair of predicted and
ground-truth label), so a 640x480 frame takes milliseconds where ``evops`` loops over label pairs
with set operations on pixel indices and takes about two seconds.

Where this module differs from evops 1.0.0 (the differential tests in ``tests/evaluate/test_metrics.py``
exclude exactly these cases, and ``tests/evaluate/evops/make_vectors.py`` marks them):

- Empty inputs (zero pixels): evops raises ``AssertionError``; here every metric is 0.
- ``full < 0.5``: a plane can then fully overlap several planes and evops pairs them greedily in
  label-id order (ground-truth ids ascending, each taking the lowest unused predicted id), so its
  TP count depends on how the planes happen to be numbered. Here TP is the size of a maximum
  one-to-one pairing, and ``mean`` takes each predicted plane with the ground-truth plane it
  overlaps most (evops: the one with the lowest id). For ``full >= 0.5`` a plane has at most two
  full partners, both at IoU exactly 0.5, and both rules give evops's values.
- Thresholds outside ``(0, 1]`` are rejected: at 0 every pair of planes "overlaps".
- Any non-zero integer is a plane, labels need not start at 1 and may lack 0 (evops agrees for
  ``full_statistics``; its ``KeyError`` on a missing 0 label is in ``evops.metrics.association``,
  which this module does not cover).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.sparse import coo_array
from scipy.sparse.csgraph import maximum_bipartite_matching

from annotate_rgbd.config.evaluate import EvaluateConfig

#: The per-frame statistics, in the order tables and CSV files show them.
METRIC_NAMES = ("precision", "recall", "fScore", "usr", "osr", "noise", "missed", "mean", "panoptic")

#: Per-pixel measures that ``mean`` can average over the matched planes.
PIXEL_MEASURES = ("iou", "dice")


@dataclass(frozen=True)
class FrameStatistics:
    """The EVOPS statistics of one frame, each in ``[0, 1]``; names as in ``evops``."""

    precision: float
    recall: float
    fScore: float  # evops's spelling, so results compare key for key
    usr: float
    osr: float
    noise: float
    missed: float
    mean: float
    panoptic: float

    def as_dict(self) -> dict[str, float]:
        """The statistics as a plain ``{name: value}`` dict in :data:`METRIC_NAMES` order."""
        return asdict(self)


@dataclass(frozen=True)
class PlaneOverlaps:
    """Pixel counts of the planes of two label arrays and of their non-empty intersections.

    Attributes
    ----------
    gt_labels, pred_labels : ndarray
        The plane labels (non-zero values) of the ground truth and of the prediction, ascending.
    gt_sizes, pred_sizes : ndarray of int64
        Pixels per plane, aligned with the labels.
    gt_index, pred_index : ndarray of intp, shape (K,)
        One entry per pair of planes that share at least one pixel: indices into the label arrays.
    intersection : ndarray of int64, shape (K,)
        The shared pixel count of each pair.
    """

    gt_labels: np.ndarray
    pred_labels: np.ndarray
    gt_sizes: np.ndarray
    pred_sizes: np.ndarray
    gt_index: np.ndarray
    pred_index: np.ndarray
    intersection: np.ndarray

    def iou(self) -> np.ndarray:
        """Intersection over union of each pair, over all pixels."""
        union = self.gt_sizes[self.gt_index] + self.pred_sizes[self.pred_index] - self.intersection
        return self.intersection / union

    def dice(self) -> np.ndarray:
        """Dice coefficient of each pair: twice the intersection over the summed sizes."""
        total = self.gt_sizes[self.gt_index] + self.pred_sizes[self.pred_index]
        return 2 * self.intersection / total


def plane_index(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Number the planes of a label array 1..N, keeping 0 for unsegmented pixels.

    Parameters
    ----------
    labels : ndarray of int or bool
        Label per pixel, any shape; 0 is unsegmented, any other value is a plane.

    Returns
    -------
    plane_labels : ndarray
        The distinct non-zero labels, ascending (length N).
    index : ndarray of intp, same size as ``labels``, flattened
        ``i`` where the pixel belongs to ``plane_labels[i - 1]``, 0 where it is unsegmented.
    sizes : ndarray of int64
        Pixels per plane, aligned with ``plane_labels``.
    """
    flat = np.asarray(labels).ravel()
    if flat.dtype == bool:
        flat = flat.view(np.uint8)
    # Small non-negative labels (the usual case) are counted in one linear pass; anything else
    # (negative or huge ids) goes through a sort.
    if flat.size and flat.dtype.kind in "ui" and flat.min() >= 0 and flat.max() <= 4 * flat.size + 65536:
        counts = np.bincount(flat.astype(np.intp, copy=False))
        present = np.flatnonzero(counts[1:]) + 1
        lookup = np.zeros(counts.size, np.intp)
        lookup[present] = np.arange(1, present.size + 1)
        return present.astype(flat.dtype), lookup[flat], counts[present].astype(np.int64)
    values, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    is_plane = values != 0
    lookup = np.where(is_plane, np.cumsum(is_plane), 0)
    return values[is_plane], lookup[inverse.ravel()], counts[is_plane].astype(np.int64)


def plane_overlaps(gt: np.ndarray, pred: np.ndarray) -> PlaneOverlaps:
    """Tabulate how the planes of a prediction overlap those of the ground truth.

    Parameters
    ----------
    gt, pred : ndarray of int or bool
        Ground-truth and predicted labels of the same pixels (same shape); 0 is unsegmented.

    Returns
    -------
    PlaneOverlaps
        Plane sizes and the sparse contingency table between the two sets of planes.
    """
    gt = np.asarray(gt)
    pred = np.asarray(pred)
    if gt.shape != pred.shape:
        raise ValueError(f"label arrays differ in shape: ground truth {gt.shape}, prediction {pred.shape}")
    _check_labels(gt, "ground truth")
    _check_labels(pred, "prediction")
    gt_labels, gt_pixels, gt_sizes = plane_index(gt)
    pred_labels, pred_pixels, pred_sizes = plane_index(pred)

    width = gt_labels.size + 1
    n_cells = (pred_labels.size + 1) * width
    codes = pred_pixels * width + gt_pixels
    if n_cells <= max(codes.size, 1 << 20):
        counts = np.bincount(codes, minlength=n_cells)
        cells = np.flatnonzero(counts)
        counts = counts[cells]
    else:  # so many labels that a dense table would not fit: count the occurring pairs only
        cells, counts = np.unique(codes, return_counts=True)
    pred_index, gt_index = np.divmod(cells, width)
    both = (pred_index > 0) & (gt_index > 0)
    return PlaneOverlaps(
        gt_labels=gt_labels,
        pred_labels=pred_labels,
        gt_sizes=gt_sizes,
        pred_sizes=pred_sizes,
        gt_index=gt_index[both] - 1,
        pred_index=pred_index[both] - 1,
        intersection=counts[both].astype(np.int64),
    )


def frame_statistics(
    gt: np.ndarray,
    pred: np.ndarray,
    *,
    full: float = EvaluateConfig.full,
    part: float = EvaluateConfig.partial,
    measure: str = "iou",
) -> FrameStatistics:
    """EVOPS statistics of one predicted segmentation against the ground truth.

    Parameters
    ----------
    gt, pred : ndarray of int or bool
        Ground-truth and predicted labels of the same pixels (same shape, any number of dimensions);
        0 is unsegmented, every other value one plane. Ids need not correspond between the two.
    full : float, optional
        IoU at which a predicted and a ground-truth plane count as the same plane, in ``(0, 1]``.
    part : float, optional
        IoU at which they count as partially overlapping (for usr, osr, noise, missed), in ``(0, 1]``.
    measure : {"iou", "dice"}, optional
        What ``mean`` (and so ``panoptic``) averages over the matched planes.

    Returns
    -------
    FrameStatistics
        The statistics, equal to ``evops.metrics.full_statistics(pred.ravel(), gt.ravel(), iou or
        dice, "iou")`` under the same thresholds except where the module docstring says otherwise.
    """
    _check_threshold(full, "full")
    _check_threshold(part, "part")
    if measure not in PIXEL_MEASURES:
        raise ValueError(f"measure must be one of {PIXEL_MEASURES}, not {measure!r}")
    overlaps = plane_overlaps(gt, pred)
    n_gt = overlaps.gt_labels.size
    n_pred = overlaps.pred_labels.size
    iou = overlaps.iou()

    is_full = iou >= full
    true_positives = _matched_pairs(overlaps.gt_index[is_full], overlaps.pred_index[is_full])
    precision = _ratio(true_positives, n_pred)
    recall = _ratio(true_positives, n_gt)
    f_score = _ratio(2 * precision * recall, precision + recall)

    values = overlaps.dice() if measure == "dice" else iou
    mean = _mean_over_matched_predictions(overlaps.pred_index[is_full], iou[is_full], values[is_full])

    is_part = iou >= part
    gt_part = overlaps.gt_index[is_part]
    pred_part = overlaps.pred_index[is_part]
    gt_part_count = np.bincount(gt_part, minlength=n_gt)
    pred_part_count = np.bincount(pred_part, minlength=n_pred)
    gt_full_count = np.bincount(overlaps.gt_index[is_full], minlength=n_gt)
    pred_full_count = np.bincount(overlaps.pred_index[is_full], minlength=n_pred)
    # A partial pair whose two planes partially overlap nothing else: the prediction is noise and
    # the ground-truth plane is missed, each unless it also has a full overlap of its own.
    exclusive = (gt_part_count[gt_part] == 1) & (pred_part_count[pred_part] == 1)
    noise_planes = np.count_nonzero(pred_part_count == 0) + np.count_nonzero(
        exclusive & (pred_full_count[pred_part] == 0)
    )
    missed_planes = np.count_nonzero(gt_part_count == 0) + np.count_nonzero(
        exclusive & (gt_full_count[gt_part] == 0)
    )
    return FrameStatistics(
        precision=precision,
        recall=recall,
        fScore=f_score,
        usr=_ratio(np.count_nonzero(pred_part_count > 1), n_pred),
        osr=_ratio(np.count_nonzero(gt_part_count > 1), n_gt),
        noise=_ratio(noise_planes, n_pred),
        missed=_ratio(missed_planes, n_gt),
        mean=mean,
        panoptic=mean * f_score,
    )


def _matched_pairs(gt_index: np.ndarray, pred_index: np.ndarray) -> int:
    """Size of a maximum one-to-one pairing along the given (gt, pred) edges."""
    if np.unique(gt_index).size == gt_index.size and np.unique(pred_index).size == pred_index.size:
        return int(gt_index.size)  # already one to one: always so when full > 0.5
    gt_nodes, gt_compact = np.unique(gt_index, return_inverse=True)
    pred_nodes, pred_compact = np.unique(pred_index, return_inverse=True)
    graph = coo_array(
        (np.ones(gt_compact.size, np.int8), (gt_compact, pred_compact)),
        shape=(gt_nodes.size, pred_nodes.size),
    ).tocsr()
    return int(np.count_nonzero(maximum_bipartite_matching(graph, perm_type="column") >= 0))


def _mean_over_matched_predictions(pred_index: np.ndarray, iou: np.ndarray, values: np.ndarray) -> float:
    """Mean of ``values`` over predicted planes, each taken on its full pair of highest IoU."""
    if pred_index.size == 0:
        return 0.0
    # Sorted by plane, then by decreasing IoU: the first entry of each plane is its best pair.
    order = np.lexsort((-iou, pred_index))
    _, first = np.unique(pred_index[order], return_index=True)
    return float(np.mean(values[order][first]))


def _ratio(numerator: float, denominator: float) -> float:
    return float(numerator / denominator) if denominator != 0 else 0.0


def _check_threshold(value: float, name: str) -> None:
    if not 0.0 < value <= 1.0:
        raise ValueError(f"{name} must be in (0, 1], not {value}")


def _check_labels(labels: np.ndarray, name: str) -> None:
    if labels.dtype != bool and labels.dtype.kind not in "ui":
        raise ValueError(f"{name} labels must be integers, not {labels.dtype}")

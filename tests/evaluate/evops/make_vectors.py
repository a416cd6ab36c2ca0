"""Compute differential test vectors with the real ``evops`` 1.0.0 package.

evops pins numpy < 2, so this script runs in its own environment, never in the project's::

    python3 -m venv /work/venv-evops
    /work/venv-evops/bin/pip install evops==1.0.0 'numpy<2'
    /work/venv-evops/bin/python tests/evops/make_vectors.py      # writes tests/evops/vectors.npz

(importing evops takes about half a minute; the whole run a few minutes). The cases are seeded, so a
rerun writes the same vectors. ``tests/test_metrics.py`` reads the file in the project's environment
without importing evops.

Each case is a pair of small label images (ground truth, prediction), the two IoU thresholds, and what
evops returned: ``full_statistics`` with ``iou`` and the ``mean`` / ``panoptic`` again with ``dice``.
A case where evops raised stores NaN and the exception name. Cases where evops's result depends on
how the planes are numbered (``full < 0.5``, see :mod:`annotate_rgbd.metrics`) are kept and marked
``order_dependent``: only the pairing-free statistics (usr, osr, noise, missed) are compared there.

The file holds every label image flattened into one array (``labels``), with per-case offsets and
shapes, so that a few hundred cases stay a small committed file.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import evops
import numpy as np
from evops.metrics import constants, dice, full_statistics, iou, mean

NAMES = ("precision", "recall", "fScore", "usr", "osr", "noise", "missed", "mean", "panoptic")
THRESHOLDS = [(0.75, 0.2), (0.8, 0.5), (0.5, 0.2), (0.5, 0.5), (0.9, 0.1), (1.0, 0.2), (0.6, 0.3), (0.7, 0.7)]
LOW_FULL = [(0.3, 0.1), (0.4, 0.2), (0.25, 0.25)]


# --- ground-truth-like label images -------------------------------------------------------------


def voronoi(rng, shape, n_planes, ids):
    """Convex-ish planes: each pixel takes the id of its nearest seed."""
    rows, cols = np.indices(shape)
    seeds = rng.uniform(0, 1, (n_planes, 2)) * np.array(shape)
    dist = (rows[None] - seeds[:, 0, None, None]) ** 2 + (cols[None] - seeds[:, 1, None, None]) ** 2
    return np.asarray(ids)[np.argmin(dist, axis=0)]


def random_ids(rng, n, high=300):
    return rng.choice(np.arange(1, high), size=n, replace=False)


def ground_truth(rng, shape):
    n = int(rng.integers(1, 9))
    labels = voronoi(rng, shape, n, random_ids(rng, n))
    # Unsegmented areas: a few rectangles and sometimes whole planes.
    for _ in range(int(rng.integers(0, 3))):
        r0, c0 = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        labels[r0 : r0 + rng.integers(2, shape[0] // 2 + 3), c0 : c0 + rng.integers(2, shape[1] // 2 + 3)] = 0
    if rng.random() < 0.3:
        labels[labels == rng.choice(np.unique(labels))] = 0
    return labels


# --- predictions derived from the ground truth --------------------------------------------------


def relabel(rng, labels):
    values = np.unique(labels)
    new = random_ids(rng, values.size, 1000)
    new[values == 0] = 0
    return new[np.searchsorted(values, labels)]


def merge(rng, labels, k=None):
    planes = np.unique(labels[labels != 0])
    if planes.size < 2:
        return labels
    k = min(k or int(rng.integers(2, 7)), planes.size)
    group = rng.choice(planes, k, replace=False)
    return np.where(np.isin(labels, group), group[0], labels)


def split(rng, labels):
    planes = np.unique(labels[labels != 0])
    if planes.size == 0:
        return labels
    plane = rng.choice(planes)
    parts = int(rng.integers(2, 4))
    cut = voronoi(rng, labels.shape, parts, np.arange(parts))
    out = labels.copy()
    on = labels == plane
    out[on] = np.where(cut[on] == 0, plane, 2000 + cut[on])
    return out


def shift(rng, labels):
    return np.roll(labels, (int(rng.integers(-4, 5)), int(rng.integers(-4, 5))), axis=(0, 1))


def jitter(rng, labels):
    """Move boundaries: a share of pixels take a neighbour's label."""
    neighbour = np.roll(labels, (int(rng.integers(-2, 3)), int(rng.integers(-2, 3))), axis=(0, 1))
    return np.where(rng.random(labels.shape) < rng.uniform(0.05, 0.5), neighbour, labels)


def add_noise(rng, labels):
    out = labels.copy()
    for i in range(int(rng.integers(1, 4))):
        r0, c0 = rng.integers(0, labels.shape[0]), rng.integers(0, labels.shape[1])
        out[r0 : r0 + rng.integers(1, 10), c0 : c0 + rng.integers(1, 10)] = 3000 + i
    return out


def drop(rng, labels):
    planes = np.unique(labels[labels != 0])
    if planes.size == 0:
        return labels
    return np.where(labels == rng.choice(planes), 0, labels)


def fill_unsegmented(rng, labels):
    """No 0 at all: unsegmented pixels join one plane (or a new one)."""
    planes = np.unique(labels[labels != 0])
    fill = rng.choice(planes) if planes.size and rng.random() < 0.5 else 4000
    return np.where(labels == 0, fill, labels)


PERTURBATIONS = [merge, split, shift, jitter, add_noise, drop, fill_unsegmented]


def prediction(rng, gt):
    pred = gt.copy()
    for step in rng.choice(len(PERTURBATIONS), int(rng.integers(1, 4)), replace=True):
        pred = PERTURBATIONS[step](rng, pred)
    return relabel(rng, pred)


# --- hand-made cases ----------------------------------------------------------------------------


def stripes(shape, n, first=1):
    """n vertical stripes of equal width, ids first..first+n-1."""
    return (np.arange(shape[1]) * n // shape[1])[None, :].repeat(shape[0], 0) + first


def hand_made():
    rng = np.random.default_rng(7)
    cases = []
    six = stripes((16, 24), 6)
    cases.append(("identical", six, six))
    cases.append(("identical renumbered", six, 7 - six))
    for k in range(2, 7):
        merged = np.where(six <= k, 1, six)
        cases.append((f"merge {k} planes", six, merged))
        cases.append((f"split into {k} planes", merged, six))
    cases.append(("all unsegmented", np.zeros((16, 16), int), np.zeros((16, 16), int)))
    cases.append(("empty prediction", six, np.zeros_like(six)))
    cases.append(("empty ground truth", np.zeros_like(six), six))
    cases.append(("empty arrays", np.zeros((0, 0), int), np.zeros((0, 0), int)))
    cases.append(("one pixel", np.ones((1, 1), int), np.ones((1, 1), int)))
    cases.append(("no 0 in prediction", np.where(six == 6, 0, six), six))
    cases.append(("no 0 in either", six, six[:, ::-1] + 10))
    cases.append(("negative and large ids", six, np.choose(six - 1, [-5, 65535, 70000, -1, 3, 1 << 30])))
    cases.append(("noise planes only", np.where(six > 3, 0, six), np.where(six > 3, six + 10, 0)))
    # IoU exactly at the thresholds: a 20-pixel plane against 15 of its pixels -> 0.75, 10 -> 0.5.
    gt = np.zeros((4, 10), int)
    gt[:2] = 1
    for kept in (15, 10, 4, 3):
        pred = np.zeros_like(gt)
        pred.ravel()[:kept] = 9
        cases.append((f"IoU {kept}/20", gt, pred))
    # full = 0.5 stars: one prediction exactly covering two ground-truth halves, and the mirror.
    halves = np.repeat([[1, 1, 2, 2]], 4, axis=0)
    cases.append(("two halves in one prediction", halves, np.ones_like(halves)))
    cases.append(("one plane predicted as two halves", np.ones_like(halves), halves))
    # Salt-and-pepper labels: many tiny planes.
    cases.append(("salt", rng.integers(0, 4, (16, 16)), rng.integers(0, 4, (16, 16))))
    cases.append(("salt many labels", rng.integers(0, 40, (32, 32)), rng.integers(0, 40, (32, 32))))
    return cases


# --- evops --------------------------------------------------------------------------------------


def evops_values(gt, pred, full, part):
    """evops's statistics (IoU mean, then Dice mean and panoptic), or NaN and the error name."""
    constants.IOU_THRESHOLD_FULL = full
    constants.IOU_THRESHOLD_PART = part
    p, g = pred.ravel(), gt.ravel()
    try:
        stats = full_statistics(p, g, iou, "iou")
        dice_mean = mean(p, g, dice, "iou")
    except Exception as error:  # noqa: BLE001 -- evops's failure is part of the vector
        return np.full(len(NAMES) + 2, np.nan), type(error).__name__
    row = [stats[name] for name in NAMES] + [dice_mean, dice_mean * stats["fScore"]]
    return np.array(row, float), ""


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("vectors.npz"))
    parser.add_argument("--random", type=int, default=260, help="number of random cases")
    args = parser.parse_args()

    rng = np.random.default_rng(20240604)
    cases = []  # (name, gt, pred, full, part)
    for name, gt, pred in hand_made():
        for full, part in THRESHOLDS[:4] + LOW_FULL[:1]:
            cases.append((name, gt, pred, full, part))
    for i in range(args.random):
        shape = (int(rng.integers(16, 65)), int(rng.integers(16, 65)))
        gt = ground_truth(rng, shape)
        pred = prediction(rng, gt)
        pool = THRESHOLDS if i % 5 else LOW_FULL
        full, part = pool[int(rng.integers(len(pool)))]
        cases.append((f"random {i}", gt, pred, full, part))

    started = time.perf_counter()
    expected, errors = [], []
    for _, gt, pred, full, part in cases:
        values, error = evops_values(gt, pred, full, part)
        expected.append(values)
        errors.append(error)
    print(f"{len(cases)} cases in {time.perf_counter() - started:.1f} s")

    flat = [np.concatenate([gt.ravel(), pred.ravel()]) for _, gt, pred, _, _ in cases]
    sizes = np.array([f.size for f in flat])
    np.savez_compressed(
        args.out,
        names=np.array([c[0] for c in cases]),
        shapes=np.array([c[1].shape for c in cases]),
        offsets=np.concatenate([[0], np.cumsum(sizes)[:-1]]),
        labels=np.concatenate(flat).astype(np.int64),
        full=np.array([c[3] for c in cases]),
        part=np.array([c[4] for c in cases]),
        expected=np.array(expected),
        columns=np.array(NAMES + ("mean_dice", "panoptic_dice")),
        evops_error=np.array(errors),
        order_dependent=np.array([c[3] < 0.5 for c in cases]),
        evops_version=np.array(evops.__version__),
        numpy_version=np.array(np.__version__),
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

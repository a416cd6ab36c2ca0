"""Per-frame time of our EVOPS statistics against the ``evops`` package, on the same 640x480 frames.

Run from the repository root::

    python benchmarks/bench_evaluate.py [--frames 3] [--evops-python PATH]

evops 1.0.0 needs numpy < 2, so it runs in its own environment (see ``tests/evaluate/evops/make_vectors.py``
for how to make one); its interpreter is ``--evops-python``, else ``$EVOPS_PYTHON``, else
``/work/venv-evops/bin/python`` if that exists. Both sides time only ``full_statistics`` on frames
already in memory (evops's half-minute import is not counted), and the values are compared too.
Without evops only our time is printed.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from annotate_rgbd.evaluate.metrics import METRIC_NAMES, frame_statistics

DEFAULT_EVOPS_PYTHON = Path("/work/venv-evops/bin/python")
SHAPE = (480, 640)

#: Runs inside the evops environment: times full_statistics per frame and prints the results as JSON.
EVOPS_SCRIPT = """
import json, sys, time
import numpy as np
from evops.metrics import full_statistics, iou
frames = np.load(sys.argv[1])
out = []
for gt, pred in zip(frames["gt"], frames["pred"]):
    start = time.perf_counter()
    stats = full_statistics(pred.ravel(), gt.ravel(), iou, "iou")
    out.append({"seconds": time.perf_counter() - start, "stats": {k: float(v) for k, v in stats.items()}})
print(json.dumps(out))
"""


def make_frames(n_frames: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth with 6-12 planes and unsegmented areas; predictions with merges, splits, ragged edges."""
    rng = np.random.default_rng(seed)
    rows, cols = np.indices(SHAPE)
    gts, preds = [], []
    for _ in range(n_frames):
        n = int(rng.integers(6, 13))
        seeds = rng.uniform(0, 1, (n, 2)) * SHAPE
        dist = (rows[None] - seeds[:, 0, None, None]) ** 2 + (cols[None] - seeds[:, 1, None, None]) ** 2
        gt = np.argmin(dist, axis=0).astype(np.int32) + 1
        gt[rng.random(n + 1)[gt] < 0.2] = 0  # some planes left unlabelled
        gt[:40] = 0
        pred = np.where(gt == 2, 1, gt) + 10  # merge, renumber
        pred[(gt == 3) & (cols < seeds[2, 1])] = 50  # split
        neighbour = np.roll(pred, (3, -2), axis=(0, 1))
        pred = np.where(rng.random(SHAPE) < 0.15, neighbour, pred)  # ragged boundaries
        pred[rng.random(SHAPE) < 0.05] = 0  # missing depth
        gts.append(gt)
        preds.append(pred.astype(np.int32))
    return np.stack(gts), np.stack(preds)


def time_ours(gts: np.ndarray, preds: np.ndarray, repeats: int) -> tuple[float, list[dict]]:
    """Median per-frame seconds over ``repeats`` passes, and the statistics of each frame."""
    stats = [frame_statistics(gt, pred).as_dict() for gt, pred in zip(gts, preds)]  # warm up
    passes = []
    for _ in range(repeats):
        start = time.perf_counter()
        for gt, pred in zip(gts, preds):
            frame_statistics(gt, pred)
        passes.append((time.perf_counter() - start) / len(gts))
    return float(np.median(passes)), stats


def time_evops(python: Path, gts: np.ndarray, preds: np.ndarray) -> tuple[float, list[dict]]:
    """Mean per-frame seconds of evops's full_statistics, and its statistics of each frame."""
    with tempfile.TemporaryDirectory() as folder:
        frames = Path(folder) / "frames.npz"
        np.savez(frames, gt=gts, pred=preds)
        done = subprocess.run(
            [str(python), "-c", EVOPS_SCRIPT, str(frames)], capture_output=True, text=True, check=True
        )
    results = json.loads(done.stdout.strip().splitlines()[-1])
    return float(np.mean([r["seconds"] for r in results])), [r["stats"] for r in results]


def find_evops_python(option: str | None) -> Path | None:
    """The evops interpreter: the option, else $EVOPS_PYTHON, else the default venv if present."""
    if option or os.environ.get("EVOPS_PYTHON"):
        return Path(option or os.environ["EVOPS_PYTHON"])
    return DEFAULT_EVOPS_PYTHON if DEFAULT_EVOPS_PYTHON.exists() else None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=3, help="number of 640x480 frame pairs")
    parser.add_argument("--repeats", type=int, default=20, help="passes over the frames for our timing")
    parser.add_argument("--evops-python", help="python of an environment with evops 1.0.0 installed")
    args = parser.parse_args()

    gts, preds = make_frames(args.frames)
    ours, our_stats = time_ours(gts, preds, args.repeats)
    print(f"frames: {args.frames} x {SHAPE[1]}x{SHAPE[0]}")
    print(f"ours:  {ours * 1e3:9.2f} ms per frame")

    python = find_evops_python(args.evops_python)
    if python is None or not python.exists():
        print("evops: not measured (no evops environment; pass --evops-python or set EVOPS_PYTHON)")
        return 0
    print(f"evops: running {python} (its import takes about half a minute, not counted) ...", flush=True)
    try:
        theirs, their_stats = time_evops(python, gts, preds)
    except subprocess.CalledProcessError as error:
        print(f"evops: failed to run: {error.stderr.strip().splitlines()[-1:]}")
        return 1
    print(f"evops: {theirs * 1e3:9.2f} ms per frame")
    print(f"ratio: ours is {theirs / ours:.0f}x faster (target >= 50x)")
    difference = max(abs(a[name] - b[name]) for a, b in zip(our_stats, their_stats) for name in METRIC_NAMES)
    print(f"largest difference of any statistic: {difference:.1e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Plane proposals: quality against the exact ground truth, and time per frame next to cvat2mask.

Run from the repository root::

    python benchmarks/bench_propose.py [--frames 60] [--seed 3] [--jobs 1] [--rounds 2] [--workdir DIR]

Renders once into ``--workdir`` (reused by later runs) ``--frames`` 640x480 frames of the room of
``annotate_rgbd.synthetic.room_scene`` (``--seed``: sensor noise, holes, timestamps; the camera
path is the same for any frame count, so fewer frames mean more motion between frames) (walls, floor, table, cabinet, a window without depth, a
corridor wall beyond 3.5 m, clutter; Kinect noise), with the renderer's camera poses as a TUM
``groundtruth.txt`` and its annotation as a CVAT video export. Then, in one run and on the same
frames, it times ``propose`` (with and without poses) and ``cvat2mask`` on the renderer's
annotation, taking turns for ``--rounds`` rounds and keeping each one's best (the shared machine's
speed drifts), and scores against the ground truth (planes expected to be kept, at least 1 % of
the frame, as a labeller keeps them):

* mean IoU: every ground-truth plane's best IoU with a proposed plane, averaged over (frame, plane);
* precision and recall at IoU 0.8 (``annotate_rgbd.metrics.frame_statistics``, frame means);
* colour consistency: the share of (plane, frame) pairs whose best-matching mask colour is the
  plane's most frequent one;
* the same for ``cvat2mask`` run on ``proposals.xml`` (what the labeller gets back unedited).

Targets (issue 13): mean IoU >= 0.85, precision and recall >= 0.85, colour >= 0.95, propose <=
2x the time of cvat2mask.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.config.settings import Config
from annotate_rgbd.cvat import write_cvat_video
from annotate_rgbd.pipeline.execute import prepare_process
from annotate_rgbd.io.labelmaps import read_label_map
from annotate_rgbd.evaluate.metrics import frame_statistics
from annotate_rgbd.pipeline.scene import run_cvat2mask
from annotate_rgbd.propose import run_propose
from annotate_rgbd.io.sequence import read_sequence
from annotate_rgbd.synthetic import make_sequence, room_trajectory

CAMERA = Camera(fx=525.0, fy=525.0, cx=319.5, cy=239.5, depth_scale=5000.0)
MIN_AREA = 0.01


def render(workdir: Path, frames: int, seed: int = 3) -> Path:
    """The sequence, its trajectory and its annotation (cached by frame count and seed)."""
    sequence = workdir / (f"room_{frames}" if seed == 3 else f"room_{frames}_seed{seed}")
    if (sequence / "annotation.xml").exists():
        return sequence
    annotation = make_sequence(sequence, n_frames=frames, width=640, height=480, camera=CAMERA, seed=seed)
    write_cvat_video(annotation, sequence / "annotation.xml", width=640, height=480)
    poses = room_trajectory(frames)
    times = read_sequence(sequence).depth.timestamps
    quaternions = Rotation.from_matrix(np.array([p.rotation for p in poses])).as_quat()
    lines = [f"{t:.6f} " + " ".join(f"{v:.9f}" for v in (*p.position, *q)) for t, p, q in zip(times, poses, quaternions)]
    (sequence / "groundtruth.txt").write_text("# timestamp tx ty tz qx qy qz qw\n" + "\n".join(lines) + "\n")
    return sequence


def score(sequence: Path, masks: Path) -> dict[str, float]:
    """Mean IoU, P/R at 0.8 and colour consistency of a folder of colour masks."""
    description = json.loads((sequence / "ground_truth" / "planes.json").read_text())
    dropped = [p["gt_value"] for p in description["planes"] if p["expected"] != "kept"]
    ious, precision, recall, colours = [], [], [], {}
    for frame in description["frames"]:
        path = masks / Path(frame["depth"]).name
        if not path.exists():
            continue
        gt = read_label_map(sequence / "ground_truth" / frame["ground_truth"]).astype(np.int64)
        gt[np.isin(gt, dropped)] = 0
        gt[(np.bincount(gt.ravel()) < MIN_AREA * gt.size)[gt]] = 0
        image = cv2.imread(str(path)).astype(np.int64)
        packed = image[..., 2] << 16 | image[..., 1] << 8 | image[..., 0]
        values, pred = np.unique(packed, return_inverse=True)
        pred = pred.reshape(packed.shape) + (values[0] != 0)
        values = values if values[0] == 0 else np.append(0, values)
        stats = frame_statistics(gt, pred, full=0.8)
        precision.append(stats.precision)
        recall.append(stats.recall)
        n = len(values)
        joint = np.bincount(gt.ravel() * n + pred.ravel(), minlength=(gt.max() + 1) * n).reshape(-1, n)
        iou = joint / np.maximum(joint.sum(1)[:, None] + joint.sum(0)[None, :] - joint, 1)
        for g in np.flatnonzero(joint[1:].sum(1)) + 1:
            best = int(np.argmax(iou[g, 1:])) + 1
            ious.append(iou[g, best])
            if iou[g, best] > 0:
                colours.setdefault(int(g), []).append(int(values[best]))
    consistent = sum(max(np.unique(c, return_counts=True)[1]) for c in colours.values())
    return {"mean IoU": float(np.mean(ious)), "P@0.8": float(np.mean(precision)), "R@0.8": float(np.mean(recall)),
            "colour": consistent / max(sum(len(c) for c in colours.values()), 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--workdir", type=Path, default=Path(tempfile.gettempdir()) / "annotate_rgbd_bench_propose")
    args = parser.parse_args()
    prepare_process(args.jobs)
    sequence = render(args.workdir, args.frames, args.seed)
    out = args.workdir / f"out_{sequence.name}"
    config = Config()
    runs = {
        "propose --poses": lambda: run_propose(sequence, out / "posed", config, poses=sequence / "groundtruth.txt",
                                               workers=args.jobs),
        "propose": lambda: run_propose(sequence, out / "plain", config, workers=args.jobs),
        "cvat2mask": lambda: run_cvat2mask(sequence, [sequence / "annotation.xml"], out / "cvat2mask", config,
                                           workers=args.jobs, force=True),
    }
    best = {name: np.inf for name in runs}
    for _ in range(args.rounds):
        for name, run in runs.items():
            start = time.perf_counter()
            run()
            best[name] = min(best[name], time.perf_counter() - start)
    run_cvat2mask(sequence, [out / "posed" / "proposals.xml"], out / "refined", config, workers=args.jobs, force=True)
    written = len(list((out / "posed" / "masks").iterdir()))
    print(f"{args.frames} rendered frames 640x480 (seed {args.seed}; {written} with an RGB frame), {args.jobs} worker(s), "
          f"best of {args.rounds} rounds\n")
    print("| run | ms per frame | vs cvat2mask | mean IoU | P@0.8 | R@0.8 | colour |")
    print("|---|---|---|---|---|---|---|")
    scores = {"propose --poses": score(sequence, out / "posed" / "masks"),
              "propose": score(sequence, out / "plain" / "masks"),
              "cvat2mask": score(sequence, out / "cvat2mask" / "masks"),
              "cvat2mask on proposals.xml": score(sequence, out / "refined" / "masks")}
    for name, values in scores.items():
        ms = f"{best[name] / written * 1000:.1f}" if name in best else "-"
        ratio = f"{best[name] / best['cvat2mask']:.2f}x" if name in best else "-"
        print(f"| {name} | {ms} | {ratio} | " + " | ".join(f"{values[k]:.3f}" for k in ("mean IoU", "P@0.8", "R@0.8", "colour")) + " |")


if __name__ == "__main__":
    main()

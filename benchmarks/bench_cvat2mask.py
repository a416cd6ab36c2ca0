"""Speed and memory of ``cvat2mask``, ``--poses`` and ``propose`` against the I/O floor, in one run.

Run from the repository root (after the quick start's set-up)::

    python benchmarks/bench_cvat2mask.py [--frames 300] [--rounds 3] [--workdir DIR]

It renders two synthetic sequences once into ``--workdir`` (reused by later runs): the room of
``annotate_rgbd.synthetic`` (``--frames`` frames at 640 x 480, about 10 planes, clutter,
Kinect-like noise) and the walk of ``bench_refine.py`` (``--walk-frames`` frames), which has a camera
trajectory.
Every figure is a whole process, start-up included, as a user runs it; the figures take turns for
``--rounds`` rounds and each keeps its best (a shared machine's speed drifts within minutes), so
the ratios compare measurements of the same run:

* the I/O floor: a process that decodes each depth PNG and encodes one colour mask per frame
  (in memory), the work no implementation can skip (:data:`IO_FLOOR`);
* ``cvat2mask --jobs 1`` and ``--jobs 2`` (every frame made: ``--force``), and the main
  process's peak resident memory in the 1-worker run (its ``VmHWM``);
* ``propose --jobs 1 --every 1`` on the same frames;
* on the walk, ``cvat2mask --jobs 1`` with and without ``--poses``, for a keyframe drawn on every
  frame (nothing to carry) and on every 10th.

It prints each figure in ms per frame and the targets of the speed issue: 1 worker at most 3x
the floor, ``--poses`` at most 1.3x the time without (1.05x when every frame is a keyframe), 2
workers at least 1.7x faster than 1, ``propose`` no slower than ``cvat2mask`` per frame, and the
1-worker peak memory (about 310 MiB before the speed work).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from annotate_rgbd.cvat import write_cvat_video, read_cvat  # noqa: E402
from annotate_rgbd.geometry.camera import Camera  # noqa: E402
from annotate_rgbd.synthetic import make_sequence  # noqa: E402

#: The I/O floor, run as its own process: ``python -c IO_FLOOR DEPTH_DIR``. A mask with the
#: structure of a real one (a few large regions, holes) is coloured and encoded per frame.
IO_FLOOR = """
import sys
from pathlib import Path
import cv2
import numpy as np
colours = np.random.default_rng(0).integers(0, 256, (256, 3), dtype=np.uint8)
colours[0] = 0
for path in sorted(Path(sys.argv[1]).glob("*.png")):
    depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    labels = np.minimum(depth // 2000, 12).astype(np.uint8)
    ok, data = cv2.imencode(".png", colours[labels])
    assert ok
"""


def make_benchmark_sequence(folder: Path, frames: int, width: int, height: int) -> tuple[Path, Path, Camera]:
    """Render the benchmark sequence once; reuse it when it is already there."""
    scale = width / 640
    camera = Camera(fx=525.0 * scale, fy=525.0 * scale, cx=width / 2 - 0.5, cy=height / 2 - 0.5, depth_scale=5000.0)
    tag = folder / f"room_{frames}_{width}x{height}"
    annotations = tag / "annotations.xml"
    if not annotations.is_file():
        shutil.rmtree(tag, ignore_errors=True)
        started = time.perf_counter()
        annotation = make_sequence(tag / "sequence", n_frames=frames, width=width, height=height, camera=camera,
                                   seed=7, dropped_rgb_frames=())
        write_cvat_video(annotation, annotations, width=width, height=height, keyframe_step=5)
        print(f"rendered {frames} frames at {width}x{height} in {time.perf_counter() - started:.1f} s")
    return tag / "sequence", annotations, camera


def camera_toml(camera: Camera, path: Path) -> Path:
    """Write the camera as a configuration file for the command line."""
    path.write_text("[camera]\n" + "".join(f"{k} = {getattr(camera, k)}\n" for k in ("fx", "fy", "cx", "cy", "depth_scale")),
                    encoding="utf-8")
    return path


def run_process(command: list[str]) -> tuple[float, float]:
    """Wall seconds of a whole process and its peak resident memory (MiB, its VmHWM read until it ends)."""
    started = time.perf_counter()
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    peak = 0.0
    status = Path(f"/proc/{process.pid}/status")
    while process.poll() is None:
        try:
            for line in status.read_text().splitlines():
                if line.startswith("VmHWM:"):
                    peak = max(peak, int(line.split()[1]) / 1024)
        except (OSError, ValueError):
            pass
        time.sleep(0.02)
    elapsed = time.perf_counter() - started
    stderr = process.stderr.read() if process.stderr else ""
    if process.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed ({process.returncode}):\n{stderr}")
    return elapsed, peak


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--walk-frames", type=int, default=120, help="frames of the walk (the --poses runs)")
    parser.add_argument("--rounds", type=int, default=3, help="rounds of every measurement; the best counts")
    parser.add_argument("--workdir", type=Path, default=Path(tempfile.gettempdir()) / "annotate-rgbd-bench")
    args = parser.parse_args()
    from bench_refine import make_contact_sequence  # the walk with its trajectory

    sequence, annotations, camera = make_benchmark_sequence(args.workdir, args.frames, 640, 480)
    walk = make_contact_sequence(args.workdir, args.walk_frames, 640, 480, 2.0, 12)
    outputs = args.workdir / "outputs"
    shutil.rmtree(outputs, ignore_errors=True)
    outputs.mkdir(parents=True)
    config = camera_toml(camera, outputs / "camera.toml")
    walk_config = camera_toml(walk.camera, outputs / "walk_camera.toml")
    walk_frames = len(list((walk.sequence / "depth").glob("*.png")))
    trajectory = walk.sequence / "groundtruth.txt"
    exports = {}
    for step in (1, 10):
        exports[step] = outputs / f"walk_keyframes_every_{step}.xml"
        write_cvat_video(read_cvat(walk.single[0]), exports[step], width=640, height=480, keyframe_step=step,
                         keyframes_only=True)

    tool = [sys.executable, "-m", "annotate_rgbd"]
    room = ["cvat2mask", str(sequence), str(annotations), "--config", str(config), "--force"]
    runs = {  # name: (command, frames)
        "I/O floor": ([sys.executable, "-c", IO_FLOOR, str(sequence / "depth")], args.frames),
        "cvat2mask --jobs 1": (tool + room + ["--out", str(outputs / "one"), "--jobs", "1"], args.frames),
        "cvat2mask --jobs 2": (tool + room + ["--out", str(outputs / "two"), "--jobs", "2"], args.frames),
        "propose --jobs 1": (tool + ["propose", str(sequence), "--config", str(config), "--out",
                                     str(outputs / "propose"), "--jobs", "1", "--every", "1"], args.frames),
    }
    for step in (1, 10):
        walk_run = tool + ["cvat2mask", str(walk.sequence), str(exports[step]), "--config", str(walk_config), "--force",
                           "--jobs", "1"]
        runs[f"walk, keyframe every {step}"] = (walk_run + ["--out", str(outputs / f"walk{step}")], walk_frames)
        runs[f"walk, keyframe every {step}, --poses"] = (
            walk_run + ["--out", str(outputs / f"walk{step}_poses"), "--poses", str(trajectory)], walk_frames)

    best = {name: float("inf") for name in runs}
    peak = {name: 0.0 for name in runs}
    for round_ in range(1, args.rounds + 1):
        line = []
        for name, (command, _) in runs.items():
            seconds, memory = run_process(command)
            best[name], peak[name] = min(best[name], seconds), max(peak[name], memory)
            line.append(f"{name} {seconds:.1f} s")
        print(f"round {round_}: " + ", ".join(line), flush=True)
    identical = all((outputs / "one" / "masks" / p.name).read_bytes() == p.read_bytes()
                    for p in (outputs / "two" / "masks").iterdir())

    per_frame = {name: 1000 * best[name] / frames for name, (_, frames) in runs.items()}
    print(f"\nroom: {args.frames} frames at 640x480; walk: {walk_frames} frames; whole processes, best of {args.rounds} rounds")
    print(f"{'':38} {'ms/frame':>9} {'x floor':>8} {'peak MiB':>9}")
    for name in runs:
        ratio = f"{per_frame[name] / per_frame['I/O floor']:8.2f}" if not name.startswith("walk") else f"{'':8}"
        print(f"{name:38} {per_frame[name]:9.1f} {ratio} {peak[name]:9.0f}")
    one, two = best["cvat2mask --jobs 1"], best["cvat2mask --jobs 2"]
    checks = [
        ("cvat2mask --jobs 1 / I/O floor", one / best["I/O floor"], "<= 3"),
        ("--poses / without, keyframe every 10th",
         best["walk, keyframe every 10, --poses"] / best["walk, keyframe every 10"], "<= 1.3"),
        ("--poses / without, every frame a keyframe",
         best["walk, keyframe every 1, --poses"] / best["walk, keyframe every 1"], "<= 1.05"),
        ("--jobs 2 speed-up over --jobs 1", one / two, ">= 1.7"),
        ("propose / cvat2mask per frame", best["propose --jobs 1"] / one, "<= 1"),
    ]
    print()
    for name, value, target in checks:
        limit = float(target.split()[1])
        met = value <= limit if target.startswith("<=") else value >= limit
        print(f"{name:44} {value:6.2f}x  target {target}: {'met' if met else 'NOT met'}")
    print(f"{'peak memory of cvat2mask --jobs 1':44} {peak['cvat2mask --jobs 1']:6.0f} MiB (about 310 before the speed work)")
    print(f"masks identical between --jobs 1 and --jobs 2: {identical}")


if __name__ == "__main__":
    main()

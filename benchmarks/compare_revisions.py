"""Speed of ``cvat2mask`` at this revision against an earlier one, measured in the same run.

Run from the repository root (the package must be installed)::

    python benchmarks/compare_revisions.py --against HEAD~3 [--frames 150] [--rounds 4] [--workers 1]

It renders the benchmark sequence of ``bench_cvat2mask.py`` once, unpacks the earlier revision's
package into a temporary folder (``git archive``), and then times ``run_cvat2mask`` with the
default configuration of each revision (its own defaults: that is what a user gets), every frame
made (``force``), in fresh processes that take turns for ``--rounds`` rounds; each revision keeps
its best round, since a shared machine's speed drifts within minutes. It prints both and their
ratio, and beside them the I/O floor of ``bench_cvat2mask.py`` (decode each depth PNG, encode one
colour mask), measured in the same rounds, with each revision's time as a multiple of it.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: Runs in a fresh interpreter with one revision's package first on the path (and a neutral
#: working folder: ``python -c`` puts the current folder before ``PYTHONPATH``, and run from the
#: repository root it would import this revision whatever the path says). It prints the seconds,
#: the frames written and the package's folder, which the caller checks.
TIMED_RUN = """
import json, sys, time
from pathlib import Path
import annotate_rgbd
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.config.settings import Config
from annotate_rgbd.pipeline.execute import prepare_process
from annotate_rgbd.pipeline.scene import run_cvat2mask

sequence, annotations, out, camera, workers = sys.argv[1:6]
workers = int(workers)
prepare_process(workers)
config = Config(camera=Camera(**json.loads(camera)))
started = time.perf_counter()
run = run_cvat2mask(sequence, [annotations], out, config, workers=workers, force=True)
print(time.perf_counter() - started, run.written, Path(annotate_rgbd.__file__).resolve().parent.parent)
"""


#: The I/O floor timed inside its process like the runs (imports before the clock starts).
TIMED_FLOOR = "import cv2, numpy, sys, time\nstarted = time.perf_counter()\n{floor}\nprint(time.perf_counter() - started)\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--against", required=True, help="the earlier revision (any git revision name)")
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--workdir", type=Path, default=Path(tempfile.gettempdir()) / "annotate-rgbd-bench")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_cvat2mask import IO_FLOOR, make_benchmark_sequence

    sequence, annotations, camera = make_benchmark_sequence(args.workdir, args.frames, 640, 480)
    camera_json = json.dumps({k: getattr(camera, k) for k in ("fx", "fy", "cx", "cy", "depth_scale")})
    with tempfile.TemporaryDirectory() as tmp:
        earlier = Path(tmp) / "earlier"
        earlier.mkdir()
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", args.against, "annotate_rgbd", "configs"],
                                 check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(earlier)], input=archive, check=True)
        configs = earlier / "annotate_rgbd" / "configs"  # the presets ship inside the package
        if not configs.exists():
            (earlier / "configs").rename(configs)
        revisions = {args.against: earlier, "this revision": ROOT}
        best = {name: float("inf") for name in revisions}
        floor = float("inf")
        for round_ in range(1, args.rounds + 1):
            done = subprocess.run([sys.executable, "-c", TIMED_FLOOR.format(floor=IO_FLOOR), str(sequence / "depth")],
                                  capture_output=True, text=True, check=True, cwd=tmp)
            floor = min(floor, float(done.stdout.split()[0]))
            line = [f"I/O floor: {1000 * float(done.stdout.split()[0]) / args.frames:.1f} ms/frame"]
            for name, tree in revisions.items():
                out = Path(tmp) / f"out-{len(line)}"
                done = subprocess.run(
                    [sys.executable, "-c", TIMED_RUN, str(sequence), str(annotations), str(out), camera_json,
                     str(args.workers)],
                    capture_output=True, text=True, env={"PYTHONPATH": str(tree), "PATH": "/usr/bin:/bin"}, cwd=tmp,
                )
                if done.returncode != 0:
                    print(done.stderr, file=sys.stderr)
                    return 1
                seconds, _, imported = done.stdout.split(maxsplit=2)
                if Path(imported.strip()) != tree.resolve():
                    print(f"{name}: the run imported the package from {imported.strip()}, not {tree}", file=sys.stderr)
                    return 1
                seconds = float(seconds)
                best[name] = min(best[name], seconds)
                line.append(f"{name}: {1000 * seconds / args.frames:.1f} ms/frame")
            print(f"round {round_}: " + ", ".join(line))
    old, new = best[args.against], best["this revision"]
    print(f"{args.frames} frames at 640x480, {args.workers} worker(s), best of {args.rounds} rounds, default configuration")
    print(f"{'I/O floor':>14}: {1000 * floor / args.frames:6.1f} ms/frame")
    print(f"{args.against:>14}: {1000 * old / args.frames:6.1f} ms/frame  ({old / floor:.2f}x the floor)")
    print(f"{'this revision':>14}: {1000 * new / args.frames:6.1f} ms/frame  ({new / floor:.2f}x the floor)")
    print(f"this revision / {args.against}: {new / old:.3f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())

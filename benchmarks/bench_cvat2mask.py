"""Speed of ``cvat2mask`` against the I/O floor, with 1 worker and with all workers, in one run.

Run from the repository root::

    python benchmarks/bench_cvat2mask.py [--frames 300] [--width 640 --height 480] [--workdir DIR]

It renders a synthetic sequence (the room of ``annotate_rgbd.synthetic``: about 10 planes,
clutter, Kinect-like noise) once into ``--workdir`` (reused by later runs), then measures, on
the same frames and in the same run:

* the I/O floor: decoding each depth PNG and encoding one colour mask per frame and writing it
  the way the tool must (atomically: a temporary file, then a rename), the work no
  implementation can skip;
* ``run_cvat2mask`` with 1 worker and with all workers (``--force``: every frame is made), in
  this process with the settings the command line makes first (helper server started, freed
  buffers kept: see ``annotate_rgbd.execute``); the 1-worker run also samples this process's
  resident memory after every frame, to show that it stays flat along the sequence.

The three measurements take turns for ``--rounds`` rounds and each keeps its best, so that a
burst of load from other work on a shared machine does not decide the ratios. Targets (issue
"Batch relabelling"): 1-worker time per frame at most 3x the I/O floor, and 2 workers at least
1.7x faster than 1 on a 2-core machine.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.config.settings import Config
from annotate_rgbd.cvat import write_cvat_video
from annotate_rgbd.pipeline.execute import default_workers, prepare_process
from annotate_rgbd.report.palette import colourize, plane_colours
from annotate_rgbd.pipeline.scene import run_cvat2mask
from annotate_rgbd.io.sequence import read_sequence
from annotate_rgbd.synthetic import make_sequence
from annotate_rgbd.io.writer import write_png


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


def io_floor(sequence_dir: Path, out: Path) -> float:
    """Seconds to decode every depth frame and encode and write (atomically) one colour mask per frame."""
    sequence = read_sequence(sequence_dir)
    colours = plane_colours(12)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    for name in sequence.depth.files:
        depth = cv2.imread(str(sequence_dir / name), cv2.IMREAD_UNCHANGED)
        # A mask with the structure of a real one: a few large regions and holes.
        labels = np.minimum(depth // 2000, 12).astype(np.uint8)
        write_png(out / Path(name).name, colourize(labels, colours))
    return time.perf_counter() - started


def timed_run(
    sequence_dir: Path, annotations: Path, out: Path, config: Config, workers: int, memory: list[float] | None = None
) -> float:
    """Seconds of one forced ``run_cvat2mask``; with ``memory``, this process's resident memory
    (MiB) is appended to it after every frame."""
    sample = (lambda done, total: memory.append(resident_mib())) if memory is not None else None
    started = time.perf_counter()
    report = run_cvat2mask(sequence_dir, [annotations], out, config, workers=workers, force=True, progress=sample)
    elapsed = time.perf_counter() - started
    assert report.counts.made == report.written > 0, report.counts
    return elapsed


def resident_mib() -> float:
    """This process's resident memory now, in MiB (Linux)."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--workdir", type=Path, default=Path(tempfile.gettempdir()) / "annotate-rgbd-bench")
    parser.add_argument("--workers", type=int, default=default_workers(), help="the 'all workers' run")
    parser.add_argument("--rounds", type=int, default=5, help="rounds of the three measurements; the best counts")
    args = parser.parse_args()
    # As the command line does first thing: the helpers' server imports Open3D in the background,
    # and this process keeps freed image buffers for reuse.
    prepare_process(args.workers)

    sequence_dir, annotations, camera = make_benchmark_sequence(args.workdir, args.frames, args.width, args.height)
    config = Config(camera=camera)  # the defaults: noise-aware band, edge growing
    n = len(read_sequence(sequence_dir).depth)
    outputs = args.workdir / "outputs"
    shutil.rmtree(outputs, ignore_errors=True)

    # Shared machines are noisy: the three measurements take turns, and each keeps its best round.
    floor = one = many = float("inf")
    memory: list[float] = []  # of the first 1-worker run, after each frame
    for round_ in range(1, args.rounds + 1):
        times = (
            io_floor(sequence_dir, outputs / "floor"),
            timed_run(sequence_dir, annotations, outputs / "one", config, 1, memory if round_ == 1 else None),
            timed_run(sequence_dir, annotations, outputs / "many", config, args.workers),
        )
        print(f"round {round_}: I/O floor {times[0]:.2f} s, 1 worker {times[1]:.2f} s, {args.workers} workers {times[2]:.2f} s")
        floor, one, many = min(floor, times[0]), min(one, times[1]), min(many, times[2])
    identical = all(
        (outputs / "one" / "masks" / p.name).read_bytes() == p.read_bytes() for p in (outputs / "many" / "masks").iterdir()
    )

    print(f"{n} frames at {args.width}x{args.height}, {os.cpu_count()} cores, best of {args.rounds} rounds")
    print(f"I/O floor            {1000 * floor / n:7.1f} ms/frame  {n / floor:6.1f} frames/s")
    print(f"cvat2mask, 1 worker  {1000 * one / n:7.1f} ms/frame  {n / one:6.1f} frames/s")
    print(f"cvat2mask, {args.workers} workers {1000 * many / n:7.1f} ms/frame  {n / many:6.1f} frames/s")
    print(f"1 worker / I/O floor      {one / floor:5.2f}x   (target <= 3)")
    print(f"{args.workers} workers speed-up over 1  {one / many:5.2f}x   (target >= 1.7 with 2 workers)")
    print(f"masks identical between the two runs: {identical}")
    fifth = max(1, n // 5)
    print(
        f"memory of the 1-worker run: {max(memory[:fifth]):.0f} MiB up to frame {fifth}, "
        f"{max(memory):.0f} MiB up to frame {n} (flat: frames are streamed)"
    )


if __name__ == "__main__":
    main()

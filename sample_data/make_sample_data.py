"""Render the committed sample: a small synthetic room sequence with its CVAT export.

Run from the repository root (the package must be installed)::

    python sample_data/make_sample_data.py            # rewrites sample_data/
    python sample_data/make_sample_data.py OUT_DIR    # writes elsewhere

The output is a pure function of the constants below: running it twice gives identical files.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from annotate_rgbd.camera import Camera
from annotate_rgbd.cvat import write_cvat_video
from annotate_rgbd.synthetic import make_sequence

#: ROS default intrinsics (525, 525, 319.5, 239.5) scaled to half resolution.
CAMERA = Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, depth_scale=5000.0)
WIDTH, HEIGHT = 320, 240
N_FRAMES = 20
SEED = 7
#: Every fifth frame is a keyframe, as when a labeller corrects the outline every few frames.
KEYFRAME_STEP = 5
#: Kinect noise (Nguyen et al. 2012) is about 1 cm at 2.5 m, the bulk of the room's planes:
#: 3 cm keeps nearly all of their pixels while the balls' pixels stay off the table.
DISTANCE_THRESHOLD = 0.03

CAMERA_TOML = f"""\
# Synthetic sample (annotate_rgbd.synthetic): half-resolution ROS default camera.
[camera]
fx = {CAMERA.fx}
fy = {CAMERA.fy}
cx = {CAMERA.cx}
cy = {CAMERA.cy}
depth_scale = {CAMERA.depth_scale}

[ransac]
distance_threshold = {DISTANCE_THRESHOLD}
"""


def make_sample_data(out_dir: Path) -> None:
    """Write ``sequence/``, ``ground_truth/``, ``annotations.xml`` and ``camera.toml``.

    Parameters
    ----------
    out_dir : Path
        Target folder; its ``sequence/`` and ``ground_truth/`` are replaced.
    """
    out_dir = Path(out_dir)
    for folder in ("sequence", "ground_truth"):
        shutil.rmtree(out_dir / folder, ignore_errors=True)
    annotation = make_sequence(
        out_dir / "sequence",
        n_frames=N_FRAMES,
        width=WIDTH,
        height=HEIGHT,
        camera=CAMERA,
        seed=SEED,
        ground_truth_dir=out_dir / "ground_truth",
    )
    write_cvat_video(
        annotation, out_dir / "annotations.xml", width=WIDTH, height=HEIGHT, keyframe_step=KEYFRAME_STEP
    )
    (out_dir / "camera.toml").write_text(CAMERA_TOML, encoding="utf-8")


if __name__ == "__main__":
    make_sample_data(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent)

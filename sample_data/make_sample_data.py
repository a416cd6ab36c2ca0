"""Render the committed sample: a small synthetic room sequence with its CVAT export.

Run from the repository root (the package must be installed)::

    python sample_data/make_sample_data.py            # rewrites sample_data/
    python sample_data/make_sample_data.py OUT_DIR    # writes elsewhere

The output is a pure function of the constants below: running it twice gives identical files.

Besides the single export ``annotations.xml``, ``parts/`` holds the same annotation exported in
two parts, as a long sequence is annotated: each part is a CVAT task of its own over a slice of
the RGB frames, with frame numbers and track ids restarting at 0 (ids in a new order), sharing a
few frames with the next part and named ``<first RGB index>-<last RGB index>.xml``.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np

from annotate_rgbd.annotation.model import Annotation, Track
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.cvat import write_cvat_video
from annotate_rgbd.synthetic import make_sequence

#: ROS default intrinsics (525, 525, 319.5, 239.5) scaled to half resolution.
CAMERA = Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, depth_scale=5000.0)
WIDTH, HEIGHT = 320, 240
N_FRAMES = 20
SEED = 7
#: Every fifth frame is a keyframe, as when a labeller corrects the outline every few frames.
KEYFRAME_STEP = 5
#: The renderer's depth noise is a Kinect v1's (Nguyen et al. 2012,
#: :func:`annotate_rgbd.synthetic.sensor.kinect_noise_sigma`): the configuration names that
#: sensor's noise model, so that the inlier band follows the noise at every pixel's depth.
NOISE_MODEL = "kinect_v1"
#: RGB index ranges of the two annotation parts: frames 9-11 are in both.
PARTS = ((0, 11), (9, 18))

CAMERA_TOML = f"""\
# Synthetic sample (annotate_rgbd.synthetic): half-resolution ROS default camera.
# Camera: the ROS default calibration TUM RGB-D recommends (525, 525, 319.5, 239.5) at 320x240.
[camera]
fx = {CAMERA.fx}
fy = {CAMERA.fy}
cx = {CAMERA.cx}
cy = {CAMERA.cy}
depth_scale = {CAMERA.depth_scale}

[noise]
# The rendered depth has a Kinect v1's axial noise, sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2 m
# (Nguyen et al. 2012): each pixel is kept when it lies within 3 sigma of its plane at its depth.
model = "{NOISE_MODEL}"
"""


def make_sample_data(out_dir: Path) -> None:
    """Write ``sequence/``, ``ground_truth/``, ``annotations.xml``, ``parts/`` and ``camera.toml``.

    Parameters
    ----------
    out_dir : Path
        Target folder; its ``sequence/``, ``ground_truth/`` and ``parts/`` are replaced.
    """
    out_dir = Path(out_dir)
    for folder in ("sequence", "ground_truth", "parts"):
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
    (out_dir / "parts").mkdir()
    for seed, (first, last) in enumerate(PARTS, start=SEED):
        name = f"{first}-{last}.xml"
        part, _ = cut_part(annotation, first, last, np.random.default_rng(seed), name)
        write_cvat_video(part, out_dir / "parts" / name, width=WIDTH, height=HEIGHT, keyframe_step=KEYFRAME_STEP)
    (out_dir / "camera.toml").write_text(CAMERA_TOML, encoding="utf-8")


def cut_part(
    annotation: Annotation, first: int, last: int, rng: np.random.Generator, name: str
) -> tuple[Annotation, dict[int, int]]:
    """The annotation of frames ``first``..``last`` as CVAT exports a task over just those frames.

    Parameters
    ----------
    annotation : Annotation
        A video annotation whose frame numbers are RGB indices.
    first, last : int
        The part's first and last frame (RGB index).
    rng : numpy.random.Generator
        Draws the part's track ids: 0..n-1 in an order unrelated to the original ids.
    name : str
        The part's file name (its ``path``, and the task name CVAT writes).

    Returns
    -------
    part : Annotation
        Frames 0..``last - first``; the tracks visible in the slice, in ascending new id (CVAT
        writes tracks by id).
    original_id : dict of int to int
        The part's track id -> the track id in ``annotation``.
    """
    visible = [t for t in annotation.tracks if any(first <= f <= last for f in t.shapes)]
    new_ids = rng.permutation(len(visible)).tolist()
    tracks = [
        Track(new, t.label, {f - first: s for f, s in t.shapes.items() if first <= f <= last})
        for new, t in zip(new_ids, visible)
    ]
    frames = list(range(last - first + 1))
    size = {f - first: annotation.image_size[f] for f in range(first, last + 1) if f in annotation.image_size}
    part = Annotation(name, "video", sorted(tracks, key=lambda t: t.track_id), frames, image_size=size)
    return part, {new: t.track_id for new, t in zip(new_ids, visible)}


if __name__ == "__main__":
    make_sample_data(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent)

"""Pose-guided propagation on real data: TUM RGB-D freiburg1_rpy with its motion-capture poses.

Rough polygons of the desk drawn by eye on two keyframes 15 frames apart (frames 14 and 29 of
the 30 in ``../shared/data/tum_fr1_rpy``; the camera rolls, pitches and yaws fast in this
sequence), and a third drawn on frame 21 only to check the propagation against.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from annotate_rgbd.annotation.model import Annotation, Shape, Track
from annotate_rgbd.config.settings import load_config
from annotate_rgbd.cvat import write_cvat_video
from annotate_rgbd.geometry.lift import plane_agreement, plane_to_world
from annotate_rgbd.pipeline.scene import run_cvat2mask
from annotate_rgbd.io.poses import poses_at, read_trajectory
from annotate_rgbd.segment.rasterize import rasterize_frame

from conftest import reference_data

#: The desk, straight over the clutter on it, as a quick labeller draws it (CVAT pixel coordinates).
DESK = {
    14: [(0, 0), (235, 0), (240, 200), (600, 205), (640, 215), (640, 480), (0, 480)],
    29: [(285, 35), (600, 35), (640, 120), (640, 480), (205, 480)],
}
#: The desk on frame 21, drawn only to check what the poses carried there.
DESK_21 = [(90, 40), (355, 35), (360, 200), (640, 200), (640, 480), (0, 480), (0, 330), (45, 190)]


@pytest.fixture(scope="module")
def propagated(tmp_path_factory):
    sequence = reference_data("tum_fr1_rpy")
    root = tmp_path_factory.mktemp("tum_propagate")
    shapes = {f: Shape("polygon", np.array(DESK[14 if f < 29 else 29], dtype=np.float64)) for f in range(14, 30)}
    annotation = Annotation(str(root / "desk.xml"), "video", [Track(0, "desk", shapes)], list(range(30)))
    export = root / "desk.xml"
    write_cvat_video(annotation, export, width=640, height=480, keyframe_step=15, keyframes_only=True)
    config = load_config("fr1_desk")
    out = root / "out"
    run = run_cvat2mask(sequence, [export], out, config, poses=sequence / "groundtruth.txt", raw_masks=True,
                        overlays=True)
    return sequence, run, out, config


def test_the_desk_is_carried_onto_the_desk_between_the_keyframes(propagated):
    sequence, run, out, config = propagated
    report = json.loads((out / "report.json").read_text())
    lift = run.propagation.lifts[("desk.xml", 0)]
    assert [k.frame for k in lift.keyframes] == [14, 29] and lift.consistent
    written = [f for f in report["frames"] if f["status"] == "written" and f["cvat_frame"] >= 14]
    assert len(written) == 16 and all(f["pose"] == "ok" for f in written)
    before = [f for f in report["frames"] if f["status"] == "written" and f["cvat_frame"] < 14]
    assert before and not any(f["kept"] or f["dropped"] for f in before)  # before the track's first keyframe
    # On frame 21 the shape the poses drew covers the desk as drawn by hand there.
    frame = next(f for f in written if f["cvat_frame"] == 21)
    assert frame["kept"][0]["propagated"] is True
    raw = cv2.imread(str(out / "masks_raw" / frame["mask"].split("/")[-1]))
    ours = raw.any(axis=2)
    hand = rasterize_frame([(1, Shape("polygon", np.array(DESK_21, dtype=np.float64)))], 480, 640) == 1
    iou = (ours & hand).sum() / (ours | hand).sum()
    assert iou > 0.75, iou
    # Every frame's refined desk is the keyframes' desk in the world (motion-capture poses).
    trajectory = read_trajectory(sequence / "groundtruth.txt")
    times = np.array([f["depth_timestamp"] for f in written])
    poses = poses_at(trajectory, times, config.sequence.max_pose_gap)
    world_desk = lift.keyframes[0].plane
    centre = lift.keyframes[0].world.mean(axis=0)
    for k, frame in enumerate(written):
        kept = frame["kept"]
        # About half: the keyboard (3 cm up), papers, clutter with a 2-pixel rim around each, and
        # the corner of the monitor the union of the keyframe outlines reaches drop out (the
        # overlays show it).
        assert len(kept) == 1 and kept[0]["inlier_ratio"] > 0.4, frame["cvat_frame"]
        plane = plane_to_world(np.array(kept[0]["equation"]), poses.rotations[k], poses.translations[k])
        angle, offset = plane_agreement(world_desk, plane, at=centre)
        assert angle < 4 and offset < 0.03, (frame["cvat_frame"], angle, offset)


def test_overlays_mark_the_carried_desk(propagated):
    _, _, out, _ = propagated
    assert len(list((out / "overlays").iterdir())) == 30

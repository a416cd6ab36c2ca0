"""Real-data failure modes of propagation: the trajectory's time offset, what keyframes excluded,
and keyframes used as drawn."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.config.settings import load_config
from annotate_rgbd.cvat import read_cvat, write_cvat_video
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.geometry.noise import NoiseSettings
from annotate_rgbd.io.poses import Trajectory
from annotate_rgbd.pipeline.scene import run_cvat2mask
from annotate_rgbd.propagate.evidence import excluded_regions, region_outlines
from annotate_rgbd.propagate.timing import KeyframeSample, estimate_time_offset, keyframe_pairs, pair_residuals
from annotate_rgbd.segment.frame import segment_frame
from annotate_rgbd.segment.rasterize import paint_layers, rasterize_frame
from annotate_rgbd.synthetic import make_sequence

CAMERA = Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, depth_scale=5000.0)


def _swinging_trajectory(start: float = 100.0) -> tuple[Trajectory, callable]:
    """A camera at the room's centre swinging about two axes at 40-80 degrees per second (100 Hz
    samples) and the pose at any time (an independent closed form)."""

    def pose(t):
        angles = np.stack([0.7 * np.sin(2.1 * (t - start)), 0.5 * np.sin(1.3 * (t - start) + 0.4),
                           0.3 * np.sin(0.9 * (t - start))], axis=-1)
        return Rotation.from_rotvec(angles).as_matrix(), np.stack([0.1 * np.sin(t - start), 0.0 * t, 0.05 * (t - start)], axis=-1)

    stamps = start + np.arange(0, 4.0, 0.01)
    rotations, translations = pose(stamps)
    quaternions = Rotation.from_matrix(rotations).as_quat()  # (x, y, z, w)
    return Trajectory(stamps, translations, quaternions), pose


def _samples(pose, times, world_planes, rng) -> list[KeyframeSample]:
    """Each world plane seen at each time: its camera-frame plane and a few points on it, from
    the exact pose (a little noise on the points and the plane, as a fit leaves)."""
    samples = []
    for group, plane in enumerate(world_planes):
        normal, offset = plane[:3], plane[3]
        for t in times:
            rotation, translation = pose(np.array([t]))
            rotation, translation = rotation[0], translation[0]
            camera_normal = rotation.T @ normal
            camera_offset = offset + normal @ translation
            # Points of the plane in front of the camera: the foot of the camera's perpendicular
            # plus a spread along the plane.
            foot = -camera_offset * camera_normal
            basis = np.linalg.svd(camera_normal[None, :])[2][1:]
            points = foot + rng.uniform(-0.8, 0.8, (12, 2)) @ basis
            noisy = np.append(camera_normal, camera_offset) + rng.normal(0, 2e-4, 4)
            samples.append(KeyframeSample(group, float(t), points, noisy / np.linalg.norm(noisy[:3])))
    return samples


def test_the_time_offset_is_found_from_the_keyframes_planes_and_is_zero_for_exact_poses():
    trajectory, pose = _swinging_trajectory()
    rng = np.random.default_rng(4)
    planes = [np.array([0.0, 0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0, -2.0]), np.array([0.0, 1.0, 0.0, 2.5])]
    times = 100.3 + np.arange(0, 3.0, 0.33)
    samples = _samples(pose, times, planes, rng)
    exact = estimate_time_offset(trajectory, samples, 0.1, 0.005, 0.05, 0.05)
    assert exact.offset == 0.0 and exact.pairs > 0 and exact.residual_at_zero < 0.005
    # The trajectory stamps every pose 30 ms late: a frame taken at t is read at t + 0.03.
    late = Trajectory(trajectory.timestamps + 0.03, trajectory.translations, trajectory.quaternions)
    found = estimate_time_offset(late, samples, 0.1, 0.005, 0.05, 0.05)
    assert abs(found.offset - 0.03) < 0.002, found
    assert found.residual < 0.3 * found.residual_at_zero
    early = Trajectory(trajectory.timestamps - 0.045, trajectory.translations, trajectory.quaternions)
    assert abs(estimate_time_offset(early, samples, 0.1, 0.005, 0.05, 0.05).offset + 0.045) < 0.002
    # Too few keyframes to tell: no offset.
    assert estimate_time_offset(late, samples[:1], 0.1, 0.005, 0.05, 0.05).offset == 0.0


def test_keyframes_without_a_pose_at_some_tried_offset_are_left_out_of_the_time_offset():
    trajectory, pose = _swinging_trajectory()
    rng = np.random.default_rng(6)
    planes = [np.array([0.0, 0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0, -2.0])]
    times = 100.3 + np.arange(0, 3.0, 0.33)
    samples = _samples(pose, times, planes, rng)
    late = Trajectory(trajectory.timestamps + 0.03, trajectory.translations, trajectory.quaternions)
    # A drop-out of the motion capture around the fourth keyframe time, wider than the search
    # (+-0.1 s) and the largest gap between poses (0.05 s): no pose there at any tried offset.
    hole = np.abs(late.timestamps - times[3]) < 0.3
    holed = Trajectory(late.timestamps[~hole], late.translations[~hole], late.quaternions[~hole])
    found = estimate_time_offset(holed, samples, 0.1, 0.005, 0.05, 0.05)
    # The same as never having had those keyframes: their pairs are not compared.
    kept = [sample for sample in samples if sample.time != times[3]]
    assert len(kept) == len(samples) - len(planes)
    assert found == estimate_time_offset(holed, kept, 0.1, 0.005, 0.05, 0.05)
    assert 0 < found.pairs < estimate_time_offset(late, samples, 0.1, 0.005, 0.05, 0.05).pairs
    assert abs(found.offset - 0.03) < 0.002


def test_pair_residuals_are_each_pair_s_median_point_to_plane_distance():
    rng = np.random.default_rng(8)
    samples = []
    for index in range(9):
        plane = rng.normal(size=4)
        plane[:3] /= np.linalg.norm(plane[:3])
        # some keyframes with no points (a pair of two of them has no residual)
        samples.append(KeyframeSample(index % 2, float(index), rng.normal(size=(int(rng.integers(0, 30)) * (index % 4 > 0), 3)), plane))
    first, second = keyframe_pairs(samples, 12)
    sets = 3  # poses for three tried offsets at once
    rotations = Rotation.random(sets * len(samples), random_state=2).as_matrix().reshape(sets, len(samples), 3, 3)
    translations = rng.normal(size=(sets, len(samples), 3))
    got = pair_residuals(samples, first, second, rotations, translations)
    assert got.shape == (sets, len(first))
    for o in range(sets):
        for j, (a, b) in enumerate(zip(first, second)):
            # Independently: each keyframe's points and plane in the world, then distances both ways.
            points_a = samples[a].points @ rotations[o, a].T + translations[o, a]
            points_b = samples[b].points @ rotations[o, b].T + translations[o, b]
            distances = []
            for points, (k, plane) in ((points_a, (b, samples[b].plane)), (points_b, (a, samples[a].plane))):
                normal = rotations[o, k] @ plane[:3]
                distances.extend(np.abs(points @ normal + plane[3] - normal @ translations[o, k]))
            if distances:
                assert got[o, j] == pytest.approx(np.median(distances), rel=1e-9, abs=1e-12)
            else:
                assert np.isnan(got[o, j])


def test_pair_residuals_are_np_median_to_the_last_bit():
    # The medians come from an in-place partition: the very values np.median gives, for odd and
    # even counts, tied distances (points repeated, coordinates rounded) and a NaN point.
    rng = np.random.default_rng(3)
    samples = []
    for index in range(6):
        plane = np.array([0.0, 0.0, 1.0, -2.0])
        points = np.round(rng.normal(size=(int(rng.integers(1, 12)), 3)), 1)
        points = np.concatenate([points, points[: index % 3]])  # ties
        if index == 5:
            points[0, 2] = np.nan
        samples.append(KeyframeSample(0, float(index), points, plane))
    first, second = keyframe_pairs(samples, 12)
    sets = 4
    rotations = Rotation.random(sets * len(samples), random_state=5).as_matrix().reshape(sets, len(samples), 3, 3)
    translations = np.round(rng.normal(size=(sets, len(samples), 3)), 1)
    got = pair_residuals(samples, first, second, rotations, translations)
    planes = np.array([s.plane for s in samples])
    normals = np.einsum("okij,kj->oki", rotations, planes[:, :3])
    for o in range(sets):
        for j, (a, b) in enumerate(zip(first, second)):
            def to(k, n):  # plane n seen from keyframe k's camera, as pair_residuals forms it
                normal = np.einsum("ji,j->i", rotations[o, k], normals[o, n])
                return normal, planes[n, 3] + np.einsum("i,i->", normals[o, n], translations[o, k] - translations[o, n])
            (n_ab, d_ab), (n_ba, d_ba) = to(a, b), to(b, a)
            distances = np.concatenate([np.abs(np.einsum("i,ni->n", n_ab, samples[a].points) + d_ab),
                                        np.abs(np.einsum("i,ni->n", n_ba, samples[b].points) + d_ba)])
            expected = np.median(distances)
            assert (np.isnan(got[o, j]) and np.isnan(expected)) or got[o, j] == expected, (o, j)
    assert np.isnan(got[:, (first == 5) | (second == 5)]).all()


def _wall_scene():
    """A 320x240 view of a wall 2 m away, a picture frame 3 cm proud of it on the right, a box
    0.5 m in front of it at the bottom; the labeller's outline covers the wall's left part and
    stops at the picture."""
    height, width = 240, 320
    depth = np.full((height, width), 2.0, dtype=np.float32)
    depth[60:160, 200:280] = 1.97  # the picture
    depth[200:240, 20:100] = 1.5  # the box
    depth[100:110, 10:20] = np.nan  # a hole in the depth
    outline = np.array([[0, 0], [200, 0], [200, 240], [0, 240]], dtype=np.float64)
    own = rasterize_frame([(1, Shape("polygon", outline))], height, width) > 0
    return depth, own


def test_what_the_outline_left_out_touching_the_plane_is_excluded():
    depth, own = _wall_scene()
    plane = np.array([0.0, 0.0, -1.0, 2.0])  # z = 2, normal towards the camera
    noise = NoiseSettings.fixed(0.01)
    excluded = excluded_regions(own, depth, plane, CAMERA, noise, 0.1, 4)
    # The picture (3 cm proud: beyond the 1 cm band, within the 10 cm reach) and the wall beyond
    # it, but not the strip along the outline nor anything inside it.
    assert excluded[60:160, 210:280].all() and excluded[:, 290:].all()
    assert not excluded[:, :204].any()
    # Without a margin (the default) what was left out starts right at the outline.
    flush = excluded_regions(own, depth, plane, CAMERA, noise, 0.1, 0)
    assert flush[:, 200:].all() and not flush[:, :200].any()
    # The box stands 0.5 m in front: not excluded (depth tells it apart on every frame), and it
    # is inside the outline anyway. With the picture 20 cm proud, it is not excluded either.
    far = depth.copy()
    far[60:160, 200:280] = 1.8
    excluded_far = excluded_regions(own, far, plane, CAMERA, noise, 0.1, 4)
    assert not excluded_far[60:160, 205:280].any() and excluded_far[:, 290:].all()
    # A surface that does not touch the outline through surfaces near the plane is not excluded:
    # the wall right of a pillar standing 0.6 m in front of it.
    pillar = depth.copy()
    pillar[:, 200:230] = 1.4
    assert not excluded_regions(own, pillar, plane, CAMERA, noise, 0.1, 4).any()
    outlines = region_outlines(excluded, 50, 1.0)
    redrawn = rasterize_frame([(1, Shape("polygon", o)) for o in outlines], *depth.shape) > 0
    assert (redrawn & ~excluded).sum() == 0 and (excluded & ~redrawn).sum() < 0.02 * excluded.sum()


def test_the_nearest_keyframe_that_saw_a_pixel_decides():
    far_in = np.array([[0, 0], [100, 0], [100, 50], [0, 50]], dtype=np.float64)
    near_out = np.array([[50, 0], [150, 0], [150, 50], [50, 50]], dtype=np.float64)
    inside, excluded = paint_layers([(1, far_in), (-1, near_out)], 60, 200)
    assert inside[:50, :50].all() and not inside[:, 50:].any()
    assert excluded[:50, 50:150].all() and not excluded[:, :50].any() and not excluded[50:].any()


def test_a_carried_plane_does_not_grow_into_what_its_keyframes_excluded():
    depth, _ = _wall_scene()
    depth_raw = np.where(np.isfinite(depth), depth * 5000, 0).astype(np.uint16)
    config = load_config(None, {"camera.fx": 262.5, "camera.fy": 262.5, "camera.cx": 159.5, "camera.cy": 119.5})
    wall = np.array([[0, 0], [200, 0], [200, 200], [0, 200]], dtype=np.float64)
    expected = {1: np.array([0.0, 0.0, -1.0, 2.0])}
    grown = segment_frame(depth_raw, [], config, {1}, expected, [(0, 1, 0, ((1, wall),), ())])
    assert (grown.labels[:200, 290:] == 1).all()  # beyond its keyframe's view, the wall went on
    excluded = np.array([[204, 0], [320, 0], [320, 240], [204, 240]], dtype=np.float64)
    kept = segment_frame(depth_raw, [], config, {1}, expected, [(0, 1, 0, ((-1, excluded), (1, wall)), ())])
    assert not (kept.labels[:, 210:] == 1).any() and (kept.labels[10:190, 30:190] == 1).all()


def test_poses_change_nothing_when_every_frame_is_drawn(tmp_path):
    annotation = make_sequence(tmp_path / "sequence", n_frames=8, width=320, height=240, camera=CAMERA, seed=5,
                               dropped_rgb_frames=(), write_trajectory=True)
    export = tmp_path / "every.xml"
    write_cvat_video(annotation, export, width=320, height=240, keyframe_step=1, keyframes_only=True)
    # The trajectory read 40 ms off: carried shapes would land elsewhere; drawn ones must not move.
    trajectory = tmp_path / "sequence" / "groundtruth.txt"
    shifted = tmp_path / "shifted.txt"
    lines = [line.split() for line in trajectory.read_text().splitlines() if not line.startswith("#")]
    shifted.write_text("".join(f"{float(f[0]) + 0.04:.6f} {' '.join(f[1:])}\n" for f in lines))
    config = load_config(None, {"camera.fx": 262.5, "camera.fy": 262.5, "camera.cx": 159.5, "camera.cy": 119.5})
    assert all(len(t.keyframes) == len(t.shapes) for t in read_cvat(export).tracks)
    run_cvat2mask(tmp_path / "sequence", [export], tmp_path / "flat", config)
    run_cvat2mask(tmp_path / "sequence", [export], tmp_path / "posed", config, poses=shifted)
    masks = sorted((tmp_path / "flat" / "masks").iterdir())
    assert len(masks) == 8
    for mask in masks:
        assert np.array_equal(cv2.imread(str(mask)), cv2.imread(str(tmp_path / "posed" / "masks" / mask.name)))
    report = json.loads((tmp_path / "posed" / "report.json").read_text())
    assert not any(p["propagated"] for f in report["frames"] if f["status"] == "written" for p in f["kept"])


def test_each_keyframe_is_fitted_or_says_why_not_in_frame_order(tmp_path):
    from annotate_rgbd.annotation.model import Track
    from annotate_rgbd.propagate.keyframes import fit_keyframes

    depth = np.full((240, 320), 2.0 * CAMERA.depth_scale, dtype=np.uint16)  # a wall 2 m away
    cv2.imwrite(str(tmp_path / "wall.png"), depth)
    (tmp_path / "broken.png").write_text("not a png")
    square = Shape("polygon", np.array([[40.0, 40.0], [200.0, 40.0], [200.0, 200.0], [40.0, 200.0]]))
    mask = Shape("mask", np.array([[40.0, 40.0]]), bitmap=np.ones((20, 20), dtype=bool))
    # ... and frame 5 beyond the sequence's RGB frames (not in the part's map): no keyframe of it,
    # not one that failed (a CLI trial's export longer than its sequence counted 276 such).
    track = Track(1, "plane", {0: square, 1: square, 2: square, 3: mask, 4: square, 5: square},
                  keyframes=frozenset({0, 1, 2, 3, 5}))
    config = load_config(None, {"camera.fx": CAMERA.fx, "camera.fy": CAMERA.fy, "camera.cx": CAMERA.cx,
                                "camera.cy": CAMERA.cy})
    # frame 0 on the wall, frame 1 on an unreadable file, frame 2 without a depth frame near it
    fitted, = fit_keyframes([("part.xml", [track], [7], {f: f for f in range(5)})], {0: 0, 1: 1}, [tmp_path / "wall.png", tmp_path / "broken.png"], config)
    assert fitted.plane == 7
    assert [k[0] for k in fitted.keyframes] == [0, 1, 2]
    plane = fitted.keyframes[0][3][0]
    assert abs(abs(plane[2]) - 1) < 1e-6 and abs(abs(plane[3]) - 2.0) < 1e-3
    assert fitted.keyframes[1][3].startswith("unreadable depth (") and fitted.keyframes[1][2] == 1
    assert fitted.keyframes[2][3] == "no depth frame is matched to its RGB frame" and fitted.keyframes[2][2] == -1
    assert fitted.failed == [(3, "mask shapes are not propagated")]
    assert set(fitted.sizes) == {0}


def test_keyframes_on_rgb_frames_no_depth_frame_takes_are_one_warning():
    from annotate_rgbd.io.poses import FramePoses
    from annotate_rgbd.pipeline.propagation import Propagation, propagation_warnings
    from annotate_rgbd.propagate.keyframes import NO_DEPTH_FRAME
    from annotate_rgbd.propagate.lift import LiftedKeyframe, TrackLift

    square = np.array([[0.0, 0, 2], [1, 0, 2], [1, 1, 2], [0, 1, 2]])
    lifted = [LiftedKeyframe(f, square, np.array([0.0, 0, -1, 2]), 0) for f in (0, 10, 20)]
    lifts = {("a.xml", 3): TrackLift("a.xml", 3, 4, keyframes=lifted, failed=[(5, NO_DEPTH_FRAME), (7, "unreadable depth")]),
             ("a.xml", 4): TrackLift("a.xml", 4, 5, keyframes=lifted[:1], failed=[(15, NO_DEPTH_FRAME)])}
    poses = FramePoses(np.tile(np.eye(3), (2, 1, 1)), np.zeros((2, 3)), np.ones(2, bool), np.array(["", ""]))
    warnings = propagation_warnings(Propagation("traj.txt", lifts, poses))
    assert warnings == [
        "2 of 6 keyframes (like a.xml track 3 frame 5) lie on RGB frames no depth frame is matched to (each depth "
        "frame takes the RGB frame nearest to it in time, within sequence.max_time_diff): the poses carry the others' "
        "shapes, not theirs (report.json: propagation, each track's keyframes_failed)"]
    # None lifted at all: the one warning that says so (every shape in 2-D), not this one too.
    for lift in lifts.values():
        lift.keyframes = []
    warnings = propagation_warnings(Propagation("traj.txt", lifts, poses))
    assert len(warnings) == 1 and "none of the 3 keyframes could be lifted" in warnings[0]

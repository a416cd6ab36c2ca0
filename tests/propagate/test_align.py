"""Frame alignment: poses refined by ICP against the keyframes' depth (annotate_rgbd.propagate.align).

The depth here is ray-cast in the test itself, from a room corner (the floor and two walls) and
known poses, so every pose the alignment finds is checked against the pose the depth was made
from, not against the code's own idea of it.
"""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from annotate_rgbd.config.settings import load_config
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.io.poses import FramePoses
from annotate_rgbd.pipeline.propagation import Propagation, propagation_warnings
from annotate_rgbd.pool import start_helpers
from annotate_rgbd.propagate import align
from annotate_rgbd.propagate.align import _between, align_frames
from annotate_rgbd.propagate.icp import MIN_MET, align_pose, frame_points, keyframe_view, stack_views

align_depth, corrections = align._depth, align._corrections
CAMERA = Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, depth_scale=5000.0)
#: The corner of a room: the floor z = 0 and the walls x = 0, y = 0 (unit normals, offsets).
CORNER = [((0.0, 0.0, 1.0), 0.0), ((1.0, 0.0, 0.0), 0.0), ((0.0, 1.0, 0.0), 0.0)]


def _look_at(centre, target) -> tuple[np.ndarray, np.ndarray]:
    """A camera-to-world pose at ``centre`` looking at ``target`` (x right, y down, z forward)."""
    forward = np.asarray(target, float) - centre
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, (0.0, 0.0, 1.0))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return np.stack([right, down, forward], axis=1), np.asarray(centre, float)


def _render(rotation, translation, planes=CORNER, size=(240, 320)) -> np.ndarray:
    """Depth (m, NaN where no plane) of the planes seen from a pose: the nearest ray hit."""
    rows, cols = np.mgrid[0:size[0], 0:size[1]].astype(float)
    rays = np.stack([(cols - CAMERA.cx) / CAMERA.fx, (rows - CAMERA.cy) / CAMERA.fy, np.ones(size)], axis=2)
    world = rays @ rotation.T
    depth = np.full(size, np.inf)
    for normal, offset in planes:
        along = world @ np.asarray(normal)
        with np.errstate(divide="ignore", invalid="ignore"):
            hit = (offset - np.dot(normal, translation)) / along
        depth = np.where((hit > 0.1) & (hit < depth), hit, depth)
    return np.where(np.isfinite(depth), depth, np.nan).astype(np.float32)


def _turn(degrees, axis) -> np.ndarray:
    """A rotation by ``degrees`` about ``axis``."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    matrix, _ = cv2.Rodrigues(np.radians(degrees) * axis.reshape(3, 1))
    return matrix


def _error(rotation, translation, true_rotation, true_translation) -> tuple[float, float]:
    """(cm, degrees) between two poses."""
    change = true_rotation.T @ rotation
    angle = np.degrees(np.arccos(np.clip((np.trace(change) - 1) / 2, -1, 1)))
    return 100 * float(np.linalg.norm(translation - true_translation)), float(angle)


def _keyframes(poses):
    return stack_views([keyframe_view(_render(r, t), CAMERA, 10.0) for r, t in poses],
                       [r for r, _ in poses], [t for _, t in poses])


KEYFRAME_POSES = [_look_at((2.5, 2.0, 1.4), (0.3, 0.3, 0.5)), _look_at((2.2, 2.6, 1.5), (0.4, 0.2, 0.4))]


def test_a_frame_off_by_a_degree_and_centimetres_is_brought_back_onto_its_keyframes():
    true_r, true_t = _look_at((2.4, 2.3, 1.45), (0.3, 0.3, 0.5))
    points = frame_points(_render(true_r, true_t), CAMERA, 4, 10.0)
    start_r, start_t = true_r @ _turn(1.2, (1, 2, 0.5)), true_t + np.array([0.015, -0.01, 0.012])
    assert _error(start_r, start_t, true_r, true_t)[1] > 1.1
    found = align_pose(points, start_r, start_t, _keyframes(KEYFRAME_POSES), CAMERA, 0.05, 3.0)
    assert found.applied
    shift, turn = _error(found.rotation, found.translation, true_r, true_t)
    assert shift < 0.2 and turn < 0.05
    assert found.shift == pytest.approx(np.linalg.norm(found.translation - start_t))


def test_where_the_world_origin_lies_does_not_change_the_correction():
    # The same frame and keyframes with every pose 10 km off along x (a trajectory in map or
    # UTM coordinates, or one whose origin a user moved): the same correction. Taking points
    # through float32 world coordinates rounds them to a millimetre out there.
    true_r, true_t = _look_at((2.4, 2.3, 1.45), (0.3, 0.3, 0.5))
    points = frame_points(_render(true_r, true_t), CAMERA, 4, 10.0)
    start_r, start_t = true_r @ _turn(1.2, (1, 2, 0.5)), true_t + np.array([0.015, -0.01, 0.012])
    near = align_pose(points, start_r, start_t, _keyframes(KEYFRAME_POSES), CAMERA, 0.05, 3.0)
    away = np.array([1e4, 0.0, 0.0])
    views = _keyframes(KEYFRAME_POSES)
    far = align_pose(points, start_r, start_t + away, replace(views, translations=views.translations + away), CAMERA,
                     0.05, 3.0)
    assert near.applied and far.applied and near.pairs == far.pairs
    assert np.abs(far.translation - away - near.translation).max() < 1e-9
    assert np.abs(far.rotation - near.rotation).max() < 1e-9


def test_a_correction_beyond_the_limits_or_without_depth_keeps_the_given_pose():
    true_r, true_t = _look_at((2.4, 2.3, 1.45), (0.3, 0.3, 0.5))
    points = frame_points(_render(true_r, true_t), CAMERA, 4, 10.0)
    start_r, start_t = true_r @ _turn(1.2, (1, 2, 0.5)), true_t + np.array([0.015, -0.01, 0.012])
    views = _keyframes(KEYFRAME_POSES)
    refused = align_pose(points, start_r, start_t, views, CAMERA, 0.005, 3.0)
    assert not refused.applied and refused.shift > 0.005
    assert refused.rotation is not None and np.array_equal(refused.translation, start_t)
    nothing = align_pose(points[:0], start_r, start_t, views, CAMERA, 0.05, 3.0)
    assert not nothing.applied and nothing.pairs == 0 and np.array_equal(nothing.rotation, start_r)


def test_a_plane_seen_alone_does_not_slide_the_pose_along_it():
    floor = [CORNER[0]]
    true_r, true_t = _look_at((2.0, 2.0, 1.5), (1.0, 1.0, 0.0))
    views = stack_views([keyframe_view(_render(r, t, floor), CAMERA, 10.0) for r, t in KEYFRAME_POSES],
                        [r for r, _ in KEYFRAME_POSES], [t for _, t in KEYFRAME_POSES])
    points = frame_points(_render(true_r, true_t, floor), CAMERA, 4, 10.0)
    found = align_pose(points, true_r, true_t + np.array([0.0, 0.0, 0.02]), views, CAMERA, 0.05, 3.0)
    assert found.applied
    assert abs(found.translation[2] - true_t[2]) < 0.002  # the height comes back
    assert np.linalg.norm(found.translation[:2] - true_t[:2]) < 0.002  # along the floor nothing moves


def _config(**propagate):
    """The default configuration with the test's camera (and ``[propagate]`` overrides)."""
    config = load_config(None)
    return replace(config, camera=CAMERA, propagate=replace(config.propagate, **propagate))


def _sequence(tmp_path, poses):
    """Depth frames of the corner from ``poses`` as 16-bit PNGs (5000 per metre)."""
    files = []
    for i, (r, t) in enumerate(poses):
        path = tmp_path / f"{i:03d}.png"
        depth = _render(r, t)
        cv2.imwrite(str(path), np.where(np.isfinite(depth), np.rint(depth * 5000), 0).astype(np.uint16))
        files.append(path)
    return files


def test_align_frames_makes_noisy_poses_agree_with_the_depth(tmp_path):
    rng = np.random.default_rng(4)
    true = [_look_at((2.6 - 0.05 * i, 2.0 + 0.06 * i, 1.4), (0.3, 0.3 + 0.02 * i, 0.5)) for i in range(9)]
    files = _sequence(tmp_path, true)
    noisy = [(r @ _turn(rng.uniform(0.5, 1.0), rng.normal(size=3)), t + rng.normal(0, 0.008, 3)) for r, t in true]
    ok = np.ones(len(true), bool)
    ok[5] = False  # a frame without a pose stays without one
    given = FramePoses(np.stack([r for r, _ in noisy]), np.stack([t for _, t in noisy]), ok,
                       np.array(["" if o else "pose_gap" for o in ok]))
    aligned, alignment = align_frames(given, [0, 4, 8], files, _config())
    assert alignment.keyframes == 3 and alignment.frames == 5 and alignment.corrected + alignment.kept == 8
    assert np.array_equal(aligned.ok, ok)
    assert np.array_equal(aligned.translations[5], given.translations[5], equal_nan=True)
    json.dumps(alignment.to_json())
    # The depth defines the poses up to one rigid motion of them all: compare each frame's pose
    # relative to the first keyframe's with the true one. Three rounds of the keyframes against
    # each other take them most of the way, eight all of it (keyframes moving all the way to
    # their neighbours' poses would trade places every round and never settle).
    def relative(rotations, translations, i):
        return rotations[0].T @ rotations[i], rotations[0].T @ (translations[i] - translations[0])
    true_r, true_t = np.stack([r for r, _ in true]), np.stack([t for _, t in true])
    before = np.array([_error(*relative(given.rotations, given.translations, i), *relative(true_r, true_t, i))
                       for i in (1, 2, 3, 4, 6, 7, 8)])
    after = np.array([_error(*relative(aligned.rotations, aligned.translations, i), *relative(true_r, true_t, i))
                      for i in (1, 2, 3, 4, 6, 7, 8)])
    assert after[:, 1].mean() < 0.25 * before[:, 1].mean()
    assert after[:, 0].mean() < 0.3 * before[:, 0].mean()
    many, _ = align_frames(given, [0, 4, 8], files, _config(align_rounds=8))
    closer = np.array([_error(*relative(many.rotations, many.translations, i), *relative(true_r, true_t, i))
                       for i in (1, 2, 3, 4, 6, 7, 8)])
    assert closer.max(axis=0).tolist() < [0.2, 0.05]
    helpers = start_helpers(2)  # helper processes find the same poses, to the bit
    try:
        assert helpers.ready.wait(60)  # so that the helper takes jobs from the start
        shared, _ = align_frames(given, [0, 4, 8], files, _config(), helpers)
    finally:
        helpers.shutdown()
    assert np.array_equal(shared.rotations, aligned.rotations, equal_nan=True)
    assert np.array_equal(shared.translations, aligned.translations, equal_nan=True)


def test_each_depth_frame_is_read_once_and_a_process_lets_go_of_the_keyframes_behind_it(tmp_path, monkeypatch):
    """However many rounds the keyframes take, each depth frame is read once (the keyframes are
    kept); the other frames' jobs go over the keyframes one way and let go of those behind them,
    so that a helper going on to make masks keeps only the last few."""
    true = [_look_at((2.6 - 0.03 * i, 2.0 + 0.04 * i, 1.4), (0.3, 0.3 + 0.01 * i, 0.5)) for i in range(13)]
    files = _sequence(tmp_path, true)
    given = FramePoses(np.stack([r for r, _ in true]), np.stack([t for _, t in true]), np.ones(13, bool),
                       np.array([""] * 13))
    read = []
    monkeypatch.setattr(align, "_depth", lambda path, camera: read.append(path) or align_depth(path, camera))
    kept = []
    monkeypatch.setattr(align, "_corrections", lambda jobs, helpers: kept.append(len(align._kept)) or
                        corrections(jobs, helpers))
    aligned, alignment = align_frames(given, [0, 2, 4, 6, 8, 10, 12], files, _config(align_rounds=4))
    assert alignment.keyframes == 7 and alignment.frames == 6
    assert sorted(read) == sorted(files)
    assert kept == [0, 7, 7, 7, 7] and not align._kept  # this process let go of every one at the end
    jobs = []
    monkeypatch.setattr(align, "_corrections", lambda batch, helpers: jobs.append(batch) or corrections(batch, helpers))
    align_frames(given, [0, 2, 4, 6, 8, 10, 12], files, _config(align_rounds=3))
    for job in jobs[-1]:  # the other frames' jobs, as a helper would run them
        align.align_job(job)
    assert sorted(frame for frame, _, _ in align._kept.values()) == [0, 2, 4, 6]  # frame 1's, the last job's
    align._kept.clear()


def test_no_rounds_or_one_keyframe_leaves_the_poses_as_they_are(tmp_path):
    poses = KEYFRAME_POSES
    files = _sequence(tmp_path, poses)
    given = FramePoses(np.stack([r for r, _ in poses]), np.stack([t for _, t in poses]), np.ones(2, bool),
                       np.array(["", ""]))
    assert align_frames(given, [0], files, _config())[0] is given
    assert align_frames(given, [0, 1], files, _config(align_rounds=0))[0] is given


def test_depth_nearer_than_the_reach_is_not_paired():
    """An object that no keyframe saw (here a fifth of the frame, 20 % nearer than the corner
    behind it) lies beyond the pairs' reach and does not pull the pose."""
    true_r, true_t = _look_at((2.4, 2.3, 1.45), (0.3, 0.3, 0.5))
    depth = _render(true_r, true_t)
    depth[60:180, 100:220] *= 0.8
    points = frame_points(depth, CAMERA, 4, 10.0)
    start_r, start_t = true_r @ _turn(0.8, (1, 2, 0.5)), true_t + np.array([0.01, -0.01, 0.008])
    found = align_pose(points, start_r, start_t, _keyframes(KEYFRAME_POSES), CAMERA, 0.05, 3.0)
    shift, turn = _error(found.rotation, found.translation, true_r, true_t)
    assert found.applied and shift < 0.2 and turn < 0.05


def test_frames_between_keyframes_take_the_nearest_on_each_side():
    runs = _between([10, 20, 30], np.arange(0, 36), 1)
    window_of = {frame: (before, after) for before, after, frames in runs for frame in frames}
    assert set(window_of) == set(range(36)) - {10, 20, 30}
    assert window_of[0] == ((), (10,)) and window_of[15] == ((10,), (20,)) and window_of[35] == ((30,), ())
    wider = {frame: (before, after) for before, after, frames in _between([10, 20, 30], np.arange(36), 2)
             for frame in frames}
    assert wider[15] == ((10,), (20, 30)) and wider[25] == ((10, 20), (30,))


def test_an_unreadable_depth_frame_leaves_only_itself_unaligned(tmp_path):
    rng = np.random.default_rng(5)
    true = [_look_at((2.6 - 0.05 * i, 2.0 + 0.06 * i, 1.4), (0.3, 0.3 + 0.02 * i, 0.5)) for i in range(5)]
    files = _sequence(tmp_path, true)
    files[2].write_bytes(b"not a png")
    noisy = [(r @ _turn(0.7, rng.normal(size=3)), t + rng.normal(0, 0.008, 3)) for r, t in true]
    given = FramePoses(np.stack([r for r, _ in noisy]), np.stack([t for _, t in noisy]), np.ones(5, bool),
                       np.array([""] * 5))
    aligned, alignment = align_frames(given, [0, 4], files, _config())
    assert alignment.unread == 1 and alignment.frames == 3 and alignment.corrected == 4
    assert np.array_equal(aligned.rotations[2], given.rotations[2])
    for i in (1, 3):
        assert not np.array_equal(aligned.rotations[i], given.rotations[i])


def test_a_pose_far_off_its_keyframes_is_kept_listed_and_warned_of(tmp_path):
    """A pose 7 cm off (every wall of the corner sees it, each within the pairs' reach): the
    alignment finds it but does not believe a correction that large, keeps the trajectory's
    pose, lists the frame, and the run warns of it by timestamp. (A jump far beyond the reach
    across every surface is apart from the keyframes, below; one of 30 cm along two of them pairs
    only those it slides along and goes unseen.)"""
    true = [_look_at((2.6 - 0.05 * i, 2.0 + 0.06 * i, 1.4), (0.3, 0.3 + 0.02 * i, 0.5)) for i in range(5)]
    files = _sequence(tmp_path, true)
    given_t = np.stack([t for _, t in true])
    given_t[2] += 0.07 * np.ones(3) / np.sqrt(3)
    given = FramePoses(np.stack([r for r, _ in true]), given_t, np.ones(5, bool), np.array([""] * 5))
    aligned, alignment = align_frames(given, [0, 4], files, _config())
    assert np.array_equal(aligned.translations[2], given_t[2])
    assert [frame for frame, _, _ in alignment.beyond] == [2] and alignment.beyond[0][1] > 0.05
    record = alignment.to_json()
    assert record["rounds"] == 3 and record["beyond_limits"][0]["depth_frame"] == 2
    propagation = Propagation("poses.txt", {}, aligned, depth_times=np.array([10.0, 10.033, 10.066, 10.1, 10.133]),
                              alignment=alignment)
    lines = [line for line in propagation_warnings(propagation) if "disagree" in line]
    assert len(lines) == 1 and "1 depth frame's pose disagrees" in lines[0] and "at depth frame 10.066000" in lines[0]


def test_a_pose_off_across_every_surface_is_apart_from_its_keyframes_listed_and_warned_of(tmp_path):
    """A jump of 30 cm across the floor and both walls: hardly a point of the frame lies within
    the pairs' reach of the keyframes' surfaces it lands on. Too few pairs to align on, so the
    trajectory's pose is kept, and the frame is listed and warned of (it used to be counted as
    kept, silently); the frames around it meet their keyframes."""
    true = [_look_at((2.6 - 0.05 * i, 2.0 + 0.06 * i, 1.4), (0.3, 0.3 + 0.02 * i, 0.5)) for i in range(5)]
    files = _sequence(tmp_path, true)
    given_t = np.stack([t for _, t in true])
    given_t[2] += 0.3 * np.ones(3) / np.sqrt(3)
    given = FramePoses(np.stack([r for r, _ in true]), given_t, np.ones(5, bool), np.array([""] * 5))
    aligned, alignment = align_frames(given, [0, 4], files, _config())
    assert np.array_equal(aligned.translations[2], given_t[2]) and not alignment.beyond
    assert [frame for frame, _ in alignment.apart] == [2] and alignment.apart[0][1] < MIN_MET
    record = alignment.to_json(np.array([10.0, 10.033, 10.066, 10.1, 10.133]))
    assert [(e["depth_frame"], e["depth_timestamp"]) for e in record["apart_from_keyframes"]] == [(2, 10.066)]
    propagation = Propagation("poses.txt", {}, aligned, depth_times=np.array([10.0, 10.033, 10.066, 10.1, 10.133]),
                              alignment=alignment)
    lines = [line for line in propagation_warnings(propagation) if "does not meet" in line]
    assert len(lines) == 1 and lines[0].startswith(
        "poses.txt: 1 depth frame does not meet its keyframes' depth (the worst at depth frame 10.066000: of its points "
        f"that land on their surfaces, {100 * alignment.apart[0][1]:.0f} % lie within reach of them)"
        if alignment.apart[0][1] >= 0.01 else "poses.txt: 1 depth frame does not meet its keyframes' depth (the worst at "
        "depth frame 10.066000: of its points that land on their surfaces, under 1 % lie within reach of them)")
    # Without the jump, nothing is apart.
    _, alone = align_frames(given._replace(translations=np.stack([t for _, t in true])), [0, 4], files, _config())
    assert alone.apart == []
    # A keyframe that jumped: it and its one neighbour are apart from each other; both keep their
    # poses, and are counted as kept, not corrected (nor in the median correction).
    jumped = np.stack([t for _, t in true])
    jumped[4] += 0.3 * np.ones(3) / np.sqrt(3)
    keys, keyed = align_frames(given._replace(translations=jumped), [0, 4], files, _config())
    assert sorted(frame for frame, _ in keyed.apart) == [0, 4] and keyed.kept >= 2
    assert keyed.corrected + keyed.kept == 5 and np.array_equal(keys.translations[[0, 4]], jumped[[0, 4]])


def test_a_correction_found_on_under_a_quarter_of_the_points_that_land_is_not_applied():
    """Enough pairs to align on, but few of the points that land on the keyframes' surfaces:
    the frame is apart (listed as such, before any limit), and its pose is kept."""
    from annotate_rgbd.propagate.icp import Correction

    eye, zero = np.eye(3), np.zeros(3)
    assert Correction(eye, zero, 0.01, 0.2, 400, False, landed=2000).apart  # 20 % met
    assert not Correction(eye, zero, 0.01, 0.2, 600, True, landed=2000).apart  # 30 %
    assert not Correction(eye, zero, 0.0, 0.0, 50, False, landed=100).apart  # too few land to tell
    alignment = align.Alignment()
    alignment.add(7, Correction(eye, zero, 0.3, 9.0, 400, False, landed=2000))
    assert alignment.apart == [(7, 0.2)] and alignment.beyond == [] and alignment.kept == 1

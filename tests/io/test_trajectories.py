"""Trajectories in every form (TUM, KITTI rows, per-frame pose files), read streaming and checked:
rigid poses, plausible motion, and the diagnosis of a trajectory that does not fit the frames."""

from __future__ import annotations

import json
import os
import threading
import tracemalloc
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.cvat import write_cvat_video
from annotate_rgbd.errors import InputError
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.io import trajectory_text
from annotate_rgbd.io.poses import (
    FRAME_NUMBERS, POSE_GAP, SECONDS, Trajectory, load_trajectory, missing_poses_text, poses_at, quaternion_matrices,
    read_trajectory,
)
from annotate_rgbd.io.sequence import read_sequence
from annotate_rgbd.io.trajectory_checks import coverage_hint
from annotate_rgbd.synthetic import make_sequence, room_trajectory

CAMERA = Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, depth_scale=5000.0)
CONFIG = "[camera]\nfx = 262.5\nfy = 262.5\ncx = 159.5\ncy = 119.5\ndepth_scale = 5000.0\n"


def random_poses(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(rotations (n, 3, 3), translations (n, 3)): a random walk, metres."""
    rng = np.random.default_rng(seed)
    rotations = Rotation.random(n, random_state=seed).as_matrix()
    return rotations, np.cumsum(rng.normal(scale=0.01, size=(n, 3)), axis=0)


def kitti_text(rotations, translations) -> str:
    rows = np.concatenate([rotations, translations[:, :, None]], axis=2).reshape(len(rotations), 12)
    return "".join(" ".join(f"{v:.12e}" for v in row) + "\n" for row in rows)


def tum_text(times, rotations, translations) -> str:
    q = Rotation.from_matrix(rotations).as_quat()
    return "".join(f"{float(t)!r} " + " ".join(f"{v:.12f}" for v in (*p, *qq)) + "\n"
                   for t, p, qq in zip(times, translations, q))


def write_pose_file(path: Path, rotation, translation, fmt="%f") -> None:
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = rotation, translation
    np.savetxt(path, matrix, fmt=fmt)


# ---------------------------------------------------------------- the forms


def test_kitti_rows_are_frame_numbered_camera_to_world_matrices(tmp_path):
    rotations, translations = random_poses(50)
    path = tmp_path / "poses.txt"
    path.write_text("# KITTI odometry poses\n" + kitti_text(rotations, translations))
    trajectory = read_trajectory(path)
    assert (trajectory.form, trajectory.clock) == ("KITTI", FRAME_NUMBERS)
    np.testing.assert_array_equal(trajectory.timestamps, np.arange(50))
    np.testing.assert_allclose(quaternion_matrices(trajectory.quaternions), rotations, atol=1e-10)
    np.testing.assert_allclose(trajectory.translations, translations, atol=1e-12)


@pytest.mark.parametrize("form", ["ScanNet", "7-Scenes"])
def test_pose_files_are_frame_numbered_and_minus_inf_means_no_pose(tmp_path, form):
    rotations, translations = random_poses(12, seed=1)
    lost = {3, 7}
    folder = tmp_path / "pose" if form == "ScanNet" else tmp_path
    folder.mkdir(exist_ok=True)
    for i in range(12):
        name = f"{i}.txt" if form == "ScanNet" else f"frame-{i:06d}.pose.txt"
        if i in lost:
            (folder / name).write_text("-inf -inf -inf -inf\n" * 4)  # as ScanNet writes lost tracking
        else:
            write_pose_file(folder / name, rotations[i], translations[i], fmt="%.9f")
    trajectory = read_trajectory(tmp_path)  # the scene folder: its pose/ is found
    assert trajectory.form == f"{form} pose files" and trajectory.clock == FRAME_NUMBERS
    kept = [i for i in range(12) if i not in lost]
    np.testing.assert_array_equal(trajectory.timestamps, kept)
    assert trajectory.without_pose == 2
    np.testing.assert_allclose(quaternion_matrices(trajectory.quaternions), rotations[kept], atol=1e-8)
    np.testing.assert_allclose(trajectory.translations, translations[kept], atol=1e-9)
    # Frame-numbered poses are exact per frame: a lost frame between two good ones gets none.
    poses = poses_at(trajectory, np.arange(12.0))
    assert np.flatnonzero(~poses.ok).tolist() == sorted(lost)


def test_every_form_gives_the_same_poses_at_the_frames(tmp_path):
    rotations, translations = random_poses(20, seed=2)
    (tmp_path / "tum.txt").write_text(tum_text(np.arange(20.0), rotations, translations))
    (tmp_path / "kitti.txt").write_text(kitti_text(rotations, translations))
    (tmp_path / "pose").mkdir()
    for i in range(20):
        write_pose_file(tmp_path / "pose" / f"{i}.txt", rotations[i], translations[i], fmt="%.12f")
    results = [poses_at(read_trajectory(tmp_path / name), np.arange(20.0)) for name in ("tum.txt", "kitti.txt", "pose")]
    for other in results[1:]:
        np.testing.assert_allclose(other.rotations, results[0].rotations, atol=1e-9)
        np.testing.assert_allclose(other.translations, results[0].translations, atol=1e-9)
    np.testing.assert_allclose(results[0].rotations, rotations, atol=1e-9)


GOOD_ROW = "1 0 0 0.5 0 1 0 0 0 0 1 2\n"


@pytest.mark.parametrize(
    ("name", "text", "problem"),
    [
        ("k.txt", GOOD_ROW + "1.1 0 0 0 0 1 0 0 0 0 1 0\n", "line 2: its rotation is not orthonormal (|R^T R - I| = 0.21"),
        ("k.txt", GOOD_ROW + "-1 0 0 0 0 1 0 0 0 0 1 0\n", "line 2: its rotation is a reflection (determinant -1)"),
        ("k.txt", "# c\n" + GOOD_ROW + "1 0 0 0 0 1 0 0 0 0 1\n", "line 3: expected 12 fields (KITTI: a 3 x 4 camera-to-world matrix"),
        ("t.txt", "1 2 3\n", "line 1: expected 8 fields (timestamp tx ty tz qx qy qz qw) or 12 fields (KITTI"),
        ("pose/4.txt", "1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 1 1\n", "pose/4.txt: its last row is 0 0 1 1, not 0 0 0 1"),
        ("pose/4.txt", "1 0 0 0\n0 1 0 0\n0 0 1 0\n", "pose/4.txt: expected a 4x4 matrix, found 3x4"),
        ("pose/4.txt", "2 0 0 0\n0 2 0 0\n0 0 2 0\n0 0 0 1\n", "pose/4.txt: its rotation is not orthonormal"),
    ],
)
def test_poses_that_are_not_rigid_transforms_are_one_line_errors(tmp_path, name, text, problem):
    path = tmp_path / name
    path.parent.mkdir(exist_ok=True)
    path.write_text(text)
    with pytest.raises(InputError) as caught:
        read_trajectory(path.parent if name.startswith("pose/") else path)
    message = str(caught.value)
    assert "\n" not in message and problem in message, message


def test_a_byte_order_mark_at_the_start_is_skipped(tmp_path):
    path = tmp_path / "groundtruth.txt"
    path.write_bytes(b"\xef\xbb\xbf1 0 0 0 0 0 0 1\n2 1 0 0 0 0 0 1\n")
    np.testing.assert_array_equal(read_trajectory(path).timestamps, [1, 2])
    path.write_bytes(b"\xef\xbb\xbf# timestamp tx ty tz qx qy qz qw\r\n1 0 0 0 0 0 0 1\r\n")
    assert len(read_trajectory(path)) == 1


@pytest.mark.parametrize("chunk", [5, 16, 31, 64, 1 << 20])
def test_blocks_split_anywhere_give_the_same_poses_and_line_numbers(tmp_path, monkeypatch, chunk):
    """Lines cut at any byte, "\\r\\n" split between blocks, lone "\\r": the poses and the line
    named in an error do not depend on where the blocks end."""
    monkeypatch.setattr(trajectory_text, "CHUNK_BYTES", chunk)
    lines = ["# TUM trajectory", "", "1.0 0.1 0 0 0 0 0 1  # a comment", "1.5 0.2 0 0 0 0 0 1"]
    lines += [f"{2 + k / 10:.1f} {k} 0 0 0 0 0 1" for k in range(20)]
    path = tmp_path / "t.txt"
    path.write_bytes(("\r\n".join(lines[:10]) + "\r" + "\n".join(lines[10:])).encode())
    trajectory = read_trajectory(path)
    np.testing.assert_allclose(trajectory.timestamps, [1.0, 1.5] + [2 + k / 10 for k in range(20)])
    np.testing.assert_allclose(trajectory.translations[:, 0], [0.1, 0.2] + list(range(20)))
    broken = lines[:-5] + ["3.4 0 0 0 0 0 0 nan"] + lines[-4:]
    path.write_bytes("\r\n".join(broken).encode())
    with pytest.raises(InputError, match=f"line {len(broken) - 4}: qw is nan"):
        read_trajectory(path)
    unordered = lines[:-5] + ["1.7 0 0 0 0 0 0 1"] + lines[-4:]
    path.write_bytes("\n".join(unordered).encode())
    with pytest.raises(InputError, match=f"line {len(unordered) - 4}: timestamp 1.7 is not after 3.4 on line {len(unordered) - 5}"):
        read_trajectory(path)


# ---------------------------------------------------------------- hostile files


def test_a_fifo_without_a_writer_is_refused_at_once(tmp_path):
    fifo = tmp_path / "poses.fifo"
    os.mkfifo(fifo)
    outcome = []
    reader = threading.Thread(target=lambda: outcome.append(_error_of(fifo)), daemon=True)
    reader.start()
    reader.join(timeout=10)
    if reader.is_alive():  # it waits for a writer: give it one, so that the thread ends
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        pytest.fail("reading a FIFO without a writer waited for one")
    assert outcome == [f"{fifo}: cannot read the trajectory file (not a regular file (a FIFO); refused)"]


def _error_of(path: Path) -> str:
    try:
        read_trajectory(path)
    except InputError as error:
        return str(error)
    return "read"


def peak_memory(function) -> tuple[int, str]:
    """Peak bytes allocated (tracemalloc sees numpy's buffers too) while ``function`` runs."""
    tracemalloc.start()
    try:
        try:
            function()
            outcome = "read"
        except InputError as error:
            outcome = str(error)
        return tracemalloc.get_traced_memory()[1], outcome
    finally:
        tracemalloc.stop()


def test_memory_is_a_small_multiple_of_the_poses_kept(tmp_path, monkeypatch):
    n = 100_000
    rng = np.random.default_rng(3)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    path = tmp_path / "long.txt"
    np.savetxt(path, np.column_stack([np.arange(n) * 0.01, rng.normal(size=(n, 3)), q]), fmt="%.6f")
    monkeypatch.setattr(trajectory_text, "CHUNK_BYTES", 64 << 10)
    kept = n * 8 * 8  # timestamp, translation and quaternion: 8 float64 a pose
    peak, outcome = peak_memory(lambda: read_trajectory(path))
    assert outcome == "read" and peak < 2 * kept + (4 << 20), (peak, kept)
    # A small file reserves no large read buffer (it was 1 GiB + 1 byte).
    small = tmp_path / "small.txt"
    small.write_text("1 0 0 0 0 0 0 1\n")
    assert peak_memory(lambda: read_trajectory(small))[0] < 4 << 20


@pytest.mark.parametrize(("data", "problem"), [
    (b"\0" * (64 << 20), "line 1: longer than 64 KiB: not a trajectory file (binary data?)"),
    (b"1 0 0 0 0 0 0 1\n\0\0\0\n", "line 2: holds a NUL byte: not a trajectory file (binary data?)"),
])
def test_binary_data_is_refused_on_sight(tmp_path, data, problem):
    path = tmp_path / "binary.txt"
    path.write_bytes(data)
    peak, outcome = peak_memory(lambda: read_trajectory(path))
    assert outcome == f"{path}: {problem}"
    assert peak < 8 << 20  # 64 MiB of NUL bytes were held (and copied) in memory before


# ---------------------------------------------------------------- plausibility and coverage


def walk(n: int = 60) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A plausible hand-held walk at 30 Hz: (times, rotations, camera centres)."""
    poses = room_trajectory(n)
    return (1000.0 + np.arange(n) / 30.0, np.array([p.rotation for p in poses]), np.array([p.position for p in poses]))


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (lambda t, r, c: (t, r, c), None),
        (lambda t, r, c: (t, r, c + 1e300), "the camera lies 1e+300 m from the world origin"),
        (lambda t, r, c: (t, r, c * 1000.0), "implausible for an RGB-D camera read as camera-to-world in metres"),
        (lambda t, r, c: (t, r, c * 1000.0), "are the translations in millimetres? (divide them by 1000)"),
        # World-to-camera stored as if camera-to-world: R^T and -R^T c, the camera 30 m out.
        (lambda t, r, c: (t, r.transpose(0, 2, 1), -np.einsum("nji,nj->ni", r, c + [30.0, 0, 0])),
         "read as world-to-camera it moves"),
        (lambda t, r, c: (t, Rotation.random(len(t), random_state=4).as_matrix(), c), "degrees/s"),
    ],
)
def test_implausible_motion_gets_one_line(tmp_path, change, words):
    times, rotations, centres = change(*walk())
    path = tmp_path / "trajectory.txt"
    path.write_text(tum_text(times, rotations, centres))
    loaded = load_trajectory(path, times, SECONDS)
    if words is None:
        assert loaded.warnings == []
    else:
        assert len(loaded.warnings) == 1 and words in loaded.warnings[0] and loaded.warnings[0].startswith(f"{path}: ")


def test_millimetres_are_suggested_only_where_they_make_the_motion_plausible(tmp_path):
    times, rotations, centres = walk()
    times = 1000.0 + (times - 1000.0) / 50000.0  # the walk 50,000 times faster: a thousandth is still too fast
    path = tmp_path / "trajectory.txt"
    path.write_text(tum_text(times, rotations, centres))
    warnings = load_trajectory(path, times, SECONDS).warnings
    assert len(warnings) == 1 and warnings[0].endswith("read as camera-to-world in metres")


@pytest.mark.parametrize(
    ("trajectory", "frames", "words"),  # 100 Hz motion capture, 30 Hz frames
    [
        ((1305031102.0, 1305031130.0), (1305031103.0, 1305031129.0), None),
        ((1.305031102e18, 1.305031130e18), (1305031103.0, 1305031129.0), "look like nanoseconds: divide them by 1e+09"),
        ((1.305031102e15, 1.305031130e15), (1305031103.0, 1305031129.0), "look like microseconds"),
        ((1.305031102e12, 1.305031130e12), (1305031103.0, 1305031129.0), "look like milliseconds"),
        ((1305031102.0, 1305031130.0), (1.305031103e18, 1.305031129e18), "the depth frames' timestamps look like nanoseconds"),
        ((0.0, 28.0), (1305031103.0, 1305031129.0), "the durations agree but the trajectory starts 1305031103.000 s "
                                                    "before the first depth frame (propagate.time_offset = "
                                                    "-1305031103.000 lines them up)"),
        ((-28e9, 0.0), (1305031103.0, 1305031129.0), "the durations agree with the trajectory in nanoseconds"),
        ((1311868164.0, 1311868200.0), (1305031103.0, 1305031129.0), "the durations agree"),
        ((1311868164.0, 1311869900.0), (1305031103.0, 1305031129.0), "is it this sequence's trajectory?"),
    ],
)
def test_a_trajectory_that_misses_the_frames_gets_its_likely_unit_or_offset(trajectory, frames, words):
    n_poses = int(100 * (trajectory[1] - trajectory[0]) / (1e9 if trajectory[0] > 1e17 else 1e6 if trajectory[0] > 1e14
                                                          else 1e3 if trajectory[0] > 1e11 else 1))
    hint = coverage_hint(*trajectory, *frames, SECONDS, n_poses=max(n_poses, 2), n_frames=780)
    assert hint is None if words is None else words in hint, hint


@pytest.mark.parametrize(("spacing", "words"), [
    (1e7, "lie 1e+07 s apart (median), too far apart to interpolate a pose: its timestamps look like nanoseconds: "
          "divide them by 1e+09"),
    (1e4, "look like microseconds: divide them by 1e+06"), (10.0, "look like milliseconds: divide them by 1000"),
    (1e12, "too far apart to interpolate a pose"),
])
def test_frames_between_samples_too_far_apart_get_the_spacing_and_its_unit(spacing, words):
    trajectory = Trajectory(np.arange(5) * spacing, np.zeros((5, 3)), np.tile([0.0, 0, 0, 1], (5, 1)))
    times = np.linspace(spacing / 3, spacing * 3.5, 9)
    reasons = poses_at(trajectory, times).reasons
    assert missing_poses_text(trajectory, times, reasons, SECONDS).endswith(words)
    on_samples = trajectory.timestamps[1:3]
    assert missing_poses_text(trajectory, on_samples, poses_at(trajectory, on_samples).reasons, SECONDS) == ""


def test_a_few_frames_in_a_gap_of_the_trajectory_are_named():
    # Samples every 0.01 s but for a 0.5 s gap (tracking lost): the frames in it are named.
    stamps = np.concatenate([np.arange(0, 1, 0.01), np.arange(1.5, 3, 0.01)])
    trajectory = Trajectory(stamps, np.zeros((len(stamps), 3)), np.tile([0.0, 0, 0, 1], (len(stamps), 1)))
    times = np.arange(0.005, 3, 0.1)
    reasons = poses_at(trajectory, times).reasons
    gaps = times[reasons == POSE_GAP]
    assert len(gaps) == 5
    assert missing_poses_text(trajectory, times, reasons, SECONDS) == (
        "the trajectory has no sample close to them (a gap in tracking): "
        f"{gaps[0]:.6f}, {gaps[1]:.6f}, {gaps[2]:.6f} s and 2 more")
    one = np.append(times[reasons != POSE_GAP], gaps[0])
    assert missing_poses_text(trajectory, one, poses_at(trajectory, one).reasons, SECONDS) == (
        f"the trajectory has no sample close to it (a gap in tracking): {gaps[0]:.6f} s")


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> dict:
    """A rendered TUM sequence with its exact trajectory and a keyframe every 4th frame."""
    root = tmp_path_factory.mktemp("walk")
    annotation = make_sequence(root / "sequence", n_frames=12, width=320, height=240, camera=CAMERA, seed=3,
                               dropped_rgb_frames=(), write_trajectory=True)
    write_cvat_video(annotation, root / "keyframes.xml", width=320, height=240, keyframe_step=4, keyframes_only=True)
    (root / "camera.toml").write_text(CONFIG)
    samples = [line.split() for line in (root / "sequence" / "groundtruth.txt").read_text().splitlines()
               if not line.startswith("#")]
    return {"root": root, "sequence": root / "sequence", "keyframes": root / "keyframes.xml",
            "config": root / "camera.toml", "samples": samples}


def write_samples(path: Path, samples, time=lambda t: t, position=lambda p: p) -> Path:
    lines = [f"{time(float(s[0])):.6f} " + " ".join(f"{float(v)!r}" for v in position(np.array(s[1:4], float)))
             + " " + " ".join(s[4:]) for s in samples]
    path.write_text("\n".join(lines) + "\n")
    return path


def run(rendered, command: str, out: Path, poses: Path, *more: str):
    args = [command, str(rendered["sequence"])] + ([str(rendered["keyframes"])] if command == "cvat2mask" else [])
    return CliRunner().invoke(app, [*args, "--out", str(out), "-c", str(rendered["config"]), "-j", "1",
                                    "--poses", str(poses), *more])


def test_nanosecond_timestamps_are_diagnosed_by_cvat2mask_and_propose(rendered, tmp_path):
    poses = write_samples(tmp_path / "ns.txt", rendered["samples"], time=lambda t: t * 1e9)
    result = run(rendered, "cvat2mask", tmp_path / "out", poses)
    assert result.exit_code == 1 and not (tmp_path / "out").exists()
    assert result.output.strip().splitlines()[-1] == (
        f"error: {poses}: no depth frame has a pose: the trajectory spans 1.7e+18 to 1.700000000376e+18 s (24 poses), "
        "the depth frames 1700000000.009 to 1700000000.376 s: the trajectory's timestamps look like nanoseconds: "
        "divide them by 1e+09")
    result = run(rendered, "propose", tmp_path / "proposals", poses)
    assert result.exit_code == 1 and not (tmp_path / "proposals").exists()  # propose made it, empty, before
    assert result.output.strip().splitlines()[-1].startswith(f"error: {poses}: no processed depth frame has a pose: "
                                                            "the trajectory spans ")
    assert "look like nanoseconds: divide them by 1e+09" in result.output
    result = run(rendered, "propose", tmp_path / "proposals", tmp_path / "missing.txt")
    assert result.exit_code == 1 and not (tmp_path / "proposals").exists()


def test_another_sequences_trajectory_is_diagnosed(rendered, tmp_path):
    poses = write_samples(tmp_path / "other.txt", rendered["samples"], time=lambda t: t - 1000.0)
    result = run(rendered, "propose", tmp_path / "proposals", poses)
    assert result.exit_code == 1
    # (the trajectory's samples begin 9 ms before the first frame)
    assert ("the durations agree but the trajectory starts 1000.009 s before the first depth frame "
            "(propagate.time_offset = -1000.009 lines them up)") in result.output.strip().splitlines()[-1]
    # ... and one 1000 s late: after, and the offset that lines them up is +1000 (tried below).
    late = write_samples(tmp_path / "late.txt", rendered["samples"], time=lambda t: t + 1000.0)
    result = run(rendered, "propose", tmp_path / "late_proposals", late)
    assert result.exit_code == 1 and "starts 999.991 s after the first depth frame (propagate.time_offset = 999.991 " \
        "lines them up)" in result.output.strip().splitlines()[-1]
    result = run(rendered, "propose", tmp_path / "late_proposals", late, "--set", "propagate.time_offset=999.991")
    assert result.exit_code == 0, result.output


def test_garbage_poses_are_said_by_cvat2mask_and_propose(rendered, tmp_path):
    poses = write_samples(tmp_path / "huge.txt", rendered["samples"], position=lambda p: p * 1e300)
    result = run(rendered, "cvat2mask", tmp_path / "out", poses)
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.output.splitlines() if line.startswith("warning: ")]
    assert any("from the world origin" in line for line in warnings)
    assert any("none of the" in line and "keyframes could be lifted onto its plane" in line for line in warnings), warnings
    result = run(rendered, "propose", tmp_path / "proposals", poses)
    assert result.exit_code == 0, result.output
    assert "from the world origin" in result.output
    assert any("from the world origin" in w for w in json.loads((tmp_path / "proposals" / "report.json").read_text())["warnings"])


def test_kitti_rows_on_a_timestamped_sequence_are_its_depth_frames_in_order(rendered, tmp_path):
    sequence = read_sequence(rendered["sequence"])
    samples = {float(s[0]): s for s in rendered["samples"]}
    rows = []
    for t in sequence.depth.timestamps:
        s = samples[round(float(t), 6)]
        matrix = Rotation.from_quat([float(v) for v in s[4:]]).as_matrix()
        rows.append(np.concatenate([matrix, np.array(s[1:4], float)[:, None]], axis=1).ravel())
    kitti = tmp_path / "kitti.txt"
    kitti.write_text("".join(" ".join(f"{v:.9f}" for v in row) + "\n" for row in rows))
    result = run(rendered, "cvat2mask", tmp_path / "out", kitti)
    assert result.exit_code == 0, result.output
    assert "KITTI poses count frames (no timestamps): pose k is taken as the k-th depth frame's" in result.output
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert [f["pose"] for f in report["frames"]] == ["ok"] * 12
    # The same masks as with the TUM trajectory, but where the first RGB frame (before the first
    # depth frame: outside the depth frames' poses) is a keyframe.
    with_tum = run(rendered, "cvat2mask", tmp_path / "tum", rendered["sequence"] / "groundtruth.txt")
    assert with_tum.exit_code == 0
    agree = [np.mean(cv2.imread(str(tmp_path / "out" / "masks" / name)) == cv2.imread(str(tmp_path / "tum" / "masks" / name)))
             for name in sorted(os.listdir(tmp_path / "tum" / "masks"))]
    assert min(agree) > 0.97, agree
    kitti.write_text(kitti.read_text() + kitti.read_text().splitlines()[-1] + "\n")
    result = run(rendered, "cvat2mask", tmp_path / "more", kitti)
    assert result.exit_code == 1
    assert "go up to frame 12, but the sequence has 12 depth frames" in result.output.strip().splitlines()[-1]


@pytest.mark.parametrize("a0, a1, expect", [
    # The trajectory stops 0.77 s into a 1.3 s sequence (a new user's cut file): 40 % covered.
    (1305031225.933, 1305031233.393, "the trajectory ends 0.773 s before the last depth frame and covers 40% of"),
    (1305031233.9, 1305031240.0, "the trajectory starts 1.03 s after the first depth frame and covers 21% of"),
    (1305031233.0, 1305031233.5, "the ranges hardly overlap"),  # inside the frames: neither end covered
    (1305031100.0, 1305031110.0, "the ranges do not overlap (the trajectory ends 123 s before the first depth frame): "
                                 "is it this sequence's trajectory?"),  # no overlap, another length
    (1305036225.9, 1305036253.6, "the ranges do not overlap (the trajectory starts 4992 s after the last depth "
                                 "frame)"),  # a user's file, 5000 s off
])
def test_a_trajectory_cut_short_is_said_to_be(a0, a1, expect):
    b0, b1 = 1305031232.869, 1305031234.166
    assert coverage_hint(a0, a1, b0, b1, SECONDS, 700, 40).startswith(expect)


def test_numbered_frames_get_no_unit_hint():
    assert coverage_hint(0, 99, 100, 300, FRAME_NUMBERS).startswith("the ranges hardly overlap: is it this sequence's")
    assert coverage_hint(1.3e9, 1.3e9 + 30, 0, 900, FRAME_NUMBERS).endswith("must be the frame's number)")
    assert coverage_hint(0, 600, 0, 900, FRAME_NUMBERS) is None

"""TUM trajectories and interpolated poses (annotate_rgbd.poses)."""

from __future__ import annotations

import bisect
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import reference_data
from scipy.spatial.transform import Rotation, Slerp

from annotate_rgbd.io import trajectory_text
from annotate_rgbd.errors import InputError
from annotate_rgbd.io.poses import (
    DEFAULT_MAX_POSE_GAP,
    OUTSIDE_TRAJECTORY,
    POSE_GAP,
    Trajectory,
    poses_at,
    quaternion_matrices,
    read_trajectory,
)

REPO_ROOT = Path(__file__).resolve().parents[2]


def shared_data() -> Path:
    """The real reference data beside the repository; skip if absent."""
    return reference_data()


def random_trajectory(seed: int, n: int = 60, step: float = 0.2) -> Trajectory:
    """Random poses at irregular times; each rotation up to ~100 degrees from the previous one,
    and each quaternion's sign chosen at random (q and -q are the same rotation)."""
    rng = np.random.default_rng(seed)
    stamps = 1305031225.0 + np.cumsum(rng.uniform(0.005, 0.02, n))
    steps = Rotation.from_rotvec(rng.normal(scale=step * 5, size=(n, 3)))
    rotations = [Rotation.identity()]
    for k in range(1, n):
        rotations.append(steps[k] * rotations[-1])
    quaternions = Rotation.concatenate(rotations).as_quat()
    quaternions *= rng.choice([-1.0, 1.0], size=(n, 1))
    return Trajectory(stamps, rng.normal(size=(n, 3)), quaternions)


def reference_poses(trajectory: Trajectory, times, max_gap):
    """The bracketing rule written out one query at a time, as the docstring states it."""
    stamps = trajectory.timestamps.tolist()
    ok, reasons = [], []
    for time_ in times:
        if time_ in stamps:
            ok.append(True)
            reasons.append("")
            continue
        after = bisect.bisect_left(stamps, time_)
        if np.isnan(time_) or after == 0 or after == len(stamps):
            ok.append(False)
            reasons.append(OUTSIDE_TRAJECTORY)
        elif time_ - stamps[after - 1] <= max_gap and stamps[after] - time_ <= max_gap:
            ok.append(True)
            reasons.append("")
        else:
            ok.append(False)
            reasons.append(POSE_GAP)
    return np.array(ok), np.array(reasons)


def write(tmp_path: Path, text: str | bytes, name: str = "groundtruth.txt") -> Path:
    path = tmp_path / name
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text)
    return path


# ---------------------------------------------------------------- reading


def test_reads_values_comments_and_blank_lines(tmp_path):
    q = Rotation.from_euler("xyz", [10, -20, 30], degrees=True).as_quat().tolist()
    lines = [
        "# ground truth trajectory",
        "# timestamp tx ty tz qx qy qz qw",
        "",
        f"1305031225.9334 1.3357 0.6698 1.6180 {q[0]!r} {q[1]!r} {q[2]!r} {q[3]!r}",
        "   ",
        # A quaternion 4e-4 too long (inside the tolerance) and a trailing comment.
        "1305031225.9434 -1 2e-3 3 0 0 0 1.0004  # after a drop-out",
    ]
    trajectory = read_trajectory(write(tmp_path, "\r\n".join(lines) + "\r\n"))
    np.testing.assert_array_equal(trajectory.timestamps, [1305031225.9334, 1305031225.9434])
    np.testing.assert_array_equal(trajectory.translations, [[1.3357, 0.6698, 1.6180], [-1, 2e-3, 3]])
    np.testing.assert_allclose(trajectory.quaternions, [q, [0, 0, 0, 1]], rtol=0, atol=1e-15)
    assert not trajectory.timestamps.flags.writeable


def test_old_mac_line_ends_are_lines_too(tmp_path):
    # A lone "\r" ends a line too (numpy's reader alone would take the file for one comment).
    trajectory = read_trajectory(write(tmp_path, "# header\r1 0 0 0 0 0 0 1\r2 5 0 0 0 0 0 1\r"))
    np.testing.assert_array_equal(trajectory.timestamps, [1, 2])
    np.testing.assert_array_equal(trajectory.translations[:, 0], [0, 5])


GOOD = "1 0 0 0 0 0 0 1\n"


@pytest.mark.parametrize(
    ("text", "line", "words"),
    [
        ("1 2 3\n", 1, "expected 8 fields"),
        ("# header\n\n" + GOOD + "2 0 0 0 0 0 1\n", 4, "found 7"),
        ("1 0 0 0 0 0 0 1 7\n2 0 0 0 0 0 0 1 7\n", 1, "found 9"),
        (GOOD + "2 0 0 abc 0 0 0 1\n", 2, "tz 'abc' is not a number"),
        (GOOD + "2 0 nan 0 0 0 0 1\n", 2, "ty is nan"),
        (GOOD + GOOD.replace("1", "2", 1) + "3 0 0 0 0 0 0 -inf\n", 3, "qw is -inf"),
        (GOOD + "2 0 0 0 0 0 0 1.01\n", 2, "length 1.01"),
        (GOOD + "2 0 0 0 0 0 0 0\n", 2, "length 0"),
        ("# c\n" + GOOD + "1 0 0 0 0 0 0 1\n", 3, "not after 1.0 on line 2"),
        (GOOD + "2 0 0 0 0 0 0 1\n" + "1.5 0 0 0 0 0 0 1\n", 3, "not after 2.0 on line 2"),
        ("# c\r\n\r\n" + GOOD + "2 0 0 0 0 0 0 nan\r\n", 4, "qw is nan"),
        ("# c\r\r" + GOOD + "2 0 0 0 0 0 0 nan\r", 4, "qw is nan"),
        ("# c\r\r" + GOOD + "2 0 0 0 0 0 1\r", 4, "found 7"),
    ],
)
def test_bad_lines_are_named(tmp_path, text, line, words):
    path = write(tmp_path, text)
    with pytest.raises(InputError) as caught:
        read_trajectory(path)
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: line {line}: ")
    assert words in message


@pytest.mark.parametrize("text", ["", "# only a comment\n\n   \n"])
def test_no_poses(tmp_path, text):
    path = write(tmp_path, text)
    with pytest.raises(InputError, match="no poses"):
        read_trajectory(path)


def test_not_utf8_names_the_line(tmp_path):
    path = write(tmp_path, GOOD.encode() + b"\r\n\r2 0 0 0 \xff 0 0 1\n")
    with pytest.raises(InputError, match=r"line 4: not UTF-8"):
        read_trajectory(path)


@pytest.mark.parametrize(("make", "words"), [(lambda tmp: tmp / "missing.txt", "cannot read the trajectory file"),
                                              (lambda tmp: tmp, "holds no pose files")])
def test_unreadable(tmp_path, make, words):
    path = make(tmp_path)
    with pytest.raises(InputError, match=words) as caught:
        read_trajectory(path)
    assert caught.value.path == path and "\n" not in str(caught.value)


def test_too_many_lines_or_bytes_are_refused(tmp_path, monkeypatch):
    path = write(tmp_path, GOOD + "\r\n\r# comment")  # four lines, the last without a break
    monkeypatch.setattr(trajectory_text, "MAX_LINES", 4)
    assert len(read_trajectory(path)) == 1
    monkeypatch.setattr(trajectory_text, "MAX_LINES", 3)
    with pytest.raises(InputError, match="more than 3 lines"):
        read_trajectory(path)
    monkeypatch.setattr(trajectory_text, "MAX_LINES", 10)
    monkeypatch.setattr(trajectory_text, "MAX_BYTES", path.stat().st_size - 1)
    with pytest.raises(InputError, match="GiB: larger than"):
        read_trajectory(path)


# ---------------------------------------------------------------- interpolation


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_interpolation_matches_scipy(seed):
    trajectory = random_trajectory(seed)
    rng = np.random.default_rng(100 + seed)
    times = rng.uniform(trajectory.timestamps[0], trajectory.timestamps[-1], 200)
    result = poses_at(trajectory, times, max_gap=1.0)
    assert result.ok.all() and (result.reasons == "").all()
    expected = Slerp(trajectory.timestamps, Rotation.from_quat(trajectory.quaternions))(times)
    np.testing.assert_allclose(result.rotations, expected.as_matrix(), rtol=0, atol=1e-10)
    for axis in range(3):
        np.testing.assert_allclose(
            result.translations[:, axis],
            np.interp(times, trajectory.timestamps, trajectory.translations[:, axis]),
            rtol=0,
            atol=1e-12,
        )


def test_sample_times_give_the_samples_exactly():
    trajectory = random_trajectory(3)
    result = poses_at(trajectory, trajectory.timestamps[::-1], max_gap=0.0)
    assert result.ok.all()
    np.testing.assert_array_equal(result.translations, trajectory.translations[::-1])
    np.testing.assert_array_equal(result.rotations, quaternion_matrices(trajectory.quaternions[::-1]))
    np.testing.assert_allclose(
        result.rotations, Rotation.from_quat(trajectory.quaternions[::-1]).as_matrix(), rtol=0, atol=1e-15
    )


def test_q_and_minus_q_interpolate_alike():
    # 40 degrees apart about z: halfway is 20 degrees whichever sign the second sample has.
    q0 = Rotation.from_euler("z", 0, degrees=True).as_quat()
    q1 = Rotation.from_euler("z", 40, degrees=True).as_quat()
    expected = Rotation.from_euler("z", 20, degrees=True).as_matrix()
    for sign in (1.0, -1.0):
        trajectory = Trajectory(np.array([0.0, 1.0]), np.zeros((2, 3)), np.array([q0, sign * q1]))
        result = poses_at(trajectory, [0.5], max_gap=1.0)
        np.testing.assert_allclose(result.rotations[0], expected, rtol=0, atol=1e-14)


def test_outside_and_gaps():
    # Dyadic times: the comparisons with max_gap are exact.
    stamps = np.array([0.0, 0.25, 0.5, 1.5, 1.75])
    trajectory = Trajectory(stamps, np.arange(15.0).reshape(5, 3), np.tile([0.0, 0, 0, 1], (5, 1)))
    times = [-0.125, 0.0, 0.375, 0.75, 1.0, 1.25, 1.75, 2.0, np.nan]
    result = poses_at(trajectory, times, max_gap=0.5)
    assert result.reasons.tolist() == [
        OUTSIDE_TRAJECTORY, "", "", POSE_GAP, "", POSE_GAP, "", OUTSIDE_TRAJECTORY, OUTSIDE_TRAJECTORY
    ]
    assert result.ok.tolist() == [reason == "" for reason in result.reasons]
    assert np.isnan(result.translations[~result.ok]).all() and np.isnan(result.rotations[~result.ok]).all()
    np.testing.assert_array_equal(result.translations[4], [7.5, 8.5, 9.5])  # middle of 0.5 .. 1.5


@pytest.mark.parametrize("seed", range(4))
def test_bracketing_rule_matches_a_one_by_one_reference(seed):
    rng = np.random.default_rng(seed)
    trajectory = random_trajectory(seed, n=200)
    keep = np.ones(200, dtype=bool)
    for start in rng.integers(1, 190, 6):  # drop-outs of 1 to 12 samples
        keep[start : start + rng.integers(1, 13)] = False
    arrays = (trajectory.timestamps, trajectory.translations, trajectory.quaternions)
    trajectory = Trajectory(*(array[keep] for array in arrays))
    stamps = trajectory.timestamps
    times = np.concatenate(
        [rng.uniform(stamps[0] - 0.05, stamps[-1] + 0.05, 300), stamps[rng.integers(0, len(stamps), 20)]]
    )
    result = poses_at(trajectory, times)  # default max_gap
    ok, reasons = reference_poses(trajectory, times, DEFAULT_MAX_POSE_GAP)
    np.testing.assert_array_equal(result.ok, ok)
    np.testing.assert_array_equal(result.reasons, reasons)
    assert (reasons == POSE_GAP).any() and (reasons == OUTSIDE_TRAJECTORY).any() and ok.any()


def test_single_sample_trajectory():
    trajectory = Trajectory(np.array([5.0]), np.array([[1.0, 2, 3]]), np.array([[0.0, 0, 0, 1]]))
    result = poses_at(trajectory, [4.99, 5.0, 5.01], max_gap=1.0)
    assert result.reasons.tolist() == [OUTSIDE_TRAJECTORY, "", OUTSIDE_TRAJECTORY]
    np.testing.assert_array_equal(result.translations[1], [1, 2, 3])


def test_bad_max_gap():
    with pytest.raises(ValueError, match="max_gap"):
        poses_at(random_trajectory(0), [0.0], max_gap=np.nan)


# ---------------------------------------------------------------- the real TUM trajectory


def test_real_tum_trajectory_and_depth_frames():
    folder = shared_data() / "tum_fr1_rpy"
    start = time.perf_counter()
    trajectory = read_trajectory(folder / "groundtruth.txt")
    seconds = time.perf_counter() - start
    reference = np.loadtxt(folder / "groundtruth.txt", comments="#")
    np.testing.assert_array_equal(trajectory.timestamps, reference[:, 0])
    np.testing.assert_array_equal(trajectory.translations, reference[:, 1:4])
    np.testing.assert_allclose(trajectory.quaternions, reference[:, 4:], rtol=0, atol=2e-4)
    assert (np.diff(trajectory.timestamps) > 0).all()

    depth_times = np.loadtxt(folder / "depth.txt", comments="#", usecols=0)
    assert len(depth_times) == 30
    result = poses_at(trajectory, depth_times)
    ok, reasons = reference_poses(trajectory, depth_times, DEFAULT_MAX_POSE_GAP)
    np.testing.assert_array_equal(result.ok, ok)
    np.testing.assert_array_equal(result.reasons, reasons)
    expected = Slerp(trajectory.timestamps, Rotation.from_quat(trajectory.quaternions))(depth_times[ok])
    np.testing.assert_allclose(result.rotations[ok], expected.as_matrix(), rtol=0, atol=1e-10)
    print(
        f"\ngroundtruth.txt: {len(trajectory)} poses read in {seconds * 1000:.1f} ms; "
        f"{ok.sum()} of {len(ok)} depth frames have a pose (max_gap {DEFAULT_MAX_POSE_GAP} s), "
        f"{(reasons == POSE_GAP).sum()} in gaps, {(reasons == OUTSIDE_TRAJECTORY).sum()} outside"
    )

"""Trajectory error as real published poses carry it: per-pose noise and a clock offset.

Rendered sequences are rendered from exact poses; a real trajectory is not exact. On a real
Kinect sequence, point-to-plane ICP of every depth frame against the fused mesh moved the
published poses by a median 0.4 cm and 0.2 degrees (95th percentile 1.2 cm, 0.47 degrees), and a
motion-capture trajectory runs on its own clock, offset from the camera's (TUM freiburg1: about
20 ms). :func:`perturb_poses` draws the first; :func:`make_sequence
<annotate_rgbd.synthetic.sequence.make_sequence>` applies both when it writes the trajectory.

The noise is Gaussian and independent per pose: a translation offset with the same standard
deviation along each axis, and a rotation by a vector (axis times angle) likewise. The length of
such a 3-D Gaussian vector follows the Maxwell (chi, 3 degrees of freedom) distribution, whose
median is :data:`MAXWELL_MEDIAN` standard deviations, so a median of 0.4 cm is a standard
deviation of 0.26 cm per axis (and a 95th percentile of 0.73 cm: real errors have heavier tails).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from .scene import Pose

#: Median of the length of a standard 3-D Gaussian vector (chi distribution, 3 degrees of
#: freedom): ``sqrt(2 * gammaincinv(1.5, 0.5))``.
MAXWELL_MEDIAN = 1.5381722544550522


def perturb_poses(
    poses: Sequence[Pose], rng: np.random.Generator, median_translation: float, median_rotation_deg: float
) -> list[Pose]:
    """Each pose moved and turned by independent Gaussian errors of the given median sizes.

    Parameters
    ----------
    poses : sequence of Pose
        Camera-to-world poses.
    rng : numpy.random.Generator
        Draws ``len(poses) * 6`` normal values (translations first).
    median_translation : float
        Median length of the position error, metres (>= 0).
    median_rotation_deg : float
        Median angle of the rotation error, degrees (>= 0); the error rotation is applied in
        the world frame, ``R' = dR @ R``.

    Returns
    -------
    list of Pose
        New poses, the same number.
    """
    if median_translation < 0 or median_rotation_deg < 0:
        raise ValueError("pose noise medians must be >= 0")
    n = len(poses)
    shift = rng.standard_normal((n, 3)) * (median_translation / MAXWELL_MEDIAN)
    turn = rng.standard_normal((n, 3)) * (np.radians(median_rotation_deg) / MAXWELL_MEDIAN)
    turns = Rotation.from_rotvec(turn).as_matrix()
    return [Pose(turns[i] @ np.asarray(p.rotation), np.asarray(p.position, dtype=np.float64) + shift[i])
            for i, p in enumerate(poses)]

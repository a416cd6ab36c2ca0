"""Rotations: unit quaternions ``(x, y, z, w)`` (scalar last, as TUM writes them) and matrices,
converted both ways, interpolated by SLERP, and pose matrices checked to be rigid transforms.
Vectorised over the first axis.
"""

from __future__ import annotations

import numpy as np

#: Largest ``|R^T R - I|`` (any element) of a rotation accepted: 7-Scenes and ScanNet print
#: their matrices with 6 to 8 digits (errors near 1e-6); a scaled or sheared matrix is far off.
ORTHONORMAL_TOLERANCE = 1e-2


def slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions along the shorter arc.

    Parameters
    ----------
    q0, q1 : ndarray, shape (M, 4)
        Unit quaternions at ``u = 0`` and ``u = 1``; ``q1`` is negated where that is nearer.
    u : ndarray, shape (M,)
        Interpolation parameters in [0, 1].

    Returns
    -------
    ndarray of float64, shape (M, 4)
        Unit quaternions.
    """
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)[:, None]
    q1 = np.where(np.sum(q0 * q1, axis=1, keepdims=True) < 0, -q1, q1)
    # The angle between the two 4-vectors; atan2 of chord lengths keeps it accurate when small,
    # which it always is between neighbouring samples (arccos of the dot product is not).
    angle = 2.0 * np.arctan2(
        np.linalg.norm(q0 - q1, axis=1, keepdims=True), np.linalg.norm(q0 + q1, axis=1, keepdims=True)
    )
    sine = np.sin(angle)
    small = sine < 1e-12  # equal rotations: weights (1 - u, u) are the limit
    with np.errstate(invalid="ignore", divide="ignore"):
        w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * angle) / sine)
        w1 = np.where(small, u, np.sin(u * angle) / sine)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def quaternion_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of unit quaternions ``(x, y, z, w)``.

    Parameters
    ----------
    q : ndarray, shape (M, 4)

    Returns
    -------
    ndarray of float64, shape (M, 3, 3)
    """
    x, y, z, w = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=-1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=-1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )


def matrix_quaternions(rotations: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(x, y, z, w)`` of rotation matrices (the inverse of
    :func:`quaternion_matrices`, up to the sign of ``q``).

    Each quaternion is taken from the largest of ``w``, ``x``, ``y``, ``z`` by the diagonal
    (Shepperd's method), which keeps it accurate for every rotation, and normalised; ``w >= 0``.

    Parameters
    ----------
    rotations : ndarray, shape (M, 3, 3)
        Rotation matrices (orthonormal up to rounding).

    Returns
    -------
    ndarray of float64, shape (M, 4)
    """
    r = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    trace = r[:, 0, 0] + r[:, 1, 1] + r[:, 2, 2]
    # 4 w^2, 4 x^2, 4 y^2, 4 z^2 from the diagonal: the largest is divided by least.
    squares = np.stack([1 + trace, 1 + 2 * r[:, 0, 0] - trace, 1 + 2 * r[:, 1, 1] - trace,
                        1 + 2 * r[:, 2, 2] - trace], axis=1)
    pick = np.argmax(squares, axis=1)
    big = np.sqrt(np.maximum(squares[np.arange(len(r)), pick], 1e-300))  # 2 |component|
    # The products of pairs of components (times 4), from the off-diagonal terms.
    wx, wy, wz = r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]
    xy, xz, yz = r[:, 0, 1] + r[:, 1, 0], r[:, 0, 2] + r[:, 2, 0], r[:, 1, 2] + r[:, 2, 1]
    candidates = np.stack([
        np.stack([wx, wy, wz, big * big], axis=1),   # from w
        np.stack([big * big, xy, xz, wx], axis=1),   # from x
        np.stack([xy, big * big, yz, wy], axis=1),   # from y
        np.stack([xz, yz, big * big, wz], axis=1),   # from z
    ], axis=1)
    q = candidates[np.arange(len(r)), pick] / (2 * big)[:, None]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.where(q[:, 3:] < 0, -q, q)


def rigid_problem(matrix: np.ndarray) -> str | None:
    """Why a 3 x 4 or 4 x 4 pose matrix is not a rigid transform, or ``None``.

    Parameters
    ----------
    matrix : ndarray, shape (3, 4) or (4, 4)

    Returns
    -------
    str or None
        ``"its last row is ..."``, ``"its rotation is not orthonormal ..."`` or ``"its rotation is
        a reflection ..."``.
    """
    index, problem = first_rigid_problem(np.asarray(matrix, dtype=np.float64)[None])
    return problem


def first_rigid_problem(matrices: np.ndarray) -> tuple[int, str | None]:
    """The first of many pose matrices that is not a rigid transform, and why.

    Parameters
    ----------
    matrices : ndarray, shape (M, 3, 4) or (M, 4, 4)
        Finite values.

    Returns
    -------
    (int, str or None)
        Its index and the reason; ``(-1, None)`` when all are rigid.
    """
    matrices = np.asarray(matrices, dtype=np.float64)
    if matrices.shape[1] == 4:
        bottom = np.abs(matrices[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) > 1e-6
        if bottom.any():
            k = int(np.argmax(bottom))
            return k, f"its last row is {' '.join(f'{v:g}' for v in matrices[k, 3])}, not 0 0 0 1"
    rotations = matrices[:, :3, :3]
    error = np.abs(np.einsum("nji,njk->nik", rotations, rotations) - np.eye(3)).max(axis=(1, 2))
    off = ~(error <= ORTHONORMAL_TOLERANCE)
    if off.any():
        k = int(np.argmax(off))
        return k, (f"its rotation is not orthonormal (|R^T R - I| = {error[k]:.3g}, tolerance "
                   f"{ORTHONORMAL_TOLERANCE:g}): not a camera-to-world rigid transform")
    mirrored = np.linalg.det(rotations) < 0
    if mirrored.any():
        k = int(np.argmax(mirrored))
        return k, "its rotation is a reflection (determinant -1), not a rotation"
    return -1, None


def rotation_angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angles (radians) between matching rotation matrices.

    Parameters
    ----------
    a, b : ndarray, shape (N, 3, 3)

    Returns
    -------
    ndarray, shape (N,)
        The angle of each ``a[i].T @ b[i]``.
    """
    cosine = (np.einsum("nij,nij->n", a, b) - 1.0) / 2.0
    return np.arccos(np.clip(cosine, -1.0, 1.0))

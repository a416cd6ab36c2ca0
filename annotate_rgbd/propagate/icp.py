"""One frame's pose aligned to its keyframes' depth: point-to-plane ICP with projective data
association, as KinectFusion tracks a camera (Newcombe et al., 2011).

A frame's depth points (every ``align_step``-th pixel, :func:`frame_points`) are taken into each
keyframe's camera with the current poses, paired with the keyframe's depth point at the pixel
they land on (:class:`KeyframeView`, on every other pixel of its grid), and the pose is moved so
that they lie on the keyframe's surface there (:func:`align_pose`). A pair's distance is measured
in its keyframe's camera, where the keyframe's surface is as it was read: no keyframe is taken to
the world. Pairs farther apart than the reach (first 5 cm, then 2 cm) are not used. A correction
larger than ``align_max_shift`` or ``align_max_turn`` is not believed (the given pose is kept),
nor is one resting on too few pairs (:func:`judged`). :mod:`annotate_rgbd.propagate.align`
decides which frames are aligned to which keyframes.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from annotate_rgbd.geometry.camera import Camera, backproject, ray_grid
from annotate_rgbd.io.rotations import rotation_angles

#: The ICP's two stages: the reach of their pairs (m), and the step (m, degrees) below which a
#: stage ends. The first pulls in poses a few centimetres off, the second fits on pairs within a
#: Kinect's noise at 2-3 m.
STAGES = ((0.05, 1e-3, 0.02), (0.02, 1e-4, 0.002))
#: Gauss-Newton steps per stage at most.
STEPS = 8
#: Half-width (px, on the keyframe's grid) of the differences a keyframe's normals are taken
#: from, on its depth smoothed over a square of twice that plus one: a Kinect's depth steps of
#: several millimetres make neighbouring pixels' normals useless.
NORMAL_REACH = 3
#: Directions of the pose whose eigenvalue in the normal equations is below this share of the
#: largest are not moved (:func:`_step`).
FREE = 1e-3
#: A pose resting on fewer pairs is not corrected.
MIN_PAIRS = 300
#: A frame of whose points that land on its keyframes' surfaces fewer than this share meet them
#: (within the pairs' reach) is apart from them (:attr:`Correction.apart`): its pose is kept. On TUM fr1_rpy at a
#: keyframe every 30th frame the share is 0.81 for the median frame and 0.41 at the 1st
#: percentile, 0.35-0.45 on the frames whose correction lies beyond the limits, 0.02-0.04 on six
#: frames with too few pairs to align on; on the rendered walk 0.80 at least.
MIN_MET = 0.25


@dataclass(frozen=True)
class KeyframeView:
    """A keyframe's depth as a surface to align to, on every other pixel of its grid (its
    camera frame).

    Parameters
    ----------
    depth : ndarray of float32, shape (ceil(H/2), ceil(W/2))
        Its depth (m); NaN where there is none or it is beyond the alignment's range. The point
        of pixel ``(u, v)`` is ``depth[v, u] * (ray_x[u], ray_y[v], 1)``.
    normals : ndarray of float32, shape (ceil(H/2), ceil(W/2), 3)
        Unit normals there; NaN where there is none.
    ray_x, ray_y : ndarray of float32, shapes (ceil(W/2),) and (ceil(H/2),)
        The grid's viewing rays at depth 1.
    """

    depth: np.ndarray
    normals: np.ndarray
    ray_x: np.ndarray
    ray_y: np.ndarray

    @property
    def nbytes(self) -> int:
        """The memory its arrays hold."""
        return self.depth.nbytes + self.normals.nbytes + self.ray_x.nbytes + self.ray_y.nbytes


@dataclass(frozen=True)
class Keyframes:
    """The keyframes a frame is aligned to: their :class:`KeyframeView` arrays stacked (each
    keyframe in its own camera frame) and their poses.

    Parameters
    ----------
    depth : ndarray of float32, shape (K, H', W')
    normals : ndarray of float32, shape (K, H', W', 3)
        The keyframes' :class:`KeyframeView` depth and normals.
    ray_x, ray_y : ndarray of float32, shape (H' * W',)
        Their grid's viewing rays (one camera) at every pixel of the raveled grid.
    rotations : ndarray, shape (K, 3, 3)
    translations : ndarray, shape (K, 3)
        The keyframes' poses (camera to world).
    """

    depth: np.ndarray
    normals: np.ndarray
    ray_x: np.ndarray
    ray_y: np.ndarray
    rotations: np.ndarray
    translations: np.ndarray


def stack_views(views: list[KeyframeView], rotations: np.ndarray, translations: np.ndarray) -> Keyframes:
    """Several keyframes' views (one camera), with their poses (camera to world: (K, 3, 3) and
    (K, 3)), as one :class:`Keyframes`."""
    height, width = views[0].depth.shape
    return Keyframes(np.stack([v.depth for v in views]), np.stack([v.normals for v in views]),
                     np.tile(views[0].ray_x, height), np.repeat(views[0].ray_y, width),
                     np.asarray(rotations, dtype=np.float64), np.asarray(translations, dtype=np.float64))


def keyframe_view(depth_m: np.ndarray, camera: Camera, max_depth: float) -> KeyframeView:
    """A keyframe's depth image as a :class:`KeyframeView`.

    Parameters
    ----------
    depth_m : ndarray, shape (H, W)
        Depth in metres, NaN where invalid (:func:`annotate_rgbd.geometry.camera.depth_to_metres`).
    camera : Camera
    max_depth : float
        Depth beyond this (m) is left out.

    Returns
    -------
    KeyframeView
    """
    depth = np.asarray(depth_m, dtype=np.float32)[::2, ::2]
    valid = np.isfinite(depth) & (depth <= max_depth)
    size = 2 * NORMAL_REACH + 1
    weight = cv2.boxFilter(valid.astype(np.float32), -1, (size, size), normalize=False)
    total = cv2.boxFilter(np.where(valid, depth, 0).astype(np.float32), -1, (size, size), normalize=False)
    with np.errstate(invalid="ignore", divide="ignore"):
        smooth = np.where(weight >= size * size / 2, total / weight, np.nan).astype(np.float32)
    ray_x, ray_y = _grid_rays(camera, *depth.shape)
    rough = np.stack([smooth * ray_x[None, :], smooth * ray_y[:, None], smooth], axis=2)
    r = NORMAL_REACH
    across = np.full_like(rough, np.nan)
    down = np.full_like(rough, np.nan)
    across[:, r:-r] = rough[:, 2 * r:] - rough[:, :-2 * r]
    down[r:-r] = rough[2 * r:] - rough[:-2 * r]
    normals = np.cross(across, down)
    length = np.linalg.norm(normals, axis=2, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        normals = (normals / length).astype(np.float32)
    normals[~valid | ~np.isfinite(length[..., 0]) | (length[..., 0] == 0)] = np.nan
    return KeyframeView(np.where(valid, depth, np.float32(np.nan)), normals, ray_x, ray_y)


def _grid_rays(camera: Camera, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """The viewing rays (float32) of every other pixel of the camera's grid, for a grid of
    ``height`` x ``width`` such pixels."""
    ray_x, ray_y = ray_grid(camera, 2 * height, 2 * width, np.float32)
    return ray_x[::2], ray_y[::2]


def frame_points(depth_m: np.ndarray, camera: Camera, step: int, max_depth: float) -> np.ndarray:
    """A frame's depth points at every ``step``-th pixel both ways (camera frame, m; float32 (N, 3))."""
    rows, cols = np.mgrid[0:depth_m.shape[0]:step, 0:depth_m.shape[1]:step]
    z = np.asarray(depth_m[::step, ::step], dtype=np.float64)
    keep = np.isfinite(z) & (z <= max_depth)
    return backproject(cols[keep], rows[keep], z[keep], camera).astype(np.float32)


@dataclass(frozen=True)
class Correction:
    """What :func:`align_pose` found for one frame.

    Parameters
    ----------
    rotation, translation : ndarray
        The aligned pose (the given one when not ``applied``).
    shift : float
        How far the alignment moved the camera centre (m).
    turn : float
        By how much it turned the camera (degrees).
    pairs : int
        Point pairs of the last step.
    applied : bool
        Whether the aligned pose is used (within the limits, on enough pairs).
    landed : int
        Of the frame's points (each with each keyframe), those the last step saw land on a
        keyframe's surface, within reach of it or not: ``pairs`` of them were within reach.
    """

    rotation: np.ndarray
    translation: np.ndarray
    shift: float
    turn: float
    pairs: int
    applied: bool
    landed: int = 0

    @property
    def apart(self) -> bool:
        """Whether the frame's depth does not meet its keyframes': enough of its points land on
        their surfaces (:data:`MIN_PAIRS`), but under :data:`MIN_MET` of those within reach. Its
        pose is off by more than the pairs' reach (a trajectory jump across the surfaces, not
        along them), or what it sees is not what they saw; a correction found on so few of its
        points is not applied."""
        return self.landed >= MIN_PAIRS and self.pairs < MIN_MET * self.landed


def align_pose(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray,
               views: Keyframes, camera: Camera, max_shift: float, max_turn: float) -> Correction:
    """Align one frame's depth to its keyframes' (point-to-plane ICP, projective pairs).

    Parameters
    ----------
    points : ndarray of float32, shape (N, 3)
        The frame's depth points (camera frame, m; :func:`frame_points`).
    rotation, translation : ndarray, shapes (3, 3) and (3,)
        Its pose to start from (camera to world).
    views : Keyframes
        The keyframes to align to (:func:`stack_views`).
    camera : Camera
        The depth camera (the frame's and the keyframes').
    max_shift, max_turn : float
        The largest correction believed (m, degrees).

    Returns
    -------
    Correction
    """
    given_r = np.asarray(rotation, dtype=np.float64)
    given_t = np.asarray(translation, dtype=np.float64)
    r, t = given_r.copy(), given_t.copy()
    pairs = landed = 0
    for reach, shortest, least_turn in STAGES:
        for _ in range(STEPS):
            rows, residuals, pairs, landed = _pairs(points, r, t, views, camera, reach)
            if pairs < MIN_PAIRS:
                break
            step = _step(rows.T @ rows, rows.T @ residuals)
            turn, _ = cv2.Rodrigues(step[:3].reshape(3, 1))
            t = t + r @ step[3:]
            r = r @ turn
            if np.linalg.norm(step[3:]) < shortest and np.degrees(np.linalg.norm(step[:3])) < least_turn:
                break
    found = replace(judged(given_r, given_t, r, t, pairs, max_shift, max_turn), landed=landed)
    return replace(found, rotation=given_r, translation=given_t, applied=False) if found.apart else found


def judged(given_r: np.ndarray, given_t: np.ndarray, r: np.ndarray, t: np.ndarray, pairs: int,
           max_shift: float, max_turn: float) -> Correction:
    """The correction from the pose ``(given_r, given_t)`` to ``(r, t)``, found on ``pairs``
    pairs, applied only within ``max_shift`` (m) and ``max_turn`` (degrees) and on at least
    :data:`MIN_PAIRS` pairs."""
    turned = float(np.degrees(rotation_angles(given_r[None], r[None])[0]))
    shifted = float(np.linalg.norm(t - given_t))
    applied = pairs >= MIN_PAIRS and shifted <= max_shift and turned <= max_turn
    return Correction(r if applied else given_r, t if applied else given_t, shifted, turned, int(pairs), applied)


def _step(hessian: np.ndarray, gradient: np.ndarray) -> np.ndarray:
    """The Gauss-Newton step ``(w, v)`` in the directions the pairs constrain: those of the
    normal equations' eigenvalues above :data:`FREE` of the largest. A plane seen alone leaves
    the camera free to slide along it and turn about its normal; noise must not move it there."""
    values, vectors = np.linalg.eigh(hessian)
    held = values > FREE * values[-1]
    return -vectors[:, held] @ ((vectors[:, held].T @ gradient) / values[held])


def _pairs(points, r, t, views: Keyframes, camera, reach):
    """The Jacobian rows (M, 6) and residuals (M,) of every pair of the frame's points with the
    keyframes' surfaces within ``reach``, for a step ``(w, v)`` applied in the frame's camera,
    their number M, and how many of the points landed on a keyframe's surface (in reach or not).
    A pair's distance is measured in its keyframe's camera (:func:`_keyframe_pairs`). The
    frame's points go there by the frame-to-keyframe transforms, composed in float64: never
    through world coordinates, whose size (where the trajectory puts its origin) would set the
    float32 rounding, and with it the pairs."""
    _, height, width = views.depth.shape
    to_keyframe = np.matmul(views.rotations.transpose(0, 2, 1), r)  # (K, 3, 3): frame -> keyframe camera
    offset = np.einsum("kji,kj->ki", views.rotations, t[None, :] - views.translations)  # R_k^T (t - t_k)
    local = np.matmul(points[None], to_keyframe.transpose(0, 2, 1).astype(np.float32))
    with np.errstate(over="ignore", invalid="ignore"):  # garbage poses (1e300 m, said when read): no pairs
        local += offset.astype(np.float32)[:, None, :]
    z = local[..., 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.rint((local[..., 0] / z * np.float32(camera.fx) + np.float32(camera.cx)) * np.float32(0.5))
        v = np.rint((local[..., 1] / z * np.float32(camera.fy) + np.float32(camera.cy)) * np.float32(0.5))
        pair = np.flatnonzero((z > 0) & (u >= 0) & (u < width) & (v >= 0) & (v < height))
        pixel = v * np.float32(width) + u  # exact: below 2^24
    point, normal, distance, landed = _keyframe_pairs(local.reshape(-1, 3), pair,
                                                      np.take(pixel, pair).astype(np.intp), len(points), views,
                                                      to_keyframe, reach)
    rows = _jacobian(np.take(points, point, axis=0), normal)
    return rows, distance.astype(np.float64), len(rows), landed


def _keyframe_pairs(local, pair, pixel, count, views: Keyframes, to_keyframe, reach):
    """The pairs within ``reach`` of the frame's points, taken into the keyframes' cameras
    (``local``, (K * N, 3)), with the keyframes' surfaces at ``pixel`` of their raveled grids:
    the frame points' indices, the keyframes' normals in the frame's camera (float32 (M, 3)),
    the points' distances to the keyframes' surfaces along them (float32 (M,)), and how many of
    ``pair`` landed on a surface (a keyframe depth and normal there). ``pair`` holds
    indices ``k * count + i`` (keyframe ``k``, frame point ``i``) in increasing order;
    ``to_keyframe`` (K, 3, 3) rotates the frame's camera into each keyframe's (column vectors),
    so a keyframe's normal as a row vector times it is the normal in the frame's camera."""
    keyframe = pair // count
    flat = keyframe * (views.depth.shape[1] * views.depth.shape[2]) + pixel
    depth = np.take(views.depth.reshape(-1), flat)
    gap = np.take(local, pair, axis=0)
    gap[:, 0] -= depth * np.take(views.ray_x, pixel)
    gap[:, 1] -= depth * np.take(views.ray_y, pixel)
    gap[:, 2] -= depth
    normal = np.take(views.normals.reshape(-1, 3), flat, axis=0)
    distance = np.einsum("ij,ij->i", gap, normal)
    with np.errstate(invalid="ignore"):
        near = np.flatnonzero((np.einsum("ij,ij->i", gap, gap) < reach * reach) & np.isfinite(distance))
    normal, keyframe = np.take(normal, near, axis=0), np.take(keyframe, near)
    ends = np.searchsorted(keyframe, np.arange(len(views.depth) + 1))
    rotate = to_keyframe.astype(np.float32)
    for k in range(len(views.depth)):
        normal[ends[k]:ends[k + 1]] = normal[ends[k]:ends[k + 1]] @ rotate[k]
    return np.take(pair, near) % count, normal, np.take(distance, near), int(np.count_nonzero(np.isfinite(distance)))


def _jacobian(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The point-to-plane Jacobian rows ``(p x n, n)`` (M, 6, float64) of points and normals
    (float32 (M, 3), the frame's camera): the cross product in float32 as ``np.cross`` computes it,
    one column at a time."""
    (px, py, pz), (nx, ny, nz) = points.T, normals.T
    rows = np.empty((len(points), 6))
    rows[:, 0] = py * nz - pz * ny
    rows[:, 1] = pz * nx - px * nz
    rows[:, 2] = px * ny - py * nx
    rows[:, 3:] = normals
    return rows

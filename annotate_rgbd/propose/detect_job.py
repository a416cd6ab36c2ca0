"""One processed depth frame's job: detect its planes, merge coplanar pieces, draw the
polygons a labeller would get, drop what a labeller would drop.

Runs in helper processes (:mod:`annotate_rgbd.pool`): the job and its result are plain,
picklable dataclasses, and this module imports no Open3D.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from annotate_rgbd.geometry.camera import Camera, depth_to_metres
from annotate_rgbd.config.settings import FilterConfig
from annotate_rgbd.detect import detect_planes
from annotate_rgbd.detect.cells import pixel_rays
from annotate_rgbd.detect.refine import relabel
from annotate_rgbd.errors import InputError
from annotate_rgbd.segment.filters import camera_distances, drop_reasons, statistics_of_distances
from annotate_rgbd.geometry.noise import NoiseSettings
from annotate_rgbd.io.sequence import read_depth
from .objects import neighbour_shares, objects_on_planes, polygon_coverage
from .outlines import fill_window, piece_outlines
from .extent import assign_in_outlines, plane_scales
from .seams import seam_groups
from .settings import ProposeConfig


@dataclass(frozen=True)
class DetectJob:
    """What a helper needs to propose the planes of one depth frame.

    Parameters
    ----------
    position : int
        Index of the frame among the processed frames.
    depth_path : Path
    camera : Camera
    settings : ProposeConfig
    noise : NoiseSettings
        The sensor's noise model (``[noise]``): the detector's ``sigma(z)``.
    filter : FilterConfig
        The drop rules (``[filter]``), as ``cvat2mask`` applies them.
    """

    position: int
    depth_path: Path
    camera: Camera
    settings: ProposeConfig
    noise: NoiseSettings
    filter: FilterConfig


@dataclass(frozen=True)
class FrameProposal:
    """The planes proposed on one depth frame (K of them, numbered 1..K by area).

    Attributes
    ----------
    position : int
        As in the job.
    labels : ndarray of uint8 or uint16, shape (H, W)
        Plane 1..K of each pixel (the detector's pixel-level masks), 0 for none.
    planes : ndarray of float64, shape (K, 4)
        ``(a, b, c, d)``, camera frame, metres, unit normal towards the camera, ``d > 0``.
    areas : ndarray of int64, shape (K,)
        Mask pixels.
    centroids : ndarray of float64, shape (K, 3)
        Mean 3-D point of each mask, camera frame, metres.
    surfaces : ndarray of float64, shape (K,)
        Area of each plane inside its outline, square metres (:func:`surface_areas`).
    mean_distance : ndarray of float64, shape (K,)
        Mean camera distance of the valid pixels inside each polygon (the filter's measure).
    outlines : list of ndarray, shape (V, 2)
        Polygon of each plane in CVAT image coordinates.
    z_order : ndarray of int64, shape (K,)
        Drawing order of the polygons (higher on top).
    dropped : list of dict
        Planes found but not proposed: ``area``, ``reason``, ``mean_distance``,
        ``invalid_ratio``, ``equation``.
    """

    position: int
    labels: np.ndarray
    planes: np.ndarray
    areas: np.ndarray
    centroids: np.ndarray
    surfaces: np.ndarray
    mean_distance: np.ndarray
    outlines: list
    z_order: np.ndarray
    dropped: list


def propose_frame(job: DetectJob) -> FrameProposal:
    """Run one :class:`DetectJob` (the worker function of the pool).

    Raises
    ------
    InputError
        The depth image cannot be read or is not a depth map.
    """
    depth = depth_to_metres(read_depth(Path(job.depth_path)), job.camera.depth_scale)
    return propose_planes(depth, job.camera, job.settings, job.noise, job.filter, job.position)


def propose_planes(
    depth: np.ndarray,
    camera: Camera,
    settings: ProposeConfig,
    noise: NoiseSettings,
    rules: FilterConfig,
    position: int = 0,
) -> FrameProposal:
    """Planes of a depth image as a labeller would draw them.

    Parameters
    ----------
    depth : ndarray of float32, shape (H, W)
        Metres, NaN where invalid.
    camera : Camera
    settings : ProposeConfig
    noise : NoiseSettings
    rules : FilterConfig
    position : int
        Stored in the result.

    Returns
    -------
    FrameProposal
    """
    sigma = noise.model.sigma
    # The detector keeps pieces down to a fraction of the smallest plane: pieces of one plane
    # that occluders cut apart (a floor around a table) reach the minimum area together.
    min_area = settings.detector.min_area_fraction * depth.size
    pieces = replace(settings.detector, min_area_fraction=settings.detector.min_area_fraction * settings.piece_fraction)
    detection = detect_planes(depth, camera, pieces, noise=sigma)
    # The detector's own moments of its final pixels: exact, and already paid for.
    moments = Moments(detection.areas.astype(np.float64), detection.means, detection.scatters)
    # Pieces of one bent surface that meet without a step or a crease, then coplanar pieces
    # apart from each other (a floor on both sides of a table).
    seams = seam_groups(detection.labels, depth, detection.planes, camera, sigma, settings.detector.band_k,
                        settings.detector.min_angle_deg, settings.seam_min_px, settings.seam_reach_px)
    joined = join_moments(moments, seams)
    ray_x, ray_y = pixel_rays(*depth.shape, camera)
    points = np.stack(np.broadcast_arrays(ray_x[None, :] * depth, ray_y[:, None] * depth, depth), axis=-1)
    # Real sensors are noisier than their published noise, and so are the pieces' joint fits:
    # each piece's measured noise scale widens the tolerance as it widens cvat2mask's band.
    scales = plane_scales(detection.labels, points, detection.planes, noise) if settings.widen_to_noise else None
    groups = merge_groups(joined, sigma, settings.merge_excess, scales)[seams]
    labels, planes, areas, centroids = _apply_groups(detection.labels, moments, groups, min_area)
    outlines = piece_outlines(labels, settings.outline_tolerance_px)
    if len(outlines) != len(areas):  # pragma: no cover - every label has pixels
        raise InputError(None, "a proposed plane has no outline")
    polygons = [outlines[k] for k in range(1, len(areas) + 1)]
    windows = [fill_window(p, *labels.shape) for p in polygons]
    coverage = polygon_coverage(labels, windows)
    objects = objects_on_planes(planes, areas, centroids, coverage, neighbour_shares(labels, settings.object_ring_px),
                                settings.object_height, settings.object_inside, settings.detector.min_angle_deg)
    early = [{"area": int(areas[k]), "reason": "on_plane", "mean_distance": None, "invalid_ratio": None,
              "equation": [float(v) for v in planes[k]]} for k in np.flatnonzero(objects)]
    kept = np.flatnonzero(~objects)
    planes, windows = planes[kept], [windows[k] for k in kept]
    if settings.widen_to_noise:
        # Each plane's pixels inside its outline, within its own (scaled) noise band.
        table = np.zeros(len(areas) + 1, dtype=labels.dtype)
        table[kept + 1] = np.arange(1, len(kept) + 1)
        scales = plane_scales(relabel(labels, table, labels.dtype), points, planes, noise)
        labels = assign_in_outlines(points, planes, windows, scales, noise)
        counts = np.bincount(labels.ravel(), minlength=len(kept) + 1)[1:]
        small = counts < min_area
        early += [{"area": int(counts[k]), "reason": "small", "mean_distance": None, "invalid_ratio": None,
                   "equation": [float(v) for v in planes[k]]} for k in np.flatnonzero(small)]
        table = np.zeros(len(kept) + 1, dtype=labels.dtype)
        table[1:][~small] = np.arange(1, np.count_nonzero(~small) + 1)
        labels, planes, areas = relabel(labels, table, labels.dtype), planes[~small], counts[~small].astype(np.int64)
        flat = labels.ravel()
        centroids = np.stack([np.bincount(flat, weights=np.nan_to_num(points[..., i]).ravel(), minlength=len(areas) + 1)[1:]
                              for i in range(3)], axis=1) / np.maximum(areas, 1)[:, None]
        outlines = piece_outlines(labels, settings.outline_tolerance_px)
        polygons = [outlines[k] for k in range(1, len(areas) + 1)]
        windows = [fill_window(p, *labels.shape) for p in polygons]
        coverage = polygon_coverage(labels, windows)
    elif objects.any():
        table = np.zeros(len(areas) + 1, dtype=labels.dtype)
        table[kept + 1] = np.arange(1, len(kept) + 1)
        labels, areas, centroids = relabel(labels, table, labels.dtype), areas[kept], centroids[kept]
        polygons = [polygons[k] for k in kept]
        coverage = coverage[np.ix_(kept, kept)]
    # What plane_statistics computes, with the distance image shared by its two uses.
    ray_distance = camera_distances(depth, camera)
    valid = ~np.isnan(depth)
    # Every pixel of the detector's labels has valid depth: the mean needs only the sums.
    distance = np.bincount(labels.ravel(), weights=ray_distance.ravel(), minlength=len(areas) + 1)[1:] / areas
    z_order = draw_order(labels, windows, distance, coverage)
    drawn = paint(windows, z_order, labels.shape)
    stats = statistics_of_distances(drawn, ray_distance, valid)
    reasons = dict(zip(stats.plane_ids.tolist(), drop_reasons(stats, rules)))
    drawn_distance = dict(zip(stats.plane_ids.tolist(), stats.mean_distance.tolist()))
    drawn_invalid = dict(zip(stats.plane_ids.tolist(), stats.invalid_ratio.tolist()))
    # A polygon covered entirely by nearer ones is not drawn at all: nothing of it would reach a mask.
    keep = np.array([reasons.get(k + 1, "hidden") is None for k in range(len(areas))], dtype=bool)
    dropped = early + [
        {"area": int(areas[k]), "reason": reasons.get(k + 1) or "hidden",
         "mean_distance": _finite(drawn_distance.get(k + 1)), "invalid_ratio": _finite(drawn_invalid.get(k + 1)),
         "equation": [float(v) for v in planes[k]]}
        for k in np.flatnonzero(~keep)
    ]
    table = np.zeros(len(areas) + 1, dtype=labels.dtype)
    table[1:][keep] = np.arange(1, np.count_nonzero(keep) + 1)
    mean_distance = np.array([drawn_distance[k + 1] for k in np.flatnonzero(keep)], dtype=np.float64)
    labels = relabel(labels, table, labels.dtype)
    return FrameProposal(
        position=position,
        labels=labels,
        planes=planes[keep],
        areas=areas[keep],
        centroids=centroids[keep],
        surfaces=surface_areas([windows[k] for k in np.flatnonzero(keep)], planes[keep], camera),
        mean_distance=mean_distance,
        outlines=[polygons[k] for k in np.flatnonzero(keep)],
        z_order=np.argsort(np.argsort(z_order[keep], kind="stable"), kind="stable").astype(np.int64),
        dropped=dropped,
    )


def surface_areas(windows: list, planes: np.ndarray, camera: Camera) -> np.ndarray:
    """Area of each plane inside its outline, square metres: what the polygon covers on the
    plane, whether or not the sensor returned depth there (a black screen's depth is speckled).

    A pixel looking along ``r = ((u - cx) / fx, (v - cy) / fy, 1)`` meets the plane ``n . X + d
    = 0`` at depth ``z = d / |n . r|`` and covers ``z**2 / (|fx fy| |n . r|)`` of it (``z**2 /
    |fx fy|`` where the plane faces the camera; more as it turns away, counted up to grazing
    rays at ``|n . r| = 0.1``).

    Parameters
    ----------
    windows : list of (int, int, ndarray of bool)
        The filled outline of plane ``k`` at position ``k - 1`` as ``(top, left, window)``.
    planes : ndarray of float, shape (K, 4)
        Unit normals, ``d > 0``.
    camera : Camera

    Returns
    -------
    ndarray of float64, shape (K,)
    """
    areas = np.zeros(len(planes))
    for k, (top, left, window) in enumerate(windows):
        rows, cols = np.nonzero(window)
        if rows.size == 0:
            continue
        a, b, c, d = np.asarray(planes[k], dtype=np.float64)
        facing = np.abs(a * (cols + left - camera.cx) / camera.fx + b * (rows + top - camera.cy) / camera.fy + c)
        areas[k] = d * d / abs(camera.fx * camera.fy) * np.sum(np.maximum(facing, 0.1) ** -3.0)
    return areas


def keep_planes(proposal: FrameProposal, keep: np.ndarray, reason) -> FrameProposal:
    """The proposal with only the planes ``keep`` selects, renumbered 1.. in their order; the
    others join ``dropped`` with their reason.

    Parameters
    ----------
    proposal : FrameProposal
    keep : ndarray of bool, shape (K,)
    reason : str or sequence of str
        Why the others are not proposed: one for all, or one per plane.

    Returns
    -------
    FrameProposal
    """
    keep = np.asarray(keep, dtype=bool)
    if keep.all():
        return proposal
    table = np.zeros(len(keep) + 1, dtype=proposal.labels.dtype)
    table[1:][keep] = np.arange(1, np.count_nonzero(keep) + 1)
    reasons = [reason] * len(keep) if isinstance(reason, str) else list(reason)
    dropped = [{"area": int(proposal.areas[k]), "reason": reasons[k],
                "mean_distance": _finite(proposal.mean_distance[k]), "invalid_ratio": None,
                "equation": [float(v) for v in proposal.planes[k]]} for k in np.flatnonzero(~keep)]
    return FrameProposal(
        position=proposal.position,
        labels=relabel(proposal.labels, table, proposal.labels.dtype),
        planes=proposal.planes[keep],
        areas=proposal.areas[keep],
        centroids=proposal.centroids[keep],
        surfaces=proposal.surfaces[keep],
        mean_distance=proposal.mean_distance[keep],
        outlines=[proposal.outlines[k] for k in np.flatnonzero(keep)],
        z_order=np.argsort(np.argsort(proposal.z_order[keep], kind="stable"), kind="stable").astype(np.int64),
        dropped=proposal.dropped + dropped,
    )


@dataclass(frozen=True)
class Moments:
    """First and second moments of each label's 3-D points (label k in row k - 1).

    Attributes
    ----------
    count : ndarray of float64, shape (K,)
    mean : ndarray of float64, shape (K, 3)
    scatter : ndarray of float64, shape (K, 3, 3)
        Sum of the outer products of the centred points.
    """

    count: np.ndarray
    mean: np.ndarray
    scatter: np.ndarray


def join_moments(moments: Moments, group: np.ndarray) -> Moments:
    """Moments of groups of labels, held by each group's head (the label ``group`` names); the
    other members get a count of 0.

    Parameters
    ----------
    moments : Moments
        ``K`` labels.
    group : ndarray of int, shape (K,)
        Head (0-based label) of each label's group; a head is its own head.

    Returns
    -------
    Moments
        ``K`` rows.
    """
    group = np.asarray(group)
    count = np.bincount(group, weights=moments.count, minlength=len(group))
    total = np.stack([np.bincount(group, weights=moments.count * moments.mean[:, i], minlength=len(group))
                      for i in range(3)], axis=1)
    mean = np.where(count[:, None] > 0, total / np.maximum(count, 1)[:, None], moments.mean)
    offset = moments.mean - mean[group]
    spread = moments.scatter + moments.count[:, None, None] * offset[:, :, None] * offset[:, None, :]
    scatter = np.zeros_like(moments.scatter)
    np.add.at(scatter, group, spread)
    return Moments(count, mean, scatter)


def fit(count: np.ndarray, mean: np.ndarray, scatter: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares planes of moments: ``(K, 4)`` planes (unit normal towards the camera,
    ``d > 0``) and the mean squared residual ``(K,)``."""
    values, vectors = np.linalg.eigh(scatter)
    normal = vectors[..., 0]
    d = -np.einsum("ki,ki->k", normal, mean)
    flip = np.where(d < 0, -1.0, 1.0)
    planes = np.concatenate([normal * flip[:, None], (d * flip)[:, None]], axis=1)
    return planes, np.maximum(values[:, 0], 0) / np.maximum(count, 1)


def merge_groups(moments: Moments, sigma, excess_k: float, scales: np.ndarray | None = None) -> np.ndarray:
    """Which labels are one plane: greedy merging of the pair whose joint fit adds the least
    residual, while it adds at most ``excess_k * (s * sigma(z))**2`` (z: the pair's mean depth;
    ``s``: the pair's noise scale, the pixel-weighted root mean square of its labels' ``scales``).

    Parameters
    ----------
    moments : Moments
    sigma : callable
        Axial noise standard deviation at a depth, metres.
    excess_k : float
    scales : ndarray of float, shape (K,), optional
        How much noisier than ``sigma`` each label's pixels are
        (:func:`annotate_rgbd.propose.extent.plane_scales`); default 1.

    Returns
    -------
    ndarray of intp, shape (K,)
        Group of each label (the smallest label of its group, 0-based), so that groups keep
        the order of their largest member.
    """
    n = len(moments.count)
    group = np.arange(n)
    count, mean, scatter = moments.count.copy(), moments.mean.copy(), moments.scatter.copy()
    scale2 = np.ones(n) if scales is None else np.asarray(scales, dtype=np.float64) ** 2
    alive = count > 0
    while alive.sum() > 1:
        idx = np.flatnonzero(alive)
        i, j = np.triu_indices(len(idx), 1)
        a, b = idx[i], idx[j]
        c = count[a] + count[b]
        m = (count[a, None] * mean[a] + count[b, None] * mean[b]) / c[:, None]
        delta = mean[a] - mean[b]
        joint = scatter[a] + scatter[b] + (count[a] * count[b] / c)[:, None, None] * delta[:, :, None] * delta[:, None, :]
        _, joint_ms = fit(c, m, joint)
        _, ms_a = fit(count[a], mean[a], scatter[a])
        _, ms_b = fit(count[b], mean[b], scatter[b])
        added = joint_ms - (count[a] * ms_a + count[b] * ms_b) / c
        pair_scale2 = (count[a] * scale2[a] + count[b] * scale2[b]) / c
        ratio = added / (excess_k * pair_scale2 * sigma(m[:, 2]) ** 2)
        best = int(np.argmin(ratio))  # first minimum: deterministic
        if ratio[best] > 1:
            break
        keep, gone = min(a[best], b[best]), max(a[best], b[best])
        count[keep], mean[keep], scatter[keep], scale2[keep] = c[best], m[best], joint[best], pair_scale2[best]
        alive[gone] = False
        group[group == gone] = keep
    return group


def _apply_groups(labels, moments: Moments, group: np.ndarray, min_area: float):
    """Relabel merged groups of at least ``min_area`` pixels 1..G by area (largest first; ties
    by smallest member label); the others become 0. ``moments.count`` counts each label's
    pixels (the detector's moments)."""
    n = len(group)
    if n == 0:
        return labels, np.zeros((0, 4)), np.zeros(0, np.int64), np.zeros((0, 3))
    heads = np.unique(group)
    count = np.array([moments.count[group == h].sum() for h in heads])
    mean = np.array([(moments.count[group == h, None] * moments.mean[group == h]).sum(0) for h in heads]) / count[:, None]
    scatter = np.array([
        sum(moments.scatter[k] + moments.count[k] * np.outer(moments.mean[k] - mean[g], moments.mean[k] - mean[g])
            for k in np.flatnonzero(group == h))
        for g, h in enumerate(heads)
    ])
    area = np.array([moments.count[group == h].sum() for h in heads]).astype(np.int64)
    order = np.lexsort((heads, -area))
    order = order[area[order] >= min_area]
    rank = np.full(len(heads), -1, dtype=np.intp)
    rank[order] = np.arange(len(order))
    table = np.zeros(n + 1, dtype=labels.dtype)
    table[1:] = rank[np.searchsorted(heads, group)] + 1
    planes, _ = fit(count[order], mean[order], scatter[order])
    return relabel(labels, table, labels.dtype), planes, area[order], mean[order]


def draw_order(labels: np.ndarray, windows: list, distance: np.ndarray, coverage: np.ndarray | None = None) -> np.ndarray:
    """``z_order`` of the polygons so that, where two overlap, the plane whose pixels fill the
    overlap is drawn on top: the nearer one where one plane occludes the other, the inner one
    where a polygon's filled holes hold another plane (a picture on a wall).

    Plane ``q`` goes above ``p`` when more of ``q``'s pixels lie inside ``p``'s polygon than of
    ``p``'s inside ``q``'s. The order is a topological sort of these relations, picking the
    farthest plane (``distance``) first among those free to go next, and the farthest of all
    when the relations form a cycle.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Planes 1..K.
    windows : list of (int, int, ndarray of bool)
        Pixels of the polygon of plane ``k`` at position ``k - 1``, as
        :func:`annotate_rgbd.rasterize.shape_mask` gives them: ``(top, left, window)``.
    distance : ndarray of float, shape (K,)
        Mean camera distance of each plane (NaN: farthest).
    coverage : ndarray of int, shape (K, K), optional
        :func:`annotate_rgbd.propose.objects.polygon_coverage` of ``labels`` and ``windows``,
        when already computed.

    Returns
    -------
    ndarray of int64, shape (K,)
        0 (bottom) .. K - 1 (top).
    """
    counts = polygon_coverage(labels, windows) if coverage is None else np.asarray(coverage)
    k = len(counts)
    below = counts.T > counts  # below[q, p]: q must be drawn above p
    farthest = np.nan_to_num(np.asarray(distance, dtype=np.float64), nan=np.inf)
    z = np.zeros(k, dtype=np.int64)
    placed = np.zeros(k, dtype=bool)
    for level in range(k):
        ready = ~placed & ~(below & ~placed[None, :]).any(axis=1)
        pool = np.flatnonzero(ready if ready.any() else ~placed)
        pick = pool[np.lexsort((pool, -farthest[pool]))[0]]
        z[pick] = level
        placed[pick] = True
    return z


def paint(windows: list, z_order: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The label image the polygons give when drawn in ``z_order`` (what ``cvat2mask`` draws).

    Parameters
    ----------
    windows : list of (int, int, ndarray of bool)
        As for :func:`draw_order`; plane ``k`` at position ``k - 1``.
    z_order : ndarray of int, shape (K,)
    shape : (int, int)

    Returns
    -------
    ndarray of uint8 or uint16, shape ``shape``
    """
    labels = np.zeros(shape, dtype=np.uint8 if len(windows) < 256 else np.uint16)
    for k in np.argsort(z_order, kind="stable").tolist():
        top, left, window = windows[k]
        rows, cols = window.shape
        np.copyto(labels[top : top + rows, left : left + cols], k + 1, where=window)
    return labels


def _finite(value) -> float | None:
    return None if value is None or not np.isfinite(value) else float(value)

"""One processed depth frame's job: detect its planes, merge coplanar pieces, draw the
polygons a labeller would get, drop what a labeller would drop.

Runs in helper processes (:mod:`annotate_rgbd.pool`): the job and its result are plain,
picklable dataclasses.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from annotate_rgbd.config.propose import DetectorConfig, ProposeConfig
from annotate_rgbd.config.masks import RansacConfig, RefineConfig
from annotate_rgbd.config.settings import FilterConfig
from annotate_rgbd.cvat.from_masks import draw_order, outline_planes, polygon_coverage
from annotate_rgbd.cvat.pieces import label_boxes
from annotate_rgbd.detect import detect_planes
from annotate_rgbd.detect.refine import relabel
from annotate_rgbd.errors import InputError
from annotate_rgbd.geometry.camera import Camera, depth_to_metres, ray_grid
from annotate_rgbd.geometry.noise import NoiseSettings
from annotate_rgbd.io.sequence import read_depth
from annotate_rgbd.segment.distances import behind_factor
from annotate_rgbd.segment.filters import camera_distances, drop_reasons, statistics_of_distances
from annotate_rgbd.segment.rasterize import fill_window
from .extent import assign_in_outlines, piece_windows, plane_scales
from .measures import label_counts, polygon_fit, surface_areas
from .merge import apply_groups, join_moments, merge_groups
from .objects import ends_on_object, join_table, neighbour_shares, object_hosts, shares_in_band
from .seams import seam_groups


@dataclass(frozen=True)
class DetectJob:
    """What a helper needs to propose the planes of one depth frame.

    Parameters
    ----------
    position : int
        Index of the frame among the processed frames.
    depth_path : Path
    camera : Camera
    detector : DetectorConfig
        The detector (``[detect]``).
    settings : ProposeConfig
        Merging and outlines (``[propose]``).
    noise : NoiseSettings
        The sensor's noise model (``[noise]``): the detector's ``sigma(z)``.
    filter : FilterConfig
        The drop rules (``[filter]``), as ``cvat2mask`` applies them.
    ransac : RansacConfig
        Its noise-scale limits (``[ransac]``), as ``cvat2mask``'s fits use them.
    refine : RefineConfig
        Its ``behind_band`` (``[refine]``), as ``cvat2mask``'s inlier test uses it.
    """

    position: int
    depth_path: Path
    camera: Camera
    detector: DetectorConfig
    settings: ProposeConfig
    noise: NoiseSettings
    filter: FilterConfig
    ransac: RansacConfig = RansacConfig()
    refine: RefineConfig = RefineConfig()


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
    polygon_pixels, polygon_iou, budget_iou_cost : ndarray, shape (K,)
        Pixels inside each polygon, their IoU with the plane's pixels, and the IoU the vertex
        budget cost (NaN where it did not stop the simplification; :func:`polygon_fit`).
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
    polygon_pixels: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    polygon_iou: np.ndarray = field(default_factory=lambda: np.zeros(0))
    budget_iou_cost: np.ndarray = field(default_factory=lambda: np.zeros(0))


class FrameTooSmall(InputError):
    """A depth image smaller than one cell of the detector: the frame is skipped, not failed."""


def propose_frame(job: DetectJob) -> FrameProposal:
    """Run one :class:`DetectJob` (the worker function of the pool).

    Raises
    ------
    InputError
        The depth image cannot be read or is not a depth map; :class:`FrameTooSmall` when it
        holds no cell of the detector.
    """
    raw = read_depth(Path(job.depth_path))
    cell = job.detector.cell_px
    if min(raw.shape) < cell:
        raise FrameTooSmall(
            job.depth_path, f"depth image is {raw.shape[1]} x {raw.shape[0]} pixels, smaller than the detector's {cell}-pixel cells"
        )
    depth = depth_to_metres(raw, job.camera.depth_scale)
    return propose_planes(depth, job.camera, job.detector, job.settings, job.noise, job.filter, job.position, job.ransac,
                          job.refine)


def propose_planes(
    depth: np.ndarray,
    camera: Camera,
    detector: DetectorConfig,
    settings: ProposeConfig,
    noise: NoiseSettings,
    rules: FilterConfig,
    position: int = 0,
    ransac: RansacConfig | None = None,
    refine: RefineConfig | None = None,
) -> FrameProposal:
    """Planes of a depth image as a labeller would draw them.

    Parameters
    ----------
    depth : ndarray of float32, shape (H, W)
        Metres, NaN where invalid.
    camera : Camera
    detector : DetectorConfig
        ``detector.min_area_fraction`` is the smallest plane proposed.
    settings : ProposeConfig
    noise : NoiseSettings
    rules : FilterConfig
    position : int
        Stored in the result.
    ransac : RansacConfig, optional
        Its noise-scale limits (defaults when not given).
    refine : RefineConfig, optional
        Its ``behind_band``: each plane's band behind it, as ``cvat2mask``'s (defaults when not given).

    Returns
    -------
    FrameProposal
    """
    sigma = noise.model.sigma
    # The detector keeps pieces down to a fraction of the smallest plane: pieces of one plane
    # that occluders cut apart (a floor around a table) reach the minimum area together.
    min_area = detector.min_area_fraction * depth.size
    pieces = replace(detector, min_area_fraction=detector.min_area_fraction * settings.piece_fraction)
    detection = detect_planes(depth, camera, pieces, noise=sigma)
    # The detector's own moments of its final pixels: exact, and already paid for.
    moments = detection.moments
    # Pieces of one bent surface that meet without a step or a crease, then coplanar pieces
    # apart from each other (a floor on both sides of a table).
    seams = seam_groups(detection.labels, depth, detection.planes, camera, sigma, detector.band_k,
                        detector.min_angle_deg, settings.seam_min_px, settings.seam_reach_px)
    joined = join_moments(moments, seams)
    ray_x, ray_y = (rays.astype(np.float32) for rays in ray_grid(camera, *depth.shape))
    points = np.stack(np.broadcast_arrays(ray_x[None, :] * depth, ray_y[:, None] * depth, depth), axis=-1)
    # Real sensors are noisier than their published noise, and so are the pieces' joint fits:
    # each piece's measured noise scale widens the tolerance as it widens cvat2mask's band.
    scales = plane_scales(detection.labels, points, detection.planes, noise, ransac) if settings.widen_to_noise else None
    groups = merge_groups(joined, sigma, settings.merge_excess, scales)[seams]
    labels, planes, areas, centroids = apply_groups(detection.labels, moments, groups, min_area)
    # The planes' extents; their CVAT polygons are drawn at the end.
    boxes = label_boxes(labels, len(areas))
    windows = piece_windows(labels, settings.outline_tolerance_px, boxes=boxes)
    coverage = polygon_coverage(labels, windows)
    hosts = object_hosts(planes, areas, centroids, coverage, neighbour_shares(labels, settings.object_ring_px, boxes),
                         settings.object_height, settings.object_inside, detector.min_angle_deg)
    part = np.zeros(len(areas), dtype=bool)
    if settings.widen_to_noise and (hosts >= 0).any():
        # An object inside its plane's own band is the plane (cvat2mask keeps it): it joins the plane.
        # The hosts' noise scales only (a plane without a box gets 1, unread).
        host_ids = set(hosts[hosts >= 0].tolist())
        scales = plane_scales(labels, points, planes, noise, ransac, [b if k in host_ids else None for k, b in enumerate(boxes)])
        part = (hosts >= 0) & (shares_in_band(labels, points, planes, hosts, scales, noise, boxes) >= settings.object_band_share)
        part &= ~ends_on_object(hosts, part)
        if part.any():
            labels = relabel(labels, join_table(hosts, part), labels.dtype)
            boxes = label_boxes(labels, len(areas))
            windows = piece_windows(labels, settings.outline_tolerance_px, boxes=boxes)
    objects = (hosts >= 0) & ~part
    early = [{"area": int(areas[k]), "reason": "on_plane", "mean_distance": None, "invalid_ratio": None,
              "equation": [float(v) for v in planes[k]]} for k in np.flatnonzero(objects)]
    kept = np.flatnonzero(~objects & ~part)
    planes, windows = planes[kept], [windows[k] for k in kept]
    if settings.widen_to_noise:
        # Each plane's pixels inside its outline, within its own (scaled) noise band.
        table = np.zeros(len(areas) + 1, dtype=labels.dtype)
        table[kept + 1] = np.arange(1, len(kept) + 1)
        scales = plane_scales(relabel(labels, table, labels.dtype), points, planes, noise, ransac, [boxes[k] for k in kept])
        behind = behind_factor(noise, (refine or RefineConfig()).behind_band)
        labels = assign_in_outlines(points, planes, windows, scales, noise, behind)
        counts = label_counts(labels, len(kept))
        small = counts < min_area
        early += [{"area": int(counts[k]), "reason": "small", "mean_distance": None, "invalid_ratio": None,
                   "equation": [float(v) for v in planes[k]]} for k in np.flatnonzero(small)]
        table = np.zeros(len(kept) + 1, dtype=labels.dtype)
        table[1:][~small] = np.arange(1, np.count_nonzero(~small) + 1)
        labels, planes, areas = relabel(labels, table, labels.dtype), planes[~small], counts[~small].astype(np.int64)
    elif objects.any():
        table = np.zeros(len(areas) + 1, dtype=labels.dtype)
        table[kept + 1] = np.arange(1, len(kept) + 1)
        labels, areas, centroids = relabel(labels, table, labels.dtype), areas[kept], centroids[kept]
    flat = labels.ravel().astype(np.intp)
    if settings.widen_to_noise:
        # Labelled pixels have valid depth: the sums need no NaN guard (label 0's are not read).
        centroids = np.stack([np.bincount(flat, weights=points[..., i].astype(np.float64).ravel(), minlength=len(areas) + 1)[1:]
                              for i in range(3)], axis=1) / np.maximum(areas, 1)[:, None]
    # The labeller's polygons: simple, within the tolerance and the vertex budget.
    final = outline_planes(labels, settings.outline_tolerance_px, settings.max_vertices)
    polygons = [final[k].points for k in range(1, len(areas) + 1)]
    windows = [fill_window(p, *labels.shape) for p in polygons]
    coverage = polygon_coverage(labels, windows)
    fit = polygon_fit(labels, polygons, [final[k].unlimited for k in range(1, len(areas) + 1)], windows, areas)
    # What plane_statistics computes, with the distance image shared by its two uses.
    ray_distance = camera_distances(depth, camera)
    valid = ~np.isnan(depth)
    # Every pixel of the detector's labels has valid depth: the mean needs only the sums.
    distance = np.bincount(flat, weights=ray_distance.ravel(), minlength=len(areas) + 1)[1:] / areas
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
        polygon_pixels=fit[0][keep],
        polygon_iou=fit[1][keep],
        budget_iou_cost=fit[2][keep],
    )


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
        polygon_pixels=proposal.polygon_pixels[keep],
        polygon_iou=proposal.polygon_iou[keep],
        budget_iou_cost=proposal.budget_iou_cost[keep],
    )


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

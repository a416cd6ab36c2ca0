"""One depth frame: the labeller's shapes -> the pixels that really lie on each plane.

Rasterise the shapes in z-order, drop planes the depth cannot support, refine the rest with
RANSAC. A pure function of the depth image, the shapes and the configuration.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Collection, Mapping, Sequence

import numpy as np

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.geometry.camera import depth_to_metres
from annotate_rgbd.config.settings import Config
from .filters import NOT_WHERE_EXPECTED, TOO_FEW_POINTS, drop_reasons, label_histogram, plane_statistics
from .grow import grow_connected, grow_planes
from annotate_rgbd.geometry.registration import sample_labels
from .rasterize import carried_shapes, draw_on_depth_grid
from annotate_rgbd.segment.plane_record import PlaneRecord
from .refine import refine_planes


@dataclass
class FrameResult:
    """What :func:`segment_frame` did on one depth frame.

    Parameters
    ----------
    labels : ndarray of uint8, uint16 or int32, shape (H, W)
        The mask: plane ids where a pixel lies on its plane (grown edges, outside every drawn
        shape, included), 0 elsewhere.
    drawn : ndarray of the same type, shape (H, W)
        The labeller's shapes as rasterised, before any depth check (for review overlays).
    kept, dropped : list of PlaneRecord
        One record per plane drawn on the frame.
    colour_grid : (ndarray, ndarray) or None
        With a colour camera of its own: where each depth pixel lies in the colour image
        (:func:`annotate_rgbd.segment.rasterize.draw_on_depth_grid`), to resample the colour
        image onto the depth grid; None when the two are registered.
    """

    labels: np.ndarray
    drawn: np.ndarray
    kept: list[PlaneRecord] = field(default_factory=list)
    dropped: list[PlaneRecord] = field(default_factory=list)
    colour_grid: tuple[np.ndarray, np.ndarray] | None = None


def segment_frame(
    depth_raw: np.ndarray, shapes: Sequence[tuple[int, Shape]], config: Config, propagated: Collection[int] = (),
    expected: Mapping[int, np.ndarray] | None = None, carried: Sequence[tuple] = (),
) -> FrameResult:
    """Rasterise, filter and refine the planes of one depth frame.

    Parameters
    ----------
    depth_raw : ndarray, shape (H, W)
        Raw depth image.
    shapes : sequence of (int, Shape)
        ``(plane id, shape)`` of the frame, in track order.
    config : Config
    propagated : collection of int
        Planes whose shapes camera poses carried here from keyframes on other frames: no
        labeller drew them over this frame (:func:`annotate_rgbd.segment.ransac.fit_plane`'s
        ``look_behind``).
    expected : mapping of int to ndarray, shape (4,), optional
        Where camera poses put those planes in this frame (camera frame, metres).
    carried : sequence of (int, int, int, layers, beyond)
        ``(position, plane id, z_order, layers, beyond)``: what the keyframes of a plane carried
        here say it covers and excludes, and polygons past their views
        (:func:`annotate_rgbd.propagate.carry.carried_layers`). What they say it covers is drawn
        among ``shapes`` before the one at ``position`` (in order of ``position``), what lies
        beyond (but for what they exclude) below every shape; what they exclude the plane does
        not grow into.

    Returns
    -------
    FrameResult
        ``labels`` holds the plane id of every pixel that lies on its plane (0 elsewhere);
        ``kept`` and ``dropped`` one record per plane drawn on the frame.
    """
    grid_shape = depth_raw.shape if config.colour_camera is None else (config.colour_camera.height, config.colour_camera.width)
    shapes, excluded = carried_shapes(shapes, carried, *grid_shape)
    depth_m = depth_to_metres(depth_raw, config.camera.depth_scale)
    drawn, colour_grid = draw_on_depth_grid(shapes, depth_m, config.camera, config.colour_camera)
    stats = plane_statistics(drawn, depth_m, config.camera)
    reasons = drop_reasons(stats, config.filter)
    kept = np.array([r is None for r in reasons], dtype=bool)
    band = config.inlier_band()
    unfit: dict[int, str] = {}  # why refine_planes found no plane (no_plane, not_where_expected)
    refined, fits = refine_planes(
        drawn, depth_m, stats.plane_ids[kept], config.camera, config.ransac, band, stats.valid_pixels[kept],
        config.refine.rim_pixels, propagated, expected, config.refine, config.propagate, unfit,
    )
    reasons = [unfit.get(plane_id, r) for plane_id, r in zip(stats.plane_ids.tolist(), reasons)]
    inlier_count = label_histogram(refined, int(drawn.max(initial=0)) + 1)
    equations = {plane_id: fit.equation for plane_id, fit in fits.items()}
    if colour_grid is not None:  # what the keyframes excluded, drawn on the colour grid
        excluded = {plane_id: sample_labels(mask.astype(np.uint8), *colour_grid) > 0 for plane_id, mask in excluded.items()}
    labels, grown = grow_planes(refined, drawn, depth_m, equations, config.camera, band, config.refine.grow_pixels,
                                excluded)
    growing = {plane_id: equation for plane_id, equation in equations.items() if plane_id in propagated}
    if growing and config.refine.grow_pixels:
        # Where a plane went on beyond every keyframe's view, nobody outlined it; shapes carried
        # by poses (an outline's extension past a keyframe's border above all) are guesses.
        claimed = (drawn > 0) & ~np.isin(drawn, list(propagated))
        labels, beyond = grow_connected(labels, drawn, claimed, depth_m, growing, config.camera, band, config.refine,
                                        excluded)
        grown = {plane_id: count + beyond.get(plane_id, 0) for plane_id, count in grown.items()}
    result = FrameResult(labels=labels, drawn=drawn, colour_grid=colour_grid)
    for i, plane_id in enumerate(stats.plane_ids.tolist()):
        # A fit whose pixels the refinement's tests all took away (e.g. 12 inliers of 474 points
        # on a carried plane) leaves the plane nothing in the mask: it is not kept on this frame.
        if reasons[i] is None and inlier_count[plane_id] + grown.get(plane_id, 0) == 0:
            reasons[i] = NOT_WHERE_EXPECTED if plane_id in propagated else TOO_FEW_POINTS
        measured = dict(
            plane=plane_id,
            pixels=int(stats.pixels[i]),
            valid_pixels=int(stats.valid_pixels[i]),
            mean_distance=_rounded(stats.mean_distance[i]),
        )
        if reasons[i] is None:
            inliers, fit = int(inlier_count[plane_id]), fits[plane_id]
            result.kept.append(PlaneRecord(
                **measured,
                inliers=inliers,
                inlier_ratio=round(inliers / max(int(stats.valid_pixels[i]), 1), 6),
                equation=tuple(round(float(v), 9) for v in fit.equation),
                band=_rounded(fit.band),
                rms_sigma=None if not np.isfinite(fit.rms_sigma) else round(fit.rms_sigma, 4),
                noise_scale=round(fit.noise_scale, 4),
                fit_points=len(fit.inliers),
                fit_inliers_ransac=fit.inliers_ransac,
                surface_behind=fit.surface_behind,
                fit_inliers_refit=fit.inliers_refit,
                grown=grown.get(plane_id, 0),
            ))
        else:
            result.dropped.append(PlaneRecord(
                **measured, reason=reasons[i], invalid_ratio=round(float(stats.invalid_ratio[i]), 6)
            ))
    return result


def _rounded(value: float) -> float | None:
    return None if not np.isfinite(value) else round(float(value), 6)

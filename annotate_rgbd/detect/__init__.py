"""Plane detection on a single depth frame, with no annotation: proposals for the labeller.

In the spirit of CAPE (Proenca & Gao 2018), vectorised with numpy:

1. back-project the depth image into an organised point cloud and fit a plane to each square
   cell by PCA; a cell is planar when its residual is within the depth noise at its distance
   (:mod:`.cells`);
2. grow regions of coplanar neighbouring cells, then merge regions that lie on one plane and
   touch or nearly touch (:mod:`.grow`);
3. give the pixels of each region's cells and of the cells around it to the nearest plane that
   holds them within the noise band, and refit every plane on its final pixels (:mod:`.refine`);
4. drop planes below a minimum area and number the rest by area.

The settings are the ``[detect]`` section of the configuration
(:class:`annotate_rgbd.config.propose.DetectorConfig`); the sensor's noise is ``[noise]``'s model.
:func:`annotate_rgbd.cvat.from_masks.plane_outlines` turns the label image into polygons for CVAT.
Everything is deterministic: no random sampling, stable sorts, ties broken by raster order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from annotate_rgbd.config.propose import DetectorConfig
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.geometry.noise import SENSOR_MODELS
from annotate_rgbd.geometry.planes import Moments, fit_planes
from .cells import NoiseModel, cloud_cells
from .grow import cell_totals, group_totals, grow_regions, merge_segments, totals_moments
from .refine import assign_pixels, claim_windows, order_labels, pixel_moments, relabel

__all__ = ["PlaneDetection", "detect_planes"]


@dataclass(frozen=True)
class PlaneDetection:
    """Planes found in one depth frame.

    Attributes
    ----------
    labels : ndarray of uint8 or uint16, shape (H, W)
        Plane of each pixel: 0 for none, else 1..K by area (largest first; equal areas by
        first pixel in raster order). uint8 when K < 256.
    planes : ndarray of float64, shape (K, 4)
        Row ``k - 1`` is label ``k``'s plane ``(a, b, c, d)`` in the camera frame:
        ``a x + b y + c z + d = 0`` for points on it, unit normal ``(a, b, c)`` pointing
        towards the camera, ``d > 0`` (distance from the camera centre in metres); fitted by
        orthogonal least squares to the label's pixels.
    areas : ndarray of int64, shape (K,)
        Pixels per label.
    means : ndarray of float64, shape (K, 3)
        Centroid of each label's points (camera frame, metres).
    scatters : ndarray of float64, shape (K, 3, 3)
        Sum of the outer products of each label's points about their centroid: with ``areas``
        and ``means``, the moments the planes were fitted to, for whoever combines labels.
    """

    labels: np.ndarray
    planes: np.ndarray
    areas: np.ndarray
    means: np.ndarray
    scatters: np.ndarray

    @property
    def moments(self) -> Moments:
        """The moments of each label's points (``areas``, ``means``, ``scatters``)."""
        return Moments(self.areas.astype(np.float64), self.means, self.scatters)


def detect_planes(
    depth_m: np.ndarray,
    camera: Camera,
    config: DetectorConfig = DetectorConfig(),
    noise: NoiseModel | None = None,
) -> PlaneDetection:
    """Find the planes of a depth image.

    Parameters
    ----------
    depth_m : ndarray of float, shape (H, W)
        Depth in metres (the z coordinate), NaN or <= 0 where invalid (as from
        :func:`annotate_rgbd.geometry.camera.depth_to_metres`).
    camera : Camera
        Intrinsics of the depth image (``depth_scale`` is not used).
    config : DetectorConfig
        Settings (``[detect]``); see its documentation for the defaults and their sources.
    noise : callable, optional
        ``sigma(z)``, the axial noise standard deviation in metres at depth ``z`` (applied
        elementwise to arrays), e.g. a ``[noise]`` model's ``sigma``; default the Kinect v1 model
        (:data:`annotate_rgbd.geometry.noise.SENSOR_MODELS`).

    Returns
    -------
    PlaneDetection
    """
    depth_m = np.asarray(depth_m)
    if depth_m.ndim != 2:
        raise ValueError(f"depth image must be 2-D, got shape {depth_m.shape}")
    noise = SENSOR_MODELS["kinect_v1"].sigma if noise is None else noise
    cells = cloud_cells(depth_m, camera, config.cell_px, noise, config.planar_k, config.min_valid_fraction)
    region = merge_segments(grow_regions(cells, config), cells, config)
    min_area = int(np.ceil(config.min_area_fraction * depth_m.size))

    # Segments too small to reach the minimum area even with a ring of boundary pixels would
    # only take pixels from their neighbours: drop them before refinement.
    cell_area = config.cell_px**2
    sizes = np.bincount(region, minlength=1)[1:]
    region = _renumber(region, sizes * cell_area * 2 >= min_area)
    moments = totals_moments(group_totals(cell_totals(cells), region - 1, int(region.max())))
    planes = fit_planes(moments.mean, moments.scatter)[0]
    labels = assign_pixels(cells, region, planes, config.band_k, config.band_behind)
    count, mean, centred = pixel_moments(cells, labels, planes.shape[0], claim_windows(cells, region))
    small = count < max(min_area, 3)
    if small.any() and not small.all():
        # Give the pixels of segments that fell short to their neighbours, using the planes
        # refitted on the survivors' pixels.
        region = _renumber(region, ~small)
        planes = fit_planes(mean[~small], centred[~small])[0]
        labels = assign_pixels(cells, region, planes, config.band_k, config.band_behind)
        count, mean, centred = pixel_moments(cells, labels, planes.shape[0], claim_windows(cells, region))
    table = order_labels(labels, count, max(min_area, 3))
    kept = np.argsort(table[1:], kind="stable")[np.count_nonzero(table[1:] == 0) :]  # old index by new label
    dtype = np.uint8 if kept.size < 256 else np.uint16
    return PlaneDetection(
        labels=relabel(labels, table, dtype),
        planes=fit_planes(mean[kept], centred[kept])[0].reshape(-1, 4),
        areas=count[kept].astype(np.int64),
        means=mean[kept].reshape(-1, 3),
        scatters=centred[kept].reshape(-1, 3, 3),
    )


def _renumber(region: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Cell segments with ``keep[k - 1]`` renumbered 1.. in order; the others become 0."""
    table = np.zeros(keep.size + 1, dtype=np.int32)
    table[1:][keep] = np.arange(1, np.count_nonzero(keep) + 1)
    return table[region]

"""Every tunable of the plane detector, with its default and the reason for it."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np


@dataclass(frozen=True)
class DetectorConfig:
    """Settings of :func:`annotate_rgbd.detect.detect_planes`.

    Lengths are in metres, image sizes in pixels of the depth image.

    Parameters
    ----------
    cell_px : int
        Side of the square cells whose planarity is tested. 20 px at 640 x 480 is CAPE's
        recommendation (Proenca & Gao 2018): large enough for a stable plane fit under Kinect
        noise, small enough to follow plane boundaries before pixel refinement.
    min_valid_fraction : float
        Share of a cell's pixels that must have depth for the cell to be tested (CAPE: half).
    noise_a, noise_b, noise_c : float
        Axial depth noise model ``sigma(z) = a + b * (z - c) ** 2`` in metres, Kinect v1
        defaults of Nguyen, Izadi & Lovell (2012): a = 0.0012, b = 0.0019, c = 0.4 m. A
        different model can be passed to ``detect_planes`` as a callable instead.
    planar_k : float
        A cell is planar when the RMS distance of its points to their best plane is at most
        ``planar_k * sigma(z)`` at the cell's mean depth. Pure sensor noise gives an RMS of
        about ``sigma``; 3 leaves room for depth quantisation and lens distortion on real
        Kinect frames while a cell across a 90-degree corner or a depth step stays far above.
    band_k : float
        Width of the band around a plane, in noise standard deviations: a cell joins a
        region, and a pixel a plane, when it lies within ``band_k * sigma(z)`` of the plane
        (3 sigma holds 99.7 % of Gaussian noise).
    min_angle_deg, max_angle_deg : float
        Two normals agree when their angle is at most the tilt the noise band allows across
        the less certain patch, ``atan(band_k * sigma / half_width)`` (half_width: half the
        patch's extent across its narrower in-plane direction), clipped to these bounds. The
        tilt bound, not a standard error, because real depth noise is correlated over a
        cell (RealSense stereo ripples tilt neighbouring 20-pixel cells of a flat screen by
        15 degrees at 0.7 m). The floor (10 degrees) covers the low-frequency distortion of
        real sensors on large segments; the ceiling (25 degrees, about CAPE's merge angle)
        keeps far, noisy cells from bridging creases. The band tests on the points do the
        finer work.
    merge_gap_cells : int
        Coplanar segments are merged when at most this many cells separate them on the cell
        grid (1: touching or one non-planar cell in between, e.g. a seam or a cable).
    min_area_fraction : float
        Smallest plane kept, as a share of the image's pixels. 1 % (3072 px at 640 x 480) is
        the smallest plane EVOPS-style annotations keep.
    """

    cell_px: int = 20
    min_valid_fraction: float = 0.5
    noise_a: float = 0.0012
    noise_b: float = 0.0019
    noise_c: float = 0.4
    planar_k: float = 3.0
    band_k: float = 3.0
    min_angle_deg: float = 10.0
    max_angle_deg: float = 25.0
    merge_gap_cells: int = 1
    min_area_fraction: float = 0.01

    def __post_init__(self):
        for item in fields(self):
            value = getattr(self, item.name)
            if not np.isfinite(value) or (value < 0 if item.name in ("noise_c", "merge_gap_cells") else value <= 0):
                raise ValueError(f"DetectorConfig.{item.name} must be positive, got {value!r}")
        if not isinstance(self.cell_px, int) or self.cell_px < 2:
            raise ValueError(f"DetectorConfig.cell_px must be an integer >= 2, got {self.cell_px!r}")
        if not isinstance(self.merge_gap_cells, int):
            raise ValueError(f"DetectorConfig.merge_gap_cells must be an integer, got {self.merge_gap_cells!r}")
        if self.min_valid_fraction > 1 or self.min_area_fraction > 1:
            raise ValueError("DetectorConfig fractions must lie in (0, 1]")
        if self.min_angle_deg > self.max_angle_deg or self.max_angle_deg >= 90:
            raise ValueError("DetectorConfig needs min_angle_deg <= max_angle_deg < 90")

    def sigma(self, depth: np.ndarray) -> np.ndarray:
        """Axial noise standard deviation at ``depth`` metres (the default noise model).

        Parameters
        ----------
        depth : ndarray
            Depth in metres.

        Returns
        -------
        ndarray
            ``noise_a + noise_b * (depth - noise_c) ** 2`` in metres, same shape.
        """
        return self.noise_a + self.noise_b * (depth - self.noise_c) ** 2

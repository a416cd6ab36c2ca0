"""What the per-frame stage says about each plane it was given: :class:`PlaneRecord`.

The record travels from the worker that segmented the frame into the journal, ``report.json``,
``review`` and ``stats`` (:mod:`annotate_rgbd.report.records` holds the records around it); its
JSON layout is part of the report format.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from annotate_rgbd.jsonfields import RecordError, int_field, mapping, number, numbers, optional_int, text

__all__ = ["PlaneRecord", "RecordError"]


@dataclass(frozen=True)
class PlaneRecord:
    """What happened to one plane drawn on one depth frame.

    Parameters
    ----------
    plane : int
        Global plane id.
    pixels : int
        Pixels of the plane's shape as drawn (rasterised on the depth grid).
    valid_pixels : int
        Of these, pixels with valid depth.
    mean_distance : float or None
        Mean distance (m) of the valid pixels from the camera, along their rays; None without any.
    inliers : int, optional
        Kept planes: pixels that lie on the fitted plane (the pixels of the mask).
    inlier_ratio : float, optional
        Kept planes: ``inliers / valid_pixels``.
    equation : tuple of 4 float, optional
        Kept planes: ``(a, b, c, d)`` with ``a x + b y + c z + d = 0`` in the camera frame (m).
    band : float, optional
        Kept planes: the inlier band (m) at the median depth of the plane's inliers.
    rms_sigma : float, optional
        Kept planes: RMS distance of the fit's inliers to the plane in units of the sensor noise
        at their depth (about 1 when the noise model fits).
    noise_scale : float, optional
        Kept planes: how much noisier than the model the plane's points are (the band is
        widened by it; 1 when the model fits, ``ransac.max_noise_scale`` at most).
    fit_points, fit_inliers_ransac, fit_inliers_refit : int, optional
        Kept planes: the grid points the plane was fitted to, and how many of them lie within
        the band of RANSAC's plane (or of the surface behind that replaced it) and of the plane
        re-fitted to its inliers.
    grown : int, optional
        Kept planes: pixels outside the drawn shape added by edge growing (the mask holds
        ``inliers + grown`` pixels of the plane).
    surface_behind : bool, optional
        Kept planes: whether the plane is a surface behind RANSAC's first plane, which an object
        covering most of the shape had won (worth a look).
    propagated : bool, optional
        With camera poses: whether the plane's shape was carried here by the poses from
        keyframes on other frames (False: drawn on this frame's keyframe). None without poses.
    reason : str, optional
        Dropped planes: why (``invalid_depth``, ``too_few_points``, ``too_far``; ``no_plane``: its
        valid depth is on one pixel row or column, or on one line in space;
        ``not_where_expected``: a plane carried by camera poses whose depth there is another
        surface); None: kept.
    invalid_ratio : float, optional
        Dropped planes: the share of the shape's pixels without valid depth.
    """

    plane: int
    pixels: int
    valid_pixels: int
    mean_distance: float | None
    inliers: int | None = None
    inlier_ratio: float | None = None
    equation: tuple[float, ...] | None = None
    band: float | None = None
    rms_sigma: float | None = None
    noise_scale: float | None = None
    fit_points: int | None = None
    fit_inliers_ransac: int | None = None
    fit_inliers_refit: int | None = None
    grown: int | None = None
    surface_behind: bool | None = None
    reason: str | None = None
    invalid_ratio: float | None = None
    propagated: bool | None = None

    @property
    def kept(self) -> bool:
        """Whether the plane is in the frame's mask (not dropped)."""
        return self.reason is None

    def to_json(self) -> dict[str, Any]:
        """The report's plane entry."""
        entry: dict[str, Any] = {
            "plane": self.plane,
            "pixels": self.pixels,
            "valid_pixels": self.valid_pixels,
            "mean_distance": self.mean_distance,
        }
        if self.kept:
            entry.update(inliers=self.inliers, inlier_ratio=self.inlier_ratio,
                         equation=None if self.equation is None else list(self.equation),
                         band=self.band, rms_sigma=self.rms_sigma, noise_scale=self.noise_scale,
                         fit_points=self.fit_points,
                         fit_inliers_ransac=self.fit_inliers_ransac, fit_inliers_refit=self.fit_inliers_refit,
                         grown=self.grown, surface_behind=self.surface_behind)
        else:
            entry.update(reason=self.reason, invalid_ratio=self.invalid_ratio)
        if self.propagated is not None:
            entry["propagated"] = self.propagated
        return entry

    @classmethod
    def from_json(cls, entry: Any) -> PlaneRecord:
        """Read a report's plane entry.

        Raises
        ------
        RecordError
            Not a plane entry.
        """
        entry = mapping(entry, "plane entry")
        equation = entry.get("equation")
        return cls(
            plane=int_field(entry, "plane"),
            pixels=int_field(entry, "pixels"),
            valid_pixels=int_field(entry, "valid_pixels"),
            mean_distance=number(entry, "mean_distance", optional=True),
            inliers=int_field(entry, "inliers") if "inliers" in entry else None,
            inlier_ratio=number(entry, "inlier_ratio", optional=True),
            equation=None if equation is None else tuple(numbers(equation, "equation", 4)),
            band=number(entry, "band", optional=True),
            rms_sigma=number(entry, "rms_sigma", optional=True),
            noise_scale=number(entry, "noise_scale", optional=True),
            fit_points=optional_int(entry, "fit_points"),
            fit_inliers_ransac=optional_int(entry, "fit_inliers_ransac"),
            fit_inliers_refit=optional_int(entry, "fit_inliers_refit"),
            grown=optional_int(entry, "grown"),
            surface_behind=entry["surface_behind"] if isinstance(entry.get("surface_behind"), bool) else None,
            reason=text(entry, "reason", optional=True),
            invalid_ratio=number(entry, "invalid_ratio", optional=True),
            propagated=entry["propagated"] if isinstance(entry.get("propagated"), bool) else None,
        )

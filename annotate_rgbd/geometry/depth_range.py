"""Whether a sequence's depth, read with the configured ``depth_scale``, looks like what an
indoor RGB-D sensor sees: a wrong scale (millimetre data read as TUM's 1/5000 m, or the other way
round) gives no error anywhere else, only masks of planes dropped as too far or proposals of
nothing."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: The median valid depth of an indoor RGB-D frame lies in this range (m): Kinect v1 is specified
#: for 0.8-4.0 m, the RealSense D435 works best at 0.3-3 m, and a desk or room scene's median is
#: 0.5-4 m (TUM fr1_rpy: about 1.2 m; the RealSense office frames: 1.2 m). Beyond the upper end
#: most planes would also be dropped as too far (``filter.max_mean_distance``, 3.5 m).
PLAUSIBLE_MEDIAN = (0.3, 4.5)
#: Scales RGB-D data comes in (units per metre): millimetres (RealSense, Kinect v2, Azure Kinect,
#: ScanNet, 7-Scenes) and 1/5000 m (TUM RGB-D, ICL-NUIM in TUM format).
COMMON_SCALES = {1000.0: "millimetres", 5000.0: "TUM RGB-D / ICL-NUIM, 1/5000 m"}
#: A typical indoor median (m): of two scales that both fit, the one nearer this is suggested.
TYPICAL_MEDIAN = 1.5


def median_raw_depth(depth_raw: np.ndarray) -> float | None:
    """Median of a raw depth image's valid values (finite, > 0, not 65535 = 7-Scenes' invalid);
    None without any."""
    values = depth_raw[np.isfinite(depth_raw) & (depth_raw > 0) & (depth_raw != 65535)]
    return float(np.median(values)) if values.size else None


def depth_scale_hint(raw_medians: Sequence[float | None], depth_scale: float) -> str | None:
    """A one-line hint when the first frames' depth, at ``depth_scale``, is implausible.

    Parameters
    ----------
    raw_medians : sequence of float or None
        :func:`median_raw_depth` of the first frames (raw units).
    depth_scale : float
        The configured depth units per metre.

    Returns
    -------
    str or None
        None when the median depth in metres is within :data:`PLAUSIBLE_MEDIAN`; else what it is
        and the common scale that puts it there (or only the problem, when none does).
    """
    known = [m for m in raw_medians if m is not None]
    if not known:
        return None
    raw = float(np.median(known))
    metres = raw / depth_scale
    low, high = PLAUSIBLE_MEDIAN
    if low <= metres <= high:
        return None
    where = "closer than" if metres < low else "farther than"
    fits = [s for s in COMMON_SCALES if low <= raw / s <= high and s != depth_scale]
    message = (f"with depth_scale {depth_scale:g} the median depth of the first frames is {metres:.2f} m, "
               f"{where} an indoor RGB-D sensor sees ({low:g}-{high:g} m)")
    if not fits:
        return message + ": check [camera] depth_scale"
    best = min(fits, key=lambda s: abs(np.log(raw / s / TYPICAL_MEDIAN)))
    return (message + f"; the data suggests depth_scale {best:g} ({COMMON_SCALES[best]}: median {raw / best:.2f} m): "
            f"set it in the --config file's [camera] or with --set camera.depth_scale={best:g}")

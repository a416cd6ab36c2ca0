"""Depth noise models: the standard deviation of a depth measurement as a function of depth.

Structured-light (Kinect v1) and active-stereo (RealSense D4xx) sensors measure disparity, and
depth is ``f b / disparity``: an error of a fixed size in disparity becomes a depth error that
grows with the square of the depth. A refinement that keeps a pixel when its 3-D point lies
within one fixed distance of its plane is therefore too strict far away and too lenient near by.
This module gives the depth-dependent alternative: a noise model ``sigma(z)`` and the inlier
band ``clip(k sigma(z), floor, cap)`` built from it.

Every default lives in this module, with its source:

============== ========= ========= ===== ==================================================
model          a (m)     b (1/m)   c (m) source
============== ========= ========= ===== ==================================================
kinect_v1      0.0012    0.0019    0.4   Nguyen, Izadi & Lovell 2012, axial noise, 0.4-3 m
icl_nuim       0         9.489e-4  0     Handa et al. 2014 (Barron & Malik disparity noise),
                                         quadratic approximation, see :data:`ICL_NUIM_B`
realsense_d435 0         2.602e-3  0     Intel's depth RMS error formula, see
                                         :data:`REALSENSE_D435_B`
============== ========= ========= ===== ==================================================

``sigma(z) = a + b (z - c)^2`` in metres for a depth ``z`` in metres. The band defaults are
``k = 3``, ``floor = 2 mm`` and ``cap = 10 cm`` (:data:`DEFAULT_K`, :data:`DEFAULT_FLOOR`,
:data:`DEFAULT_CAP`). A fixed ``distance_threshold`` ``t`` is the band of ``ConstantNoise(t / k)`` (with
``floor <= t <= cap``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Union

import numpy as np

from .statistics import median


@dataclass(frozen=True)
class ConstantNoise:
    """Depth noise that does not depend on depth.

    Parameters
    ----------
    value : float
        Standard deviation of the depth in metres, >= 0.
    """

    value: float

    def sigma(self, z: np.ndarray) -> np.ndarray:
        """Standard deviation of the depth at depths ``z``.

        Parameters
        ----------
        z : array_like of float
            Depth in metres, any shape; NaN where unknown.

        Returns
        -------
        ndarray of float64, shape of ``z``
            ``value`` everywhere, NaN where ``z`` is NaN.
        """
        result = np.array(z, dtype=np.float64)  # a copy
        result *= 0.0  # carries NaN through (depths are finite or NaN, never infinite)
        result += self.value
        return result


@dataclass(frozen=True)
class QuadraticNoise:
    """Depth noise ``sigma(z) = a + b (z - c)^2`` (metres).

    Parameters
    ----------
    a : float
        Noise at depth ``c``, in metres, >= 0.
    b : float
        Growth with the squared depth, in 1/m, >= 0.
    c : float
        Depth of least noise, in metres, >= 0 (0 for a pure ``b z^2`` law).
    """

    a: float
    b: float
    c: float = 0.0

    def sigma(self, z: np.ndarray) -> np.ndarray:
        """Standard deviation of the depth at depths ``z``.

        Parameters
        ----------
        z : array_like of float
            Depth in metres, any shape; NaN where unknown.

        Returns
        -------
        ndarray of float64, shape of ``z``
            ``a + b (z - c)^2``, NaN where ``z`` is NaN.
        """
        result = np.array(z, dtype=np.float64)  # a copy; in place from here: one array
        result -= self.c
        result *= result
        result *= self.b
        result += self.a
        return result


#: Either noise model: both have ``sigma(z)``.
NoiseModel = Union[ConstantNoise, QuadraticNoise]


#: Inlier band half-width in standard deviations. 3 sigma keeps 99.73 % of the pixels of a
#: plane with Gaussian depth noise (the loss the issue measured at 2.5 m with a fixed 2 cm band
#: was ~4 %); for the ICL-NUIM model it spans +-1 disparity unit: rounding's +-0.5 unit plus
#: 3 sigma of its Gaussian noise (see ICL_NUIM_B).
DEFAULT_K = 3.0

#: Narrowest band, in metres. Depth is stored in steps of 0.2 mm (TUM, ICL-NUIM: 1/5000 m) or
#: 1 mm (RealSense: 1/1000 m), and no real wall or table top is flat to better than about a
#: millimetre; a band below 2 mm would reject pixels for storage rounding and surface
#: roughness, not for lying off the plane. It also keeps 1 / sigma^2 weights finite.
DEFAULT_FLOOR = 0.002

#: Widest band, in metres. The 3-sigma band of the presets reaches 10 cm only beyond 3.6 m
#: (RealSense D435) or 4.5 m (Kinect v1), past the 3.5 m mean distance at which the filter
#: drops planes (config.FilterConfig.max_mean_distance), so the cap does not bite in normal use;
#: it stops a mistyped model (b in mm, say) from turning every object standing on a plane
#: (books, keyboards, monitors are taller than 10 cm) into plane.
DEFAULT_CAP = 0.10

#: ICL-NUIM (Handa, Whelan, McDonald & Davison, ICRA 2014) renders clean depth and adds
#: Kinect-like noise after Barron & Malik (CVPR 2013) in a disparity domain with
#: ``disparity = 35130 / Z`` (Z in cm, so 351.3 / z with z in metres): Gaussian noise of
#: standard deviation 1/6 unit is added and the disparity is rounded to a whole unit (the
#: authors' released simulator, ankurhanda/simkinect, also shifts pixels laterally by
#: N(0, 0.5^2) px, which moves points along the surface and is left out here). Rounding adds
#: uniform noise of variance 1/12, so the disparity error has standard deviation
#: sqrt(1/36 + 1/12) = 1/3 unit, and to first order the depth error is
#: ``sigma(z) = z^2 / 351.3 / 3 = 9.489e-4 z^2`` m (0.95 mm at 1 m, 3.8 mm at 2 m).
#: This quadratic is an approximation: the rounding error is uniform rather than Gaussian,
#: and is a systematic staircase over a smooth surface rather than independent per pixel.
ICL_NUIM_B = 1.0 / (3.0 * 351.3)

#: Intel RealSense D4xx: "depth RMS error = z^2 * subpixel / (focal_px * baseline)" (Intel,
#: "Tuning depth cameras for best performance" and the D400 series datasheet). D435: baseline
#: 50 mm, subpixel RMS about 0.08 px for a textured target, focal length 615 px (the D435 at
#: 640x480 of the project's RealSense reference data), so
#: ``sigma(z) = 0.08 / (615 * 0.05) z^2 = 2.60e-3 z^2`` m (2.6 mm at 1 m, 10 mm at 2 m).
#: Strictly, ``focal_px`` is the focal length of the stereo imagers at the resolution depth was
#: matched at (0.5 * Xres / tan(HFOV / 2), HFOV ~ 87-90 deg: ~320-385 px at 640x480, ~424 px at
#: 848x480, ~640 px at 1280x720), not that of the colour camera depth is aligned to; a smaller
#: focal length means more noise (5e-3 z^2 at 320 px). 615 px is kept because it fits the
#: recorded data better: on realsense_d435_office, the residuals of 12x12-pixel local planes
#: (which miss spatially correlated error, so they understate sigma) are about 0.4 of this
#: model (1.5 mm at 1-1.5 m, 15 mm at 3.5-4 m), so a larger coefficient is not supported.
REALSENSE_D435_B = 0.08 / (615.0 * 0.050)

#: Named noise models (the ``model = "..."`` presets of a ``[noise]`` section).
SENSOR_MODELS: dict[str, NoiseModel] = {
    # Nguyen, Izadi & Lovell, "Modeling Kinect sensor noise for improved 3D reconstruction and
    # tracking", 3DIMPVT 2012: axial noise of a Kinect v1 facing a plane (angles below ~60 deg),
    # fitted for 0.4-3 m. Khoshelham & Elberink, Sensors 2012, report the random error growing
    # as about 1.4 mm x z^2 (z in m), consistent with it (1.9 vs 1.4 mm at 1 m, 14 vs 13 mm at
    # 3 m). On tum_fr1_rpy (Kinect v1), the median residual of 12x12-pixel local planes is
    # 0.8-1.1 of this model from 0.5 to 3 m.
    "kinect_v1": QuadraticNoise(a=0.0012, b=0.0019, c=0.4),
    "icl_nuim": QuadraticNoise(a=0.0, b=ICL_NUIM_B, c=0.0),
    "realsense_d435": QuadraticNoise(a=0.0, b=REALSENSE_D435_B, c=0.0),
}


def inlier_band(
    z: np.ndarray,
    model: NoiseModel,
    k: float = DEFAULT_K,
    floor: float = DEFAULT_FLOOR,
    cap: float = DEFAULT_CAP,
) -> np.ndarray:
    """Largest point-to-plane distance of an inlier at depths ``z``: ``clip(k sigma(z), floor, cap)``.

    Parameters
    ----------
    z : array_like of float
        Depth in metres, any shape; NaN where unknown.
    model : ConstantNoise or QuadraticNoise
    k : float
        Band half-width in standard deviations, > 0.
    floor, cap : float
        Narrowest and widest band in metres, ``0 < floor <= cap``.

    Returns
    -------
    ndarray of float64, shape of ``z``
        Metres; NaN where ``z`` is NaN (so that a comparison with it is False).
    """
    band = model.sigma(z)
    band *= k
    return np.clip(band, floor, cap, out=band)


@dataclass(frozen=True)
class NoiseSettings:
    """A noise model and the band built from it (a ``[noise]`` configuration section).

    Parameters
    ----------
    model : ConstantNoise or QuadraticNoise
    k : float
        Band half-width in standard deviations.
    floor, cap : float
        Narrowest and widest band in metres.
    """

    model: NoiseModel = SENSOR_MODELS["kinect_v1"]
    k: float = DEFAULT_K
    floor: float = DEFAULT_FLOOR
    cap: float = DEFAULT_CAP

    def band(self, z: np.ndarray) -> np.ndarray:
        """:func:`inlier_band` at depths ``z`` with these settings."""
        return inlier_band(z, self.model, self.k, self.floor, self.cap)

    def to_mapping(self) -> dict[str, Any]:
        """The settings as a ``[noise]`` section: the inverse of :func:`noise_settings_from_mapping`."""
        names = [name for name, model in SENSOR_MODELS.items() if model == self.model]
        if names:
            values: dict[str, Any] = {"model": names[0]}
        elif isinstance(self.model, ConstantNoise):
            values = {"model": "constant", "sigma": self.model.value}
        else:
            values = {"model": "quadratic", "a": self.model.a, "b": self.model.b, "c": self.model.c}
        return {**values, "k": self.k, "floor": self.floor, "cap": self.cap}

    def scaled(self, factor: float) -> NoiseSettings:
        """The same settings with the noise ``factor`` times larger (the band's floor and cap
        stay: a fixed band stays fixed)."""
        if isinstance(self.model, ConstantNoise):
            model: NoiseModel = ConstantNoise(self.model.value * factor)
        else:
            model = QuadraticNoise(self.model.a * factor, self.model.b * factor, self.model.c)
        return NoiseSettings(model, self.k, self.floor, self.cap)

    @classmethod
    def fixed(cls, threshold: float) -> NoiseSettings:
        """A band of the same width at every depth (a ``distance_threshold``)."""
        return cls(ConstantNoise(threshold / DEFAULT_K), DEFAULT_K, threshold, threshold)


#: Keys a ``[noise]`` mapping may hold, by model kind.
_MODEL_KEYS = {"quadratic": ("a", "b", "c"), "constant": ("sigma",)}
_BAND_KEYS = ("k", "floor", "cap")


def noise_settings_from_mapping(values: Mapping[str, Any]) -> NoiseSettings:
    """Build :class:`NoiseSettings` from plain values, as a TOML ``[noise]`` section gives them.

    ``model`` is ``"quadratic"`` (then ``b`` is required, ``a`` and ``c`` default to 0),
    ``"constant"`` (then ``sigma`` is required) or the name of a sensor in
    :data:`SENSOR_MODELS` (then none of ``a``, ``b``, ``c``, ``sigma`` may be given). Without
    ``model``: ``kinect_v1``. ``k``, ``floor`` and ``cap`` default to :data:`DEFAULT_K`,
    :data:`DEFAULT_FLOOR` and :data:`DEFAULT_CAP`.

    Parameters
    ----------
    values : mapping of str to value

    Returns
    -------
    NoiseSettings

    Raises
    ------
    ValueError
        One line naming the key: unknown key or model, a key the model does not take, a missing
        key, a value that is not a finite number, a negative value, ``k <= 0``, ``floor <= 0``
        or ``floor > cap``. (The configuration loader turns it into an ``InputError`` with the
        file name.)
    """
    known = ("model",) + _MODEL_KEYS["quadratic"] + _MODEL_KEYS["constant"] + _BAND_KEYS
    for key in values:
        if key not in known:
            raise ValueError(f"unknown key 'noise.{key}' (known in [noise]: {', '.join(known)})")
    name = values.get("model", "kinect_v1")
    choices = sorted(_MODEL_KEYS) + sorted(SENSOR_MODELS)
    if not isinstance(name, str) or name not in choices:
        raise ValueError(f"'noise.model' must be one of {', '.join(choices)}, got {name!r}")
    numbers = {key: _number(key, value) for key, value in values.items() if key != "model"}
    allowed = _MODEL_KEYS.get(name, ())
    for key in _MODEL_KEYS["quadratic"] + _MODEL_KEYS["constant"]:
        if key in numbers and key not in allowed:
            raise ValueError(f"'noise.{key}' is not a parameter of model '{name}'")
    if name == "quadratic":
        if "b" not in numbers:
            raise ValueError("'noise.b' is missing (model 'quadratic' needs a, b, c; a and c default to 0)")
        model: NoiseModel = QuadraticNoise(numbers.get("a", 0.0), numbers["b"], numbers.get("c", 0.0))
    elif name == "constant":
        if "sigma" not in numbers:
            raise ValueError("'noise.sigma' is missing (model 'constant' needs sigma)")
        model = ConstantNoise(numbers["sigma"])
    else:
        model = SENSOR_MODELS[name]
    settings = NoiseSettings(
        model,
        numbers.get("k", DEFAULT_K),
        numbers.get("floor", DEFAULT_FLOOR),
        numbers.get("cap", DEFAULT_CAP),
    )
    if settings.k <= 0:
        raise ValueError(f"'noise.k' must be > 0, got {settings.k!r}")
    if settings.floor <= 0:
        raise ValueError(f"'noise.floor' must be > 0 (a band of zero width keeps nothing), got {settings.floor!r}")
    if settings.floor > settings.cap:
        raise ValueError(f"'noise.floor' ({settings.floor!r}) must not exceed 'noise.cap' ({settings.cap!r})")
    return settings


def _number(key: str, value: Any) -> float:
    """``value`` as a finite, non-negative float, or a ValueError naming ``noise.key``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"'noise.{key}' must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"'noise.{key}' must be finite, got {value!r}")
    if value < 0:
        raise ValueError(f"'noise.{key}' must be >= 0, got {value!r}")
    return value


def noise_scale(points: np.ndarray, equation: np.ndarray, noise: NoiseSettings) -> float:
    """How much noisier than ``noise`` a plane's points are: ``1.4826 median(|d| / sigma(z))``
    over the points within its band on the side of the plane where that is smaller (``d`` the
    signed distance to the plane, ``z`` the depth), at least 1; 1 for a fixed band or fewer than
    5 points on either side.

    Parameters
    ----------
    points : ndarray of float64, shape (N, 3)
    equation : ndarray, shape (4,)
    noise : NoiseSettings

    Returns
    -------
    float
    """
    if noise.floor >= noise.cap:
        return 1.0  # a fixed band: nothing to adapt
    z = points[:, 2]
    sigma = noise.model.sigma(z)
    signed = np.einsum("ij,j->i", points, equation[:3]) + equation[3]
    with np.errstate(invalid="ignore"):
        inside = np.abs(signed) <= np.clip(noise.k * sigma, noise.floor, noise.cap)
    residual = signed[inside] / np.maximum(sigma[inside], 1e-9)
    front, behind = residual[residual > 0], -residual[residual < 0]
    if min(front.size, behind.size) < 5:
        return 1.0
    # Each side of the plane on its own: a surface in the band on one side (a whiteboard on a
    # wall, a book on a table) widens that side only; the narrower side is the plane's noise.
    return max(1.0, 1.4826 * float(min(median(front), median(behind))))

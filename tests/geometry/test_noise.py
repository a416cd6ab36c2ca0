"""Depth noise models: values against the papers' formulas, NaN handling, the band, the [noise] mapping."""

from __future__ import annotations

import math

import numpy as np
import pytest

from annotate_rgbd.geometry.noise import (
    DEFAULT_CAP,
    DEFAULT_FLOOR,
    DEFAULT_K,
    SENSOR_MODELS,
    ConstantNoise,
    NoiseSettings,
    QuadraticNoise,
    inlier_band,
    noise_settings_from_mapping,
)


@pytest.mark.parametrize(
    "z, expected",
    [
        # Nguyen, Izadi & Lovell 2012: 0.0012 + 0.0019 (z - 0.4)^2, worked by hand.
        (0.4, 0.0012),
        (1.0, 0.0012 + 0.0019 * 0.36),  # 1.884 mm
        (2.0, 0.0012 + 0.0019 * 2.56),  # 6.064 mm
        (3.0, 0.0012 + 0.0019 * 6.76),  # 14.044 mm
    ],
)
def test_kinect_v1_is_nguyen_2012(z, expected):
    assert SENSOR_MODELS["kinect_v1"].sigma(z) == pytest.approx(expected, rel=1e-12)


def test_kinect_v1_agrees_with_khoshelham_within_the_valid_range():
    # Khoshelham & Elberink 2012: random error about 1.4 mm x z^2. The two studies differ by
    # at most ~35 % between 1 and 3 m (the docstring's "consistent").
    z = np.linspace(1.0, 3.0, 21)
    ratio = SENSOR_MODELS["kinect_v1"].sigma(z) / (0.0014 * z**2)
    assert np.all((ratio > 1.0) & (ratio < 1.36))


@pytest.mark.parametrize("z", [0.8, 1.0, 2.0, 3.5])
def test_realsense_d435_is_intel_rms_formula(z):
    # Intel: RMS error = z^2 * subpixel / (focal_px * baseline); 0.08 px, 615 px, 50 mm.
    assert SENSOR_MODELS["realsense_d435"].sigma(z) == pytest.approx(z**2 * 0.08 / (615 * 0.050), rel=1e-12)


@pytest.mark.parametrize("z", [1.0, 2.0, 3.0])
def test_icl_nuim_is_the_disparity_noise_propagated_to_depth(z):
    # Barron & Malik as used by ICL-NUIM: disparity 35130 / Z_cm, Gaussian noise 1/6 unit plus
    # rounding to whole units (uniform, variance 1/12); dZ/dd = Z^2 / 35130 (cm).
    sigma_disparity = math.sqrt((1 / 6) ** 2 + 1 / 12)
    z_cm = 100 * z
    expected = z_cm**2 / 35130 * sigma_disparity / 100
    assert SENSOR_MODELS["icl_nuim"].sigma(z) == pytest.approx(expected, rel=1e-3)


@pytest.mark.parametrize("z", [1.0, 2.5])
def test_icl_nuim_quadratic_matches_a_simulation_of_the_noise(z):
    # Simulate the disparity-domain model itself: depths spread evenly over ten quantisation
    # steps (so rounding acts as the uniform error the approximation assumes), noisy disparity
    # rounded to a whole unit, back to depth. The depth error's spread matches sigma(z).
    rng = np.random.default_rng(1)
    step_cm = (100 * z) ** 2 / 35130  # depth of one disparity unit
    depth_cm = 100 * z + rng.uniform(-5 * step_cm, 5 * step_cm, 400_000)
    disparity = 35130 / depth_cm + rng.normal(0, 1 / 6, depth_cm.size)
    noisy_cm = 35130 / np.floor(disparity + 0.5)
    error_m = (noisy_cm - depth_cm) / 100
    assert error_m.std() == pytest.approx(SENSOR_MODELS["icl_nuim"].sigma(z), rel=0.03)


@pytest.mark.parametrize("model", [ConstantNoise(0.004), QuadraticNoise(0.001, 0.002, 0.5)])
def test_sigma_is_vectorised_and_nan_in_gives_nan_out(model):
    z = np.array([[0.5, np.nan, 2.0], [np.nan, 1.0, 3.0]])
    out = model.sigma(z)
    assert out.shape == z.shape
    assert np.array_equal(np.isnan(out), np.isnan(z))
    # element by element, independently of the vectorised call
    for value, got in zip(z.ravel(), out.ravel()):
        if not np.isnan(value):
            assert got == pytest.approx(model.sigma(float(value)))
    assert z[0, 0] == 0.5  # the input is not modified


def test_quadratic_formula_by_hand():
    model = QuadraticNoise(a=0.001, b=0.002, c=0.5)
    assert model.sigma(np.array([0.5, 1.5, 2.5])) == pytest.approx([0.001, 0.003, 0.009])


def test_constant_model_is_constant():
    assert np.all(ConstantNoise(0.004).sigma(np.array([0.3, 1.0, 7.0])) == 0.004)


def test_inlier_band_is_k_sigma_clipped_to_floor_and_cap():
    model = QuadraticNoise(a=0.0, b=0.01, c=0.0)  # 10 mm x z^2
    z = np.array([0.2, 0.5, 1.0, 1.5, 2.0, np.nan])
    band = inlier_band(z, model, k=2.0, floor=0.003, cap=0.05)
    # 2 * 0.01 z^2 = 0.0008, 0.005, 0.02, 0.045, 0.08 -> floor / as is / cap
    assert band[:5] == pytest.approx([0.003, 0.005, 0.02, 0.045, 0.05])
    assert np.isnan(band[5])


def test_a_fixed_threshold_is_the_constant_model_with_sigma_t_over_k():
    t = 0.02
    band = inlier_band(np.array([0.5, 2.0, 4.0]), ConstantNoise(t / DEFAULT_K), DEFAULT_K, DEFAULT_FLOOR, DEFAULT_CAP)
    assert band == pytest.approx([t, t, t])


def test_default_cap_does_not_bite_within_the_filter_distance():
    # The documented reason for the cap: the presets' 3-sigma band stays below it up to 3.5 m.
    for name, model in SENSOR_MODELS.items():
        assert DEFAULT_K * model.sigma(3.5) < DEFAULT_CAP, name


def test_default_floor_exceeds_the_depth_storage_step():
    assert DEFAULT_FLOOR >= 2 * 0.001  # RealSense stores millimetres; TUM / ICL-NUIM 0.2 mm


def test_settings_band_uses_its_fields():
    settings = NoiseSettings(QuadraticNoise(0.0, 0.01, 0.0), k=2.0, floor=0.003, cap=0.05)
    z = np.array([0.2, 1.0, 2.0])
    assert settings.band(z) == pytest.approx(inlier_band(z, settings.model, 2.0, 0.003, 0.05))


# --- the [noise] mapping -------------------------------------------------------------------


def test_empty_mapping_gives_the_defaults():
    settings = noise_settings_from_mapping({})
    assert settings == NoiseSettings(SENSOR_MODELS["kinect_v1"], DEFAULT_K, DEFAULT_FLOOR, DEFAULT_CAP)


@pytest.mark.parametrize("name", ["kinect_v1", "icl_nuim", "realsense_d435"])
def test_named_models(name):
    settings = noise_settings_from_mapping({"model": name, "k": 2.5})
    assert settings.model == SENSOR_MODELS[name]
    assert settings.k == 2.5


def test_quadratic_and_constant_models_from_values():
    quadratic = noise_settings_from_mapping({"model": "quadratic", "a": 0.001, "b": 0.002, "c": 0.4, "floor": 0.001, "cap": 0.2})
    assert quadratic == NoiseSettings(QuadraticNoise(0.001, 0.002, 0.4), DEFAULT_K, 0.001, 0.2)
    assert noise_settings_from_mapping({"model": "quadratic", "b": 0.003}).model == QuadraticNoise(0.0, 0.003, 0.0)
    constant = noise_settings_from_mapping({"model": "constant", "sigma": 0.005, "k": 2})
    assert constant.model == ConstantNoise(0.005)
    assert constant.k == 2.0 and isinstance(constant.k, float)


@pytest.mark.parametrize(
    "values, key",
    [
        ({"model": "kinect_v2"}, "noise.model"),
        ({"model": 3}, "noise.model"),
        ({"sigmaa": 0.01}, "noise.sigmaa"),
        ({"model": "quadratic", "a": 0.001}, "noise.b"),
        ({"model": "constant"}, "noise.sigma"),
        ({"model": "constant", "sigma": 0.01, "b": 0.1}, "noise.b"),
        ({"model": "kinect_v1", "a": 0.001}, "noise.a"),
        ({"model": "quadratic", "b": -0.001}, "noise.b"),
        ({"model": "quadratic", "b": float("nan")}, "noise.b"),
        ({"model": "quadratic", "b": float("inf")}, "noise.b"),
        ({"model": "quadratic", "b": "0.002"}, "noise.b"),
        ({"model": "constant", "sigma": True}, "noise.sigma"),
        ({"k": 0}, "noise.k"),
        ({"k": -1.0}, "noise.k"),
        ({"floor": 0.0}, "noise.floor"),
        ({"floor": 0.2, "cap": 0.1}, "noise.floor"),
        ({"cap": float("inf")}, "noise.cap"),
    ],
)
def test_bad_mapping_raises_one_line_value_error_naming_the_key(values, key):
    with pytest.raises(ValueError) as info:
        noise_settings_from_mapping(values)
    message = str(info.value)
    assert f"'{key}'" in message
    assert "\n" not in message


def test_floor_equal_to_cap_is_allowed():
    settings = noise_settings_from_mapping({"floor": 0.01, "cap": 0.01})
    assert settings.band(np.array([0.5, 3.0])) == pytest.approx([0.01, 0.01])

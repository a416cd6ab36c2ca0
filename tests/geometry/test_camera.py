import numpy as np
import pytest

from annotate_rgbd.geometry.camera import Camera, backproject, depth_to_metres, project

TUM = Camera(fx=517.3, fy=516.5, cx=318.6, cy=255.3, depth_scale=5000.0)
ICL = Camera(fx=481.2, fy=-480.0, cx=319.5, cy=239.5, depth_scale=5000.0)


def test_depth_to_metres_marks_invalid_values_nan():
    raw = np.array([[0, 5000, 10000], [-5, 1, 7]], dtype=np.float64)
    raw[1, 2] = np.nan
    metres = depth_to_metres(raw, 5000.0)
    assert metres.dtype == np.float32
    np.testing.assert_allclose(metres[0, 1:], [1.0, 2.0])
    assert np.isnan(metres[0, 0]) and np.isnan(metres[1, 0]) and np.isnan(metres[1, 2])
    assert metres[1, 1] == pytest.approx(1 / 5000)
    assert np.isnan(depth_to_metres(np.array([np.inf]), 5000.0)[0])


def test_depth_to_metres_reads_uint16_tum_png_values():
    raw = np.array([[65535, 12345]], dtype=np.uint16)
    np.testing.assert_allclose(depth_to_metres(raw, 5000.0), [[13.107, 2.469]], rtol=1e-6)


@pytest.mark.parametrize("camera", [TUM, ICL], ids=["tum", "icl_negative_fy"])
def test_backproject_then_project_returns_the_pixels(camera):
    rng = np.random.default_rng(1)
    cols, rows = rng.uniform(0, 640, 100), rng.uniform(0, 480, 100)
    z = rng.uniform(0.5, 5, 100)
    points = backproject(cols, rows, z, camera)
    np.testing.assert_allclose(points[:, 2], z)
    np.testing.assert_allclose(project(points, camera), np.stack([cols, rows], 1), atol=1e-9)


def test_negative_fy_flips_the_y_axis():
    above_centre = backproject(np.array([319.5]), np.array([139.5]), np.array([2.0]), ICL)
    assert above_centre[0, 1] > 0  # image row above cy -> y up in ICL's frame
    assert backproject(np.array([319.5]), np.array([139.5]), np.array([2.0]), TUM)[0, 1] < 0

"""A plane's depth bend (the sensor's disparity error): fitted robustly, kept only where it
explains the plane's depth, never bent towards an object inside the band."""

import numpy as np

from annotate_rgbd.config.settings import RansacConfig, RefineConfig
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.geometry.noise import SENSOR_MODELS, NoiseSettings
from annotate_rgbd.segment.bend import bend_terms, fit_bend
from annotate_rgbd.segment.refine import refine_planes

KINECT = NoiseSettings(SENSOR_MODELS["kinect_v1"])
CAMERA = Camera(fx=300.0, fy=300.0, cx=159.5, cy=119.5, depth_scale=5000.0)
SHAPE = (240, 320)
#: A bowl: the disparity error grows towards the image's borders (metres per m^2 of depth; about
#: 1 cm at the corners of a desk 1 m away, as Kinect v1 bows it).
BOWL = np.array([-0.004, 0.001, -0.001, 0.030, 0.002, 0.025])


def kinect_sigma(z):
    return 0.0012 + 0.0019 * (z - 0.4) ** 2


def rays():
    rows, cols = np.mgrid[: SHAPE[0], : SHAPE[1]]
    return (cols - CAMERA.cx) / CAMERA.fx, (rows - CAMERA.cy) / CAMERA.fy


def bowed_desk(rng, bowl=BOWL, z0=1.0, tilt_deg=40.0):
    """A desk seen from above at ``tilt_deg``, its depth bowed by ``bowl`` along the rays, with
    the sensor's noise. Returns depth (float32 m) and the bow's distance to the flat plane (m)."""
    x, y = rays()
    tilt = np.radians(tilt_deg)
    normal = np.array([0.0, -np.cos(tilt), -np.sin(tilt)])
    d = z0 * np.sin(tilt)
    flat = -d / (np.stack([x, y, np.ones(SHAPE)], -1) @ normal)
    bow = (bend_terms(x.ravel(), y.ravel(), flat.ravel()) @ bowl).reshape(SHAPE)
    # A distance along the normal is bow / |n . ray| along the ray (ray's z = 1: that is depth).
    depth = flat + bow / np.abs(np.stack([x, y, np.ones(SHAPE)], -1) @ normal)
    depth += rng.standard_normal(SHAPE) * kinect_sigma(depth)
    return depth.astype(np.float32), bow


def test_fit_bend_recovers_a_known_bend_from_cells_and_ignores_cells_off_it():
    rng = np.random.default_rng(0)
    x = rng.uniform(-0.5, 0.5, 200)
    y = rng.uniform(-0.4, 0.4, 200)
    z = rng.uniform(0.8, 2.0, 200)
    distance = bend_terms(x, y, z) @ BOWL + rng.normal(0, 2e-4, 200)
    distance[:30] += 0.015  # an object inside the band over 15 % of the cells
    coefficients, kept = fit_bend(x, y, z, distance, np.full(200, 0.01))
    assert not kept[:30].any() and kept[30:].mean() > 0.95
    # The same numbers as a least-squares fit to the clean cells alone (independent solve).
    clean = np.linalg.lstsq(bend_terms(x[30:], y[30:], z[30:]), distance[30:], rcond=None)[0]
    assert np.abs(bend_terms(x, y, z) @ (coefficients - clean)).max() < 3e-4
    assert np.abs(bend_terms(x, y, z) @ (coefficients - BOWL)).max() < 5e-4


def test_fit_bend_keeps_no_bend_for_a_flat_plane():
    rng = np.random.default_rng(1)
    x, y, z = rng.uniform(-0.5, 0.5, 150), rng.uniform(-0.4, 0.4, 150), rng.uniform(0.8, 2.0, 150)
    assert fit_bend(x, y, z, rng.normal(0, 5e-4, 150), np.full(150, 0.01)) is None
    assert fit_bend(x[:8], y[:8], z[:8], np.zeros(8), np.full(8, 0.01)) is None  # too few cells


def test_a_bowed_desk_keeps_more_of_its_far_end_with_the_bend():
    rng = np.random.default_rng(2)
    depth, bow = bowed_desk(rng)
    labels = np.ones(SHAPE, np.uint8)
    bent, _ = refine_planes(labels, depth, np.array([1]), CAMERA, RansacConfig(), KINECT)
    flat, _ = refine_planes(labels, depth, np.array([1]), CAMERA, RansacConfig(), KINECT,
                            refine=RefineConfig(bend_rounds=0))
    far = np.abs(bow - np.median(bow)) > np.percentile(np.abs(bow - np.median(bow)), 85)  # most bowed 15 %
    assert flat[far].mean() < 0.9  # the bow leaves the flat band there
    assert bent[far].mean() > flat[far].mean() + 0.02 and bent.mean() > flat.mean()


def test_a_flat_plane_refines_the_same_with_and_without_the_bend():
    rng = np.random.default_rng(3)
    depth, _ = bowed_desk(rng, bowl=np.zeros(6))
    labels = np.ones(SHAPE, np.uint8)
    bent, _ = refine_planes(labels, depth, np.array([1]), CAMERA, RansacConfig(), KINECT)
    flat, _ = refine_planes(labels, depth, np.array([1]), CAMERA, RansacConfig(), KINECT,
                            refine=RefineConfig(bend_rounds=0))
    assert (bent == flat).all()

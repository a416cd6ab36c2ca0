"""segment.grow.grow_connected against a plain reference: every plane tested on the whole image,
one plane after another (the formulation before it worked on the free pixels only), on random
scenes with ties, exclusions, holes in the depth and every label type: the same labels, pixel
for pixel."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from annotate_rgbd.config.settings import RefineConfig
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.geometry.noise import SENSOR_MODELS, NoiseSettings
from annotate_rgbd.segment.distances import signed_distances
from annotate_rgbd.segment.grow import grow_connected
from annotate_rgbd.segment.refine import label_lookup, window_scores


def reference_grow_connected(labels, drawn, claimed, depth_m, equations, camera, noise, refine=RefineConfig(),
                             excluded=None):
    """grow_connected as it was first written: whole-image passes, plane by plane."""
    labels = labels.copy()
    grown = {int(plane_id): 0 for plane_id in equations}
    if not grown:
        return labels, grown
    depth = np.asarray(depth_m, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        free = np.isfinite(depth) & (depth > 0) & ~np.asarray(claimed, dtype=bool) & (labels == 0)
    if not free.any():
        return labels, grown
    drawn = np.asarray(drawn)
    band = np.asarray(noise.band(depth), dtype=np.float32)
    ids = sorted(grown)
    candidate = np.zeros(labels.shape, dtype=labels.dtype)
    best = np.full(labels.shape, np.inf, dtype=np.float32)
    residual = np.zeros(labels.shape, dtype=np.float32)
    growing = np.zeros(max(int(labels.max(initial=0)), ids[-1]) + 1, dtype=np.uint8)
    growing[ids] = 1
    own = label_lookup(growing, labels).view(bool)  # pixels of the growing planes
    # Each free pixel goes to the nearest plane it lies on (a tie: the lowest id), but never to a
    # plane whose own shape covers it: those pixels refinement left out (a whiteboard on a wall).
    for plane_id in ids:
        signed = signed_distances(depth, *(np.float32(v) for v in equations[plane_id]), camera)
        distance = np.abs(signed)
        with np.errstate(invalid="ignore"):
            closer = distance <= band
            closer &= distance < best
        closer &= free
        closer &= drawn != plane_id
        if excluded and plane_id in excluded:
            closer &= ~excluded[plane_id]
        candidate[closer] = plane_id
        np.copyto(best, distance, where=closer)
        scored = closer | ((labels == plane_id) & np.isfinite(signed))
        with np.errstate(invalid="ignore"):
            np.copyto(residual, signed * np.float32(noise.k) / band, where=scored)
    # The window test of refinement (a doormat on the floor lies within its band): residuals in
    # noise units, averaged over each candidate's window, must look like the plane's noise.
    score, usable = window_scores(residual, own | (candidate > 0), refine.coherence_window, refine.min_window_inliers)
    candidate[~(usable & (np.abs(score) <= refine.coherence_limit))] = 0
    for plane_id in ids:
        mine = labels == plane_id
        if not mine.any():
            continue
        reach = (mine | (candidate == plane_id)).view(np.uint8)
        # On the window of what the plane may reach (a small plane's is a small part of the image).
        left, top, width, height = cv2.boundingRect(reach)
        window = (slice(top, top + height), slice(left, left + width))
        count, components = cv2.connectedComponents(reach[window], connectivity=8)
        mine = mine[window]
        linked = np.bincount(components[mine], minlength=count) > 0
        linked[0] = False
        take = np.take(linked, components) & ~mine
        labels[window][take] = plane_id
        grown[plane_id] = int(np.count_nonzero(take))
    return labels, grown

def _scene(seed: int):
    """A floor and two walls seen by a 60 x 80 camera, Kinect-like noise, holes; some of their
    pixels already labelled, the rest free; the planes to grow (duplicates: exact ties)."""
    rng = np.random.default_rng(seed)
    camera = Camera(fx=70.0, fy=70.0, cx=39.5, cy=29.5, depth_scale=5000.0)
    rows, cols = np.mgrid[:60, :80]
    x, y = (cols - camera.cx) / camera.fx, (rows - camera.cy) / camera.fy
    planes = [np.array([0.0, -1.0, 0.0, 0.8]), np.array([0.0, 0.0, -1.0, 2.5]), np.array([-0.6, 0.0, -0.8, 2.2])]
    depth = np.full((60, 80), np.inf)
    which = np.zeros((60, 80), dtype=np.int64)
    for index, (a, b, c, d) in enumerate(planes, start=1):
        with np.errstate(divide="ignore"):
            z = -d / (a * x + b * y + c)
        nearer = (z > 0) & (z < depth)
        depth[nearer], which[nearer] = z[nearer], index
    depth += rng.standard_normal(depth.shape) * (0.0012 + 0.0019 * (depth - 0.4) ** 2)
    depth[rng.random(depth.shape) < 0.05] = np.nan
    depth[rng.random(depth.shape) < 0.02] = 0.0
    depth = np.where(np.isfinite(depth), np.round(depth * 5000) / 5000, np.nan).astype(np.float32)
    dtype = (np.uint8, np.int32, np.int64, np.uint16)[seed % 4]
    ids = rng.choice(np.arange(1, 200), size=4, replace=False)
    labels = np.zeros(depth.shape, dtype=dtype)
    equations = {}
    for plane, plane_id in zip(range(1, 4), ids):
        keep = (which == plane) & (rng.random(depth.shape) < 0.4) & (cols < rng.integers(20, 80))
        labels[keep] = plane_id
        equations[int(plane_id)] = planes[plane - 1] + rng.normal(0, 0.002, 4) * (seed % 3 > 0)
    equations[int(ids[3])] = equations[int(ids[0])].copy()  # the same plane under another id: ties
    labels[(which == 1) & (rows > 55) & (cols < 10)] = ids[3]
    labels[rng.random(depth.shape) < 0.03] = 250  # a plane that does not grow
    drawn = np.where(rng.random(depth.shape) < 0.1, labels, 0).astype(dtype)
    claimed = rng.random(depth.shape) < 0.05
    excluded = {int(ids[1]): rng.random(depth.shape) < 0.2} if seed % 2 else None
    return labels, drawn, claimed, depth, equations, camera, excluded


@pytest.mark.parametrize("seed", range(24))
def test_the_same_labels_as_the_whole_image_reference(seed):
    labels, drawn, claimed, depth, equations, camera, excluded = _scene(seed)
    noise = NoiseSettings(SENSOR_MODELS["kinect_v1"], 3.0, 0.002, 0.1)
    refine = RefineConfig(coherence_limit=(5.0, 2.0, 1.0)[seed % 3])
    got, grown = grow_connected(labels, drawn, claimed, depth, equations, camera, noise, refine, excluded)
    expected, expected_grown = reference_grow_connected(labels, drawn, claimed, depth, equations, camera, noise,
                                                        refine, excluded)
    assert got.dtype == labels.dtype
    np.testing.assert_array_equal(got, expected)
    assert grown == expected_grown
    assert sum(grown.values()) > 0  # the scenes do grow


@pytest.mark.parametrize("seed", range(6))
def test_without_a_window_test_every_candidate_linked_to_the_plane_grows(seed):
    # refine.coherence_window = 0 turns the window test off (as in refinement): the same as a
    # test every candidate passes (no fewest inliers, no limit). It raised in OpenCV's boxFilter.
    labels, drawn, claimed, depth, equations, camera, excluded = _scene(seed)
    noise = NoiseSettings(SENSOR_MODELS["kinect_v1"], 3.0, 0.002, 0.1)
    got, grown = grow_connected(labels, drawn, claimed, depth, equations, camera, noise,
                                RefineConfig(coherence_window=0), excluded)
    expected, expected_grown = reference_grow_connected(
        labels, drawn, claimed, depth, equations, camera, noise,
        RefineConfig(coherence_limit=np.inf, min_window_inliers=0), excluded)
    np.testing.assert_array_equal(got, expected)
    assert grown == expected_grown
    tested, _ = grow_connected(labels, drawn, claimed, depth, equations, camera, noise, RefineConfig(), excluded)
    assert sum(grown.values()) >= np.count_nonzero(tested != labels) > 0

"""Pieces of one gently bent surface: planes that meet without a step or a crease.

A real depth sensor does not see a large flat surface as flat: Kinect-style sensors bend a desk or
a wall by a centimetre or more over a few metres (a systematic, spatially smooth error beyond the
random noise). The detector, whose bands follow the random noise, then cuts one desk into a near
and a far plane a few degrees apart, and fitting one plane to both leaves residuals far above the
noise, so the merge of coplanar pieces (:func:`annotate_rgbd.propose.merge.merge_groups`)
keeps them apart. Where two such pieces meet, though, the surface is continuous: the points
along the seam lie on both planes within the noise band, while at a step (a book on the desk, a
whiteboard on a wall) they lie off the other plane by the step, and at a crease (a wall corner,
a table's edge) the normals differ. :func:`seam_groups` joins the pieces that meet that way.
"""

from __future__ import annotations

import numpy as np

from annotate_rgbd.cvat.rings import sorted_unique
from annotate_rgbd.geometry.camera import Camera


def seam_pairs(labels: np.ndarray, reach: int) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """The pixels where two labels meet: within ``reach`` pixels along a row or a column.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        0 for none, else 1..K.
    reach : int
        Largest gap, in pixels, between two pixels that meet (1: neighbours; 0: nothing meets).

    Returns
    -------
    dict of (int, int) to (ndarray, ndarray)
        For every pair ``(a, b)`` with ``a < b`` that meets, in ascending order: the flat indices
        of ``a``'s pixels and of ``b``'s pixels on the seam (ascending, each pixel once).
    """
    labels = np.asarray(labels)
    height, width = labels.shape
    flat = labels.ravel()
    labelled = flat > 0
    first, second = [], []
    for shift in range(1, reach + 1):
        # Pixel pairs (p, p + step) along rows (step = shift; not across a row's end) and columns.
        for step in (shift, shift * width):
            if step >= flat.size:
                continue
            meet = flat[:-step] != flat[step:]
            meet &= labelled[:-step]
            meet &= labelled[step:]
            at = np.flatnonzero(meet)
            if step == shift:
                at = at[at % width < width - shift]
            first.append(at)
            second.append(at + step)
    if not first:
        return {}
    one, two = np.concatenate(first), np.concatenate(second)
    if one.size == 0:
        return {}
    label_one, label_two = flat[one].astype(np.int64), flat[two].astype(np.int64)
    swap = label_two < label_one
    low_pixel, high_pixel = np.where(swap, two, one), np.where(swap, one, two)
    n = int(flat.max()) + 1
    key = np.minimum(label_one, label_two) * n + np.maximum(label_one, label_two)
    # Each pair's pixels, sorted and unique, for all pairs at once: (pair, pixel) as one integer.
    size = labels.size
    low = sorted_unique(key * size + low_pixel)
    high = sorted_unique(key * size + high_pixel)
    low_key, high_key = low // size, high // size
    keys = sorted_unique(low_key)  # = np.unique(high_key): each meeting adds a pixel to both sides
    low_bounds = np.searchsorted(low_key, keys).tolist() + [len(low)]
    high_bounds = np.searchsorted(high_key, keys).tolist() + [len(high)]
    low_pixels, high_pixels = low % size, high % size
    return {(k // n, k % n): (low_pixels[low_bounds[i] : low_bounds[i + 1]], high_pixels[high_bounds[i] : high_bounds[i + 1]])
            for i, k in enumerate(keys.tolist())}


def seam_groups(
    labels: np.ndarray,
    depth: np.ndarray,
    planes: np.ndarray,
    camera: Camera,
    sigma,
    band_k: float,
    angle_deg: float,
    min_seam: int,
    reach: int,
) -> np.ndarray:
    """Which labels are pieces of one surface that meet without a step or a crease.

    Two labels ``a`` and ``b`` join when they meet along at least ``min_seam`` pixels (of each),
    their planes' normals agree within ``angle_deg``, and the seam pixels of each lie on the
    other's plane within the noise band: mean squared distance at most ``(band_k * sigma(z))**2``
    (the detector's test for a cell against a plane). Joining is transitive (a desk bent in
    three pieces becomes one).

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Planes 1..K.
    depth : ndarray of float, shape (H, W)
        z depth, metres (valid wherever ``labels > 0``).
    planes : ndarray of float, shape (K, 4)
        Plane of label ``k`` in row ``k - 1``, unit normals towards the camera.
    camera : Camera
    sigma : callable
        Axial noise standard deviation at a depth, metres.
    band_k, angle_deg : float
    min_seam : int
        Pixels of each side a seam needs to be tested.
    reach : int
        Pixels between two labels that still meet (see :func:`seam_pairs`).

    Returns
    -------
    ndarray of intp, shape (K,)
        Group of each label: the smallest label (0-based) of its group.
    """
    k = len(planes)
    group = np.arange(k)
    if k < 2:
        return group
    planes = np.asarray(planes, dtype=np.float64)
    cos_limit = np.cos(np.radians(angle_deg))
    width = labels.shape[1]
    z = np.asarray(depth).ravel()  # the seams' pixels alone are read (as float64)
    for (a, b), (pixels_a, pixels_b) in sorted(seam_pairs(labels, reach).items()):
        if min(len(pixels_a), len(pixels_b)) < min_seam or planes[a - 1, :3] @ planes[b - 1, :3] < cos_limit:
            continue
        if _off_plane(pixels_a, planes[b - 1], z, width, camera, sigma) > band_k**2:
            continue
        if _off_plane(pixels_b, planes[a - 1], z, width, camera, sigma) > band_k**2:
            continue
        low, high = sorted((group[a - 1], group[b - 1]))
        group[group == high] = low
    return group


def _off_plane(pixels: np.ndarray, plane: np.ndarray, z: np.ndarray, width: int, camera: Camera, sigma) -> float:
    """Mean squared distance of the pixels' points to ``plane``, in units of ``sigma(z)**2``."""
    rows, cols = np.divmod(pixels, width)
    depth = z[pixels].astype(np.float64)
    points = np.stack([(cols - camera.cx) / camera.fx * depth, (rows - camera.cy) / camera.fy * depth, depth], axis=1)
    distance = points @ plane[:3] + plane[3]
    return float(np.mean((distance / sigma(depth)) ** 2))

"""A fixed palette of clearly distinct plane colours.

Colour ``k`` (for plane id ``k``, from 1) is chosen greedily as the colour of a 16-level RGB grid
farthest in CIELAB from black and from all earlier colours (the idea behind Glasbey et al.,
"Colour displays for categorical images", 2007). The palette is computed, not random: the same
plane id has the same colour on every machine and in every run. Black is reserved for
"unsegmented", and very dark colours, too close to it, are never used.

The grid holds 3,823 such colours. Plane ids beyond take, in a fixed order, the unused colours of
a 64-level grid (multiples of 4): its points ordered coarse to fine (the bits of each channel
reversed), so that nearby ids still tend to differ clearly. No colour is ever used twice, up to
``MAX_PLANES``, the most a 16-bit plane id can number.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from annotate_rgbd.errors import InputError
from annotate_rgbd.io.limits import MAX_PLANES

#: Colours darker than this CIELAB lightness are not used (too close to black = unsegmented).
MIN_LIGHTNESS = 25.0


def plane_colours(count: int) -> np.ndarray:
    """The first ``count`` palette colours.

    Parameters
    ----------
    count : int
        How many colours (one per plane id 1..count).

    Returns
    -------
    ndarray of uint8, shape (count, 3)
        RGB colours, all distinct; row ``k - 1`` is the colour of plane id ``k``.

    Raises
    ------
    InputError
        ``count`` is above ``MAX_PLANES``.
    """
    if count <= 0:
        return np.zeros((0, 3), dtype=np.uint8)
    if count > MAX_PLANES:
        raise InputError(None, f"{count} planes to colour; masks give distinct colours to at most {MAX_PLANES}")
    size = 64
    while size < count:
        size *= 2
    greedy = _palette(min(size, _grid_colours()))
    if count <= len(greedy):
        return greedy[:count].copy()
    return np.concatenate([greedy, _fine_order()[: count - len(greedy)]])


def id_image(labels: np.ndarray, n_planes: int) -> np.ndarray:
    """A mask whose pixel values are plane ids, for tools that want ids rather than colours.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Plane ids, 0 = unsegmented.
    n_planes : int
        Planes in the run: every frame of a run gets the same type, 8-bit up to 255 planes,
        else 16-bit (at most 65,535, as many as the palette has colours).

    Returns
    -------
    ndarray of uint8 or uint16, shape (H, W)
    """
    return labels.astype(np.uint8 if n_planes <= np.iinfo(np.uint8).max else np.uint16)


def colourize(labels: np.ndarray, colours: np.ndarray) -> np.ndarray:
    """Paint a label image with plane colours.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Plane ids, 0 = unsegmented.
    colours : ndarray of uint8, shape (N, 3)
        Colour of plane id ``k`` in row ``k - 1``; N >= the largest id.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        RGB image, black where ``labels`` is 0.
    """
    lookup = np.vstack([np.zeros((1, 3), dtype=np.uint8), colours])
    if len(lookup) <= 256:
        # A table look-up on 8-bit labels is several times faster than fancy indexing.
        table = np.zeros((256, 1, 3), dtype=np.uint8)
        table[: len(lookup), 0] = lookup
        small = labels.astype(np.uint8)
        return cv2.LUT(cv2.merge([small, small, small]), table)
    return lookup[labels]


def colour_hex(colour: np.ndarray) -> str:
    """``#rrggbb`` for an RGB triple."""
    return "#" + "".join(f"{int(c):02x}" for c in colour)


#: sRGB (linear) to CIE XYZ, and the D65 white point for the 2-degree observer: the constants of
#: scikit-image's ``rgb2lab``, whose results :func:`srgb_to_lab` reproduces bit for bit.
XYZ_FROM_RGB = np.array([[0.412453, 0.357580, 0.180423],
                         [0.212671, 0.715160, 0.072169],
                         [0.019334, 0.119193, 0.950227]])
D65_WHITE = np.array([0.95047, 1.0, 1.08883])


def srgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """CIELAB (D65, 2-degree observer) of sRGB colours, as scikit-image's ``rgb2lab`` computes it
    (without importing scikit-image's colour module, a quarter of a second at every start).

    Parameters
    ----------
    rgb : ndarray of float64, shape (N, 3)
        sRGB in [0, 1].

    Returns
    -------
    ndarray of float64, shape (N, 3)
        ``(L, a, b)``.
    """
    linear = np.array(rgb, dtype=np.float64)
    curved = linear > 0.04045
    linear[curved] = np.power((linear[curved] + 0.055) / 1.055, 2.4)
    linear[~curved] /= 12.92
    xyz = (linear @ XYZ_FROM_RGB.T) / D65_WHITE
    steep = xyz > 0.008856
    xyz[steep] = np.cbrt(xyz[steep])
    xyz[~steep] = 7.787 * xyz[~steep] + 16.0 / 116.0
    x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    return np.stack([(116.0 * y) - 16.0, 500.0 * (x - y), 200.0 * (y - z)], axis=-1)


@lru_cache(maxsize=1)
def _grid() -> tuple[np.ndarray, np.ndarray]:
    """The 16-level RGB grid's colours of at least ``MIN_LIGHTNESS``, in grid order, and their CIELAB."""
    levels = np.linspace(0, 255, 16).round().astype(np.uint8)
    grid = np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), axis=-1).reshape(-1, 3)
    lab = srgb_to_lab(grid.astype(np.float64) / 255.0)
    candidates = lab[:, 0] >= MIN_LIGHTNESS
    return grid[candidates], lab[candidates]


def _grid_colours() -> int:
    """How many colours the greedy palette can choose from (3,823)."""
    return len(_grid()[0])


@lru_cache(maxsize=8)
def _palette(count: int) -> np.ndarray:
    """The first ``count`` greedy colours, ``count`` at most :func:`_grid_colours`."""
    grid, lab = _grid()
    # Distance of every candidate to the nearest colour chosen so far, black included.
    nearest = np.linalg.norm(lab, axis=1)
    chosen = np.empty(count, dtype=np.intp)
    for k in range(count):
        chosen[k] = np.argmax(nearest)  # ties: the first in grid order, so the result is fixed
        nearest = np.minimum(nearest, np.linalg.norm(lab - lab[chosen[k]], axis=1))
    palette = grid[chosen]
    palette.setflags(write=False)
    return palette


@lru_cache(maxsize=1)
def _fine_order() -> np.ndarray:
    """The 64-level grid's colours (multiples of 4) of at least ``MIN_LIGHTNESS`` that the greedy
    palette does not use, coarse to fine.

    Point ``i`` of the grid has as its channels' bits, most significant first, the bits of ``i``
    read from the least significant (a bit-reversed Morton order): the first 8 points are the
    2-level grid, the first 64 the 4-level grid, and so on, each level filling the gaps of the
    one before.
    """
    from skimage.color import rgb2lab

    index = np.arange(64**3, dtype=np.int64)
    channels = np.zeros((len(index), 3), dtype=np.int64)
    for bit in range(6):  # bit b of channel c is bit 3 * b + c of i, from the most significant
        for c in range(3):
            channels[:, c] |= ((index >> (3 * bit + c)) & 1) << (7 - bit)
    colours = channels.astype(np.uint8)
    bright = rgb2lab(colours[None].astype(np.float64) / 255.0)[0][:, 0] >= MIN_LIGHTNESS
    used = _pack(_palette(_grid_colours()))
    return colours[bright & ~np.isin(_pack(colours), used)]


def _pack(colours: np.ndarray) -> np.ndarray:
    return (colours[:, 0].astype(np.int64) << 16) | (colours[:, 1].astype(np.int64) << 8) | colours[:, 2]

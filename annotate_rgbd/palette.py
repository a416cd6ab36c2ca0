"""A fixed palette of clearly distinct plane colours.

Colour ``k`` (for plane id ``k``, from 1) is chosen greedily as the colour of a 16-level RGB grid
farthest in CIELAB from black and from all earlier colours (the idea behind Glasbey et al.,
"Colour displays for categorical images", 2007). The palette is computed, not random: the same
plane id has the same colour on every machine and in every run. Black is reserved for
"unsegmented", and very dark colours, too close to it, are never used.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

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
        RGB colours; row ``k - 1`` is the colour of plane id ``k``.
    """
    if count <= 0:
        return np.zeros((0, 3), dtype=np.uint8)
    size = 64
    while size < count:
        size *= 2
    return _palette(size)[:count].copy()


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


@lru_cache(maxsize=8)
def _palette(count: int) -> np.ndarray:
    from skimage.color import rgb2lab  # here: worker processes only colour masks, never build palettes

    levels = np.linspace(0, 255, 16).round().astype(np.uint8)
    grid = np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), axis=-1).reshape(-1, 3)
    lab = rgb2lab(grid[None].astype(np.float64) / 255.0)[0]
    candidates = lab[:, 0] >= MIN_LIGHTNESS
    grid, lab = grid[candidates], lab[candidates]
    # Distance of every candidate to the nearest colour chosen so far, black included.
    nearest = np.linalg.norm(lab, axis=1)
    chosen = np.empty(count, dtype=np.intp)
    for k in range(count):
        chosen[k] = np.argmax(nearest)  # ties: the first in grid order, so the result is fixed
        nearest = np.minimum(nearest, np.linalg.norm(lab - lab[chosen[k]], axis=1))
    palette = grid[chosen]
    palette.setflags(write=False)
    return palette

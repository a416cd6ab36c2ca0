"""Whether a shape's geometry is usable: coordinates, area, self-crossings, mask and box sizes.

Pure functions over numpy arrays; each returns the reason a shape is skipped, or None.
"""

from __future__ import annotations

import numpy as np

from .format import MAX_COORDINATE, MAX_MASK_PIXELS


def polygon_problem(points: np.ndarray) -> str | None:
    if len(points) < 3:
        return "polygon with fewer than 3 points"
    problem = _coordinate_problem(points)
    if problem is not None:
        return problem
    # Zero area: every triangle of the fan from the first vertex is flat, so the polygon covers
    # nothing. (Its signed area is no test: the lobes of a figure of eight cancel out.)
    d = points[1:] - points[0]
    if np.abs(d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]).sum() < 1e-9:
        return "polygon with zero area"
    return None


def crosses_itself(points: np.ndarray) -> bool:
    """Whether two edges of the closed polygon properly cross (not merely touch).

    Edges i and j cross when the ends of each lie strictly on opposite sides of the other;
    neighbouring edges share a vertex, which lies on neither side, so they never count. All
    pairs are tested at once, in blocks of rows to bound memory.
    """
    if len(points) < 4:
        return False
    start = points
    end = np.concatenate([points[1:], points[:1]])
    along = end - start
    for first in range(0, len(points), 512):
        block = slice(first, first + 512)
        # Ends of every edge against the block's edges, and the block's ends against every edge.
        others_straddle = _straddles(start[block], along[block], start, end)
        block_straddles = _straddles(start, along, start[block], end[block]).T
        if (others_straddle & block_straddles).any():
            return True
    return False


def _straddles(
    origin: np.ndarray, along: np.ndarray, first: np.ndarray, second: np.ndarray
) -> np.ndarray:
    """``[i, j]``: points ``first[j]`` and ``second[j]`` lie strictly on opposite sides of the
    line through ``origin[i]`` along ``along[i]``."""
    def side(points: np.ndarray) -> np.ndarray:
        dx = points[None, :, 0] - origin[:, None, 0]
        dy = points[None, :, 1] - origin[:, None, 1]
        return along[:, None, 0] * dy - along[:, None, 1] * dx

    return side(first) * side(second) < 0


def _coordinate_problem(points: np.ndarray) -> str | None:
    largest = np.abs(points).max()
    if not np.isfinite(largest):
        return "non-finite coordinates"
    if largest > MAX_COORDINATE:
        return f"coordinates beyond {MAX_COORDINATE:.0f} pixels"
    return None


def mask_problem(
    runs: np.ndarray, width: int, height: int, image_size: tuple[int, int] | None
) -> str | None:
    if width < 1 or height < 1 or np.any(runs < 0) or runs.sum() != width * height:
        return "mask RLE runs do not add up to width x height"
    if image_size is not None and (width > image_size[0] or height > image_size[1]):
        return "mask larger than the image"
    if image_size is None and width * height > MAX_MASK_PIXELS:
        return f"mask larger than {MAX_MASK_PIXELS} pixels"
    return None


def box_problem(corners: np.ndarray, rotation: float) -> str | None:
    problem = _coordinate_problem(corners)
    if problem is not None:
        return problem
    if not np.isfinite(rotation):
        return "non-finite coordinates"
    (xtl, ytl), (xbr, ybr) = corners
    if xbr <= xtl or ybr <= ytl:
        return "box with xbr <= xtl or ybr <= ytl"
    return None

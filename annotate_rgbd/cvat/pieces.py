"""The pieces of a label mask: their boxes, which of them an outline covers, the corridors
that join them into one region, and the pixels that make that region well-composed.

:mod:`annotate_rgbd.cvat.from_masks` traces and simplifies the regions these functions build (its
docstring tells why: a traced outline of a region whose pixels meet along edges never touches
itself); ``propose`` outlines its planes' pieces with them too.
"""

from __future__ import annotations

import cv2
import numpy as np

#: Up to so many labels, :func:`label_boxes` finds each label's box by its own pass over the image.
_FEW_LABELS = 64
#: The 4-neighbourhood: a border pixel has a neighbour outside across an edge.
_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


def label_boxes(labels: np.ndarray, n: int | None = None) -> list:
    """The bounding box of each label 1..n, as ``scipy.ndimage.find_objects`` gives them.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Labels >= 0 (0: none).
    n : int, optional
        Largest label (default: the image's largest).

    Returns
    -------
    list of (slice, slice) or None
        ``(rows, cols)`` of label ``k`` at position ``k - 1``; None for a label not present.
    """
    labels = np.asarray(labels)
    n = int(labels.max(initial=0)) if n is None else int(n)
    if n <= _FEW_LABELS:
        boxes = []
        for k in range(1, n + 1):
            left, top, width, height = cv2.boundingRect((labels == k).view(np.uint8))
            boxes.append((slice(top, top + height), slice(left, left + width)) if width else None)
        return boxes
    # Many labels: one pass over the labelled pixels, grouped by label.
    flat = labels.ravel()
    at = np.flatnonzero((flat > 0) & (flat <= n))
    order = np.argsort(flat[at], kind="stable")
    at, found = at[order], flat[at][order].astype(np.int64)
    starts = np.flatnonzero(np.diff(found, prepend=-1))
    rows, cols = np.divmod(at, labels.shape[1])
    low_row, high_row = rows[starts], np.maximum.reduceat(rows, starts)  # rows ascend within a label
    low_col, high_col = np.minimum.reduceat(cols, starts), np.maximum.reduceat(cols, starts)
    boxes: list = [None] * n
    for i, k in enumerate(found[starts].tolist()):
        boxes[k - 1] = (slice(int(low_row[i]), int(high_row[i]) + 1), slice(int(low_col[i]), int(high_col[i]) + 1))
    return boxes


def join_pieces(mask: np.ndarray, min_piece: int | None, most: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """One 4-connected region from the pieces of a mask.

    Parameters
    ----------
    mask : ndarray of bool, shape (H, W)
    min_piece : int or None
        Keep the 8-connected pieces of at least this many pixels (the largest when none is),
        joined by corridors; None: the largest piece only.
    most : int
        Keep at most this many pieces, the largest (0: no limit).

    Returns
    -------
    region : ndarray of bool, shape (H, W)
        The kept pieces, the corridors between them, and a pixel beside every two pixels that
        touch only at a corner (:func:`close_corners`).
    corridors : ndarray of bool, shape (H, W)
        The corridors' pixels outside the pieces.
    """
    region, pieces, kept = kept_pieces(mask, min_piece, most)
    corridors = np.zeros(mask.shape, dtype=bool)
    if len(kept) > 1:
        lines = np.zeros(mask.shape, dtype=np.uint8)
        for a, b in piece_corridors(region, pieces, kept):
            cv2.line(lines, a, b, 1, thickness=1, lineType=4)
        corridors = (lines > 0) & ~region
        region = region | corridors
    return close_corners(region), corridors


def kept_pieces(mask: np.ndarray, min_piece: int | None, most: int = 0) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """The pieces of a mask to outline (see :func:`join_pieces`): their pixels, the piece labels
    and the kept pieces' labels, largest first (ties: lowest label, first in raster order)."""
    mask = np.asarray(mask, dtype=bool)
    count, pieces = cv2.connectedComponents(mask.view(np.uint8), connectivity=8, ltype=cv2.CV_32S)
    if count <= 1:
        return np.zeros(mask.shape, dtype=bool), pieces, []
    if count == 2:  # one piece: the mask itself
        return mask.copy(), pieces, [1]
    # Sizes counted here: OpenCV's statistics take several times as long as the labelling.
    sizes = np.bincount(pieces[mask], minlength=count)[1:]
    largest = int(np.argmax(sizes)) + 1
    kept = [largest] if min_piece is None else [largest] + [
        k + 1 for k in np.argsort(-sizes, kind="stable").tolist() if sizes[k] >= min_piece and k + 1 != largest]
    if most:
        kept = kept[:most]
    if len(kept) == 1:
        return pieces == largest, pieces, kept
    chosen = np.zeros(count, dtype=bool)
    chosen[kept] = True
    return np.take(chosen, pieces), pieces, kept  # np.take: a few times faster than indexing


def piece_corridors(region: np.ndarray, pieces: np.ndarray, kept: list[int]) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """Where to draw the corridors that join the pieces: from each piece, in the order Prim's
    algorithm takes them from the first, to the nearest border pixel of the pieces taken before.

    Parameters
    ----------
    region : ndarray of bool, shape (H, W)
        The kept pieces.
    pieces : ndarray of int, shape (H, W)
        Piece labels (connected components).
    kept : list of int
        The pieces to join, the first one first.

    Returns
    -------
    list of ((int, int), (int, int))
        ``(x, y)`` pixel pairs, one per piece after the first.
    """
    inner = cv2.erode(region.view(np.uint8), _CROSS, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    border = region & (inner == 0)
    at = np.flatnonzero(border)
    ys, xs = np.divmod(at, border.shape[1])
    owner = pieces.ravel()[at]
    order = np.argsort(owner, kind="stable")
    ordered, owners = np.stack([xs, ys], axis=1)[order], owner[order]
    points = {k: ordered[np.searchsorted(owners, k, "left") : np.searchsorted(owners, k, "right")] for k in kept}
    # best[k]: (distance, k's border pixel, the joined piece, its border pixel) nearest so far.
    best: dict[int, tuple[float, int, int, int]] = {}
    corridors = []
    from scipy.spatial import cKDTree  # here: SciPy takes a while to load, and only planes of several pieces need it

    boxes = {k: (points[k].min(axis=0).tolist(), points[k].max(axis=0).tolist()) for k in kept}
    joined = kept[0]
    remaining = list(kept[1:])
    while remaining:
        tree = None  # built when a piece asks
        low, high = (np.array(v) for v in boxes[joined])
        for k in remaining:
            # Only a nearer pair than the best so far matters: the search stops at its distance.
            bound = best[k][0] if k in best else np.inf
            if np.isfinite(bound) and _box_gap2(boxes[k], boxes[joined]) > bound * bound + 1e-6:
                continue  # the pieces' boxes lie farther apart than that
            # Only k's pixels no farther from the joined piece's box than that (or than the
            # pixel nearest the box is from the piece) can be nearest: the tree answers each
            # pixel on its own, so asking for these alone finds the same pixel and partner.
            tree = cKDTree(points[joined]) if tree is None else tree
            gap = np.maximum(np.maximum(low - points[k], points[k] - high), 0)
            box2 = gap[:, 0] * gap[:, 0] + gap[:, 1] * gap[:, 1]
            if not np.isfinite(bound):
                bound_px = int(np.argmin(box2))
                reach = float(tree.query(points[k][bound_px])[0])
            else:
                reach = bound
            near = np.flatnonzero(box2 <= reach * reach + 1e-6)
            if len(near) == 0:
                continue
            distance, index = tree.query(points[k][near], distance_upper_bound=bound)
            i = int(np.argmin(distance))
            if distance[i] < bound:
                best[k] = (float(distance[i]), int(near[i]), joined, int(index[i]))
        joined = min(remaining, key=lambda k: (best[k][0], kept.index(k)))
        _, i, other, j = best[joined]
        corridors.append((tuple(int(v) for v in points[joined][i]), tuple(int(v) for v in points[other][j])))
        remaining.remove(joined)
    return corridors


def _box_gap2(a: tuple, b: tuple) -> int:
    """Squared distance between two boxes ``((x0, y0), (x1, y1))`` of integer points."""
    dx = max(a[0][0] - b[1][0], b[0][0] - a[1][0], 0)
    dy = max(a[0][1] - b[1][1], b[0][1] - a[1][1], 0)
    return dx * dx + dy * dy


def close_corners(region: np.ndarray) -> np.ndarray:
    """Fill, where two pixels of a region touch only at a corner, the pixel beside them to the
    upper right (or upper left), until no such corner is left.

    Parameters
    ----------
    region : ndarray of bool, shape (H, W)

    Returns
    -------
    ndarray of bool, shape (H, W)
        A region whose pieces are 4-connected (well-composed), a superset of ``region``.
    """
    region = region.copy()
    height, width = region.shape
    if height < 2 or width < 2:
        return region
    a, b, c, d = region[:-1, :-1], region[:-1, 1:], region[1:, :-1], region[1:, 1:]
    # The 2 x 2 blocks (by their upper left pixel) where two pixels touch at a corner only.
    falling = np.flatnonzero(a & d & ~b & ~c)  # upper left and lower right
    rising = np.flatnonzero(b & c & ~a & ~d)  # upper right and lower left
    rows, cols = np.divmod(np.concatenate([falling, rising]), width - 1)
    while len(rows):
        cols[: len(falling)] += 1  # falling: fill the upper right pixel; rising: the upper left
        region[rows, cols] = True
        # A block that had such a corner got a pixel: only blocks holding a filled pixel can
        # have one now.
        rows = np.concatenate([rows - 1, rows - 1, rows, rows])
        cols = np.concatenate([cols - 1, cols, cols - 1, cols])
        inside = (rows >= 0) & (rows < height - 1) & (cols >= 0) & (cols < width - 1)
        rows, cols = rows[inside], cols[inside]
        a, b, c, d = region[rows, cols], region[rows, cols + 1], region[rows + 1, cols], region[rows + 1, cols + 1]
        fall, rise = a & d & ~b & ~c, b & c & ~a & ~d
        falling = np.flatnonzero(fall)
        rows, cols = np.concatenate([rows[fall], rows[rise]]), np.concatenate([cols[fall], cols[rise]])
    return region

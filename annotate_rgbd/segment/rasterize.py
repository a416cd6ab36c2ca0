"""Shapes -> plane label image on the depth grid.

A pixel belongs to a shape when its centre lies inside it. In CVAT coordinates the image's
top-left corner is (0, 0), so the centre of pixel ``(col, row)`` is ``(col + 0.5, row + 0.5)``.
A centre exactly on an outline belongs to the shape on the outline's top and left sides only
(half-open spans, the usual rasterisation rule), so two polygons that share an edge never share
a pixel. Polygons are filled with the even-odd rule, as CVAT draws them.

TUM and ICL-NUIM depth images are registered to the RGB images, so the labeller's pixel
coordinates carry over to the depth grid unchanged. When a colour camera of its own is
configured, the shapes are drawn on the colour grid and every depth pixel takes the label of
the colour pixel its 3-D point projects to (:func:`draw_on_depth_grid`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Sequence

import cv2
import numpy as np

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.geometry.registration import ColourCamera, colour_pixel_grid, sample_labels


#: The drawing order below every drawn shape (CVAT's z_order is a 32-bit integer).
BOTTOM_Z_ORDER = -(2**31)


def rasterize_frame(shapes: Iterable[tuple[int, Shape]], height: int, width: int) -> np.ndarray:
    """Draw one frame's shapes into a label image.

    Shapes are drawn in ascending ``z_order``; at equal ``z_order`` later shapes (later tracks in
    the export) are drawn on top, as CVAT shows them.

    Parameters
    ----------
    shapes : iterable of (int, Shape)
        ``(plane id, shape)`` pairs in track order; plane ids are > 0.
    height, width : int
        Size of the depth image.

    Returns
    -------
    ndarray of uint8, uint16 or int32, shape (height, width)
        The plane id on top at each pixel, 0 where no shape covers it; the smallest of these
        types that holds the largest id (uint8 for the usual < 256 planes: every later pass
        over the image moves a quarter of the bytes).
    """
    shapes = list(shapes)
    labels = np.zeros((height, width), dtype=label_dtype(max((pid for pid, _ in shapes), default=0)))
    ordered = sorted(shapes, key=lambda item: item[1].z_order)  # stable: keeps track order
    # Every polygon's spans in one pass (a frame has a few to a few hundred).
    polygons = [k for k, (_, shape) in enumerate(ordered) if shape.kind == "polygon"]
    spans = polygon_spans([ordered[k][1].points for k in polygons], height, width)
    index = {k: j for j, k in enumerate(polygons)}
    for k, (plane_id, shape) in enumerate(ordered):
        top, left, inside = fill_spans(spans, index[k]) if k in index else shape_mask(shape, height, width)
        rows, cols = inside.shape
        np.copyto(labels[top : top + rows, left : left + cols], plane_id, where=inside)
    return labels


def draw_on_depth_grid(
    shapes: Iterable[tuple[int, Shape]], depth_m: np.ndarray, depth_camera: Camera, colour: ColourCamera | None
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
    """Draw one frame's shapes, drawn on the colour image, onto the depth grid.

    Parameters
    ----------
    shapes : iterable of (int, Shape)
        ``(plane id, shape)`` pairs in track order, in colour image coordinates.
    depth_m : ndarray of float, shape (H, W)
        The depth frame in metres (NaN where invalid).
    depth_camera : Camera
    colour : ColourCamera or None
        None: colour and depth share one pixel grid (registered).

    Returns
    -------
    labels : ndarray, shape (H, W)
        As :func:`rasterize_frame` on the depth grid. With a colour camera, the shapes are
        rasterised on the colour grid and each depth pixel takes the label at its position
        there (:func:`annotate_rgbd.geometry.registration.colour_pixel_grid`).
    grid : (ndarray, ndarray) or None
        That position, ``(map_x, map_y)`` of float32 (H, W), for resampling the colour image
        onto the depth grid; None without a colour camera.
    """
    height, width = depth_m.shape
    if colour is None:
        return rasterize_frame(shapes, height, width), None
    map_x, map_y = colour_pixel_grid(depth_m, depth_camera, colour)
    return sample_labels(rasterize_frame(shapes, colour.height, colour.width), map_x, map_y), (map_x, map_y)


def label_dtype(largest: int) -> np.dtype:
    """The smallest label image type for plane ids up to ``largest``."""
    for dtype in (np.uint8, np.uint16):
        if largest <= np.iinfo(dtype).max:
            return np.dtype(dtype)
    return np.dtype(np.int32)


def shape_mask(shape: Shape, height: int, width: int) -> tuple[int, int, np.ndarray]:
    """The pixels of a shape, as a boolean window of the image.

    Parameters
    ----------
    shape : Shape
        A polygon, box or mask.
    height, width : int
        Image size.

    Returns
    -------
    top, left : int
        Position of the window in the image.
    inside : ndarray of bool, shape (rows, cols)
        ``True`` for the pixels of the window whose centres lie inside the shape; the window
        lies within the image (it may be empty).
    """
    if shape.kind == "polygon":
        return polygon_window(shape.points, height, width)
    if shape.kind == "box":
        (xtl, ytl), (xbr, ybr) = shape.points
        left, right = _span(xtl, xbr, width)
        top, bottom = _span(ytl, ybr, height)
        return top, left, np.ones((max(bottom - top, 0), max(right - left, 0)), dtype=bool)
    if shape.kind == "mask":
        left, top = (int(round(v)) for v in shape.points[0])
        rows, cols = shape.bitmap.shape
        row0, row1 = max(top, 0), min(top + rows, height)
        col0, col1 = max(left, 0), min(left + cols, width)
        if row1 <= row0 or col1 <= col0:
            return 0, 0, np.zeros((0, 0), dtype=bool)
        return row0, col0, shape.bitmap[row0 - top : row1 - top, col0 - left : col1 - left]
    raise ValueError(f"unsupported shape kind {shape.kind!r}")


def polygon_window(points: np.ndarray, height: int, width: int) -> tuple[int, int, np.ndarray]:
    """Fill a polygon: the pixels whose centres are inside, in the window of the image it spans.

    :func:`polygon_spans` of the one polygon, filled (:func:`fill_spans`).

    Parameters
    ----------
    points : ndarray, shape (N, 2)
        Vertices (x, y) in CVAT coordinates.
    height, width : int
        Image size.

    Returns
    -------
    top, left : int
        Position of the window in the image.
    inside : ndarray of bool, shape (rows, cols)
        The polygon's pixels in the window (which lies within the image; it may be empty).
    """
    spans = polygon_spans([points], height, width)
    return fill_spans(spans, 0)


@dataclass(frozen=True)
class PolygonSpans:
    """The inside spans of several polygons (:func:`polygon_spans`).

    Parameters
    ----------
    top, bottom : ndarray of int64, shape (P,)
        First and last image row of each polygon's window (``bottom < top``: the polygon lies
        outside the image).
    start : ndarray of int64, shape (P + 1,)
        Polygon ``p``'s spans are ``start[p]`` to ``start[p + 1]`` of the arrays below.
    row : ndarray of int64, shape (S,)
        Image row of each span.
    first, stop : ndarray of int32, shape (S,)
        Columns ``first`` to ``stop - 1`` are inside (``first < stop``); the spans of one
        polygon's row are disjoint and in ascending order.
    """

    top: np.ndarray
    bottom: np.ndarray
    start: np.ndarray
    row: np.ndarray
    first: np.ndarray
    stop: np.ndarray


def polygon_spans(polygons: Sequence[np.ndarray], height: int, width: int) -> PolygonSpans:
    """The pixels of several polygons as spans of rows: the pixels whose centres are inside.

    Scanline fill, vectorised over the edges of all the polygons at once: each edge crosses the
    pixel-centre lines of the rows it spans (half-open in y), at one x each; sorted by polygon,
    row and x, pairs of crossings bound the inside spans. The work grows with the crossings
    (about twice the rows for a convex outline), not with rows times vertices, and a few dozen
    array operations serve all the polygons (the layers carried to a frame are a hundred).

    Parameters
    ----------
    polygons : sequence of ndarray, shape (N, 2)
        Vertices (x, y) in CVAT coordinates (pixel ``(col, row)`` has its centre at
        ``(col + 0.5, row + 0.5)``).
    height, width : int
        Image size.

    Returns
    -------
    PolygonSpans
    """
    count = len(polygons)
    sizes = np.array([len(p) for p in polygons], dtype=np.int64)
    vertices = (np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in polygons])
                if count else np.zeros((0, 2)))
    first_vertex = np.cumsum(sizes) - sizes
    top = np.zeros(count, dtype=np.int64)
    bottom = np.full(count, -1, dtype=np.int64)
    used = sizes > 0
    x0, y0 = vertices[:, 0], vertices[:, 1]
    if used.any():
        low = np.minimum.reduceat(y0, first_vertex[used])
        high = np.maximum.reduceat(y0, first_vertex[used])
        top[used] = np.maximum(np.floor(low - 0.5), 0)
        bottom[used] = np.minimum(np.ceil(high - 0.5), height - 1)
    # Each edge's end: the next vertex, the first one after the last.
    following = np.arange(1, len(vertices) + 1)
    following[first_vertex[used] + sizes[used] - 1] = first_vertex[used]
    x1, y1 = x0[following], y0[following]
    polygon = np.repeat(np.arange(count), sizes)
    edge_top, edge_bottom = top[polygon], bottom[polygon]
    # An edge counts for the rows whose centre r + 0.5 lies in [min(y0, y1), max(y0, y1)): r from
    # ceil(min - 0.5) to ceil(max - 0.5) - 1 (none for a horizontal edge), within its window.
    first_row = np.clip(np.ceil(np.minimum(y0, y1) - 0.5), edge_top, edge_bottom + 1).astype(np.int64)
    stop_row = np.clip(np.ceil(np.maximum(y0, y1) - 0.5), edge_top, edge_bottom + 1).astype(np.int64)
    spanned = np.where(edge_bottom >= edge_top, stop_row - first_row, 0)
    edges = np.flatnonzero(spanned > 0)
    counts = spanned[edges]
    edge = np.repeat(edges, counts)
    offsets = np.cumsum(counts) - counts
    rows = first_row[edge] + (np.arange(edge.size) - np.repeat(offsets, counts))
    centre_y = rows + 0.5
    xs = x0[edge] + (centre_y - y0[edge]) * (x1[edge] - x0[edge]) / (y1[edge] - y0[edge])
    owner = polygon[edge]
    order = np.lexsort((xs, rows, owner))
    rows, xs, owner = rows[order], xs[order], owner[order]
    # Pairs within a polygon's row: crossings 0-1, 2-3, ... (a row's last crossing without a
    # partner, on a degenerate outline, bounds nothing).
    key = owner * (height + 1) + rows
    row_start = np.searchsorted(key, key, side="left")
    start = np.flatnonzero(((np.arange(key.size) - row_start) % 2 == 0)[:-1] & (key[1:] == key[:-1]))
    # Pixels with centre c + 0.5 in [start, end): c from ceil(start - 0.5) to ceil(end - 0.5) - 1.
    first = np.ceil(xs[start] - 0.5).clip(0, width).astype(np.int32)
    stop = np.ceil(xs[start + 1] - 0.5).clip(0, width).astype(np.int32)
    filled = stop > first
    owner = owner[start][filled]
    return PolygonSpans(top, bottom, np.searchsorted(owner, np.arange(count + 1)), rows[start][filled],
                        first[filled], stop[filled])


def fill_spans(spans: PolygonSpans, index: int) -> tuple[int, int, np.ndarray]:
    """One polygon of :func:`polygon_spans` as a boolean window of the image.

    Returns
    -------
    top, left : int
        Position of the window in the image: its rows are the polygon's rows, its columns those
        its spans reach.
    inside : ndarray of bool, shape (rows, cols)
        Empty (0, 0) when no pixel centre lies inside.
    """
    a, b = int(spans.start[index]), int(spans.start[index + 1])
    if b == a:
        return 0, 0, np.zeros((0, 0), dtype=bool)
    top = int(spans.top[index])
    span_rows, first, stop = spans.row[a:b] - top, spans.first[a:b], spans.stop[a:b]
    left, right = int(first.min()), int(stop.max())
    # +1 where a span starts, -1 where it stops (a row's spans are disjoint: no two starts nor two
    # stops share a pixel), summed along each row: inside where the sum is positive. The row sums
    # are differences of OpenCV's integral image (exact: small integers in float32).
    steps = np.zeros((int(spans.bottom[index]) - top + 1, right - left + 1), dtype=np.float32)
    steps[span_rows, first - left] += 1
    steps[span_rows, stop - left] -= 1
    total = cv2.integral(steps, sdepth=cv2.CV_32F)
    inside = (total[1:, 1:-1] - total[:-1, 1:-1]) > 0.5
    return top, left, inside


def fill_window(polygon: np.ndarray, height: int, width: int) -> tuple[int, int, np.ndarray]:
    """The pixels of a polygon, as a boolean window of the image, filled by OpenCV.

    A fast stand-in for :func:`shape_mask` where a pixel more or less on
    the outline does not matter (draw order, drop statistics, overlap of reprojected outlines):
    ``cv2.fillPoly`` at 1/16 pixel takes the outline's pixels too, and is ~20x faster on the
    long outlines of real planes.

    Parameters
    ----------
    polygon : ndarray, shape (V, 2)
        CVAT image coordinates (pixel ``(col, row)`` has its centre at ``(col + 0.5, row + 0.5)``).
    height, width : int

    Returns
    -------
    top, left : int
    window : ndarray of bool, shape (rows, cols)
        Empty when the polygon lies outside the image.
    """
    points = np.asarray(polygon, dtype=np.float64) - 0.5  # OpenCV puts pixel centres at integers
    left = int(np.clip(np.floor(points[:, 0].min()), 0, width))
    right = int(np.clip(np.ceil(points[:, 0].max()) + 1, 0, width))
    top = int(np.clip(np.floor(points[:, 1].min()), 0, height))
    bottom = int(np.clip(np.ceil(points[:, 1].max()) + 1, 0, height))
    window = np.zeros((max(bottom - top, 0), max(right - left, 0)), dtype=np.uint8)
    if window.size:
        fixed = np.round((points - (left, top)) * 16).astype(np.int32)
        cv2.fillPoly(window, [fixed.reshape(-1, 1, 2)], 1, lineType=cv2.LINE_8, shift=4)
    return top, left, window.view(bool)


def _span(low: float, high: float, size: int) -> tuple[int, int]:
    """Pixel range [first, stop) whose centres lie in [low, high), clipped to [0, size)."""
    first = min(max(int(np.ceil(low - 0.5)), 0), size)
    stop = min(max(int(np.ceil(high - 0.5)), 0), size)
    return first, stop


def paint_layers(layers: Iterable[tuple[int, np.ndarray]], height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Paint signed polygons in order, each over the ones before: what the last one covering a
    pixel says decides it.

    Parameters
    ----------
    layers : iterable of (int, ndarray of shape (V, 2))
        ``(+1, polygon)`` (the plane is there) or ``(-1, polygon)`` (it is not), in CVAT image
        coordinates, the least trusted first.
    height, width : int
        Image size.

    Returns
    -------
    inside, excluded : ndarray of bool, shape (height, width)
        Pixels whose last covering polygon is positive, and negative; neither where none
        covers them.
    """
    top, left, verdict = paint_window(layers, height, width)
    inside = np.zeros((height, width), dtype=bool)
    excluded = np.zeros((height, width), dtype=bool)
    rows, cols = verdict.shape
    np.greater(verdict, 0, out=inside[top : top + rows, left : left + cols])
    np.less(verdict, 0, out=excluded[top : top + rows, left : left + cols])
    return inside, excluded


def paint_window(layers: Iterable[tuple[int, np.ndarray]], height: int, width: int) -> tuple[int, int, np.ndarray]:
    """:func:`paint_layers` on the window of the image the polygons span.

    Returns
    -------
    top, left : int
        Position of the window in the image.
    verdict : ndarray of int8, shape (rows, cols)
        +1 where the last covering polygon is positive, -1 where it is negative, 0 where none
        covers the pixel (the window may be empty).
    """
    layers = list(layers)
    spans = polygon_spans([polygon for _, polygon in layers], height, width)
    windows = []
    for index, (sign, _) in enumerate(layers):
        top, left, inside = fill_spans(spans, index)
        if inside.size:
            windows.append((np.int8(1 if sign > 0 else -1), top, left, inside))
    if not windows:
        return 0, 0, np.zeros((0, 0), dtype=np.int8)
    top = min(w[1] for w in windows)
    left = min(w[2] for w in windows)
    bottom = max(w[1] + w[3].shape[0] for w in windows)
    right = max(w[2] + w[3].shape[1] for w in windows)
    verdict = np.zeros((bottom - top, right - left), dtype=np.int8)
    for sign, row, col, inside in windows:
        rows, cols = inside.shape
        np.copyto(verdict[row - top : row - top + rows, col - left : col - left + cols], sign, where=inside)
    return top, left, verdict


def carried_shapes(
    shapes: Sequence[tuple[int, Shape]], carried: Sequence[tuple], height: int, width: int
) -> tuple[list[tuple[int, Shape]], dict[int, np.ndarray]]:
    """A frame's shapes with what camera poses carried to it among them, as mask shapes.

    Parameters
    ----------
    shapes : sequence of (int, Shape)
        The frame's shapes, in track order.
    carried : sequence of (int, int, int, layers, beyond)
        ``(position, plane id, z_order, layers, beyond)`` per carried plane
        (:func:`annotate_rgbd.propagate.carry.carried_layers`): ``layers`` are signed polygons
        for :func:`paint_layers`, ``beyond`` polygons past the keyframes' views.
    height, width : int
        The grid the shapes are drawn on.

    Returns
    -------
    shapes : list of (int, Shape)
        ``shapes`` with, before the one at each ``position``, the carried plane's pixels (what
        its keyframes say it covers, at its ``z_order``) and, below every other shape
        (:data:`BOTTOM_Z_ORDER`), what lies beyond their views but for what they exclude.
    excluded : dict of int to ndarray of bool, shape (height, width)
        Per carried plane, the pixels its keyframes say it does not cover.
    """
    shapes = list(shapes)
    excluded: dict[int, np.ndarray] = {}
    for position, plane_id, z_order, layers, beyond in reversed(list(carried)):  # later positions first
        # Painted on the window the polygons span, not on the whole image: what the keyframes
        # say (+1 inside, -1 excluded), and past their views (2) where they say nothing.
        said_window = paint_window(layers, height, width)
        beyond_window = paint_window([(1, quad) for quad in beyond], height, width)
        painted = [w for w in (beyond_window, said_window) if w[2].size]
        if not painted:
            continue
        top, left = min(w[0] for w in painted), min(w[1] for w in painted)
        bottom = max(w[0] + w[2].shape[0] for w in painted)
        right = max(w[1] + w[2].shape[1] for w in painted)
        said = np.zeros((bottom - top, right - left), dtype=np.int8)
        for (row, col, verdict), weight in ((beyond_window, 2), (said_window, 1)):
            rows, cols = verdict.shape
            np.copyto(said[row - top : row - top + rows, col - left : col - left + cols], verdict * np.int8(weight),
                      where=verdict != 0)
        outside = said == -1
        for mask, z in ((said == 2, BOTTOM_Z_ORDER), (said == 1, z_order)):  # inserted in reverse
            if mask.any():
                corner = np.array([[left, top]], dtype=np.float64)
                shapes.insert(position, (plane_id, Shape("mask", corner, z_order=z, bitmap=mask)))
        if outside.any():
            full = np.zeros((height, width), dtype=bool)
            full[top:bottom, left:right] = outside
            excluded[plane_id] = full | excluded[plane_id] if plane_id in excluded else full
    return shapes, excluded

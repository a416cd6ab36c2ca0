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

from typing import Iterable, Sequence

import cv2
import numpy as np

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.geometry.registration import ColourCamera, colour_pixel_grid, sample_labels
from .spans import fill_spans, polygon_spans


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
    return paint_values([polygon for _, polygon in layers], [1 if sign > 0 else -1 for sign, _ in layers],
                        height, width)


def paint_values(polygons: Sequence[np.ndarray], values: Sequence[int], height: int,
                 width: int) -> tuple[int, int, np.ndarray]:
    """Paint polygons in order, each with its value, over the ones before, on the window of the
    image they span.

    The work grows with the polygons' spans, not with their pixels: a span toggles its polygon's
    bit where it starts and where it stops; between toggles, an exclusive or over them gives the
    polygons holding the pixels, the highest bit the last of them, and that polygon's value
    fills the stretch.

    Parameters
    ----------
    polygons : sequence of ndarray, shape (V, 2)
        In CVAT image coordinates, the one painted first first.
    values : sequence of int
        Each polygon's value, non-zero, within int8.
    height, width : int
        Image size.

    Returns
    -------
    top, left : int
        Position of the window in the image: the rows of the polygons that hold a pixel, and the
        columns their pixels reach.
    painted : ndarray of int8, shape (rows, cols)
        The value of the last polygon holding each pixel, 0 where none does (the window may be
        empty).
    """
    spans = polygon_spans(polygons, height, width)
    counts = np.diff(spans.start)
    used = counts > 0
    if not used.any():
        return 0, 0, np.zeros((0, 0), dtype=np.int8)
    top, bottom = int(spans.top[used].min()), int(spans.bottom[used].max()) + 1
    left, right = int(spans.first.min()), int(spans.stop.max())
    rows, cols = bottom - top, right - left
    owner = np.repeat(np.arange(len(polygons)), counts)
    # Every span toggles its polygon's bit where it starts and where it stops, at its position in
    # the window read row after row (a span that stops at a row's end toggles at the next row's
    # start: the same place).
    start = (spans.row - top) * cols - left
    position = np.concatenate([[0], start + spans.first, start + spans.stop])
    toggled = np.concatenate([[-1], owner, owner])
    order = np.argsort(position, kind="stable")
    position, toggled = position[order], toggled[order]
    # Between two toggles the polygons covering a pixel stay the same: one value per stretch.
    stretch = np.ones(position.size, dtype=bool)
    np.not_equal(position[1:], position[:-1], out=stretch[1:])
    begins = np.flatnonzero(stretch)
    words = -(-len(polygons) // 64)
    bits = np.zeros((position.size, words), dtype=np.uint64)
    real = toggled >= 0
    bits[np.flatnonzero(real), toggled[real] // 64] = np.left_shift(np.uint64(1), (toggled[real] % 64).astype(np.uint64))
    cover = np.bitwise_xor.accumulate(np.bitwise_xor.reduceat(bits, begins, axis=0), axis=0)
    last = _last_polygon(cover)
    value = np.where(last >= 0, np.asarray(values, dtype=np.int8)[np.maximum(last, 0)], np.int8(0))
    inside = position[begins] < rows * cols
    begins_at = position[begins][inside]
    lengths = np.diff(begins_at, append=rows * cols)
    painted = np.repeat(value[inside], lengths).reshape(rows, cols)
    return top, left, painted


def _last_polygon(cover: np.ndarray) -> np.ndarray:
    """The highest bit set in each row of 64-bit words (word ``w`` bit ``b``: polygon
    ``64 w + b``), -1 where none is.

    Parameters
    ----------
    cover : ndarray of uint64, shape (N, words)

    Returns
    -------
    ndarray of int64, shape (N,)
    """
    held = cover != 0
    if cover.shape[1] == 1:
        word, value = np.zeros(len(cover), dtype=np.int64), cover[:, 0]
    else:
        word = cover.shape[1] - 1 - np.argmax(held[:, ::-1], axis=1)
        value = cover[np.arange(len(cover)), word]
    # Each half word is exact in float64, whose exponent tells its highest bit (frexp(0): 0).
    high = np.frexp((value >> np.uint64(32)).astype(np.float64))[1]
    low = np.frexp((value & np.uint64(0xFFFFFFFF)).astype(np.float64))[1]
    bit = np.where(high > 0, high + 31, low - 1)
    return np.where(held.any(axis=1), 64 * word + bit, -1)


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
        # Past the views first: what any keyframe says goes over it.
        top, left, said = paint_values([*beyond, *(polygon for _, polygon in layers)],
                                       [2] * len(beyond) + [1 if sign > 0 else -1 for sign, _ in layers], height, width)
        if not said.size:
            continue
        bottom, right = top + said.shape[0], left + said.shape[1]
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

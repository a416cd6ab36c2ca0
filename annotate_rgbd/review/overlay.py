"""Review overlays: what the automatic stages did to what the labeller drew, on the RGB frame.

:func:`render_overlay` draws one frame (pure: arrays in, an array out):

* **kept plane** - the RGB image tinted with the plane's colour where the refined mask has it,
  the labeller's polygon outlined in that colour (solid line), and its global plane id in a box
  of its colour (``7*`` when camera poses carried the shape here from keyframes on other
  frames, :mod:`annotate_rgbd.propagate.carry`);
* **removed pixels** - inside a kept plane's polygon but not in its mask (RANSAC outliers or no
  valid depth): the image darkened, with diagonal stripes in the plane's colour;
* **grown pixels** - outside every drawn shape but added to a plane by edge growing (its depth
  lies on the plane): the plane's colour, nearly opaque, just outside the polygon's outline;
* **dropped plane** - the polygon outlined with a dashed line (plane colour and black), not
  tinted, with ``<id> dropped: <reason>`` in a black box.

:func:`overlay_for_frame` reads the frame's RGB image first (a missing or unreadable one: plain
grey, and a warning): ``cvat2mask --overlays`` calls it with the result it has just segmented,
so that no frame is segmented twice.
:func:`contact_sheet` puts a few overlays in a grid for a quick look or a bug report.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage

from annotate_rgbd.errors import InputError
from annotate_rgbd.segment.frame import FrameResult
from annotate_rgbd.io.sequence import read_rgb

log = logging.getLogger("annotate_rgbd")

#: Background of an overlay whose RGB image is missing or unreadable.
NO_RGB_GREY = 96
#: Weight of the plane colour in the tint of a kept plane.
TINT_ALPHA = 0.45
#: Weight of the plane colour on grown pixels: they stand out against the tint.
GROWN_ALPHA = 0.85
#: Removed pixels are darkened to this share of their brightness (under the stripes).
REMOVED_DARKEN = 0.45
#: Period and width, in pixels, of the diagonal stripes on removed pixels.
STRIPE_PERIOD = 6
STRIPE_WIDTH = 2
#: Dash length and line width, in pixels, of a dropped plane's outline.
DASH_LENGTH = 6
DROPPED_LINE_WIDTH = 2


FONT = cv2.FONT_HERSHEY_SIMPLEX
#: Smallest default font scale: below it OpenCV's font is no longer readable.
MIN_FONT_SCALE = 0.33


def render_overlay(
    rgb: np.ndarray,
    result: FrameResult,
    colours: np.ndarray,
    *,
    alpha: float = TINT_ALPHA,
    font_scale: float | None = None,
) -> np.ndarray:
    """Draw the review overlay of one frame.

    Parameters
    ----------
    rgb : ndarray of uint8, shape (H, W, 3)
        The RGB frame, on the depth grid (same size as ``result.labels``).
    result : FrameResult
        The segmentation of the frame: ``drawn`` (the labeller's shapes), ``labels`` (the
        refined mask) and the ``kept`` / ``dropped`` plane records.
    colours : ndarray of uint8, shape (N, 3)
        Plane colours, row ``k - 1`` for plane id ``k``.
    alpha : float
        Weight of the plane colour in the tint of kept planes.
    font_scale : float, optional
        OpenCV font scale of the id labels; default grows with the image width (0.4 at 640 pixels).

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        The overlay (RGB).
    """
    labels, drawn = result.labels, result.drawn
    if rgb.shape[:2] != labels.shape:
        raise ValueError(f"RGB image is {rgb.shape[1]}x{rgb.shape[0]}, mask is {labels.shape[1]}x{labels.shape[0]}")
    lookup = _lookup(colours, max(int(drawn.max(initial=0)), int(labels.max(initial=0))))
    kept_ids = np.array([r.plane for r in result.kept], dtype=np.int64)
    dropped_ids = np.array([r.plane for r in result.dropped], dtype=np.int64)

    out = rgb.astype(np.float32)
    in_kept = np.isin(drawn, kept_ids)
    # Drawn for a kept plane but not in its refined mask (a dropped plane shows by its outline).
    removed = (labels != drawn) & in_kept
    out[removed] *= REMOVED_DARKEN
    striped = removed & stripes(labels.shape)
    out[striped] = lookup[drawn[striped]]

    on_plane = labels > 0
    out[on_plane] = (1 - alpha) * out[on_plane] + alpha * lookup[labels[on_plane]]
    grown = on_plane & (drawn == 0)  # only edge growing puts a plane outside every drawn shape
    out[grown] = (1 - GROWN_ALPHA) * rgb[grown] + GROWN_ALPHA * lookup[labels[grown]]
    # The outline is the labeller's polygon, not the refined mask: the mask's holes are speckle.
    kept_region = np.where(in_kept, drawn, 0)
    edge = inner_boundary(kept_region, 1)
    out[edge] = lookup[kept_region[edge]]

    dropped_region = np.where(np.isin(drawn, dropped_ids), drawn, 0)
    outline = inner_boundary(dropped_region, DROPPED_LINE_WIDTH)
    dash = outline & stripes(labels.shape, period=2 * DASH_LENGTH, width=DASH_LENGTH)
    out[outline] = 0
    out[dash] = lookup[dropped_region[dash]]
    out = np.clip(out, 0, 255).round().astype(np.uint8)

    # Ids go where each plane is widest: in its kept pixels, or in its polygon when it has none.
    unplaced = np.setdiff1d(np.concatenate([kept_ids, dropped_ids]), labels)
    regions = np.where((labels == 0) & np.isin(drawn, unplaced), drawn, labels)
    points = label_points(regions)
    scale = font_scale if font_scale is not None else max(0.4 * labels.shape[1] / 640, MIN_FONT_SCALE)
    carried = {r.plane for r in result.kept if r.propagated}
    for plane in kept_ids.tolist():
        if plane in points:
            text = f"{plane}*" if plane in carried else str(plane)  # * : carried by the poses
            _text_box(out, text, points[plane], scale, lookup[plane], _ink(lookup[plane]))
    for record in result.dropped:
        plane = record.plane
        if plane in points:
            text = f"{plane} dropped: {record.reason}"
            _text_box(out, text, points[plane], scale, np.zeros(3), (255, 255, 255), border=lookup[plane])
    return out


def overlay_for_frame(rgb_path: Path, result: FrameResult, colours: np.ndarray) -> tuple[np.ndarray, InputError | None]:
    """Read a frame's RGB image and draw its review overlay.

    Parameters
    ----------
    rgb_path : Path
        The RGB image associated with the depth frame.
    result : FrameResult
        :func:`annotate_rgbd.segment.frame.segment_frame` of the depth frame.
    colours : ndarray of uint8, shape (n_planes, 3)
        The plane palette of the run.

    Returns
    -------
    overlay : ndarray of uint8, shape (H, W, 3)
        The overlay on the depth grid: with a colour camera of its own (``result.colour_grid``)
        the RGB image is resampled where each depth pixel lies in it; else an RGB image of
        another size is resized to it. A missing or unreadable RGB image leaves the frame's
        mask reviewable: the overlay is drawn on plain grey (:data:`NO_RGB_GREY`).
    problem : InputError or None
        Why the RGB image could not be used, for a warning (its message ends in "its overlay is
        drawn on grey").
    """
    height, width = result.labels.shape
    try:
        rgb = read_rgb(rgb_path)
    except InputError as exc:
        grey = np.full((height, width, 3), NO_RGB_GREY, dtype=np.uint8)
        return render_overlay(grey, result, colours), InputError(exc.path, f"{exc.message}; its overlay is drawn on grey")
    if result.colour_grid is not None:
        rgb = cv2.remap(rgb, *result.colour_grid, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    elif rgb.shape[:2] != (height, width):
        rgb = cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA)
    return render_overlay(rgb, result, colours), None


def stripes(shape: tuple[int, int], period: int = STRIPE_PERIOD, width: int = STRIPE_WIDTH) -> np.ndarray:
    """Diagonal stripes: ``True`` where ``(row + col) mod period < width``.

    Parameters
    ----------
    shape : (int, int)
        (H, W).
    period, width : int
        Stripe period and width along a row, in pixels.

    Returns
    -------
    ndarray of bool, shape (H, W)
    """
    return np.add.outer(np.arange(shape[0]), np.arange(shape[1])) % period < width


def inner_boundary(labels: np.ndarray, width: int = 1) -> np.ndarray:
    """The pixels of each region within ``width`` pixels of another region (or of 0).

    The image border is not a boundary: a plane cut by the frame edge is not outlined there.

    Parameters
    ----------
    labels : ndarray of int, shape (H, W)
        Region ids, 0 = background.
    width : int
        Line width, in pixels.

    Returns
    -------
    ndarray of bool, shape (H, W)
    """
    size = 2 * width + 1
    high = ndimage.maximum_filter(labels, size=size, mode="nearest")
    low = ndimage.minimum_filter(labels, size=size, mode="nearest")
    return (labels > 0) & ((high != labels) | (low != labels))


def label_points(regions: np.ndarray) -> dict[int, tuple[int, int]]:
    """For every region, its pixel farthest from the region's edge (where its label goes).

    Unlike the centroid, this point always lies inside the region, also for a concave or
    ring-shaped one.

    Parameters
    ----------
    regions : ndarray of int, shape (H, W)
        Region ids, 0 = background.

    Returns
    -------
    dict of int to (int, int)
        Region id -> (row, col); empty when ``regions`` has no region.
    """
    padded = np.pad(regions, 1, constant_values=-1)
    centre = padded[1:-1, 1:-1]
    edge = (
        (padded[:-2, 1:-1] != centre) | (padded[2:, 1:-1] != centre)
        | (padded[1:-1, :-2] != centre) | (padded[1:-1, 2:] != centre)
    )
    index = np.flatnonzero(regions > 0)
    if index.size == 0:  # a frame without shapes (e.g. its track ended): nothing to label
        return {}
    distance = ndimage.distance_transform_edt(~edge)
    ids = regions.ravel()[index]
    order = np.lexsort((distance.ravel()[index], ids))  # by id, then distance: the last is the deepest
    ids, index = ids[order], index[order]
    last = np.append(ids[1:] != ids[:-1], True)
    rows, cols = np.unravel_index(index[last], regions.shape)
    return {int(k): (int(r), int(c)) for k, r, c in zip(ids[last], rows, cols)}


#: Tallest thumbnail on the contact sheet, as a multiple of its width: a taller frame (a
#: portrait 480 x 640 frame fits) is scaled down to fit, so that a degenerate frame (1 x 20000
#: pixels) gives a thin thumbnail rather than a gigabyte sheet.
MAX_THUMB_ASPECT = 2.0
#: Frames more elongated than this (either way) get a warning: their thumbnails are a sliver.
DEGENERATE_ASPECT = 8.0


def thumbnail_size(shape: tuple[int, ...], thumb_width: int, max_aspect: float = MAX_THUMB_ASPECT) -> tuple[int, int]:
    """Size of an image's thumbnail: the image scaled, keeping its aspect ratio, to fit a box
    ``thumb_width`` wide and ``max_aspect * thumb_width`` tall.

    Parameters
    ----------
    shape : tuple of int
        The image's ``(H, W, ...)``, both at least 1.
    thumb_width : int
        Box width, pixels.
    max_aspect : float
        Box height over box width.

    Returns
    -------
    (int, int)
        ``(width, height)``, each between 1 and the box's side.
    """
    height, width = shape[0], shape[1]
    box_height = max(1, int(max_aspect * thumb_width))
    scale = min(thumb_width / width, box_height / height)
    return (min(thumb_width, max(1, round(width * scale))), min(box_height, max(1, round(height * scale))))


def contact_sheet(
    images: Iterable[np.ndarray],
    captions: Sequence[str] | None = None,
    *,
    columns: int = 4,
    thumb_width: int = 320,
    gap: int = 4,
) -> np.ndarray:
    """A grid of thumbnails, each with an optional caption below it.

    Each image is shrunk as it arrives, so that memory holds one full image at a time; every
    thumbnail fits a ``thumb_width`` x ``MAX_THUMB_ASPECT * thumb_width`` box, whatever the
    image's aspect ratio (a frame more elongated than :data:`DEGENERATE_ASPECT` gets one warning).

    Parameters
    ----------
    images : iterable of ndarray of uint8, shape (H, W, 3)
        The images, in reading order (sizes may differ); a generator is read one image at a time.
    captions : sequence of str, optional
        One per image (e.g. the frame's file name).
    columns : int
        Thumbnails per row.
    thumb_width : int
        Width of each cell, in pixels; thumbnails keep each image's aspect ratio.
    gap : int
        Space between thumbnails, in pixels.

    Returns
    -------
    ndarray of uint8, shape (H', W', 3)
        The sheet (RGB), white between the thumbnails; at most
        ``(MAX_THUMB_ASPECT * thumb_width + caption + gap)`` pixels tall per row of ``columns``.
    """
    thumbs, degenerate = [], None
    for image in images:
        if degenerate is None and max(image.shape[0] / image.shape[1], image.shape[1] / image.shape[0]) > DEGENERATE_ASPECT:
            degenerate = image.shape
        thumbs.append(cv2.resize(image, thumbnail_size(image.shape, thumb_width), interpolation=cv2.INTER_AREA))
    if not thumbs:
        raise ValueError("no images for the contact sheet")
    if captions is not None and len(captions) != len(thumbs):
        raise ValueError(f"{len(captions)} captions for {len(thumbs)} images")
    if degenerate is not None:
        log.warning(
            "frames of %d x %d pixels are too elongated for thumbnails: the contact sheet shows them as slivers",
            degenerate[1], degenerate[0],
        )
    columns = max(1, min(columns, len(thumbs)))
    scale = 0.4 * thumb_width / 320
    caption_height = cv2.getTextSize("Ag", FONT, scale, 1)[0][1] + 8 if captions is not None else 0
    cell_height = max(t.shape[0] for t in thumbs) + caption_height
    rows = -(-len(thumbs) // columns)
    sheet = np.full((gap + rows * (cell_height + gap), gap + columns * (thumb_width + gap), 3), 255, np.uint8)
    for i, thumb in enumerate(thumbs):
        top = gap + (i // columns) * (cell_height + gap)
        left = gap + (i % columns) * (thumb_width + gap)
        sheet[top : top + thumb.shape[0], left : left + thumb.shape[1]] = thumb
        if captions is not None:
            baseline = top + thumb.shape[0] + caption_height - 4
            cv2.putText(sheet, captions[i], (left + 2, baseline), FONT, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return sheet


def _lookup(colours: np.ndarray, largest: int) -> np.ndarray:
    """Colour by plane id (row 0 unused); ids beyond the palette are grey."""
    lookup = np.full((max(largest, len(colours)) + 1, 3), 128, dtype=np.float32)
    lookup[1 : len(colours) + 1] = colours
    return lookup


def _ink(colour: np.ndarray) -> tuple[int, int, int]:
    """Black or white text, whichever reads better on ``colour``."""
    luma = 0.299 * colour[0] + 0.587 * colour[1] + 0.114 * colour[2]
    return (0, 0, 0) if luma > 140 else (255, 255, 255)


def _text_box(
    image: np.ndarray,
    text: str,
    point: tuple[int, int],
    scale: float,
    fill: np.ndarray,
    ink: tuple[int, int, int],
    border: np.ndarray | None = None,
) -> None:
    """Write ``text`` in a filled box centred on ``point`` (row, col), kept inside the image."""
    (width, height), baseline = cv2.getTextSize(text, FONT, scale, 1)
    pad = 2
    box_w, box_h = width + 2 * pad, height + baseline + 2 * pad
    left = int(np.clip(point[1] - box_w // 2, 0, max(image.shape[1] - box_w, 0)))
    top = int(np.clip(point[0] - box_h // 2, 0, max(image.shape[0] - box_h, 0)))
    corner = (left + box_w - 1, top + box_h - 1)
    cv2.rectangle(image, (left, top), corner, tuple(int(v) for v in fill), thickness=-1)
    if border is not None:
        cv2.rectangle(image, (left, top), corner, tuple(int(v) for v in border), thickness=1)
    cv2.putText(image, text, (left + pad, top + pad + height), FONT, scale, ink, 1, cv2.LINE_AA)

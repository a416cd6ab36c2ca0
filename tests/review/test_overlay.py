"""Overlay content on a synthetic frame: tints, removed-pixel stripes, dropped outlines, labels."""

from __future__ import annotations

import cv2
from dataclasses import replace

import numpy as np
import pytest

from annotate_rgbd.review.overlay import (
    REMOVED_DARKEN,
    TINT_ALPHA,
    contact_sheet,
    inner_boundary,
    label_points,
    NO_RGB_GREY,
    overlay_for_frame,
    render_overlay,
    stripes,
)
from annotate_rgbd.report.records import PlaneRecord
from annotate_rgbd.report.palette import plane_colours
from annotate_rgbd.segment.frame import FrameResult

H, W = 120, 200
GREY = 100


@pytest.fixture
def frame():
    """Plane 1 kept with a clutter disc removed from it; plane 2 dropped as too far."""
    drawn = np.zeros((H, W), dtype=np.int32)
    drawn[10:70, 10:100] = 1
    drawn[80:115, 110:195] = 2
    rows, cols = np.mgrid[:H, :W]
    clutter = (rows - 40) ** 2 + (cols - 30) ** 2 <= 12**2
    labels = np.where((drawn == 1) & ~clutter, 1, 0).astype(np.int32)
    result = FrameResult(
        labels=labels,
        drawn=drawn,
        kept=[PlaneRecord(1, int((drawn == 1).sum()), int((drawn == 1).sum()), 1.0, inliers=int(labels.astype(bool).sum()))],
        dropped=[PlaneRecord(2, int((drawn == 2).sum()), int((drawn == 2).sum()), 5.0, reason="too_far")],
    )
    rgb = np.full((H, W, 3), GREY, dtype=np.uint8)
    colours = plane_colours(2)
    return rgb, result, colours, clutter, render_overlay(rgb, result, colours)


def _away_from_labels(result: FrameResult) -> np.ndarray:
    """Pixels clear of the id boxes (centred on the label points): "1" is short, "2 dropped: ..." long."""
    half_width = {1: 12, 2: 70}
    clear = np.ones((H, W), dtype=bool)
    regions = np.where(result.labels > 0, result.labels, np.where(result.drawn == 2, 2, 0))
    for plane, (row, col) in label_points(regions).items():
        clear[max(row - 12, 0) : row + 12, max(col - half_width[plane], 0) : col + half_width[plane]] = False
    return clear


def test_kept_plane_pixels_are_tinted_with_its_colour(frame):
    _, result, colours, _, overlay = frame
    inside = (result.labels == 1) & ~inner_boundary(result.labels, 2) & _away_from_labels(result)
    assert inside.sum() > 500
    expected = np.round((1 - TINT_ALPHA) * GREY + TINT_ALPHA * colours[0].astype(float))
    assert np.all(np.abs(overlay[inside].astype(float) - expected) <= 1)


def test_kept_plane_outline_is_its_colour(frame):
    _, result, colours, _, overlay = frame
    edge = inner_boundary(result.drawn == 1, 1) & _away_from_labels(result)
    assert edge.sum() > 50
    assert np.all(overlay[edge] == colours[0])


def test_removed_pixels_are_striped_in_the_plane_colour_over_a_darkened_image(frame):
    _, result, colours, clutter, overlay = frame
    removed = clutter & _away_from_labels(result)
    on_stripe = removed & stripes((H, W))
    assert on_stripe.sum() > 50 and (removed & ~on_stripe).sum() > 50
    assert np.all(overlay[on_stripe] == colours[0])
    assert np.all(overlay[removed & ~on_stripe] == round(GREY * REMOVED_DARKEN))
    # Nowhere else is darkened or striped: outside both planes the image is unchanged.
    assert np.all(overlay[(result.drawn == 0) & _away_from_labels(result)] == GREY)


def test_dropped_plane_has_a_dashed_outline_and_no_tint(frame):
    _, result, colours, _, overlay = frame
    edge = inner_boundary(result.drawn == 2, 2) & _away_from_labels(result)
    coloured = np.all(overlay[edge] == colours[1], axis=1)
    black = np.all(overlay[edge] == 0, axis=1)
    assert np.all(coloured | black) and coloured.mean() > 0.3 and black.mean() > 0.3
    interior = (result.drawn == 2) & ~inner_boundary(result.drawn == 2, 2) & _away_from_labels(result)
    assert interior.sum() > 100 and np.all(overlay[interior] == GREY)


def test_plane_ids_and_drop_reason_are_written_in_boxes(frame):
    rgb, result, colours, _, overlay = frame
    plain = render_overlay(rgb, FrameResult(result.labels, result.drawn, [], []), colours)
    changed = np.any(overlay != plain, axis=2)
    points = label_points(np.where(result.labels > 0, result.labels, np.where(result.drawn == 2, 2, 0)))
    (r1, c1), (r2, _) = points[1], points[2]
    # The kept id's box is filled with the plane colour; the drop's box is black and wider (text).
    box1 = overlay[r1 - 3 : r1 + 4, c1 - 8 : c1 + 9]
    assert np.any(np.all(box1 == colours[0], axis=-1))
    box2 = changed[r2 - 4 : r2 + 5, :]
    assert box2.sum(axis=1).max() > 60


def test_label_point_lies_inside_a_ring_shaped_region():
    rows, cols = np.mgrid[:101, :101]
    radius = np.hypot(rows - 50, cols - 50)
    ring = ((radius >= 25) & (radius <= 45)).astype(np.int32)  # its centroid is in the hole
    square = np.zeros_like(ring)
    square[:10, :10] = 2
    points = label_points(ring + square)
    row, col = points[1]
    assert ring[row, col] == 1 and 30 <= np.hypot(row - 50, col - 50) <= 40
    assert points[2] in {(4, 4), (4, 5), (5, 4), (5, 5)}


def test_inner_boundary_ignores_the_image_border():
    labels = np.zeros((20, 20), dtype=np.int32)
    labels[:, :10] = 1
    edge = inner_boundary(labels, 1)
    assert np.array_equal(np.flatnonzero(edge.any(axis=0)), [9])
    assert edge[:, 9].all()
    assert inner_boundary(labels, 3).any(axis=0).sum() == 3


def test_overlay_rejects_an_rgb_image_of_another_size(frame):
    rgb, result, colours, *_ = frame
    with pytest.raises(ValueError, match="RGB image"):
        render_overlay(rgb[:-1], result, colours)


def test_overlay_for_frame_reads_and_fits_the_rgb_to_the_depth_grid(frame, tmp_path):
    _, result, colours, *_ = frame
    path = tmp_path / "rgb.png"
    cv2.imwrite(str(path), np.full((2 * H, 2 * W, 3), GREY, dtype=np.uint8))
    overlay, problem = overlay_for_frame(path, result, colours)
    assert overlay.shape == (H, W, 3) and problem is None
    assert np.array_equal(overlay, frame[4])


@pytest.mark.parametrize("content", [None, b"not an image"])
def test_an_unreadable_rgb_image_gives_the_overlay_on_grey_and_says_why(frame, tmp_path, content):
    rgb, result, colours, *_ = frame
    path = tmp_path / "rgb.png"
    if content is not None:
        path.write_bytes(content)
    overlay, problem = overlay_for_frame(path, result, colours)
    # The same drawing as on an RGB image of plain grey.
    grey = np.full_like(rgb, NO_RGB_GREY)
    assert np.array_equal(overlay, render_overlay(grey, result, colours))
    assert problem.path == path and problem.message.endswith("; its overlay is drawn on grey")


def test_contact_sheet_places_thumbnails_in_reading_order():
    images = [np.full((60, 80, 3), 40 * (i + 1), dtype=np.uint8) for i in range(5)]
    sheet = contact_sheet(images, columns=2, thumb_width=40, gap=2)
    # 3 rows of 30-pixel thumbnails, 2 columns of 40, with 2-pixel gaps.
    assert sheet.shape == (2 + 3 * 32, 2 + 2 * 42, 3)
    for i in range(5):
        top, left = 2 + (i // 2) * 32, 2 + (i % 2) * 42
        assert np.all(sheet[top : top + 30, left : left + 40] == 40 * (i + 1))
    assert np.all(sheet[2 + 2 * 32 :, 2 + 42 :] == 255)  # the empty sixth cell


def test_contact_sheet_captions_add_a_line_below_each_thumbnail():
    images = [np.zeros((60, 80, 3), dtype=np.uint8)] * 2
    plain = contact_sheet(images, columns=2, thumb_width=80)
    captioned = contact_sheet(images, ["frame 1", "frame 2"], columns=2, thumb_width=80)
    assert captioned.shape[0] > plain.shape[0]
    assert np.any(captioned[64:, :, 0] < 128)  # dark caption text under the thumbnails
    with pytest.raises(ValueError):
        contact_sheet(images, ["only one"])
    with pytest.raises(ValueError):
        contact_sheet([])


def test_grown_pixels_are_nearly_opaque_in_the_plane_colour(frame):
    rgb, result, colours, _, plain = frame
    labels = result.labels.copy()
    labels[10:70, 100:103] = 1  # three columns grown just outside the polygon's right edge
    grown = FrameResult(labels=labels, drawn=result.drawn, kept=result.kept, dropped=result.dropped)
    out = render_overlay(rgb, grown, colours)
    rows = slice(15, 30)  # clear of the id box
    expected = np.round(0.15 * GREY + 0.85 * colours[0].astype(float))
    assert (out[rows, 100:103] == expected).all()
    # The tint inside the polygon is lighter: grown pixels stand out from it.
    assert np.abs(out[rows, 60].astype(int) - colours[0]).sum() > np.abs(out[rows, 101].astype(int) - colours[0]).sum()
    assert (plain[rows, 100:103] == GREY).all()


def test_a_frame_without_shapes_has_no_label_points_and_shows_the_rgb_image():
    empty = np.zeros((H, W), dtype=np.int32)
    assert label_points(empty) == {}
    rgb = np.random.default_rng(0).integers(0, 256, (H, W, 3), dtype=np.uint8)
    result = FrameResult(labels=empty, drawn=empty.copy())
    assert np.array_equal(render_overlay(rgb, result, plane_colours(3)), rgb)


def test_a_plane_carried_by_the_poses_is_marked_with_a_star(frame):
    rgb, result, colours, _, plain = frame
    carried = FrameResult(labels=result.labels, drawn=result.drawn,
                          kept=[replace(r, propagated=True) for r in result.kept], dropped=result.dropped)
    out = render_overlay(rgb, carried, colours)
    changed = np.argwhere((out != plain).any(axis=2))
    assert len(changed) > 0  # the id box of plane 1 is wider: "1*"
    (top, left), (bottom, right) = changed.min(axis=0), changed.max(axis=0)
    assert bottom - top < 30 and right - left < 40  # only around the id box

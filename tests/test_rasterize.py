import numpy as np

from annotate_rgbd.annotation import Shape
from annotate_rgbd.rasterize import rasterize_frame, shape_pixels


def polygon(points, z=0):
    return Shape("polygon", np.asarray(points, dtype=float), z_order=z)


def test_polygon_covers_pixels_whose_centres_are_inside():
    # CVAT corners (1,1)-(4,3): pixel centres x in {1.5, 2.5, 3.5}, y in {1.5, 2.5}.
    labels = rasterize_frame([(7, polygon([[1, 1], [4, 1], [4, 3], [1, 3]]))], 5, 6)
    expected = np.zeros((5, 6), np.int32)
    expected[1:3, 1:4] = 7
    np.testing.assert_array_equal(labels, expected)


def test_box_and_mask_shapes():
    box = Shape("box", np.array([[0.0, 0.0], [2.0, 3.0]]))
    rows, cols = shape_pixels(box, 10, 10)
    assert sorted(zip(rows.tolist(), cols.tolist())) == [(r, c) for r in range(3) for c in range(2)]
    bitmap = np.array([[1, 0], [1, 1]], dtype=bool)
    mask = Shape("mask", np.array([[8.0, 9.0]]), bitmap=bitmap)
    rows, cols = shape_pixels(mask, 10, 10)  # the bottom row of the bitmap falls off the image
    assert sorted(zip(rows.tolist(), cols.tolist())) == [(9, 8)]


def test_higher_z_order_is_on_top_and_equal_z_keeps_track_order():
    low = polygon([[0, 0], [4, 0], [4, 4], [0, 4]], z=5)
    high = polygon([[2, 0], [6, 0], [6, 4], [2, 4]], z=9)
    assert rasterize_frame([(1, high), (2, low)], 4, 6)[0].tolist() == [2, 2, 1, 1, 1, 1]
    first = polygon([[0, 0], [4, 0], [4, 4], [0, 4]])
    later = polygon([[2, 0], [6, 0], [6, 4], [2, 4]])
    assert rasterize_frame([(1, first), (2, later)], 4, 6)[0].tolist() == [1, 1, 2, 2, 2, 2]
    assert rasterize_frame([(2, later), (1, first)], 4, 6)[0].tolist() == [1, 1, 1, 1, 2, 2]


def test_shapes_beyond_the_image_are_clipped():
    labels = rasterize_frame([(1, polygon([[-50, -50], [3, -50], [3, 2], [-50, 2]]))], 4, 4)
    assert labels.sum() == 6
    box = Shape("box", np.array([[100.0, 100.0], [200.0, 200.0]]))
    assert rasterize_frame([(1, box)], 4, 4).sum() == 0

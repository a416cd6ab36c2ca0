import numpy as np
import pytest
from skimage.draw import polygon as skimage_polygon

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.segment.rasterize import rasterize_frame, shape_mask


def polygon(points, z=0):
    return Shape("polygon", np.asarray(points, dtype=float), z_order=z)


def test_polygon_covers_pixels_whose_centres_are_inside():
    # CVAT corners (1,1)-(4,3): pixel centres x in {1.5, 2.5, 3.5}, y in {1.5, 2.5}.
    labels = rasterize_frame([(7, polygon([[1, 1], [4, 1], [4, 3], [1, 3]]))], 5, 6)
    expected = np.zeros((5, 6), np.int32)
    expected[1:3, 1:4] = 7
    np.testing.assert_array_equal(labels, expected)


@pytest.mark.parametrize("seed", range(40))
def test_polygon_fill_equals_the_centre_in_polygon_test(seed):
    # Random (also concave and self-intersecting) polygons, partly outside the image, against
    # scikit-image's point-in-polygon test at the pixel centres.
    rng = np.random.default_rng(seed)
    n = rng.integers(3, 12)
    angles = rng.uniform(0, 2 * np.pi, n)
    if seed % 2:
        angles.sort()
    points = rng.uniform([-50, -50], [130, 110]) + np.c_[np.cos(angles), np.sin(angles)] * rng.uniform(3, 90, (n, 1))
    expected = np.zeros((60, 80), np.int32)
    rows, cols = skimage_polygon(points[:, 1] - 0.5, points[:, 0] - 0.5, shape=(60, 80))
    expected[rows, cols] = 1
    np.testing.assert_array_equal(rasterize_frame([(1, polygon(points))], 60, 80), expected)


def test_polygons_sharing_an_edge_share_no_pixel():
    # The shared edge x = 2.5 runs through pixel centres: they belong to the right polygon only.
    left = polygon([[0, 0], [2.5, 0], [2.5, 4], [0, 4]])
    right = polygon([[2.5, 0], [6, 0], [6, 4], [2.5, 4]])
    a = rasterize_frame([(1, left)], 4, 6) > 0
    b = rasterize_frame([(1, right)], 4, 6) > 0
    assert not (a & b).any()
    assert (a | b).all()


def test_box_and_mask_shapes():
    box = Shape("box", np.array([[0.0, 0.0], [2.0, 3.0]]))
    top, left, inside = shape_mask(box, 10, 10)
    assert (top, left, inside.shape, inside.all()) == (0, 0, (3, 2), True)
    bitmap = np.array([[1, 0], [1, 1]], dtype=bool)
    mask = Shape("mask", np.array([[8.0, 9.0]]), bitmap=bitmap)
    labels = rasterize_frame([(2, mask)], 10, 10)  # the bottom row of the bitmap falls off the image
    assert list(zip(*np.nonzero(labels))) == [(9, 8)]


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
    far = Shape("mask", np.array([[-10.0, -10.0]]), bitmap=np.ones((3, 3), bool))
    assert rasterize_frame([(1, far)], 4, 4).sum() == 0


def test_label_images_use_the_smallest_type_for_the_plane_ids():
    square = polygon([[0, 0], [2, 0], [2, 2], [0, 2]])
    assert rasterize_frame([(255, square)], 4, 4).dtype == np.uint8
    big = rasterize_frame([(256, square)], 4, 4)
    assert big.dtype == np.uint16 and big[0, 0] == 256
    assert rasterize_frame([(70000, square)], 4, 4).dtype == np.int32


def _centres_inside(points, height, width):
    """Pixels whose centre lies inside a polygon (scikit-image's test; CVAT coordinates)."""
    inside = np.zeros((height, width), bool)
    rows, cols = skimage_polygon(points[:, 1] - 0.5, points[:, 0] - 0.5, shape=(height, width))
    inside[rows, cols] = True
    return inside


@pytest.mark.parametrize("seed", range(12))
def test_carried_shapes_paint_what_the_last_layer_says_on_the_whole_image(seed):
    # Painted on the layers' window only, the carried plane's pixels are those of painting every
    # signed layer in order on the whole image; beyond the keyframes' views where no layer speaks.
    from annotate_rgbd.segment.rasterize import BOTTOM_Z_ORDER, carried_shapes

    rng = np.random.default_rng(seed)
    height, width = 50, 70

    def random_polygon():
        n = rng.integers(3, 9)
        angles = np.sort(rng.uniform(0, 2 * np.pi, n))
        return rng.uniform([-10, -10], [80, 60]) + np.c_[np.cos(angles), np.sin(angles)] * rng.uniform(3, 30, (n, 1))

    layers = [(int(rng.choice([-1, 1])), random_polygon()) for _ in range(rng.integers(0, 6))]
    beyond = [random_polygon() for _ in range(rng.integers(0, 4))]
    verdict = np.zeros((height, width), np.int8)
    for sign, points in layers:
        verdict[_centres_inside(points, height, width)] = sign
    further = np.zeros((height, width), bool)
    for points in beyond:
        further |= _centres_inside(points, height, width)
    further &= verdict == 0

    drawn = polygon([[0, 0], [3, 0], [3, 3], [0, 3]], z=5)
    shapes, excluded = carried_shapes([(1, drawn)], [(0, 9, 2, layers, beyond)], height, width)
    by_z = {shape.z_order: shape for plane_id, shape in shapes if plane_id == 9}
    expected = {2: verdict > 0, BOTTOM_Z_ORDER: further}
    assert set(by_z) == {z for z, mask in expected.items() if mask.any()}
    for z, shape in by_z.items():
        top, left, window = shape_mask(shape, height, width)
        painted = np.zeros((height, width), bool)
        painted[top : top + window.shape[0], left : left + window.shape[1]] = window
        np.testing.assert_array_equal(painted, expected[z])
    np.testing.assert_array_equal(excluded.get(9, np.zeros((height, width), bool)), verdict < 0)


@pytest.mark.parametrize("count", [1, 7, 64, 65, 150])
def test_paint_values_gives_each_pixel_the_value_of_the_last_polygon_holding_it(count):
    # Spans toggle one bit per polygon (several 64-bit words past 64 polygons): the result must
    # be painting the polygons one after the other on the whole image (each filled as a shape is,
    # which the tests above hold to the centre-in-polygon rule).
    from annotate_rgbd.segment.rasterize import paint_values

    rng = np.random.default_rng(count)
    height, width = 40, 55
    polygons = []
    for _ in range(count):
        n = rng.integers(3, 10)
        points = rng.uniform([-15, -15], [70, 55], (n, 2))  # self-crossing ones too (even-odd)
        polygons.append(np.round(points * 2) / 2 if rng.random() < 0.3 else points)  # on pixel centres
    values = rng.choice([-1, 1, 2, 5], count)
    expected = np.zeros((height, width), np.int8)
    for points, value in zip(polygons, values):  # one polygon at a time, each filled on its own
        top, left, inside = shape_mask(Shape("polygon", points), height, width)
        expected[top : top + inside.shape[0], left : left + inside.shape[1]][inside] = value
    top, left, painted = paint_values(polygons, values.tolist(), height, width)
    whole = np.zeros((height, width), np.int8)
    whole[top : top + painted.shape[0], left : left + painted.shape[1]] = painted
    np.testing.assert_array_equal(whole, expected)

import json
import os

import cv2
import numpy as np
import pytest
from skimage.color import rgb2lab

from annotate_rgbd.errors import InputError
from annotate_rgbd.report.palette import colour_hex, colourize, id_image, plane_colours
from annotate_rgbd.io.writer import write_csv, write_json, write_png


def test_palette_is_fixed_distinct_and_never_dark():
    colours = plane_colours(200)
    assert colours.dtype == np.uint8 and colours.shape == (200, 3)
    assert len({tuple(c) for c in colours}) == 200
    lab = rgb2lab(colours[None] / 255.0)[0]
    assert lab[:, 0].min() >= 25  # far from black, which means "unsegmented"
    first = lab[:20]
    distance = np.linalg.norm(first[:, None] - first[None], axis=-1) + np.eye(20) * 1e9
    assert distance.min() > 30  # the first 20 planes are clearly distinct (CIELAB delta E)
    # A prefix never depends on how many colours were asked for.
    np.testing.assert_array_equal(plane_colours(5), colours[:5])
    assert colour_hex(colours[0]) == "#00ff00"


def test_colourize_paints_planes_and_leaves_black():
    colours = plane_colours(3)
    labels = np.array([[0, 1], [3, 2]])
    image = colourize(labels, colours)
    assert image[0, 0].tolist() == [0, 0, 0]
    assert image[1, 0].tolist() == colours[2].tolist()


def test_png_is_rgb_on_disk_and_no_temporary_file_remains(tmp_path):
    image = np.zeros((2, 2, 3), np.uint8)
    image[0, 0] = [255, 0, 0]
    write_png(tmp_path / "masks" / "a.png", image)
    read = cv2.cvtColor(cv2.imread(str(tmp_path / "masks" / "a.png")), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(read, image)
    write_json(tmp_path / "r.json", {"a": [1, 2]})
    write_csv(tmp_path / "t.csv", ["x", "y"], [[1, "b"]])
    assert json.loads((tmp_path / "r.json").read_text()) == {"a": [1, 2]}
    assert (tmp_path / "t.csv").read_text() == "x,y\n1,b\n"
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a.png", "masks", "r.json", "t.csv"]


def test_unwritable_output_folder_is_an_input_error(tmp_path):
    (tmp_path / "out").write_text("a file where the output folder should be")
    with pytest.raises(InputError, match="cannot write output") as error:
        write_json(tmp_path / "out" / "r.json", {})
    assert str(tmp_path / "out" / "r.json") in str(error.value)


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    write_json(tmp_path / "r.json", {"old": True})

    def full_disk(*args):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(InputError, match="No space left on device"):
        write_json(tmp_path / "r.json", {"new": True})
    assert json.loads((tmp_path / "r.json").read_text()) == {"old": True}
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]


@pytest.mark.parametrize(("n_planes", "dtype"), [(1, np.uint8), (255, np.uint8), (256, np.uint16), (65535, np.uint16)])
def test_id_images_are_8_bit_up_to_255_planes_else_16_bit(tmp_path, n_planes, dtype):
    labels = np.array([[0, 1], [n_planes, n_planes // 2]], np.int32)
    image = id_image(labels, n_planes)
    assert image.dtype == dtype
    write_png(tmp_path / "ids.png", image)
    assert np.array_equal(cv2.imread(str(tmp_path / "ids.png"), cv2.IMREAD_UNCHANGED), labels)


def test_palette_lab_is_scikit_images_bit_for_bit():
    # The palette's CIELAB (computed without scikit-image's colour module, slow to import) is
    # scikit-image's rgb2lab exactly: the greedy palette depends on every bit of it.
    from skimage.color import rgb2lab

    from annotate_rgbd.report.palette import srgb_to_lab

    rng = np.random.default_rng(4)
    rgb = np.concatenate([rng.random((5000, 3)), np.eye(3), np.zeros((1, 3)), np.ones((1, 3)),
                          np.full((1, 3), 0.04045), np.full((1, 3), 0.2)])
    np.testing.assert_array_equal(srgb_to_lab(rgb), rgb2lab(rgb[None])[0])

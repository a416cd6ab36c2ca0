"""Planes fitted under a keyframe's shapes (propagate.keyframes.keyframe_planes): each plane or
why there is none."""

import cv2
import numpy as np

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.config.settings import load_config
from annotate_rgbd.propagate.keyframes import keyframe_planes


def test_each_keyframe_shape_gets_its_plane_or_the_reason_there_is_none(tmp_path):
    # A wall 2 m away below row 80, one row of depth at row 60 (+-1 raw unit of noise: its
    # points lie in a plane through the camera, which is no surface), nothing elsewhere; three
    # shapes: the wall, the row's strip and a shape over no depth at all.
    config = load_config(None, {"camera.fx": 150.0, "camera.fy": 150.0, "camera.cx": 79.5, "camera.cy": 59.5,
                                "propagate.exclude": False})
    raw = np.zeros((120, 160), np.uint16)
    raw[60] = 10000 + np.random.default_rng(0).integers(-1, 2, 160)
    raw[80:] = 10000
    path = tmp_path / "depth.png"
    cv2.imwrite(str(path), raw)

    def box(top, bottom):
        return Shape("polygon", np.array([[10.0, top], [150.0, top], [150.0, bottom], [10.0, bottom]]))

    shapes = [(1, box(85.0, 115.0)), (2, box(55.0, 65.0)), (3, box(5.0, 40.0))]
    planes, size = keyframe_planes(shapes, [1, 2, 3], path, config)
    assert size == (160, 120)
    equation, valid = planes[1][0], planes[1][1]
    assert np.allclose(equation, [0.0, 0.0, -1.0, 2.0], atol=1e-6) and valid > 3000
    assert planes[2].startswith("no plane in the shape's depth")
    assert planes[3].startswith("too little valid depth")

"""Reading and writing CVAT XML exports (annotate_rgbd.cvat)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from annotate_rgbd.annotation.model import Annotation, Shape, Track
from annotate_rgbd.cvat import (
    decode_rle,
    encode_rle,
    read_cvat,
    rotated_box_corners,
    write_cvat_images,
    write_cvat_video,
)
from annotate_rgbd.errors import InputError

TRIANGLE = "1.00,1.00;9.00,1.00;5.00,7.00"


# --------------------------------------------------------------------------------------------
# Helpers: small exports written by hand, as CVAT writes them
# --------------------------------------------------------------------------------------------


def task_meta(start=0, stop=9, step=1, size=(64, 48), tag="task") -> str:
    frame_filter = f"step={step}" if step > 1 else ""
    original_size = ""
    if size is not None:
        original_size = (
            f"<original_size><width>{size[0]}</width><height>{size[1]}</height></original_size>"
        )
    return (
        f"<meta><{tag}><id>1</id><mode>interpolation</mode>"
        f"<start_frame>{start}</start_frame><stop_frame>{stop}</stop_frame>"
        f"<frame_filter>{frame_filter}</frame_filter>{original_size}</{tag}></meta>"
    )


def export(tmp_path: Path, body: str, meta: str | None = None, version="1.1", name="a.xml") -> Path:
    """Write an export whose ``body`` (tracks or images) starts on line 4."""
    version_line = "" if version is None else f"<version>{version}</version>"
    meta = task_meta() if meta is None else meta
    text = (
        '<?xml version="1.0" encoding="utf-8"?>\n<annotations>\n'
        f"{version_line}{meta}\n{body}\n</annotations>\n"
    )
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def box(frame, xtl, ytl, xbr, ybr, keyframe=1, outside=0, **extra) -> str:
    attributes = " ".join(f'{key}="{value}"' for key, value in extra.items())
    return (
        f'<box frame="{frame}" keyframe="{keyframe}" outside="{outside}" occluded="0" '
        f'xtl="{xtl}" ytl="{ytl}" xbr="{xbr}" ybr="{ybr}" z_order="0" {attributes}></box>'
    )


def polygon(frame, points: np.ndarray | str, keyframe=1, outside=0, z_order=0) -> str:
    if not isinstance(points, str):
        points = ";".join(f"{x:.2f},{y:.2f}" for x, y in points)
    return (
        f'<polygon frame="{frame}" keyframe="{keyframe}" outside="{outside}" occluded="0" '
        f'points="{points}" z_order="{z_order}"></polygon>'
    )


def track(track_id, label, *shapes) -> str:
    return f'<track id="{track_id}" label="{label}" source="manual">{"".join(shapes)}</track>'


def boxes_of(annotation_track: Track) -> dict[int, list]:
    return {f: s.points.ravel().tolist() for f, s in sorted(annotation_track.shapes.items())}


def assert_same_annotation(read: Annotation, expected: Annotation, atol: float = 0.005) -> None:
    assert read.frames == expected.frames
    assert read.image_names == expected.image_names
    assert read.image_size == expected.image_size
    assert [(t.track_id, t.label) for t in read.tracks] == [
        (t.track_id, t.label) for t in expected.tracks
    ]
    for got, want in zip(read.tracks, expected.tracks):
        assert sorted(got.shapes) == sorted(want.shapes)
        for frame, shape in want.shapes.items():
            other = got.shapes[frame]
            assert (other.kind, other.z_order, other.occluded) == (
                shape.kind,
                shape.z_order,
                shape.occluded,
            )
            np.testing.assert_allclose(other.points, shape.points, rtol=0, atol=atol + 1e-9)
            if shape.bitmap is not None:
                np.testing.assert_array_equal(other.bitmap, shape.bitmap)


# --------------------------------------------------------------------------------------------
# CVAT for video 1.1
# --------------------------------------------------------------------------------------------


def test_track_attributes_are_read_from_their_shapes(tmp_path):
    # CVAT writes a track's attributes into each of its shapes: the first value of each name
    # counts, and a plane_id that changes along the track is noted.
    def with_attributes(shape: str, **values) -> str:
        inner = "".join(f'<attribute name="{k}">{v}</attribute>' for k, v in values.items())
        return shape.replace("></polygon>", f">{inner}</polygon>")

    body = track(3, "wall", with_attributes(polygon(0, TRIANGLE), plane_id="12", equation="0 0 1 -2"),
                 with_attributes(polygon(2, TRIANGLE), plane_id=" 12 "))
    body += track(4, "floor", with_attributes(polygon(0, TRIANGLE), plane_id="5"),
                  with_attributes(polygon(1, TRIANGLE), plane_id="6"))
    body += track(5, "desk", polygon(0, TRIANGLE))
    annotation = read_cvat(export(tmp_path, body))
    assert [t.attributes for t in annotation.tracks] == [
        {"plane_id": "12", "equation": "0 0 1 -2"}, {"plane_id": "5"}, {}]
    assert any(n.startswith("tracks whose plane_id attribute changes along the track") for n in annotation.notes)


def test_written_track_attributes_read_back(tmp_path):
    square = np.array([[1.0, 1.0], [9.0, 1.0], [9.0, 9.0], [1.0, 9.0]])
    tracks = [Track(7, "wall", {0: Shape("polygon", square), 3: Shape("polygon", square + 2)},
                    attributes={"plane_id": "7", "equation": "0 0 -1 2"})]
    path = tmp_path / "w.xml"
    write_cvat_video(Annotation("w", "video", tracks, list(range(6))), path, width=32, height=32)
    assert read_cvat(path).tracks[0].attributes == {"plane_id": "7", "equation": "0 0 -1 2"}


def test_file_export_keeps_every_frame(tmp_path):
    shapes = [box(f, 1 + f, 2, 11 + f, 12, keyframe=int(f in (0, 4))) for f in range(5)]
    path = export(tmp_path, track(0, "wall", *shapes), meta=task_meta(stop=4))
    annotation = read_cvat(path)
    assert annotation.format == "video"
    assert annotation.frames == [0, 1, 2, 3, 4]
    assert annotation.image_names == {}
    assert annotation.image_size == dict.fromkeys(range(5), (64, 48))
    (wall,) = annotation.tracks
    assert (wall.track_id, wall.label) == (0, "wall")
    assert boxes_of(wall) == {f: [1 + f, 2, 11 + f, 12] for f in range(5)}
    assert annotation.notes == []


def test_attribute_order_does_not_matter(tmp_path):
    one = '<polygon frame="2" keyframe="1" outside="0" occluded="1" points="{}" z_order="3"/>'
    other = '<polygon z_order="3" points="{}" occluded="1" outside="0" frame="2" keyframe="1"/>'
    results = []
    for i, element in enumerate([one, other]):
        path = export(tmp_path, track(5, "floor", element.format(TRIANGLE)), name=f"{i}.xml")
        results.append(read_cvat(path))
    assert_same_annotation(results[0], results[1], atol=0)
    shape = results[1].tracks[0].shapes[2]
    assert (shape.kind, shape.z_order, shape.occluded) == ("polygon", 3, True)


def test_keyframes_only_boxes_are_interpolated_linearly(tmp_path):
    body = track(0, "wall", box(0, 0, 0, 10, 10), box(4, 8, 4, 30, 14))
    (wall,) = read_cvat(export(tmp_path, body, meta=task_meta(stop=5))).tracks
    assert boxes_of(wall) == {
        0: [0, 0, 10, 10],
        1: [2, 1, 15, 11],
        2: [4, 2, 20, 12],
        3: [6, 3, 25, 13],
        4: [8, 4, 30, 14],
        5: [8, 4, 30, 14],  # the last keyframe persists to stop_frame
    }


def test_keyframes_only_polygon_follows_a_translation(tmp_path):
    p0 = np.array([[10.0, 10.0], [30.0, 12.0], [25.0, 30.0], [12.0, 24.0]])
    shift = np.array([10.0, -5.0])
    body = track(0, "table", polygon(0, p0), polygon(10, p0 + shift))
    (table,) = read_cvat(export(tmp_path, body, meta=task_meta(stop=10))).tracks
    assert sorted(table.shapes) == list(range(11))
    for frame in range(11):
        np.testing.assert_allclose(table.shapes[frame].points, p0 + frame / 10 * shift, atol=1e-9)


def test_keyframes_only_polygon_may_change_its_vertex_count(tmp_path):
    square = "0.00,0.00;10.00,0.00;10.00,10.00;0.00,10.00"
    with_midpoint = "0.00,0.00;5.00,0.00;10.00,0.00;10.00,10.00;0.00,10.00"
    body = track(0, "wall", polygon(0, square), polygon(10, with_midpoint))
    (wall,) = read_cvat(export(tmp_path, body, meta=task_meta(stop=10))).tracks
    counts = [len(wall.shapes[f].points) for f in range(11)]
    assert counts[0] == 4 and counts[10] == 5
    assert counts[1] == 4  # the new vertex is still within the thinning distance
    np.testing.assert_allclose(wall.shapes[5].points[:2], [[0, 0], [2.5, 0]])


def test_outside_hides_the_track_until_its_next_keyframe(tmp_path):
    body = track(
        0,
        "wall",
        box(0, 0, 0, 10, 10),
        box(4, 4, 0, 14, 10, outside=1),
        box(6, 20, 20, 30, 30),
    )
    (wall,) = read_cvat(export(tmp_path, body, meta=task_meta(stop=9))).tracks
    # Like CVAT, frames before an outside keyframe move towards its position.
    assert boxes_of(wall) == {
        0: [0, 0, 10, 10],
        1: [1, 0, 11, 10],
        2: [2, 0, 12, 10],
        3: [3, 0, 13, 10],
        **{f: [20, 20, 30, 30] for f in range(6, 10)},
    }


def test_track_that_ends_outside_does_not_persist(tmp_path):
    body = track(0, "wall", box(2, 0, 0, 10, 10), box(3, 0, 0, 10, 10, outside=1))
    (wall,) = read_cvat(export(tmp_path, body, meta=task_meta(stop=9))).tracks
    assert sorted(wall.shapes) == [2]


def test_frame_filter_step_and_start_frame(tmp_path):
    body = track(
        0,
        "wall",
        box(10, 0, 0, 10, 10),
        box(11, 5, 5, 9, 9),  # not a task frame: between 10 and 13
        box(16, 6, 0, 16, 10),
        box(25, 1, 1, 2, 2),  # after stop_frame
    )
    annotation = read_cvat(export(tmp_path, body, meta=task_meta(start=10, stop=19, step=3)))
    assert annotation.frames == [10, 13, 16, 19]
    assert boxes_of(annotation.tracks[0]) == {
        10: [0, 0, 10, 10],
        13: [3, 0, 13, 10],
        16: [6, 0, 16, 10],
        19: [6, 0, 16, 10],
    }
    assert annotation.notes == [
        "skipped 1 shape: frame off the task's step grid (step 3) (first at line 4)",
        "skipped 1 shape: frame outside the task range 10-19 (first at line 4)",
    ]


def test_job_export_and_original_size_beside_the_job(tmp_path):
    meta = task_meta(start=100, stop=104, size=None, tag="job").replace(
        "</meta>", "<original_size><width>640</width><height>480</height></original_size></meta>"
    )
    annotation = read_cvat(export(tmp_path, track(3, "wall", box(101, 0, 0, 4, 4)), meta=meta))
    assert annotation.frames == [100, 101, 102, 103, 104]
    assert sorted(annotation.tracks[0].shapes) == [101, 102, 103, 104]
    assert set(annotation.image_size.values()) == {(640, 480)}


def test_project_export_with_one_task(tmp_path):
    task = task_meta(start=0, stop=3).removeprefix("<meta>").removesuffix("</meta>")
    body = track(0, "wall", box(1, 0, 0, 4, 4))
    annotation = read_cvat(
        export(tmp_path, body, meta=f"<meta><project><tasks>{task}</tasks></project></meta>")
    )
    assert annotation.frames == [0, 1, 2, 3]
    assert sorted(annotation.tracks[0].shapes) == [1, 2, 3]
    two_tasks = f"<meta><project><tasks>{task}{task}</tasks></project></meta>"
    message = read_error(export(tmp_path, body, meta=two_tasks, name="b.xml"))
    assert message == "a project export with 2 tasks: export one task or job instead"


def test_masks_are_decoded_and_repeated_between_keyframes(tmp_path):
    # 3 x 2 box at (4, 5): rows "011", "110"
    mask = (
        '<mask frame="{}" keyframe="1" outside="0" occluded="0" rle="1, 4, 1" '
        'left="4" top="5" width="3" height="2" z_order="1"></mask>'
    )
    body = track(0, "wall", mask.format(0), mask.format(3).replace('outside="0"', 'outside="1"'))
    (wall,) = read_cvat(export(tmp_path, body)).tracks
    assert sorted(wall.shapes) == [0, 1, 2]
    shape = wall.shapes[2]
    assert shape.kind == "mask" and shape.z_order == 1
    np.testing.assert_array_equal(shape.points, [[4, 5]])
    np.testing.assert_array_equal(shape.bitmap, [[False, True, True], [True, True, False]])


def test_rotated_box_becomes_a_polygon(tmp_path):
    body = track(0, "wall", box(0, 0, 0, 4, 2, rotation="90.00"))
    shape = read_cvat(export(tmp_path, body)).tracks[0].shapes[0]
    assert shape.kind == "polygon"
    # CVAT turns the corners about the centre (2, 1), clockwise on screen.
    np.testing.assert_allclose(shape.points, [[3, -1], [3, 3], [1, 3], [1, -1]], atol=1e-12)


def test_rotated_box_corners_without_rotation_are_the_box():
    corners = rotated_box_corners(np.array([[1.0, 2.0], [5.0, 4.0]]), 0.0)
    np.testing.assert_allclose(corners, [[1, 2], [5, 2], [5, 4], [1, 4]])


def test_shapes_without_area_are_counted(tmp_path):
    line = (
        '<polyline frame="0" keyframe="1" outside="0" occluded="0" points="1,1;5,5" z_order="0"/>'
    )
    points = '<points frame="0" keyframe="1" outside="0" occluded="0" points="1,1" z_order="0"/>'
    body = (
        track(0, "edge", line, line.replace('"0"', '"1"', 1), line.replace('"0"', '"2"', 1))
        + track(1, "corner", points)
        + track(2, "wall", box(0, 0, 0, 4, 4))
        + track(3, "lamp", '<star frame="0" keyframe="1" outside="0" points="1,1"/>')
    )
    annotation = read_cvat(export(tmp_path, body))
    assert [t.label for t in annotation.tracks] == ["wall"]
    assert annotation.notes == [
        "ignored 3 polyline shapes (no area)",
        "ignored 1 points shape (no area)",
        "ignored 1 <star> element (unknown shape kind)",
    ]


def test_unusable_shapes_are_skipped_with_notes(tmp_path):
    body = track(
        0,
        "wall",
        polygon(0, "1,1;5,5"),  # two points
        polygon(1, "1,1;nan,5;5,1"),
        polygon(2, "1,1;3,3;5,5"),  # collinear
        box(3, 5, 0, 5, 10),  # zero width
        '<mask frame="4" keyframe="1" outside="0" occluded="0" rle="1, 2" left="0" top="0" '
        'width="2" height="2" z_order="0"></mask>',  # runs add up to 3, not 4
        polygon(5, TRIANGLE),
        polygon(6, TRIANGLE, outside=1),
    )
    annotation = read_cvat(export(tmp_path, body))
    assert sorted(annotation.tracks[0].shapes) == [5]
    assert annotation.notes == [
        "skipped 1 shape: polygon with fewer than 3 points (first at line 4)",
        "skipped 1 shape: non-finite coordinates (first at line 4)",
        "skipped 1 shape: polygon with zero area (first at line 4)",
        "skipped 1 shape: box with xbr <= xtl or ybr <= ytl (first at line 4)",
        "skipped 1 shape: mask RLE runs do not add up to width x height (first at line 4)",
    ]


def test_label_filter(tmp_path):
    body = (
        track(0, "wall", box(0, 0, 0, 4, 4), box(1, 0, 0, 4, 4))
        + track(1, "floor", box(0, 0, 0, 4, 4))
        + track(2, "person", box(0, 0, 0, 4, 4), box(1, 0, 0, 4, 4), box(2, 0, 0, 4, 4))
    )
    annotation = read_cvat(export(tmp_path, body), labels=["wall", "floor", "ceiling"])
    assert [t.label for t in annotation.tracks] == ["wall", "floor"]
    assert annotation.notes == [
        "label filter dropped 3 shapes with other labels",
        "label filter: no shape has the label 'ceiling'",
    ]


def test_missing_version_is_accepted_with_a_note(tmp_path):
    annotation = read_cvat(export(tmp_path, track(0, "wall", box(0, 0, 0, 4, 4)), version=None))
    assert annotation.notes == ["no <version> element: read as CVAT XML 1.1"]


def test_track_never_visible_is_dropped_with_a_note(tmp_path):
    body = track(7, "wall", box(2, 0, 0, 4, 4, outside=1))
    annotation = read_cvat(export(tmp_path, body))
    assert annotation.tracks == []
    assert annotation.notes == ["track 7 (line 4) is never visible: dropped"]


# --------------------------------------------------------------------------------------------
# CVAT for images 1.1
# --------------------------------------------------------------------------------------------


def image(frame, *shapes, name=None, size=(32, 24)) -> str:
    name = name or f"img_{frame}.png"
    return (
        f'<image id="{frame}" name="{name}" width="{size[0]}" height="{size[1]}">'
        f"{''.join(shapes)}</image>"
    )


def image_polygon(label, points=TRIANGLE, **extra) -> str:
    attributes = " ".join(f'{key}="{value}"' for key, value in extra.items())
    return f'<polygon label="{label}" source="manual" occluded="0" points="{points}" {attributes}/>'


def test_images_identity_is_group_then_label(tmp_path):
    body = (
        image(0, image_polygon("wall", group_id=4), image_polygon("wall"), image_polygon("floor"))
        + image(1, image_polygon("floor"), image_polygon("wall", group_id=4))
        + image(2, image_polygon("wall", z_order=2), size=(64, 48))
    )
    annotation = read_cvat(export(tmp_path, body, meta=task_meta(stop=2, size=None)))
    assert annotation.format == "images"
    assert annotation.frames == [0, 1, 2]
    assert annotation.image_names == {0: "img_0.png", 1: "img_1.png", 2: "img_2.png"}
    assert annotation.image_size == {0: (32, 24), 1: (32, 24), 2: (64, 48)}
    summary = [(t.track_id, t.label, sorted(t.shapes)) for t in annotation.tracks]
    assert summary == [(0, "wall", [0, 1]), (1, "wall", [0, 2]), (2, "floor", [0, 1])]
    assert annotation.tracks[1].shapes[2].z_order == 2
    assert annotation.notes == []


def plane_polygon(label, plane_id, points=TRIANGLE) -> str:
    """A shape of an images export made from a video task: the track's plane_id on the shape."""
    return (f'<polygon label="{label}" source="manual" occluded="0" points="{points}">'
            f'<attribute name="plane_id">{plane_id}</attribute></polygon>')


def test_images_identity_is_the_plane_id_first(tmp_path):
    # CVAT's images export of a video task keeps each track's plane_id on its shapes and no
    # group: two planes of one label, in another order on each image, stay two tracks, and keep
    # their ids (a shape without one groups by label as before).
    body = (
        image(0, plane_polygon("plane", 6), plane_polygon("plane", 2), image_polygon("plane"))
        + image(1, plane_polygon("plane", 2), plane_polygon("plane", 6, points="20,20;30,20;25,28"))
        + image(2, image_polygon("plane"), plane_polygon("plane", 6))
    )
    annotation = read_cvat(export(tmp_path, body, meta=task_meta(stop=2, size=None)))
    summary = [(t.attributes.get("plane_id"), sorted(t.shapes)) for t in annotation.tracks]
    assert summary == [("6", [0, 1, 2]), ("2", [0, 1]), (None, [0, 2])]
    assert annotation.tracks[0].shapes[1].points.tolist() == [[20, 20], [30, 20], [25, 28]]
    assert annotation.notes == []


def test_images_two_shapes_of_one_identity_stay_apart(tmp_path):
    body = image(0, image_polygon("wall"), image_polygon("wall", points="20,20;30,20;25,28"))
    body += image(1, image_polygon("wall"))
    annotation = read_cvat(export(tmp_path, body, meta=task_meta(stop=1)))
    assert [sorted(t.shapes) for t in annotation.tracks] == [[0, 1], [0]]
    assert annotation.notes == [
        (
            "1 images hold two or more shapes of one label (or group): each extra shape became"
            " a track of its own; give such planes distinct group ids"
        )
    ]


def test_images_boxes_masks_and_ignored_shapes(tmp_path):
    body = image(
        0,
        '<box label="wall" occluded="1" xtl="1" ytl="2" xbr="5" ybr="6" z_order="1"/>',
        '<mask label="floor" rle="0, 2, 2" left="3" top="3" width="2" height="2"/>',
        '<polyline label="edge" points="1,1;4,4"/>',
        '<ellipse label="lamp" cx="5" cy="5" rx="2" ry="1"/>',
        '<tag label="kitchen"/>',
        image_polygon("wall", points="1,1;2,2"),
    )
    annotation = read_cvat(export(tmp_path, body, meta=task_meta(stop=0)))
    wall, floor = annotation.tracks
    assert wall.shapes[0].kind == "box" and wall.shapes[0].occluded
    np.testing.assert_array_equal(floor.shapes[0].bitmap, [[True, True], [False, False]])
    assert annotation.notes == [
        "ignored 1 polyline shape (no area)",
        "ignored 1 ellipse shape (not supported, draw planes as polygons)",
        "ignored 1 tag (no geometry)",
        "skipped 1 shape: polygon with fewer than 3 points (first at line 4)",
    ]


def test_images_off_the_task_grid_are_skipped(tmp_path):
    body = image(0, image_polygon("wall")) + image(1, image_polygon("wall")) + image(2)
    annotation = read_cvat(export(tmp_path, body, meta=task_meta(stop=2, step=2)))
    assert annotation.frames == [0, 2]
    assert [sorted(t.shapes) for t in annotation.tracks] == [[0]]
    assert annotation.notes == [
        "skipped 1 shape: frame off the task's step grid (step 2) (first at line 4)"
    ]


# --------------------------------------------------------------------------------------------
# Errors
# --------------------------------------------------------------------------------------------


def read_error(path: Path, **kwargs) -> str:
    with pytest.raises(InputError) as caught:
        read_cvat(path, **kwargs)
    assert caught.value.path == path
    assert "\n" not in caught.value.message
    return caught.value.message


def test_missing_empty_and_folder_inputs(tmp_path):
    assert read_error(tmp_path / "none.xml") == "file not found"
    assert read_error(tmp_path) == "not a file"
    empty = tmp_path / "empty.xml"
    empty.write_text("")
    assert read_error(empty) == "the file is empty"


def test_malformed_xml_names_the_line(tmp_path):
    path = export(
        tmp_path, track(0, "wall", box(0, 0, 0, 4, 4)) + '\n<track id="1" label="x">\n</trak>'
    )
    assert read_error(path) == (
        "malformed XML at line 6: Opening and ending tag mismatch: track line 5 and trak"
    )


def test_wrong_root(tmp_path):
    path = tmp_path / "a.xml"
    path.write_text("<dataset><item/></dataset>")
    assert (
        read_error(path)
        == "not a CVAT XML export: the root element is <dataset>, not <annotations>"
    )


def test_unsupported_version(tmp_path):
    path = export(tmp_path, "", version="2.0")
    assert read_error(path) == "unsupported CVAT XML version '2.0' (expected 1.1)"


@pytest.mark.parametrize(
    ("element", "message"),
    [
        (box(0, 0, 0, 4, 4).replace('xtl="0" ', ""), "<box> at line 4: attribute 'xtl' is missing"),
        (box(0, "a", 0, 4, 4), "<box> at line 4: attribute xtl='a' is not a number"),
        (box("x", 0, 0, 4, 4), "<box> at line 4: attribute frame='x' is not an integer"),
        (
            polygon(0, "1,1;2;3,3"),
            "<polygon> at line 4: attribute 'points' is not a list of x,y pairs",
        ),
        (polygon(0, "1,1;2,b;3,3"), "<polygon> at line 4: attribute 'points' holds a non-number"),
    ],
)
def test_bad_attributes_name_element_line_and_attribute(tmp_path, element, message):
    assert read_error(export(tmp_path, track(0, "wall", element))) == message


def test_track_without_id(tmp_path):
    path = export(tmp_path, '<track label="wall"></track>')
    assert read_error(path) == "<track> at line 4: attribute 'id' is missing"


def test_duplicate_track_ids(tmp_path):
    body = track(1, "wall", box(0, 0, 0, 4, 4)) + "\n" + track(1, "floor", box(0, 0, 0, 4, 4))
    assert read_error(export(tmp_path, body)) == (
        "<track> at line 5: duplicate track id 1 (first at line 4)"
    )


def test_video_export_needs_a_frame_range(tmp_path):
    path = export(tmp_path, track(0, "wall", box(0, 0, 0, 4, 4)), meta="<meta><task/></meta>")
    assert read_error(path) == "video export without <start_frame>/<stop_frame> in <meta>"


@pytest.mark.parametrize(
    ("meta", "message"),
    [
        (task_meta(start=5, stop=2), "<stop_frame> at line 3: 2 is before start_frame 5"),
        (
            task_meta().replace("<frame_filter>", "<frame_filter>size=2"),
            "<frame_filter> at line 3: unsupported filter 'size=2'",
        ),
        (
            task_meta().replace("<start_frame>0", "<start_frame>zero"),
            "<start_frame> at line 3: 'zero' is not an integer",
        ),
    ],
)
def test_bad_meta(tmp_path, meta, message):
    assert read_error(export(tmp_path, "", meta=meta)) == message


def test_external_entity_is_never_read(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("TOP-SECRET-CONTENT")
    path = tmp_path / "a.xml"
    path.write_text(
        f'<?xml version="1.0"?>\n<!DOCTYPE annotations [<!ENTITY xxe SYSTEM "{secret.as_uri()}">]>\n'
        "<annotations><version>1.1</version><meta><task><name>&xxe;</name></task></meta>\n"
        f"{image(0, image_polygon('&xxe;'))}</annotations>\n"
    )
    message = read_error(path)
    assert "DTD" in message and "TOP-SECRET" not in message


def test_entity_expansion_bomb_is_refused(tmp_path):
    entities = '<!ENTITY a0 "aaaaaaaaaa">' + "".join(
        f'<!ENTITY a{i} "{f"&a{i - 1};" * 10}">' for i in range(1, 10)
    )
    path = tmp_path / "a.xml"
    path.write_text(
        f'<?xml version="1.0"?>\n<!DOCTYPE annotations [{entities}]>\n'
        f"<annotations><version>1.1</version>{image(0, name='&a9;')}</annotations>\n"
    )
    assert "DTD" in read_error(path)


# --------------------------------------------------------------------------------------------
# Writers and round trips
# --------------------------------------------------------------------------------------------


def sample_annotation(fmt: str) -> Annotation:
    rng = np.random.default_rng(7)
    outline = np.array([[10.0, 10.0], [40.0, 12.0], [38.0, 35.0], [12.0, 30.0]])
    bitmap = rng.random((5, 7)) > 0.5
    wall = Track(
        0, "wall", {f: Shape("polygon", outline + rng.normal(0, 2, (4, 2)), 1) for f in range(12)}
    )
    table = Track(
        1,
        "table",
        {
            f: Shape("box", np.array([[2.0 + f, 3.0], [9.5 + f, 8.25]]), occluded=f % 2 == 0)
            for f in [2, 3, 4, 8, 9]
        },
    )
    rug = Track(
        2,
        "rug",
        {
            f: Shape("mask", np.array([[3.0, 4.0]]), bitmap=np.roll(bitmap, f, axis=1))
            for f in [5, 6]
        },
    )
    annotation = Annotation("sample.xml", fmt, [wall, table, rug], list(range(12)))
    if fmt == "images":
        annotation.image_names = {f: f"rgb/{f:04d}.png" for f in annotation.frames}
    annotation.image_size = dict.fromkeys(annotation.frames, (64, 48))
    return annotation


def test_video_round_trip(tmp_path):
    expected = sample_annotation("video")
    path = tmp_path / "video.xml"
    write_cvat_video(expected, path, width=64, height=48)
    read = read_cvat(path)
    assert read.format == "video" and read.notes == []
    assert_same_annotation(read, expected)


def test_video_round_trip_with_frame_step(tmp_path):
    expected = sample_annotation("video")
    expected.frames = [10 + 3 * f for f in expected.frames]
    expected.image_size = dict.fromkeys(expected.frames, (64, 48))
    for t in expected.tracks:
        t.shapes = {10 + 3 * f: shape for f, shape in t.shapes.items()}
    path = tmp_path / "video.xml"
    write_cvat_video(expected, path, width=64, height=48, keyframe_step=2)
    assert_same_annotation(read_cvat(path), expected)


def test_images_round_trip(tmp_path):
    expected = sample_annotation("images")
    path = tmp_path / "images.xml"
    write_cvat_images(expected, path, width=64, height=48)
    read = read_cvat(path)
    assert read.format == "images" and read.notes == []
    assert_same_annotation(read, expected)


def test_keyframes_only_export_reads_back_the_same_linear_motion(tmp_path):
    frames = list(range(20))
    outline = np.array([[10.0, 10.0], [40.0, 12.0], [38.0, 35.0], [12.0, 30.0]])
    moving = Track(
        0, "wall", {f: Shape("polygon", outline + [0.5 * f, 0.25 * f]) for f in frames[:15]}
    )
    sliding = Track(
        1, "door", {f: Shape("box", np.array([[f, 2.0], [f + 10.0, 12.0]])) for f in frames}
    )
    expected = Annotation("x.xml", "video", [moving, sliding], frames)
    expected.image_size = dict.fromkeys(frames, (64, 48))
    path = tmp_path / "api.xml"
    write_cvat_video(expected, path, width=64, height=48, keyframe_step=4, keyframes_only=True)
    text = path.read_text()
    assert 'keyframe="0"' not in text
    assert (
        len(re.findall(r"<(?:polygon|box) ", text)) == 4 + 1 + 1 + 5 + 1
    )  # 0,4,8,12,14 + outside; 0,4,...,16,19
    assert_same_annotation(read_cvat(path), expected)


def test_writer_marks_keyframes_and_closes_runs(tmp_path):
    frames = list(range(10))
    shape = Shape("box", np.array([[0.0, 0.0], [4.0, 4.0]]))
    annotation = Annotation(
        "x.xml", "video", [Track(0, "wall", dict.fromkeys([0, 1, 2, 3, 4, 7, 8], shape))], frames
    )
    path = tmp_path / "x.xml"
    write_cvat_video(annotation, path, width=8, height=8, keyframe_step=3)
    flags = re.findall(r'frame="(\d+)" keyframe="(\d)" outside="(\d)"', path.read_text())
    assert flags == [
        ("0", "1", "0"), ("1", "0", "0"), ("2", "0", "0"), ("3", "1", "0"), ("4", "1", "0"),
        ("5", "1", "1"),
        ("7", "1", "0"), ("8", "1", "0"),
        ("9", "1", "1"),
    ]  # fmt: skip


def test_writer_needs_evenly_spaced_frames(tmp_path):
    annotation = Annotation("x.xml", "video", [], [0, 1, 3])
    with pytest.raises(ValueError):
        write_cvat_video(annotation, tmp_path / "x.xml", width=8, height=8)


def test_rle_round_trip():
    rng = np.random.default_rng(3)
    for bitmap in [rng.random((6, 9)) > 0.5, np.ones((2, 3), bool), np.zeros((2, 3), bool)]:
        runs = encode_rle(bitmap)
        assert runs.sum() == bitmap.size
        np.testing.assert_array_equal(
            decode_rle(runs, 9 if bitmap.shape[1] == 9 else 3, bitmap.shape[0]), bitmap
        )
    np.testing.assert_array_equal(encode_rle(np.array([[True, True, False]])), [0, 2, 1])
    with pytest.raises(ValueError):
        decode_rle([1, 2], 2, 2)


# --------------------------------------------------------------------------------------------
# Real exports (../shared/data, skipped where absent)
# --------------------------------------------------------------------------------------------


def test_datumaro_video_export(shared_data):
    annotation = read_cvat(shared_data / "cvat/datumaro_for_video/annotations.xml")
    # start_frame 10, stop_frame 19, step=3; the folder holds images for 10, 13 and 16 only.
    assert annotation.frames == [10, 13, 16, 19]
    assert set(annotation.image_size.values()) == {(25, 20)}
    (track_0,) = annotation.tracks  # the other two tracks hold points and a polyline
    assert (track_0.track_id, track_0.label, sorted(track_0.shapes)) == (0, "II", [10])
    assert boxes_of(track_0) == {10: [3, 4, 10, 5]}
    assert track_0.shapes[10].occluded
    assert annotation.notes == [
        "ignored 2 points shapes (no area)",
        "ignored 2 polyline shapes (no area)",
    ]


def test_datumaro_images_exports(shared_data):
    folder = shared_data / "cvat/datumaro_for_images"
    annotation = read_cvat(folder / "export_task/train.xml")
    assert annotation.frames == [0, 1]
    assert annotation.image_names == {0: "img0.jpg", 1: "img1.jpg"}
    assert [
        (t.label, sorted(t.shapes), t.shapes[f].kind) for t in annotation.tracks for f in t.shapes
    ] == [
        ("label1", [0], "box"),
        ("", [1], "polygon"),
    ]
    # The project export repeats image ids over its three tasks.
    message = read_error(folder / "export_project/annotations.xml")
    assert message.startswith("<image> at line 140: duplicate image id 0")


def test_real_images_job_export(shared_data):
    annotation = read_cvat(shared_data / "cvat/images_1.1_job_polygons.xml")
    assert annotation.format == "images"
    assert annotation.frames == list(range(99))
    assert annotation.image_names[0] == "BlackRot_1.JPG"
    assert set(annotation.image_size.values()) == {(256, 256)}
    assert sum(len(t.shapes) for t in annotation.tracks) == 99
    counts = {t.label: len(t.shapes) for t in annotation.tracks}
    assert counts == {
        "BR_Advanced": 16,
        "BR_EarlyStage": 9,
        "Esca_Advanced": 21,
        "Esca_EarlyStage": 4,
        "Healthy": 25,
        "LB_Advanced": 21,
        "LB_EarlyStage": 3,
    }
    # A real labeller's polygons: five of them cross themselves, and are used as drawn.
    assert annotation.notes == ["self-intersecting polygons, used as drawn (filled by the even-odd rule): 5 (first at line 375)"]
    healthy = read_cvat(shared_data / "cvat/images_1.1_job_polygons.xml", labels={"Healthy"})
    assert [t.label for t in healthy.tracks] == ["Healthy"]
    assert healthy.notes == ["label filter dropped 74 shapes with other labels"]


def test_real_video_job_export(shared_data):
    path = shared_data / "cvat/video_1.1_job_boxes_interpolated.xml"
    annotation = read_cvat(path)
    assert annotation.format == "video"
    assert annotation.frames == list(range(221))
    assert set(annotation.image_size.values()) == {(1280, 720)}
    assert len(annotation.tracks) == 20
    assert [t.track_id for t in annotation.tracks] == list(range(20))
    assert [t.label for t in annotation.tracks].count("car") == 1
    spans = {t.track_id: (min(t.shapes), max(t.shapes), len(t.shapes)) for t in annotation.tracks}
    assert spans[0] == (0, 220, 221)
    assert spans[4] == (0, 2, 3)  # outside="1" on frame 3
    assert spans[19] == (219, 220, 2)  # persists to stop_frame
    assert all(last - first + 1 == count for first, last, count in spans.values())
    assert annotation.notes == []


def test_real_video_job_export_without_interpolated_frames(shared_data, tmp_path):
    """Dropping the keyframe="0" boxes (an API-style export) gives back CVAT's own values."""
    path = shared_data / "cvat/video_1.1_job_boxes_interpolated.xml"
    text = path.read_text(encoding="utf-8")
    keyframes_only = re.sub(r'\s*<box frame="\d+" keyframe="0"[^>]*>\s*</box>', "", text)
    assert keyframes_only.count("<box ") < text.count("<box ")
    api_path = tmp_path / "api.xml"
    api_path.write_text(keyframes_only, encoding="utf-8")
    # Both hold values rounded to 2 decimals.
    assert_same_annotation(read_cvat(api_path), read_cvat(path), atol=0.01)

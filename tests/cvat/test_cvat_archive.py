"""CVAT's zip download read in place; COCO and other exports named with what to export instead."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.config.settings import load_config
from annotate_rgbd.cvat import archive, read_cvat
from annotate_rgbd.errors import InputError
from annotate_rgbd.pipeline.scene import run_cvat2mask

from conftest import SAMPLE_DATA

ANNOTATIONS = SAMPLE_DATA / "annotations.xml"
ADVICE = "export the task as 'CVAT for video 1.1' or 'CVAT for images 1.1'"


def make_zip(path, members, compression=zipfile.ZIP_DEFLATED):
    """A zip at ``path`` holding ``members`` (name -> bytes or str)."""
    with zipfile.ZipFile(path, "w", compression) as handle:
        for name, data in members.items():
            handle.writestr(name, data)
    return path


def read_error(path) -> str:
    with pytest.raises(InputError) as caught:
        read_cvat(path)
    message = str(caught.value)
    assert "\n" not in message
    return message


def same_annotation(a, b):
    assert (a.format, a.frames, a.labels, a.notes) == (b.format, b.frames, b.labels, b.notes)
    assert [(t.track_id, t.label, sorted(t.shapes)) for t in a.tracks] == [
        (t.track_id, t.label, sorted(t.shapes)) for t in b.tracks
    ]
    for ta, tb in zip(a.tracks, b.tracks):
        for frame in ta.shapes:
            np.testing.assert_array_equal(ta.shapes[frame].points, tb.shapes[frame].points)


@pytest.mark.parametrize("compression", [zipfile.ZIP_DEFLATED, zipfile.ZIP_STORED, zipfile.ZIP_LZMA])
def test_a_cvat_zip_reads_like_its_xml(tmp_path, compression):
    xml = ANNOTATIONS.read_bytes()
    task = make_zip(tmp_path / "task.zip", {"annotations.xml": xml, "images/frame_000000.png": b"\x89PNG"}, compression)
    annotation = read_cvat(task)
    same_annotation(annotation, read_cvat(ANNOTATIONS))
    assert annotation.path == str(task)  # a part is known by the file the user gave
    # An archive with one .xml elsewhere (a job folder) is read as well.
    same_annotation(read_cvat(make_zip(tmp_path / "job.zip", {"job_7/annotations.xml": xml})), annotation)
    # The top-level annotations.xml is the one read, whatever other .xml files come with it.
    extra = {"images/info.xml": "<info/>", "annotations.xml": xml, "other/annotations.xml": "<broken"}
    same_annotation(read_cvat(make_zip(tmp_path / "extra.zip", extra)), annotation)


def test_cvat2mask_on_the_zip_gives_the_masks_of_the_xml(tmp_path):
    config = SAMPLE_DATA / "camera.toml"
    run_cvat2mask(SAMPLE_DATA / "sequence", [ANNOTATIONS], tmp_path / "from_xml", load_config(config))
    task = make_zip(tmp_path / "task.zip", {"annotations.xml": ANNOTATIONS.read_bytes()})
    result = CliRunner().invoke(
        app, ["cvat2mask", str(SAMPLE_DATA / "sequence"), str(task), "--config", str(config), "--out", str(tmp_path / "from_zip")]
    )
    assert result.exit_code == 0, result.output
    masks = sorted(p.name for p in (tmp_path / "from_xml" / "masks").iterdir())
    assert masks and masks == sorted(p.name for p in (tmp_path / "from_zip" / "masks").iterdir())
    for name in masks:
        assert (tmp_path / "from_xml" / "masks" / name).read_bytes() == (tmp_path / "from_zip" / "masks" / name).read_bytes()
    # The planes are the same; each names the part by the file given.
    planes = (tmp_path / "from_zip" / "planes.csv").read_text()
    assert "task.zip" in planes
    assert planes.replace("task.zip", "annotations.xml") == (tmp_path / "from_xml" / "planes.csv").read_text()


def test_coco_and_other_exports_are_named_with_what_to_export(tmp_path):
    coco = {"licenses": [], "info": {}, "categories": [{"id": 1, "name": "wall"}], "images": [], "annotations": []}
    (tmp_path / "instances_default.json").write_text(json.dumps(coco))
    assert read_error(tmp_path / "instances_default.json") == (
        f"{tmp_path / 'instances_default.json'}: this is a COCO export (JSON), not CVAT XML: {ADVICE}"
    )
    zipped = make_zip(tmp_path / "coco.zip", {"annotations/instances_default.json": json.dumps(coco), "images/a.jpg": b"x"})
    assert read_error(zipped) == (
        f"{zipped}: this is a COCO export (it holds annotations/instances_default.json), not CVAT XML: {ADVICE}"
    )
    datumaro = make_zip(tmp_path / "dm.zip", {"annotations/default.json": '{"items": []}'})
    assert read_error(datumaro).startswith(f"{datumaro}: this is a Datumaro export (it holds annotations/default.json)")
    voc = make_zip(tmp_path / "voc.zip", {"Annotations/a.xml": "<annotation/>", "ImageSets/Main/default.txt": "a"})
    assert read_error(voc).startswith(f"{voc}: this is a Pascal VOC export")
    (tmp_path / "items.json").write_text('\ufeff {"info": {}, "categories": {}, "items": []}', encoding="utf-8")
    assert "this is a Datumaro export (JSON)" in read_error(tmp_path / "items.json")


def test_zips_without_a_cvat_xml(tmp_path):
    other = make_zip(tmp_path / "other.zip", {"readme.txt": "hi", "a/b.png": b"x"})
    assert read_error(other) == f"{other}: a zip archive without annotations.xml (it holds readme.txt, a/b.png): {ADVICE}"
    empty = make_zip(tmp_path / "empty.zip", {})
    assert read_error(empty) == f"{empty}: a zip archive without annotations.xml (it holds nothing): {ADVICE}"
    several = make_zip(tmp_path / "several.zip", {"a.xml": "<annotations/>", "b.xml": "<annotations/>"})
    assert read_error(several).startswith(f"{several}: a zip archive of 2 .xml files (a.xml, ...) without annotations.xml")


def test_errors_inside_the_zip_name_the_archive_and_the_member(tmp_path):
    text = ANNOTATIONS.read_text()
    broken = make_zip(tmp_path / "broken.zip", {"annotations.xml": text.replace("</meta>", "</mta>", 1)})
    assert read_error(broken).startswith(f"{broken}/annotations.xml: malformed XML at line ")
    cut = make_zip(tmp_path / "cut.zip", {"annotations.xml": text[: len(text) // 2]})
    assert "/annotations.xml: the file ends at line " in read_error(cut)
    one = make_zip(tmp_path / "one.zip", {"export/task.xml": "<annotation><object/></annotation>"})
    assert read_error(one) == (
        f"{one}/export/task.xml: not a CVAT XML export: the root element is <annotation>, not <annotations>"
    )


def test_a_damaged_zip_is_one_line(tmp_path):
    task = make_zip(tmp_path / "task.zip", {"annotations.xml": ANNOTATIONS.read_bytes()})
    data = task.read_bytes()
    cut = tmp_path / "cut.zip"
    cut.write_bytes(data[: len(data) // 2])  # a download cut short: no central directory
    assert read_error(cut).startswith(f"{cut}: a damaged or incomplete zip archive (")
    # A flipped byte in the compressed data: found while reading (checksum or inflate error).
    flipped = bytearray(data)
    flipped[200] ^= 0xFF
    (tmp_path / "flipped.zip").write_bytes(bytes(flipped))
    assert "a damaged or incomplete zip archive" in read_error(tmp_path / "flipped.zip")


def test_a_zip_bomb_is_refused_by_its_declared_size_and_by_what_it_unpacks(tmp_path, monkeypatch):
    monkeypatch.setattr(archive, "MAX_ARCHIVE_XML_BYTES", 10_000)
    size = ANNOTATIONS.stat().st_size
    task = make_zip(tmp_path / "task.zip", {"annotations.xml": ANNOTATIONS.read_bytes()})
    assert read_error(task) == f"{task}/annotations.xml: unpacks to {size} bytes, more than 10000: not read (unzip it yourself if it really is that large)"
    # A stream that unpacks more than it declares is cut off at the bound while read.
    reader = archive._BoundedReader(io.BytesIO(b"x" * 1000), tmp_path / "bomb.zip/annotations.xml", limit=100)
    with pytest.raises(InputError, match="bomb.zip/annotations.xml: unpacks to more than 100 bytes"):
        while reader.read(64):
            pass
    exact = archive._BoundedReader(io.BytesIO(b"x" * 100), tmp_path / "a", limit=100)
    assert len(exact.read(1000)) + len(exact.read(1000)) == 100  # at the bound itself: read whole
    # A zip whose header understates the size: zipfile stops at the stated size, and the
    # checksum then fails; either way one line, no traceback.
    lying = bytearray(task.read_bytes())
    record = lying.rfind(b"PK\x01\x02")  # the central directory entry: uncompressed size at +24
    lying[record + 24 : record + 28] = (5000).to_bytes(4, "little")
    (tmp_path / "lying.zip").write_bytes(bytes(lying))
    assert "a damaged or incomplete zip archive" in read_error(tmp_path / "lying.zip")


def test_too_many_members(tmp_path, monkeypatch):
    monkeypatch.setattr(archive, "MAX_ARCHIVE_MEMBERS", 5)
    many = make_zip(tmp_path / "many.zip", {"annotations.xml": ANNOTATIONS.read_bytes()} | {f"images/{i}.png": b"x" for i in range(5)})
    assert read_error(many) == (
        f"{many}: a zip archive of 6 files, more than the 5 a CVAT export holds: not read; {ADVICE}"
    )
    five = make_zip(tmp_path / "five.zip", {"annotations.xml": ANNOTATIONS.read_bytes()} | {f"images/{i}.png": b"x" for i in range(4)})
    assert read_cvat(five).tracks


def test_nothing_is_extracted(tmp_path):
    # A member whose name climbs out of the folder is read in place, never written anywhere.
    folder = tmp_path / "inside"
    folder.mkdir()
    evil = make_zip(folder / "evil.zip", {"../../annotations.xml": ANNOTATIONS.read_bytes()})
    before = sorted(p for p in tmp_path.rglob("*"))
    assert read_cvat(evil).tracks
    assert sorted(p for p in tmp_path.rglob("*")) == before


def test_the_command_line_prints_one_error_line(tmp_path):
    coco = make_zip(tmp_path / "coco.zip", {"annotations/instances_default.json": "{}"})
    result = CliRunner().invoke(
        app, ["cvat2mask", str(SAMPLE_DATA / "sequence"), str(coco), "--config", str(SAMPLE_DATA / "camera.toml"),
              "--out", str(tmp_path / "out")]
    )
    assert result.exit_code == 1
    assert result.output.strip().splitlines() == [
        f"error: {coco}: this is a COCO export (it holds annotations/instances_default.json), not CVAT XML: {ADVICE}"
    ]

"""The record of what ``review`` wrote into an output folder: to JSON and back."""

from __future__ import annotations

import json

from annotate_rgbd.io.cleanup import ReviewRecord, read_review_record
from annotate_rgbd.io.outdir import REVIEW_RECORD


def test_a_record_reads_back_as_written(tmp_path):
    record = ReviewRecord({"review.html": "ab12", "contact_sheet.png": "cd34"}, ("1.5.png", "2.5.png"), "ef56")
    (tmp_path / REVIEW_RECORD).write_text(json.dumps(record.to_json()))
    assert read_review_record(tmp_path) == record


def test_an_earlier_versions_record_reads_as_its_files_without_overlays(tmp_path):
    (tmp_path / REVIEW_RECORD).write_text(json.dumps({"review.html": "ab12", "contact_sheet.png": 3}))
    assert read_review_record(tmp_path) == ReviewRecord({"review.html": "ab12"}, ())


def test_what_is_not_of_the_records_shape_is_left_out(tmp_path):
    (tmp_path / REVIEW_RECORD).write_text(json.dumps(
        {"files": {"review.html": "ab12"}, "overlays": ["a.png", "../../x.png", "sub\\\\y.png", 4]}))
    assert read_review_record(tmp_path) == ReviewRecord({"review.html": "ab12"}, ("a.png",))
    for text in ("[1, 2]", "not json", '{"files": [], "overlays": {}}'):
        (tmp_path / REVIEW_RECORD).write_text(text)
        assert read_review_record(tmp_path) == ReviewRecord()
    (tmp_path / REVIEW_RECORD).unlink()
    assert read_review_record(tmp_path) == ReviewRecord()

"""Review of proposals: ``review`` on a ``propose`` folder draws its polygons and masks from its
records, before they go to CVAT."""

from __future__ import annotations

import json
import logging
import shlex
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import SAMPLE_DATA
from scipy import ndimage
from typer.testing import CliRunner

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.cli import app
from annotate_rgbd.config.settings import load_config
from annotate_rgbd.cvat import read_cvat
from annotate_rgbd.errors import InputError
from annotate_rgbd.io.sequence import read_rgb
from annotate_rgbd.propose import run_propose
from annotate_rgbd.review.overlay import TINT_ALPHA
from annotate_rgbd.review.review import review_run
from annotate_rgbd.segment.rasterize import shape_mask


@pytest.fixture(scope="module")
def proposals(tmp_path_factory) -> Path:
    """propose on the sample sequence, every 3rd frame."""
    out = tmp_path_factory.mktemp("proposals") / "out"
    config = load_config(SAMPLE_DATA / "camera.toml", {"propose.every": 3})
    run_propose(SAMPLE_DATA / "sequence", out, config, workers=1)
    return out


def _report(out: Path) -> dict:
    return json.loads((out / "report.json").read_text(encoding="utf-8"))


def _hex(colour: str) -> np.ndarray:
    return np.array([int(colour[i : i + 2], 16) for i in (1, 3, 5)], dtype=float)


def test_review_draws_the_proposals_from_the_records(proposals, tmp_path, monkeypatch):
    out = tmp_path / "out"
    shutil.copytree(proposals, out)
    # Review reads what propose recorded: no stage runs again.
    import annotate_rgbd.detect as detect
    import annotate_rgbd.propose.detect_job as detect_job

    def no_detecting(*args, **kwargs):
        raise AssertionError("review detected planes again")

    monkeypatch.setattr(detect, "detect_planes", no_detecting)
    monkeypatch.setattr(detect_job, "propose_planes", no_detecting)
    result = review_run(out, workers=1)
    report = _report(out)
    written = [f for f in report["frames"] if f["status"] == "written"]
    assert sorted(p.name for p in result.overlays) == sorted(Path(f["mask"]).name for f in written)
    assert result.page.is_file() and result.sheet.is_file()
    colour = {t["track"]: _hex(t["colour"]) for t in report["tracks"]}
    tracks = {t.track_id: t for t in read_cvat(out / "proposals.xml").tracks}
    checked = 0
    for frame in written:
        rgb = read_rgb(SAMPLE_DATA / "sequence" / frame["rgb"]).astype(float)
        mask = read_rgb(out / frame["mask"]).astype(float)
        overlay = read_rgb(out / "overlays" / Path(frame["mask"]).name).astype(float)
        for plane in frame["planes"]:
            pixels = (mask == colour[plane["track"]]).all(axis=2)
            # The plane's pixels inside its polygon are tinted with its colour (away from the
            # outline, where the outline and the id label are drawn).
            points = tracks[plane["track"]].shapes[frame["rgb_index"]].points if frame["cvat_keyframe"] else None
            if points is None:
                continue
            top, left, window = shape_mask(Shape("polygon", points), *pixels.shape)
            inside = np.zeros_like(pixels)
            inside[top : top + window.shape[0], left : left + window.shape[1]] = window
            core = ndimage.binary_erosion(pixels & inside, iterations=4)
            expected = (1 - TINT_ALPHA) * rgb[core] + TINT_ALPHA * colour[plane["track"]]
            if core.sum() > 200:
                close = np.abs(overlay[core] - expected).max(axis=1) <= 2
                assert close.mean() > 0.9, (frame["mask"], plane["track"], close.mean())
                checked += 1
    assert checked >= 5
    page = (out / "review.html").read_text(encoding="utf-8")
    assert all(t["colour"] in page for t in report["tracks"])


def test_the_page_lists_the_proposed_planes_and_their_polygons(proposals, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(proposals, out)
    outcome = CliRunner().invoke(app, ["review", str(out), "--jobs", "1"])
    assert outcome.exit_code == 0, outcome.output
    page = (out / "review.html").read_text(encoding="utf-8")
    start = page.index('id="run-data">') + len('id="run-data">')
    data = json.loads(page[start : page.index("</script>", start)])
    report = _report(out)
    assert [p["plane"] for p in data["planes"]] == [t["track"] for t in report["tracks"]]
    written = [f for f in report["frames"] if f["status"] == "written"]
    assert len(data["frames"]) == len(written)
    for shown, frame in zip(data["frames"], written):
        rows = {row[0]: row for row in shown["planes"]}
        assert sorted(rows) == sorted(p["track"] for p in frame["planes"])
        for plane in frame["planes"]:
            pixels, inside = rows[plane["track"]][3], rows[plane["track"]][4]
            assert pixels == plane["polygon_pixels"]
            assert inside / (pixels + plane["area"] - inside) == pytest.approx(plane["polygon_iou"], abs=1e-4)


def test_review_of_proposals_without_their_polygons_says_what_to_do(proposals, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(proposals, out)
    (out / ".annotate-rgbd-shapes.jsonl").unlink()
    with pytest.raises(InputError, match="run propose again"):
        review_run(out, page=False, sheet=False)


def test_a_new_propose_run_removes_the_earlier_review(proposals, tmp_path, caplog):
    out = tmp_path / "out"
    shutil.copytree(proposals, out)
    review_run(out, workers=1)
    assert (out / "review.html").exists() and any((out / "overlays").iterdir())
    overlays = len(list((out / "overlays").iterdir()))
    config = load_config(SAMPLE_DATA / "camera.toml", {"propose.every": 4})
    with caplog.at_level(logging.INFO, logger="annotate_rgbd"):
        run_propose(SAMPLE_DATA / "sequence", out, config, workers=1)
    assert not (out / "review.html").exists() and not (out / "contact_sheet.png").exists()
    assert not (out / "overlays").exists()
    # Said, with the overlays: the user who looks for the page knows where it went.
    said = [r.getMessage() for r in caplog.records]
    assert [line for line in said if "earlier review" in line] == [
        f"removed review.html, contact_sheet.png and {overlays} overlays (overlays/) of an earlier review (they showed "
        "the earlier output; run review again)"]
    assert not any("no longer asked for" in line for line in said)


def test_other_commands_still_refuse_a_propose_folder(proposals, tmp_path):
    # Each says how a propose folder becomes a run they take: cvat2mask on its proposals.xml.
    sequence = shlex.quote(str(SAMPLE_DATA / "sequence"))
    for command in (["export-cvat", str(proposals), str(tmp_path / "x.xml")], ["stats", str(proposals)],
                    ["export", str(proposals), str(tmp_path / "e"), "--format", "evops"]):
        outcome = CliRunner().invoke(app, command)
        assert outcome.exit_code == 1 and outcome.stderr == (
            f"error: {proposals / 'report.json'}: this is the output of `propose`, not of a cvat2mask run: its planes "
            f"become masks with `annotate-rgbd cvat2mask {sequence} {shlex.quote(str(proposals / 'proposals.xml'))} "
            "--config CONFIG --out DIR` (CONFIG: the propose run's; after correcting the planes in CVAT, or as they "
            "are); then use DIR\n"), command
    assert not (tmp_path / "e").exists()

"""Label file reading, frame matching, sequence scoring and the ``evaluate`` command."""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from annotate_rgbd.cli import app
from annotate_rgbd.errors import InputError
from annotate_rgbd.evaluate.evaluate import evaluate_paths, looks_like_a_photograph, match_frames
from annotate_rgbd.io.labelmaps import colours_to_labels, read_cape_csv, read_label_map
from annotate_rgbd.evaluate.metrics import METRIC_NAMES, frame_statistics

COLOURS = np.array([[0, 0, 0], [255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 0]], np.uint8)


def _planes(shape=(12, 16), n=4, seed=0):
    """A label image with planes 1..n in blocks and an unsegmented strip."""
    rows, cols = np.indices(shape)
    labels = (cols * n // shape[1]) + 1
    labels[rows < 2] = 0
    return np.roll(labels, seed, axis=1)


def _same_partition(a, b):
    """Two label images describe the same planes, whatever their ids (0 kept as 0)."""
    pairs = np.unique(np.stack([a.ravel(), b.ravel()]), axis=1)
    return (
        np.array_equal(a == 0, b == 0)
        and np.unique(pairs[0]).size == pairs.shape[1]
        and np.unique(pairs[1]).size == pairs.shape[1]
    )


def _write_cape(path, labels, trailing_comma=True):
    end = ",\n" if trailing_comma else "\n"
    path.write_text("".join(",".join(map(str, row)) + end for row in labels))


# --- label files ---------------------------------------------------------------------------------


def test_colour_png_round_trip(tmp_path):
    labels = _planes()
    cv2.imwrite(str(tmp_path / "m.png"), COLOURS[labels])
    read = read_label_map(tmp_path / "m.png")
    assert read.shape == labels.shape
    assert _same_partition(read, labels)


def test_colour_mask_without_black_has_no_unsegmented_pixel():
    image = COLOURS[1:3][np.indices((4, 4))[0] % 2]
    labels = colours_to_labels(image)
    assert labels.min() == 1 and np.unique(labels).size == 2


def test_colours_differing_in_one_channel_are_different_planes():
    image = np.array([[[10, 20, 30], [10, 20, 31], [0, 0, 0]]], np.uint8)
    np.testing.assert_array_equal(colours_to_labels(image), [[1, 2, 0]])


@pytest.mark.parametrize("black", [True, False])
def test_colours_are_numbered_by_their_packed_value(black):
    # Independently: every pixel's colour packed to 24 bits, numbered by np.unique (1-based
    # without black); blocks of colour with single odd pixels, as masks with specks are.
    rng = np.random.default_rng(4)
    palette = rng.integers(1, 256, size=(7, 3)).astype(np.uint8)
    if black:
        palette[0] = 0
    image = palette[np.repeat(np.repeat(rng.integers(0, 7, size=(6, 8)), 5, axis=0), 7, axis=1)]
    image[rng.integers(0, 30, 40), rng.integers(0, 56, 40)] = palette[rng.integers(0, 7, 40)]
    packed = (image[..., 0].astype(np.int64) << 16) | (image[..., 1].astype(np.int64) << 8) | image[..., 2]
    expected = np.unique(packed, return_inverse=True)[1].reshape(packed.shape) + (packed.min() != 0)
    got = colours_to_labels(image)
    assert got.dtype == np.int32
    np.testing.assert_array_equal(got, expected)
    assert colours_to_labels(np.zeros((0, 5, 3), np.uint8)).shape == (0, 5)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_single_channel_png_keeps_label_values(tmp_path, dtype):
    labels = (_planes() * (1000 if dtype == np.uint16 else 10)).astype(dtype)
    cv2.imwrite(str(tmp_path / "m.png"), labels)
    read = read_label_map(tmp_path / "m.png")
    assert read.dtype == dtype
    np.testing.assert_array_equal(read, labels)


def test_npy_and_cape_csv(tmp_path):
    labels = _planes()
    np.save(tmp_path / "a.npy", labels)
    _write_cape(tmp_path / "b.csv", labels)
    _write_cape(tmp_path / "c.csv", labels, trailing_comma=False)
    for name in ("a.npy", "b.csv", "c.csv"):
        np.testing.assert_array_equal(read_label_map(tmp_path / name), labels)


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("ragged.csv", "1,2,3,\n1,2,\n", "differ in length"),
        ("text.csv", "1,a,3,\n", "not an integer"),
        ("empty.csv", "\n\n", "empty"),
        ("broken.png", "not a png", "cannot read PNG"),
        ("mask.jpg", "", "unsupported"),
    ],
)
def test_unreadable_label_files(tmp_path, name, content, message):
    (tmp_path / name).write_text(content)
    with pytest.raises(InputError, match=message) as error:
        read_label_map(tmp_path / name)
    assert error.value.path == tmp_path / name


@pytest.mark.parametrize(
    ("array", "message"), [(np.ones((3, 3)), "integers"), (np.ones((2, 3, 3), int), "2-D")]
)
def test_rejects_npy_that_is_not_a_label_image(tmp_path, array, message):
    np.save(tmp_path / "x.npy", array)
    with pytest.raises(InputError, match=message):
        read_label_map(tmp_path / "x.npy")


def test_cape_csv_reads_large_frames_exactly(tmp_path):
    labels = np.random.default_rng(1).integers(0, 40, (480, 640))
    _write_cape(tmp_path / "f.csv", labels)
    np.testing.assert_array_equal(read_cape_csv(tmp_path / "f.csv"), labels)


# --- sequences -----------------------------------------------------------------------------------


@pytest.fixture
def sequence(tmp_path):
    """GT: three colour masks. PRED: one per format, a merge on frame b, frame c missing, one extra."""
    gt_dir, pred_dir = tmp_path / "gt", tmp_path / "pred"
    gt_dir.mkdir()
    pred_dir.mkdir()
    frames = {name: _planes(seed=i) for i, name in enumerate(("0001.5", "0002.5", "0003.5"))}
    for name, labels in frames.items():
        cv2.imwrite(str(gt_dir / f"{name}.png"), COLOURS[labels])
    predictions = {
        "0001.5": np.where(frames["0001.5"] == 0, 0, frames["0001.5"] + 7),  # renumbered
        "0002.5": np.where(frames["0002.5"] == 2, 1, frames["0002.5"]),  # planes 1 and 2 merged
    }
    np.save(pred_dir / "0001.5.npy", predictions["0001.5"])
    _write_cape(pred_dir / "0002.5.csv", predictions["0002.5"])
    np.save(pred_dir / "9999.npy", frames["0001.5"])
    (pred_dir / "notes.txt").write_text("ignored")
    return gt_dir, pred_dir, frames, predictions


def test_evaluate_paths_scores_each_frame_and_averages(sequence):
    gt_dir, pred_dir, frames, predictions = sequence
    result = evaluate_paths(gt_dir, pred_dir)
    assert [f.name for f in result.frames] == ["0001.5", "0002.5", "0003.5"]
    assert result.frames_missing == ["0003.5"]
    assert result.predictions_unmatched == ("9999.npy",)
    expected = [
        frame_statistics(frames["0001.5"], predictions["0001.5"]),
        frame_statistics(frames["0002.5"], predictions["0002.5"]),
        frame_statistics(frames["0003.5"], np.zeros_like(frames["0003.5"])),
    ]
    assert [f.statistics for f in result.frames] == expected
    assert expected[0].fScore == 1.0 and expected[1].usr > 0 and expected[2].missed == 1.0
    for name in METRIC_NAMES:
        assert result.means[name] == pytest.approx(np.mean([getattr(s, name) for s in expected]))
    assert set(result.to_dict()) == {*METRIC_NAMES, "frames", "frames_missing", "frames_skipped"}


def test_skip_missing_scores_only_the_frames_pred_has(sequence, caplog):
    gt_dir, pred_dir, frames, predictions = sequence
    result = evaluate_paths(gt_dir, pred_dir, skip_missing=True)
    assert [f.name for f in result.frames] == ["0001.5", "0002.5"]
    assert result.frames_missing == [] and result.frames_skipped == ("0003.5",)
    expected = [frame_statistics(frames[name], predictions[name]) for name in ("0001.5", "0002.5")]
    for name in METRIC_NAMES:
        assert result.means[name] == pytest.approx(np.mean([getattr(s, name) for s in expected]))
    assert result.to_dict()["frames"] == 2 and result.to_dict()["frames_skipped"] == ["0003.5"]
    # One missing frame of three: no warning; two of three: a warning naming --skip-missing.
    assert "--skip-missing" not in caplog.text
    (pred_dir / "0002.5.csv").unlink()
    evaluate_paths(gt_dir, pred_dir)
    assert "no mask for 2 of the 3 ground-truth frames" in caplog.text and "--skip-missing" in caplog.text


def test_thresholds_change_the_result(sequence):
    gt_dir, pred_dir, _, _ = sequence
    # The merged prediction overlaps each of its two planes with IoU 0.5: a partial overlap at
    # part 0.2, none at part 0.6.
    assert evaluate_paths(gt_dir, pred_dir, part=0.2).means["usr"] > 0
    assert evaluate_paths(gt_dir, pred_dir, full=0.75, part=0.6).means["usr"] == 0


def test_single_files_are_paired_whatever_their_names(tmp_path):
    labels = _planes()
    cv2.imwrite(str(tmp_path / "gt.png"), COLOURS[labels])
    np.save(tmp_path / "out.npy", labels)
    result = evaluate_paths(tmp_path / "gt.png", tmp_path / "out.npy")
    assert len(result.frames) == 1 and result.means["panoptic"] == 1.0


def test_flat_npy_labels_of_the_evops_export_are_read_row_major(tmp_path):
    # export --format evops writes each frame's labels flat, row after row (what the evops
    # package scores): evaluate takes them in the ground truth's shape, scoring as the 2-D mask.
    labels = _planes(seed=3)
    prediction = np.where(labels == 2, 1, labels)  # two planes merged: a score below 1
    cv2.imwrite(str(tmp_path / "gt.png"), COLOURS[labels])
    np.save(tmp_path / "flat.npy", prediction.ravel().astype(np.int32))
    np.save(tmp_path / "square.npy", prediction)
    flat = evaluate_paths(tmp_path / "gt.png", tmp_path / "flat.npy").frames[0].statistics
    assert flat == evaluate_paths(tmp_path / "gt.png", tmp_path / "square.npy").frames[0].statistics
    assert flat == frame_statistics(labels, prediction) and flat.usr > 0
    # A transposed frame read row-major is another frame: the scores say so.
    np.save(tmp_path / "transposed.npy", prediction.T.ravel())
    assert evaluate_paths(tmp_path / "gt.png", tmp_path / "transposed.npy").means["mean"] < flat.mean
    np.save(tmp_path / "short.npy", prediction.ravel()[:-1])
    with pytest.raises(InputError, match=rf"frame is {labels.size - 1} labels but ground truth gt.png is "
                                         rf"{labels.shape[1]}x{labels.shape[0]}"):
        evaluate_paths(tmp_path / "gt.png", tmp_path / "short.npy")


def test_input_errors(tmp_path, sequence):
    gt_dir, pred_dir, frames, _ = sequence
    np.save(pred_dir / "0003.5.npy", np.zeros((5, 5), int))
    with pytest.raises(InputError, match="5x5 but ground truth 0003.5.png is 16x12") as error:
        evaluate_paths(gt_dir, pred_dir)
    assert error.value.path == pred_dir / "0003.5.npy"
    np.save(pred_dir / "0002.5.npy", frames["0002.5"])
    with pytest.raises(InputError, match="ambiguous"):
        match_frames(gt_dir, pred_dir)
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no label files"):
        evaluate_paths(tmp_path / "empty", pred_dir)
    with pytest.raises(InputError, match="both be folders or both be files"):
        evaluate_paths(gt_dir, pred_dir / "0001.5.npy")
    with pytest.raises(InputError, match="not found"):
        evaluate_paths(gt_dir, tmp_path / "nowhere")
    with pytest.raises(InputError, match="--full"):
        evaluate_paths(gt_dir, pred_dir, full=0)


def test_a_prediction_that_cannot_be_matched_is_an_error_not_a_zero_score(tmp_path, sequence):
    gt_dir, _, _, _ = sequence
    empty = tmp_path / "empty_pred"
    empty.mkdir()
    (empty / "notes.txt").write_text("not a label file")
    with pytest.raises(InputError, match=r"no label files \(.png, .npy, .csv\) in the prediction folder") as error:
        evaluate_paths(gt_dir, empty)
    assert error.value.path == empty
    renamed = tmp_path / "renamed"
    renamed.mkdir()
    np.save(renamed / "frame_0001.npy", _planes())
    with pytest.raises(InputError, match="no file name in common with the ground truth .PRED has e.g. frame_0001, GT 0001.5."):
        evaluate_paths(gt_dir, renamed)
    # One name in common is enough: the rest are listed, as before.
    np.save(renamed / "0002.5.npy", _planes(seed=1))
    assert evaluate_paths(gt_dir, renamed).frames_missing == ["0001.5", "0003.5"]


def test_photographs_given_as_masks_are_warned_about(tmp_path, caplog):
    gt_dir, pred_dir = tmp_path / "gt", tmp_path / "pred"
    gt_dir.mkdir()
    pred_dir.mkdir()
    rng = np.random.default_rng(0)
    planes = np.repeat(np.repeat(_planes(), 4, axis=0), 4, axis=1)  # 64x48
    planes[0, 0] = 9  # one speck of one pixel in a real mask is no photograph
    shading = (rng.normal(0, 6, (*planes.shape, 3)) + COLOURS[planes % len(COLOURS)]).clip(0, 255).astype(np.uint8)
    for name in ("a", "b"):
        cv2.imwrite(str(gt_dir / f"{name}.png"), COLOURS[planes % len(COLOURS)])
        cv2.imwrite(str(pred_dir / f"{name}.png"), shading)  # every shade of noise becomes a "plane"
    with caplog.at_level("WARNING", logger="annotate_rgbd"):
        result = evaluate_paths(gt_dir, pred_dir)
    assert [f.unlikely_masks for f in result.frames] == [(str(pred_dir / "a.png"),), (str(pred_dir / "b.png"),)]
    assert len(caplog.records) == 1
    assert caplog.records[0].getMessage() == (
        f"{pred_dir / 'a.png'}: made mostly of tiny labels or of hundreds of them (every shade a plane): a photograph or a depth image rather than a mask? "
        "(and 1 more label files)")
    assert looks_like_a_photograph(planes) is False
    assert looks_like_a_photograph(colours_to_labels(shading)) is True


# --- command line --------------------------------------------------------------------------------


def test_cli_table(sequence):
    gt_dir, pred_dir, _, _ = sequence
    result = CliRunner().invoke(app, ["evaluate", str(gt_dir), str(pred_dir)])
    assert result.exit_code == 0, result.output
    for name in METRIC_NAMES:
        assert name in result.output
    assert "frames: 3" in result.output and "0003.5" in result.output
    assert "PRED files without a GT frame (ignored): 1: 9999.npy" in result.output
    skipped = CliRunner().invoke(app, ["evaluate", str(gt_dir), str(pred_dir), "--skip-missing"])
    assert skipped.exit_code == 0, skipped.output
    assert "frames: 2" in skipped.output and "missing in PRED (not scored: --skip-missing): 1: 0003.5" in skipped.output


def test_cli_json_and_per_frame_csv(sequence, tmp_path):
    gt_dir, pred_dir, _, _ = sequence
    per_frame = tmp_path / "frames.csv"
    args = ["evaluate", str(gt_dir), str(pred_dir), "--json", "--full", "0.8", "--partial", "0.3"]
    result = CliRunner().invoke(app, [*args, "--per-frame", str(per_frame)])
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    expected = evaluate_paths(gt_dir, pred_dir, full=0.8, part=0.3)
    assert payload == expected.to_dict()
    assert list(payload) == [*METRIC_NAMES, "frames", "frames_missing", "frames_skipped"]
    assert payload["frames"] == 3 and payload["frames_missing"] == ["0003.5"] and payload["frames_skipped"] == []
    with per_frame.open() as stream:
        rows = list(csv.DictReader(stream))
    assert [row["frame"] for row in rows] == ["0001.5", "0002.5", "0003.5"]
    assert [row["missing"] for row in rows] == ["0", "0", "1"]
    for row, frame in zip(rows, expected.frames):
        assert float(row["recall"]) == frame.statistics.recall


def test_per_frame_csv_never_replaces_what_is_scored_nor_a_runs_files(tmp_path):
    from builders import error_line
    from conftest import SAMPLE_DATA

    run = tmp_path / "run"
    made = CliRunner().invoke(app, ["cvat2mask", str(SAMPLE_DATA / "sequence"), str(SAMPLE_DATA / "annotations.xml"),
                                    "--config", str(SAMPLE_DATA / "camera.toml"), "--out", str(run), "--jobs", "1"])
    assert made.exit_code == 0, made.output
    before = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    gt = SAMPLE_DATA / "ground_truth"
    cases = {
        run / "planes.csv": f"is planes.csv of the annotate-rgbd output folder {run}; write the per-frame CSV elsewhere",
        run / "report.json": f"is report.json of the annotate-rgbd output folder {run}; write the per-frame CSV elsewhere",
        run / "masks" / "x.csv": f"is inside the masks being scored ({run / 'masks'}); write the per-frame CSV elsewhere",
        gt / "x.csv": f"is inside the ground truth being scored ({gt}); write the per-frame CSV elsewhere",
        run: f"is a folder: name the CSV file to write (e.g. {run / 'per_frame.csv'})",
        tmp_path / "none" / "x.csv": f"cannot write output: its folder {tmp_path / 'none'} does not exist",
    }
    for target, message in cases.items():
        result = CliRunner().invoke(app, ["evaluate", str(gt), str(run), "--per-frame", str(target)])
        assert result.exit_code == 1
        assert error_line(result) == f"error: {target}: {message}"
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == before
    assert not (gt / "x.csv").exists()
    fine = CliRunner().invoke(app, ["evaluate", str(gt), str(run), "--per-frame", str(tmp_path / "frames.csv")])
    assert fine.exit_code == 0 and (tmp_path / "frames.csv").read_text().startswith("frame,")
    # An earlier per-frame CSV is replaced; any other file stays (a frame list or an annotation
    # export named by mistake: a CLI trial lost both).
    again = CliRunner().invoke(app, ["evaluate", str(gt), str(run), "--per-frame", str(tmp_path / "frames.csv")])
    assert again.exit_code == 0, again.output
    listing = tmp_path / "rgb.txt"
    listing.write_text("# color images\n0.1 rgb/0.1.png\n")
    refused = CliRunner().invoke(app, ["evaluate", str(gt), str(run), "--per-frame", str(listing)])
    assert refused.exit_code == 1
    assert error_line(refused) == (f"error: {listing}: already exists and is not a per-frame CSV of evaluate (it begins "
                                   "'# color images'): it is not replaced; write the per-frame CSV elsewhere, or delete "
                                   "that file first")
    assert listing.read_text() == "# color images\n0.1 rgb/0.1.png\n"


def test_cli_part_is_the_deprecated_name_of_partial(sequence):
    gt_dir, pred_dir, _, _ = sequence
    base = ["evaluate", str(gt_dir), str(pred_dir), "--json"]
    # At 0.6 the merged prediction is no partial overlap any more: the threshold is really used.
    expected = evaluate_paths(gt_dir, pred_dir, part=0.6).to_dict()
    assert expected != evaluate_paths(gt_dir, pred_dir).to_dict()
    new = CliRunner().invoke(app, [*base, "--partial", "0.6"])
    old = CliRunner().invoke(app, [*base, "--part", "0.6"])
    assert new.exit_code == old.exit_code == 0, old.output
    assert json.loads(new.stdout) == json.loads(old.stdout) == expected
    assert new.stderr == ""
    assert old.stderr.count("\n") == 1 and old.stderr.startswith("warning: evaluate --part is deprecated, use --partial")
    both = CliRunner().invoke(app, [*base, "--part", "0.6", "--partial", "0.5"])
    assert both.exit_code == 1 and both.stderr.startswith("error: give --partial only")
    help_text = CliRunner().invoke(app, ["evaluate", "--help"], env={"COLUMNS": "200"}).stdout
    assert "--partial" in help_text and "--part " not in help_text


def test_cli_reads_the_thresholds_from_the_evaluate_section(sequence, tmp_path):
    gt_dir, pred_dir, _, _ = sequence
    base = ["evaluate", str(gt_dir), str(pred_dir), "--json"]
    # At partial 0.6 the merged prediction is no partial overlap any more (as above).
    expected = evaluate_paths(gt_dir, pred_dir, part=0.6).to_dict()
    assert expected != evaluate_paths(gt_dir, pred_dir).to_dict()
    config = tmp_path / "scene.toml"
    config.write_text("[evaluate]\npartial = 0.6\n")
    from_file = CliRunner().invoke(app, [*base, "--config", str(config)])
    from_set = CliRunner().invoke(app, [*base, "--set", "evaluate.partial=0.6"])
    assert from_file.exit_code == from_set.exit_code == 0, from_file.output
    assert json.loads(from_file.stdout) == json.loads(from_set.stdout) == expected
    # The option beats the file.
    option = CliRunner().invoke(app, [*base, "--config", str(config), "--partial", "0.2"])
    assert json.loads(option.stdout) == evaluate_paths(gt_dir, pred_dir).to_dict()
    bad = CliRunner().invoke(app, [*base, "--set", "evaluate.full=1.5"])
    assert bad.exit_code == 1
    assert bad.stderr == "error: command-line option: 'evaluate.full' must be in (0, 1], got 1.5\n"
    # A partial overlap stricter than a full match scores nonsense (precision + noise above 1).
    above = CliRunner().invoke(app, [*base, "--partial", "0.9"])
    assert above.exit_code == 1
    assert above.stderr == ("error: --partial (0.9) must be at most --full (0.75): a partial overlap is a weaker "
                            "match\n")
    assert CliRunner().invoke(app, [*base, "--partial", "0.75"]).exit_code == 0


def test_cli_reports_bad_input_in_one_line(sequence, tmp_path):
    gt_dir, _, _, _ = sequence
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "0001.5.csv").write_text("1,2,\n3,\n")
    result = CliRunner().invoke(app, ["evaluate", str(gt_dir), str(broken)])
    assert result.exit_code == 1
    assert result.stderr.strip().count("\n") == 0
    assert result.stderr.startswith(f"error: {broken / '0001.5.csv'}: ")
    assert "Traceback" not in result.output


def test_a_depth_folder_given_as_ground_truth_is_warned_about(tmp_path, caplog):
    """Kinect depth has a few hundred distinct values spread over the frame: not a plane mask."""
    from conftest import SAMPLE_DATA

    depth = sorted((SAMPLE_DATA / "sequence" / "depth").glob("*.png"))[0]
    quantised = (cv2.imread(str(depth), cv2.IMREAD_UNCHANGED) // 25 * 25).astype(np.uint16)  # ~ TUM's 350 values
    assert 257 < len(np.unique(quantised)) < 2000
    assert looks_like_a_photograph(quantised.astype(np.int64))
    assert not looks_like_a_photograph(np.repeat(np.arange(200), 400).reshape(320, 250))  # 200 planes: a mask


def test_a_runs_output_folder_stands_for_its_masks(tmp_path):
    from annotate_rgbd.evaluate.evaluate import label_folder

    (tmp_path / "run" / "masks").mkdir(parents=True)
    (tmp_path / "run" / "report.json").write_text("{}")
    assert label_folder(tmp_path / "run") == tmp_path / "run" / "masks"
    assert label_folder(tmp_path / "other") == tmp_path / "other"


# --- don't-care pixels of the ground truth --------------------------------------------------------


def _dont_care_frame(tmp_path):
    """GT: 16-bit labels 1..4 with a 2-px band of 65535 on the borders of planes 1 and 2. PRED:
    the GT planes, but plane 1 also takes the band, and plane 3 the band's first column too."""
    gt_dir, pred_dir = tmp_path / "gt", tmp_path / "pred"
    gt_dir.mkdir()
    pred_dir.mkdir()
    planes = _planes(shape=(24, 32))
    gt = planes.astype(np.uint16)
    band = (np.indices(gt.shape)[1] // 2 == 3) | (np.indices(gt.shape)[1] // 2 == 4)  # columns 6..9
    gt[band & (planes > 0)] = 65535
    cv2.imwrite(str(gt_dir / "f.png"), gt)
    pred = planes.copy()
    pred[band & (planes > 0)] = 1
    np.save(pred_dir / "f.npy", pred)
    return gt_dir, pred_dir, gt, pred


def test_ignore_leaves_dont_care_pixels_out_of_both(tmp_path, caplog):
    gt_dir, pred_dir, gt, pred = _dont_care_frame(tmp_path)
    dont_care = gt == 65535
    with caplog.at_level("WARNING", logger="annotate_rgbd"):
        ignored = evaluate_paths(gt_dir, pred_dir, ignore=65535)
    assert caplog.text == ""
    # Independently: both label maps with the band set to "no plane".
    expected = frame_statistics(np.where(dont_care, 0, gt).astype(np.int64), np.where(dont_care, 0, pred))
    assert ignored.frames[0].statistics == expected
    assert expected.fScore == 1.0  # off the band, PRED is GT
    # Without it the band is a plane of its own, and a warning says what it may be.
    scored = evaluate_paths(gt_dir, pred_dir)
    assert scored.frames[0].statistics == frame_statistics(gt.astype(np.int64), pred)
    assert scored.means["fScore"] < 1.0
    share = 100 * dont_care.mean()
    assert (f"{gt_dir / 'f.png'}: label 65535 (its type's largest value, a common \"don't care\" mark) covers "
            f"{share:.0f} % of the pixels of 1 ground-truth frames and is scored as a plane; if it marks pixels to "
            "leave out, add --ignore 65535") in caplog.text
    # A mask of one plane as 0 / 255 is no "don't care" mark: no warning.
    caplog.clear()
    cv2.imwrite(str(gt_dir / "f.png"), np.where(pred > 0, 255, 0).astype(np.uint8))
    with caplog.at_level("WARNING", logger="annotate_rgbd"):
        evaluate_paths(gt_dir, pred_dir)
    assert caplog.text == ""
    cv2.imwrite(str(gt_dir / "f.png"), gt)
    # A label value that is not there changes nothing, and a warning says so (70000: no 16-bit label
    # file can hold it); from the command line and the configuration.
    with caplog.at_level("WARNING", logger="annotate_rgbd"):  # the "no plane" label: a likely mistake
        evaluate_paths(gt_dir, pred_dir, ignore=0)
    assert caplog.text.count("--ignore 0: label 0 is \"no plane\" in every label format") == 1
    for absent in (7, 70000):
        caplog.clear()
        with caplog.at_level("WARNING", logger="annotate_rgbd"):
            assert evaluate_paths(gt_dir, pred_dir, ignore=absent).to_dict() == scored.to_dict()
        assert caplog.text.count(f"--ignore {absent}: no ground-truth pixel holds that label in any of the 1 frames "
                                 "scored, so nothing was left out") == 1
    for args in (["--ignore", "65535"], ["--set", "evaluate.ignore=65535"]):
        result = CliRunner().invoke(app, ["evaluate", str(gt_dir), str(pred_dir), "--json", *args])
        assert result.exit_code == 0, result.output
        assert json.loads(result.stdout) == ignored.to_dict()


def test_ignore_refuses_colour_ground_truth(tmp_path):
    gt_dir, pred_dir = tmp_path / "gt", tmp_path / "pred"
    gt_dir.mkdir()
    pred_dir.mkdir()
    cv2.imwrite(str(gt_dir / "f.png"), COLOURS[_planes()])
    np.save(pred_dir / "f.npy", _planes())
    result = CliRunner().invoke(app, ["evaluate", str(gt_dir), str(pred_dir), "--ignore", "65535"])
    assert result.exit_code == 1
    assert result.stderr == (f"error: {gt_dir / 'f.png'}: a colour mask, whose colours have no label values: "
                             "--ignore 65535 needs label files (single-channel PNG, .npy or .csv)\n")
    bad = CliRunner().invoke(app, ["evaluate", str(gt_dir), str(pred_dir), "--set", "evaluate.ignore=-2"])
    assert bad.exit_code == 1 and "'evaluate.ignore' must be a label value >= 0, or -1 for none" in bad.stderr


def test_an_evops_export_folder_is_scored_by_its_labels_as_the_run_is(sample_run, tmp_path):
    # The export's labels/ (plane ids in .npy) and the run's colour masks are one segmentation:
    # the same score. Before, the folder itself was read and held no label file.
    from conftest import SAMPLE_DATA
    from annotate_rgbd.export import export_run

    out, _ = sample_run
    export_run(out, "evops", tmp_path / "evops")
    gt = SAMPLE_DATA / "ground_truth"
    result = CliRunner().invoke(app, ["evaluate", str(gt), str(tmp_path / "evops"), "--json"])
    assert result.exit_code == 0, result.output
    assert f"info: {tmp_path / 'evops'}: an EVOPS export: scoring its labels/" in result.stderr
    scored, expected = json.loads(result.stdout), evaluate_paths(gt, out / "masks").to_dict()
    assert scored.keys() == expected.keys()
    for key, value in expected.items():  # the planes' order differs: sums may differ in the last bit
        assert scored[key] == (pytest.approx(value, abs=1e-12) if isinstance(value, float) else value), key

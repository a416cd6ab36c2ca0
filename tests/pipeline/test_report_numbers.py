"""Every number of the report, and every field of the resume fingerprint, pinned.

The report's plane numbers are recomputed here from the files alone — the depth PNGs, the
written colour masks, the raw masks (the shapes as drawn) and the camera — with plain numpy,
never with the package's own functions. Replacing any of them by a constant, or leaving a
field out of the fingerprint, makes a test here fail.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from annotate_rgbd.config.settings import load_config
from annotate_rgbd.pipeline.scene import run_cvat2mask
from annotate_rgbd.pipeline.plan import Association
from annotate_rgbd.io.sequence import associate

from conftest import SAMPLE_DATA

SEQUENCE, ANNOTATIONS, CAMERA = SAMPLE_DATA / "sequence", SAMPLE_DATA / "annotations.xml", SAMPLE_DATA / "camera.toml"
PARTS = [SAMPLE_DATA / "parts" / "0-11.xml", SAMPLE_DATA / "parts" / "9-18.xml"]


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("numbers") / "out"
    run_cvat2mask(SEQUENCE, [ANNOTATIONS], out, load_config(CAMERA), raw_masks=True)
    return out


def _ids(image: Path, rows: list[dict]) -> np.ndarray:
    """Plane id per pixel of a colour mask, through planes.csv."""
    rgb = cv2.cvtColor(cv2.imread(str(image)), cv2.COLOR_BGR2RGB).astype(np.int64)
    packed = (rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]
    ids = np.zeros(packed.shape, np.int64)
    for row in rows:
        ids[packed == (int(row["r"]) << 16) | (int(row["g"]) << 8) | int(row["b"])] = int(row["plane_id"])
    return ids


def _points(depth_raw: np.ndarray, camera: dict) -> np.ndarray:
    """(H, W, 3) camera-frame points in metres (NaN where the depth is 0)."""
    z = depth_raw.astype(np.float64) / camera["depth_scale"]
    z[depth_raw == 0] = np.nan
    rows, cols = np.mgrid[: z.shape[0], : z.shape[1]]
    return np.dstack([(cols - camera["cx"]) / camera["fx"] * z, (rows - camera["cy"]) / camera["fy"] * z, z])


def _kinect_sigma(z: np.ndarray) -> np.ndarray:
    """Axial depth noise of a Kinect v1, metres (Nguyen, Izadi & Lovell 2012)."""
    return 0.0012 + 0.0019 * (z - 0.4) ** 2


def test_every_plane_number_of_the_report_follows_from_the_files(run):
    report = json.loads((run / "report.json").read_text())
    camera = report["config"]["camera"]
    noise = report["config"]["noise"]
    # The sample's: the noise model the renderer draws its depth noise from, no fixed band.
    assert noise == {"model": "kinect_v1", "k": 3.0, "floor": 0.002, "cap": 0.1}
    assert report["config"]["ransac"]["distance_threshold"] == 0.0
    with open(run / "planes.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    checked = {"kept": 0, "dropped": 0}
    for frame in (f for f in report["frames"] if f["status"] == "written"):
        depth = cv2.imread(str(SEQUENCE / frame["depth"]), cv2.IMREAD_UNCHANGED)
        points = _points(depth, camera)
        valid = depth > 0
        mask = _ids(run / frame["mask"], rows)
        drawn = _ids(run / "masks_raw" / Path(frame["mask"]).name, rows)
        for record in frame["kept"] + frame["dropped"]:
            plane = record["plane"]
            shape = drawn == plane
            assert record["pixels"] == int(shape.sum())
            assert record["valid_pixels"] == int((shape & valid).sum())
            distance = np.linalg.norm(points[shape & valid], axis=1)
            assert record["mean_distance"] == pytest.approx(distance.mean(), abs=2e-6)
            if "reason" in record:
                assert record["invalid_ratio"] == pytest.approx(1 - record["valid_pixels"] / record["pixels"], abs=2e-6)
                assert not (mask == plane).any()
                checked["dropped"] += 1
                continue
            ours = mask == plane
            inside = ours & shape
            assert record["inliers"] == int(inside.sum())
            assert record["grown"] == int((ours & ~shape).sum())
            assert record["inlier_ratio"] == pytest.approx(record["inliers"] / record["valid_pixels"], abs=2e-6)
            # The plane: a least-squares fit to the mask's own points agrees with the equation.
            xyz = points[inside]
            centre = xyz.mean(axis=0)
            normal = np.linalg.svd(xyz - centre, full_matrices=False)[2][-1]
            equation = np.array(record["equation"])
            assert abs(abs(normal @ equation[:3]) - 1) < 1e-3  # within 2.6 degrees
            assert abs(centre @ equation[:3] + equation[3]) < 0.005
            # The band: 3 sigma(z) of the Kinect v1 model (Nguyen et al. 2012) at the median depth
            # of the plane's inliers, clipped to [floor, cap]; the report's median is over the
            # fit's grid points (about a thousand of them), so a sample of these. The renders
            # carry the model's own noise: no plane is scaled.
            assert record["noise_scale"] == 1.0
            median = np.median(points[inside][:, 2])
            assert record["band"] == pytest.approx(np.clip(3 * _kinect_sigma(median), 0.002, 0.1), rel=0.05)
            # Residual in sigma units (sigma(z) at each pixel's own depth) of the shape's points
            # within the band (the mask leaves out rims next to objects).
            xyz = points[shape & valid]
            residual = np.abs(xyz @ equation[:3] + equation[3]) / _kinect_sigma(xyz[:, 2])
            residual = residual[residual <= 3]
            assert record["rms_sigma"] == pytest.approx(np.sqrt(np.mean(residual**2)), rel=0.25)
            assert record["fit_inliers_refit"] <= record["fit_points"] <= record["valid_pixels"]
            assert record["fit_inliers_ransac"] <= record["fit_points"]
            checked["kept"] += 1
    assert checked["kept"] > 50 and checked["dropped"] > 10
    summary = report["summary"]
    written = [f for f in report["frames"] if f["status"] == "written"]
    assert summary["planes_kept"] == sum(len(f["kept"]) for f in written)
    assert summary["planes_dropped"] == sum(len(f["dropped"]) for f in written)
    assert summary["masks_written"] == len(written) == len(list((run / "masks").iterdir()))


def _redone(out: Path, config, annotations=(ANNOTATIONS,), **options) -> set[str]:
    """Mask names a re-run into ``out`` made anew."""
    before = {p.name: p.stat().st_mtime_ns for p in (out / "masks").iterdir()}
    report = run_cvat2mask(SEQUENCE, list(annotations), out, config, **options)
    assert report.counts.made + report.counts.reused == report.written
    return {p.name for p in (out / "masks").iterdir() if before.get(p.name) != p.stat().st_mtime_ns}


def test_editing_matches_redoes_exactly_the_frames_of_the_affected_track(tmp_path):
    config = load_config(CAMERA)
    out = tmp_path / "out"
    first = run_cvat2mask(SEQUENCE, PARTS, out, config)
    track = next(t for t in first.tracks if t.part == "9-18.xml" and t.how == "auto")
    toml = tmp_path / "pinned.toml"
    toml.write_text(CAMERA.read_text() + f'\n[[matches]]\npart = "9-18.xml"\ntrack = {track.track}\nnew = true\n')
    redone = _redone(out, load_config(toml), PARTS)
    # The frames the later part owns and where that track has a shape, and only those.
    report = json.loads((out / "report.json").read_text())
    new_plane = max(t["plane"] for t in report["tracks"])
    expected = {Path(f["mask"]).name for f in report["frames"]
                if f["status"] == "written" and any(r["plane"] == new_plane for r in f["kept"] + f["dropped"])}
    assert expected and redone == expected


def test_the_fingerprint_holds_the_plane_ids(tmp_path):
    # Two tracks swap their plane ids (a manual match): the masks change colour, so are redone.
    out = tmp_path / "out"
    config = load_config(CAMERA)
    first = run_cvat2mask(SEQUENCE, PARTS, out, config)
    a, b = [t for t in first.tracks if t.part == "9-18.xml" and t.how == "auto"][:2]
    toml = tmp_path / "swapped.toml"
    toml.write_text(CAMERA.read_text() + f'\n[[matches]]\npart = "9-18.xml"\ntrack = {a.track}\nplane = {b.plane}\n'
                    f'\n[[matches]]\npart = "9-18.xml"\ntrack = {b.track}\nplane = {a.plane}\n')
    redone = _redone(out, load_config(toml), PARTS)
    assert redone, "swapped plane ids must redo the frames that show them"


def test_the_fingerprint_holds_the_mask_bitmap_and_the_image_size(tmp_path):
    from annotate_rgbd.annotation.model import Shape
    from annotate_rgbd.cvat import read_cvat, write_cvat_video

    annotation = read_cvat(ANNOTATIONS)
    track = annotation.tracks[2]
    frames = sorted(track.shapes)
    for frame in frames:  # the track as a mask (CVAT's brush tool) instead of a polygon
        bitmap = np.zeros((240, 320), bool)
        outline = np.round(track.shapes[frame].points).astype(np.int32)
        cv2.fillPoly(bitmap.view(np.uint8), [outline], 1)
        track.shapes[frame] = Shape("mask", np.array([[0.0, 0.0]]), bitmap=bitmap)
    export = tmp_path / "masks.xml"
    write_cvat_video(annotation, export, width=320, height=240)
    out = tmp_path / "out"
    config = load_config(CAMERA)
    run_cvat2mask(SEQUENCE, [export], out, config)
    # One pixel of one frame's bitmap changes: that frame only is redone.
    changed = frames[3]
    track.shapes[changed].bitmap[120, 160] = ~track.shapes[changed].bitmap[120, 160]
    write_cvat_video(annotation, export, width=320, height=240)
    report = json.loads((out / "report.json").read_text())
    name = next(Path(f["mask"]).name for f in report["frames"] if f.get("cvat_frame") == changed)
    assert _redone(out, config, [export]) == {name}
    # The export now says the images are larger: the re-run must check, not reuse.
    write_cvat_video(annotation, export, width=640, height=480)
    with pytest.raises(Exception, match="annotates 640x480 images"):
        run_cvat2mask(SEQUENCE, [export], out, config)


def test_a_depth_frame_halfway_between_two_rgb_frames_takes_the_earlier():
    rgb = np.array([10.0, 10.5, 11.0])
    depth = np.array([10.25, 10.75, 10.5])  # exactly halfway twice, and on a frame once
    nearest, time_diff, matched = associate(np.sort(depth), rgb, 0.3)
    assert nearest.tolist() == [0, 1, 1]
    np.testing.assert_array_equal(time_diff, [-0.25, 0.0, -0.25])
    assert matched.all()


def test_an_rgb_frame_equally_near_two_depth_frames_is_shown_by_the_earlier():
    # For matching parts, the RGB frame's depth frame is the nearest; of two equally near, the first.
    association = Association(nearest=np.array([0, 0, 1]), time_diff=np.array([0.25, -0.25, 0.0]),
                              matched=np.array([True, True, True]))
    assert association.depth_of_rgb() == {0: 0, 1: 2}
    later_nearer = Association(nearest=np.array([0, 0]), time_diff=np.array([0.25, -0.125]), matched=np.array([True, True]))
    assert later_nearer.depth_of_rgb() == {0: 1}

"""Fixed band against noise-aware refinement on real frames: one picture and the numbers.

Run from the repository root, with the reference data beside it (``../shared/data``)::

    python benchmarks/real_overlays.py [--out docs/noise_aware.png]

It refines the rough polygons of ``tests/fixtures/real_polygons.json`` (drawn by eye on a TUM
fr1_rpy frame and a RealSense D435 frame) twice — with a fixed 2 cm band (EVOPS's default) and
with the sensor's noise model (the presets ``fr1_desk`` and ``realsense_d435``) — draws the
review overlays side by side into one PNG and prints, per plane, the pixels kept, the band at the
plane's median depth, the residual in sigma units and the pixels grown.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from annotate_rgbd.annotation.model import Shape
from annotate_rgbd.config.settings import load_config
from annotate_rgbd.review.overlay import overlay_for_frame
from annotate_rgbd.report.palette import plane_colours
from annotate_rgbd.segment.frame import segment_frame
from annotate_rgbd.io.sequence import read_depth, read_sequence

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data"
POLYGONS = ROOT / "tests" / "fixtures" / "real_polygons.json"
PICKS = (("tum_fr1_rpy", "21"), ("realsense_d435_office", "20"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "noise_aware.png")
    args = parser.parse_args()
    fixture = json.loads(POLYGONS.read_text(encoding="utf-8"))
    rows = []
    for name, frame in PICKS:
        sequence = read_sequence(DATA / name)
        rgb_index = int(frame)
        rgb_file = sequence.rgb.files[rgb_index]
        depth_index = int(np.argmin(np.abs(sequence.depth.timestamps - sequence.rgb.timestamps[rgb_index])))
        depth = read_depth(sequence.root / sequence.depth.files[depth_index])
        polygons = fixture[name]["frames"][frame]
        shapes = [(k + 1, Shape("polygon", np.array(points, dtype=np.float64))) for k, points in enumerate(polygons.values())]
        colours = plane_colours(len(shapes))
        preset = fixture[name]["preset"]
        tiles = []
        for title, overrides in (("fixed 2 cm", {"ransac.distance_threshold": 0.02}), (f"noise-aware ({preset})", {})):
            result = segment_frame(depth, shapes, load_config(preset, overrides))
            image = overlay_for_frame(sequence.root / rgb_file, result, colours)
            tile = cv2.resize(image, (640, 480))
            cv2.rectangle(tile, (0, 0), (639, 28), (0, 0, 0), -1)
            cv2.putText(tile, f"{name} frame {frame}: {title}", (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1,
                        cv2.LINE_AA)
            tiles.append(tile)
            for label, record in zip(polygons, result.kept):
                rows.append((name, title, label, record.inliers, record.grown, record.band, record.rms_sigma))
            for label, record in zip(polygons, result.dropped):
                rows.append((name, title, label, f"dropped: {record.reason}", "", "", ""))
        tiles_row = np.hstack(tiles)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        if name == PICKS[0][0]:
            picture = tiles_row
        else:
            picture = np.vstack([picture, tiles_row])
    picture = cv2.resize(picture, (picture.shape[1] // 2 * 2 * 5 // 8, picture.shape[0] * 5 // 8))
    cv2.imwrite(str(args.out), cv2.cvtColor(picture, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"{'sequence':24} {'refinement':28} {'plane':10} {'kept px':>9} {'grown':>6} {'band m':>8} {'rms sigma':>9}")
    for name, title, label, kept, grown, band, rms in rows:
        band_text = f"{band:.4f}" if isinstance(band, float) else band
        rms_text = f"{rms:.2f}" if isinstance(rms, float) else rms
        print(f"{name:24} {title:28} {label:10} {kept!s:>9} {grown!s:>6} {band_text:>8} {rms_text:>9}")
    print(f"picture: {args.out} ({args.out.stat().st_size // 1024} KiB)")


if __name__ == "__main__":
    main()

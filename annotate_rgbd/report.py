"""The run's tables and report: ``planes.csv``, ``tracks.csv`` and ``report.json``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from . import __version__
from .config import Config, config_to_dict
from .palette import colour_hex
from .stitch import TrackPlane, plane_origins
from .writer import write_csv

if TYPE_CHECKING:  # pipeline imports this module
    from .pipeline import RunReport


def write_tables(out_dir: Path, tracks: list[TrackPlane], colours: np.ndarray) -> None:
    """Write ``planes.csv`` (colour <-> plane <-> label and tracks) and ``tracks.csv`` (how each
    track got its plane)."""
    write_csv(
        out_dir / "planes.csv",
        ["plane_id", "colour", "r", "g", "b", "label", "part", "track_id", "tracks"],
        [
            [
                plane, colour_hex(colours[plane - 1]), *map(int, colours[plane - 1]), t.label, t.part, t.track,
                " ".join(f"{u.part}:{u.track}" for u in tracks if u.plane == plane),
            ]
            for plane, t in sorted(plane_origins(tracks).items())
        ],
    )
    write_csv(
        out_dir / "tracks.csv",
        ["part", "track", "label", "plane", "how", "iou", "matched_part", "matched_track"],
        [
            [t.part, t.track, t.label, t.plane, t.how, "" if t.iou is None else t.iou, t.matched_part or "",
             "" if t.matched_track is None else t.matched_track]
            for t in tracks
        ],
    )


def report_json(report: RunReport, config: Config) -> dict:
    """The content of ``report.json``: inputs, configuration, summary, planes, tracks, frames."""
    plan = report.plan
    colours = plan.colours
    written = [f for f in report.frames if f["status"] == "written"]
    skipped: dict[str, int] = {}
    for f in report.frames:
        if f["status"] == "skipped":
            skipped[f["reason"]] = skipped.get(f["reason"], 0) + 1
    return {
        "tool": {"name": "annotate-rgbd", "version": __version__},
        "inputs": {
            "sequence": str(plan.sequence.root.resolve()),
            "parts": [
                {
                    "file": str(Path(p.annotation.path).resolve()),
                    "name": p.name,
                    "offset": p.offset,
                    "first_rgb": p.first,
                    "last_rgb": p.last,
                    "placed_by": p.offset_source,
                }
                for p in plan.parts
            ],
        },
        "config": config_to_dict(config),
        "summary": {
            "depth_frames": len(report.frames),
            "masks_written": len(written),
            "frames_skipped": skipped,
            "frames_failed": sum(1 for f in report.frames if f["status"] == "failed"),
            "planes": report.n_planes,
            "planes_kept": sum(len(f["kept"]) for f in written),
            "planes_dropped": sum(len(f["dropped"]) for f in written),
        },
        "planes": [
            {"plane": plane, "colour": colour_hex(colours[plane - 1]), "label": t.label, "part": t.part, "track_id": t.track}
            for plane, t in sorted(plane_origins(report.tracks).items())
        ],
        "tracks": [
            {k: v for k, v in vars(t).items() if v is not None} for t in report.tracks
        ],
        "frames": report.frames,
        "warnings": report.warnings,
        "notes": report.notes,
    }

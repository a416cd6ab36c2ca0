"""The run's tables and report: ``planes.csv``, ``tracks.csv`` and the record behind ``report.json``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from annotate_rgbd import __version__
from annotate_rgbd.config.settings import OTHER_COMMANDS_SECTIONS, Config, config_to_dict
from annotate_rgbd.report.palette import colour_hex
from annotate_rgbd.report.records import PartRecord, PlaneInfo, RunRecord
from annotate_rgbd.annotation.stitch import TrackPlane, plane_origins
from annotate_rgbd.io.writer import write_csv

if TYPE_CHECKING:
    from .plan import RunPlan


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


def run_record(plan: RunPlan, config: Config) -> RunRecord:
    """The record of a run (``report.json``): inputs, configuration, planes, tracks, frames."""
    colours = plan.colours
    return RunRecord(
        version=__version__,
        sequence=str(plan.sequence.root.resolve()),
        parts=[
            PartRecord(str(Path(p.annotation.path).resolve()), p.name, p.offset, p.first, p.last, p.offset_source)
            for p in plan.parts
        ],
        config=config_to_dict(config, leave_out=OTHER_COMMANDS_SECTIONS),
        planes=[
            PlaneInfo(plane, colour_hex(colours[plane - 1]), t.label, t.part, t.track)
            for plane, t in sorted(plane_origins(plan.tracks).items())
        ],
        n_planes=plan.n_planes,
        tracks=[{k: v for k, v in vars(t).items() if v is not None} for t in plan.tracks],
        frames=plan.frames,
        warnings=plan.warnings,
        notes=plan.notes,
        propagation=None if plan.propagation is None else plan.propagation.to_json(),
    )

"""QA summary of a finished run: the EVOPS dataset-table numbers plus what the checks dropped.

The EVOPS paper describes each annotated sequence by its number of observations (frames with a
mask), total planes (plane instances summed over the observations) and planes per observation.
:func:`run_stats` computes these from ``report.json``, together with the number of distinct
planes, the dropped planes by reason and the mean RANSAC inlier ratio of the kept planes.
"""

from __future__ import annotations

import json
from collections import Counter


def run_stats(report: dict) -> dict:
    """Summary numbers of a run.

    Parameters
    ----------
    report : dict
        The content of ``report.json``.

    Returns
    -------
    dict
        ``observations`` (masks written), ``total_planes`` (kept planes summed over the masks),
        ``planes_per_observation``, ``distinct_planes`` (global planes kept in at least one
        mask), ``planes_annotated`` (global planes of the annotation), ``depth_frames``,
        ``frames_skipped`` (by reason), ``frames_failed`` (unreadable depth), ``planes_dropped`` and ``dropped_by_reason`` (plane
        records of the written frames), ``mean_inlier_ratio`` (over the kept plane records;
        ``None`` without any).
    """
    frames = report["frames"]
    written = [f for f in frames if f["status"] == "written"]
    kept = [r for f in written for r in f.get("kept", [])]
    dropped = [r for f in written for r in f.get("dropped", [])]
    ratios = [r["inlier_ratio"] for r in kept if r.get("inlier_ratio") is not None]
    return {
        "observations": len(written),
        "total_planes": len(kept),
        "planes_per_observation": round(len(kept) / len(written), 3) if written else 0.0,
        "distinct_planes": len({r["plane"] for r in kept}),
        "planes_annotated": len(report.get("planes", [])),
        "depth_frames": len(frames),
        "frames_skipped": dict(sorted(Counter(f.get("reason", "unknown") for f in frames if f["status"] == "skipped").items())),
        "frames_failed": sum(1 for f in frames if f["status"] == "failed"),
        "planes_dropped": len(dropped),
        "dropped_by_reason": dict(sorted(Counter(r.get("reason", "unknown") for r in dropped).items())),
        "mean_inlier_ratio": round(sum(ratios) / len(ratios), 4) if ratios else None,
    }


def format_stats(stats: dict) -> str:
    """The summary as an aligned two-column table for the terminal.

    Parameters
    ----------
    stats : dict
        :func:`run_stats` output.

    Returns
    -------
    str
    """
    rows = [
        ("observations (masks)", stats["observations"]),
        ("total planes", stats["total_planes"]),
        ("planes per observation", f"{stats['planes_per_observation']:.2f}"),
        ("distinct planes", f"{stats['distinct_planes']} of {stats['planes_annotated']} annotated"),
        ("depth frames", stats["depth_frames"]),
    ]
    rows += [(f"  skipped: {reason}", count) for reason, count in stats["frames_skipped"].items()]
    if stats["frames_failed"]:
        rows.append(("  failed (unreadable depth)", stats["frames_failed"]))
    rows.append(("planes dropped", stats["planes_dropped"]))
    rows += [(f"  {reason}", count) for reason, count in stats["dropped_by_reason"].items()]
    ratio = stats["mean_inlier_ratio"]
    rows.append(("mean inlier ratio", "-" if ratio is None else f"{ratio:.3f}"))
    width = max(len(name) for name, _ in rows)
    return "\n".join(f"{name:<{width}}  {value}" for name, value in rows)


def format_stats_json(stats: dict) -> str:
    """The summary as indented JSON."""
    return json.dumps(stats, indent=1)

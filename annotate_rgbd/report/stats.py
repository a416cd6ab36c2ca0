"""QA summary of a finished run: the EVOPS dataset-table numbers plus what the checks dropped.

The EVOPS paper describes each annotated sequence by its number of observations (frames with a
mask), total planes (plane instances summed over the observations) and planes per observation.
:func:`run_stats` computes these from ``report.json``, together with the number of distinct
planes, the dropped planes by reason and the mean RANSAC inlier ratio of the kept planes.
"""

from __future__ import annotations

import json

from .records import RunRecord, RunSummary, summarize


def run_stats(report: RunRecord) -> dict:
    """Summary numbers of a run.

    Parameters
    ----------
    report : RunRecord
        The run's ``report.json`` (:func:`annotate_rgbd.report.run_folder.read_report`).

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
    summary = summarize(report.frames)
    written, kept = summary.masks_written, summary.planes_kept
    return {
        "observations": written,
        "total_planes": kept,
        "planes_per_observation": round(kept / written, 3) if written else 0.0,
        "distinct_planes": summary.distinct_planes,
        "planes_annotated": len(report.planes),
        "depth_frames": summary.depth_frames,
        "frames_skipped": dict(sorted(summary.frames_skipped.items())),
        "frames_failed": summary.frames_failed,
        "planes_dropped": summary.planes_dropped,
        "dropped_by_reason": summary.dropped_by_reason,
        "mean_inlier_ratio": summary.mean_inlier_ratio,
        "tracks_to_review": list((report.propagation or {}).get("inconsistent_tracks", [])),
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
    if stats.get("tracks_to_review"):
        rows.append(("tracks to review (keyframes off their plane)", ", ".join(stats["tracks_to_review"])))
    width = max(len(name) for name, _ in rows)
    return "\n".join(f"{name:<{width}}  {value}" for name, value in rows)


def format_stats_json(stats: dict) -> str:
    """The summary as indented JSON."""
    return json.dumps(stats, indent=1)


#: The likely cause when most planes of a run are dropped for one reason.
DROP_HINTS = {
    "too_far": "is camera.depth_scale right for this sensor? (TUM, ICL-NUIM: 5000 per metre; RealSense: 1000)",
    "invalid_depth": "is the depth registered to the RGB images, and are the polygons drawn on them?",
    "too_few_points": "are the shapes tiny, or the depth images of another size than the annotated ones?",
}


def drop_hint(summary: RunSummary, depth_scale: float) -> str | None:
    """A warning when more than half of a run's plane records were dropped for one reason,
    with the likely cause; None otherwise.

    Parameters
    ----------
    summary : RunSummary
    depth_scale : float
        The configuration's, quoted in the hint about distances.
    """
    total = summary.planes_kept + summary.planes_dropped
    if not total or not summary.dropped_by_reason:
        return None
    reason, count = max(summary.dropped_by_reason.items(), key=lambda item: item[1])
    if count * 2 <= total:
        return None
    hint = DROP_HINTS.get(reason, "")
    if reason == "too_far":
        hint = hint.replace("camera.depth_scale right", f"camera.depth_scale = {depth_scale:g} right")
    return f"{count} of {total} planes were dropped as {reason}: {hint}"

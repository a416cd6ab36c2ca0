"""QA summary of a finished run: the EVOPS dataset-table numbers plus what the checks dropped.

The EVOPS paper describes each annotated sequence by its number of observations (frames with a
mask), total planes (plane instances summed over the observations) and planes per observation.
:func:`run_stats` computes these from ``report.json``, together with the number of distinct
planes, the dropped planes by reason and the mean RANSAC inlier ratio of the kept planes.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Mapping
from typing import TYPE_CHECKING

from annotate_rgbd.propagate import DISAGREE_BELOW
from .records import RunRecord, RunSummary, summarize

if TYPE_CHECKING:  # stats imports no configuration (it pulls in OpenCV): `stats` runs in 1 GB
    from annotate_rgbd.config.masks import FilterConfig

#: The drop reason of a plane the poses carried that was not where they put it
#: (:data:`annotate_rgbd.segment.filters.NOT_WHERE_EXPECTED`; not imported: ``stats`` loads no
#: image library).
NOT_WHERE_EXPECTED = "not_where_expected"


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
        ``None`` without any), ``tracks_to_review`` (keyframes off their track's plane),
        ``frames_to_review`` (depth frames where a plane the poses carried was not where they
        put it: dropped there, ``not_where_expected``), ``poses_to_check`` (depth frames whose
        pose disagreed with the keyframes' depth beyond the alignment's limits, or whose depth
        did not meet theirs) and
        ``carried_to_check`` (:func:`carried_to_check`).
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
        # With poses: frames where a carried plane was not where the poses put it (dropped there).
        "frames_to_review": [f.depth for f in report.frames if any(p.reason == NOT_WHERE_EXPECTED for p in f.dropped)],
        "poses_to_check": poses_to_check(report),
        "carried_to_check": carried_to_check(report),
    }


def poses_to_check(report: RunRecord) -> list[str]:
    """The depth frames (file names) whose trajectory pose disagreed with the keyframes' depth
    beyond the alignment's limits, or whose depth did not meet theirs
    (``propagation.alignment``: ``beyond_limits``, ``apart_from_keyframes``)."""
    alignment = (report.propagation or {}).get("alignment") or {}
    entries = [*alignment.get("beyond_limits", []), *alignment.get("apart_from_keyframes", [])]
    times = {round(float(entry["depth_timestamp"]), 6) for entry in entries
             if isinstance(entry, dict) and isinstance(entry.get("depth_timestamp"), (int, float))}
    return [f.depth for f in report.frames if round(f.depth_timestamp, 6) in times]


def carried_to_check(report: RunRecord, below: float = DISAGREE_BELOW) -> list[dict]:
    """The planes the poses carried to a frame's mask between two keyframes that disagree there,
    worst first: where a labeller's check pays most (a carried plane dropped from the mask is
    not listed: one dropped because it was not where the poses put it is in
    ``frames_to_review``, one dropped by a drop rule in neither).

    Parameters
    ----------
    report : RunRecord
    below : float
        Listed when the keyframes' agreement (``keyframes_agree``) is below this.

    Returns
    -------
    list of dict
        ``{"depth": file, "part": annotation part, "cvat_frame": its frame there (where to add a
        keyframe in CVAT), "plane": id, "keyframes_agree": agreement}``, by agreement, then in
        sequence order.
    """
    found = []  # (agreement, position in the sequence, entry)
    for index, frame in enumerate(report.frames):
        if frame.written and frame.keyframes_agree:
            kept = {r.plane for r in frame.kept}
            found += [(agree, index, {"depth": frame.depth, "part": frame.part, "cvat_frame": frame.cvat_frame,
                                      "plane": plane, "keyframes_agree": agree})
                      for plane, agree in sorted(frame.keyframes_agree.items()) if agree < below and plane in kept]
    return [entry for _, _, entry in sorted(found, key=lambda item: item[:2])]


def merge_stats(scenes: list[dict], names: list[str] | None = None) -> dict:
    """One summary of several runs (the scenes of a batch, e.g. run as shards).

    Parameters
    ----------
    scenes : list of dict
        :func:`run_stats` of each run.
    names : list of str, optional
        Each run's name (a batch's scene names); default: its position, from 1.

    Returns
    -------
    dict
        The keys of :func:`run_stats`: counts summed over the runs (distinct and annotated planes
        per run: plane ids are a run's own), ``planes_per_observation`` and
        ``mean_inlier_ratio`` over all of them (the ratio weighted by each run's kept planes),
        ``tracks_to_review``, ``frames_to_review`` and ``poses_to_check`` prefixed by the run's
        name (``kitchen:part.xml:5``), ``carried_to_check`` of all runs, worst first, each with its
        run's name (``scene``); and ``scenes``.
    """
    names = [str(i) for i in range(1, len(scenes) + 1)] if names is None else list(names)
    def total(key: str) -> int:
        return sum(s[key] for s in scenes)

    def by_reason(key: str) -> dict:
        counts: Counter = Counter()
        for s in scenes:
            counts.update(s[key])
        return dict(sorted(counts.items()))

    written, kept = total("observations"), total("total_planes")
    rated = [(s["mean_inlier_ratio"], s["total_planes"]) for s in scenes if s["mean_inlier_ratio"] is not None]
    weight = sum(w for _, w in rated)
    return {
        "scenes": len(scenes),
        "observations": written,
        "total_planes": kept,
        "planes_per_observation": round(kept / written, 3) if written else 0.0,
        "distinct_planes": total("distinct_planes"),
        "planes_annotated": total("planes_annotated"),
        "depth_frames": total("depth_frames"),
        "frames_skipped": by_reason("frames_skipped"),
        "frames_failed": total("frames_failed"),
        "planes_dropped": total("planes_dropped"),
        "dropped_by_reason": by_reason("dropped_by_reason"),
        "mean_inlier_ratio": round(sum(r * w for r, w in rated) / weight, 4) if weight else None,
        "tracks_to_review": [f"{name}:{t}" for name, s in zip(names, scenes) for t in s["tracks_to_review"]],
        "frames_to_review": [f"{name}:{f}" for name, s in zip(names, scenes) for f in s.get("frames_to_review", [])],
        "poses_to_check": [f"{name}:{f}" for name, s in zip(names, scenes) for f in s.get("poses_to_check", [])],
        "carried_to_check": sorted(  # stable: runs in their order at equal agreement
            ({"scene": name, **c} for name, s in zip(names, scenes) for c in s.get("carried_to_check", [])),
            key=lambda c: c["keyframes_agree"]),
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
    rows = [("scenes", stats["scenes"])] if "scenes" in stats else []
    rows += [
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
    if stats.get("frames_to_review"):
        frames = stats["frames_to_review"]
        rows.append((f"frames to review ({len(frames)}: a carried plane not where the poses put it)", _first_ten(frames)))
    if stats.get("poses_to_check"):
        frames = stats["poses_to_check"]
        rows.append((f"poses to check ({len(frames)}: off the keyframes' depth beyond the alignment's limits, "
                      "or not meeting it)",
                     _first_ten(frames)))
    if stats.get("carried_to_check"):
        carried = stats["carried_to_check"]
        rows.append((f"carried planes to check ({len(carried)}, worst first)",
                     _first_ten([_carried_text(c) for c in carried])))
    width = max(len(name) for name, _ in rows)
    return "\n".join(f"{name:<{width}}  {value}" for name, value in rows)


def _first_ten(items: list[str]) -> str:
    """``a, b, c`` and, past ten, `` and 5 more``."""
    return ", ".join(items[:10]) + (f" and {len(items) - 10} more" if len(items) > 10 else "")


def _carried_text(entry: dict) -> str:
    """``kitchen:000123.png plane 4 (0.12)``."""
    scene = f"{entry['scene']}:" if "scene" in entry else ""
    return f"{scene}{entry['depth']} plane {entry['plane']} ({entry['keyframes_agree']:.2f})"


def format_stats_json(stats: dict) -> str:
    """The summary as indented JSON."""
    return json.dumps(stats, indent=1)


#: The likely cause when most planes of a run are dropped for one reason.
DROP_HINTS = {
    "too_far": "is camera.depth_scale right for this sensor? (TUM, ICL-NUIM: 5000 per metre; RealSense: 1000); "
               "are the [camera] focal lengths in pixels of these images? If so, the planes are far: "
               "--set filter.max_mean_distance=METRES keeps them (EVOPS drops planes beyond 3.5 m)",
    "invalid_depth": "is the depth registered to the RGB images, and are the polygons drawn on them?",
    "too_few_points": "are the shapes tiny, or the depth images of another size than the annotated ones?",
    "no_plane": "is the depth mostly missing under the shapes, but for single rows or columns of pixels?",
    "not_where_expected": "do the camera poses belong to this sequence, and is propagate.time_offset right?",
}


#: Each drop reason in the words of a run's summary line.
DROP_WORDS = {
    "invalid_depth": "no depth",
    "too_far": "too far",
    "too_few_points": "too few points",
    "no_plane": "no plane there",
    "not_where_expected": "not where the poses put it",
}


def dropped_words(by_reason: Mapping[str, int]) -> str:
    """The drop reasons of a run in words, most frequent first: ``"too far 19, no depth 10"``."""
    ranked = sorted(by_reason.items(), key=lambda item: (-item[1], item[0]))
    return ", ".join(f"{DROP_WORDS.get(reason, reason)} {count}" for reason, count in ranked if count)


#: The ``[filter]`` rule behind a drop reason, and whether a value is stricter than the default
#: (drops more planes): the hint then names that setting first, before the cause in the data.
FILTER_RULES = {
    "invalid_depth": ("max_invalid_ratio", lambda value, default: value < default),
    "too_far": ("max_mean_distance", lambda value, default: value < default),
    "too_few_points": ("min_valid_pixels", lambda value, default: value > default),
}


def drop_hint(summary: RunSummary, depth_scale: float, drop_rules: FilterConfig | None = None) -> str | None:
    """A warning when more than half of a run's plane records were dropped for one reason,
    with the likely cause; None otherwise.

    Parameters
    ----------
    summary : RunSummary
    depth_scale : float
        The configuration's, quoted in the hint about distances.
    drop_rules : FilterConfig, optional
        The run's ``[filter]`` section: when the reason's rule is set stricter than its default (``--set
        filter.max_invalid_ratio=0`` drops every plane with a pixel without depth; the
        ``fr2_pioneer_slam`` preset's 0.75 is EVOPS's own), the hint names that setting first, then
        the cause in the data.
    """
    return dropped_hint(summary.dropped_by_reason, summary.planes_kept + summary.planes_dropped, depth_scale,
                        drop_rules=drop_rules)


def dropped_hint(by_reason: Mapping[str, int], total: int, depth_scale: float, what: str = "planes",
                 known_only: bool = False, drop_rules: FilterConfig | None = None) -> str | None:
    """:func:`drop_hint` from the counts: ``by_reason`` of ``total`` records of ``what`` (e.g.
    ``propose``'s "detected planes"); with ``known_only``, only for a reason with a likely
    cause in :data:`DROP_HINTS` (``propose`` drops small and flickering detections by design)."""
    if not total or not by_reason:
        return None
    reason, count = max(by_reason.items(), key=lambda item: item[1])
    if count * 2 <= total or (known_only and reason not in DROP_HINTS):
        return None
    hint = DROP_HINTS.get(reason, "")
    if reason == "too_far":
        hint = hint.replace("camera.depth_scale right", f"camera.depth_scale = {depth_scale:g} right")
    if drop_rules is not None and reason in FILTER_RULES:
        key, stricter = FILTER_RULES[reason]
        value, default = getattr(drop_rules, key), getattr(type(drop_rules), key)  # the dataclass's default
        if stricter(value, default):  # a cause of its own, beside the data's (a preset may set it on purpose)
            hint = (f"filter.{key} is {value:g} here, stricter than its default {default:g}, which drops more planes"
                    + (f"; or {hint[0].lower()}{hint[1:]}" if hint else ""))
    return f"{count} of {total} {what} were dropped as {reason}" + (f": {hint}" if hint else "")

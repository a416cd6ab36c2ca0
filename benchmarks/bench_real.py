"""Labeller effort on a real RGB-D sequence, scored against independent ground truth.

Run from the repository root, with the ground-truth kit and a scene it made::

    python benchmarks/bench_real.py SCENE [--kit ../shared/realdata_kit] [--gt gt_strict]
        [--out DIR] [--jobs 2] [--variants full every10 every30 every100 once propose]
        [--poses-only] [--trajectory FILE] [--reuse] [--set SECTION.KEY=VALUE ...]

``SCENE`` is a folder the kit's ``build_gt.sh`` made (its README: fuse the sequence's depth
with its poses, segment planes on the fused mesh, ray-cast every frame): ``seq/`` (TUM layout,
``camera.toml``, ``groundtruth.txt``), ``eval/gt_strict/`` (per-frame plane ground truth) and
``eval/full.xml`` (a simulated careful labeller's polygon on every frame, one CVAT track per
plane). The kit shares no code with ``annotate-rgbd`` (it is an independent check only as long
as it does not): this script only runs its scripts, never imports them.

For each variant the kit's ``thin_keyframes.py`` thins ``full.xml`` to what a labeller draws
(``full``: every frame; ``everyN``: a keyframe every N frames and where a plane enters or leaves
the view; ``once``: once per appearance), ``annotate-rgbd cvat2mask`` runs on it without and with
``--poses seq/groundtruth.txt``, ``propose`` runs without human input, and the kit's
``evaluate.py`` scores the masks: mean IoU (unmatched ground truth counts 0), precision and
recall at IoU 0.8, leak (the share of ground-truth "no plane" pixels given a plane). It prints
the table of issue 26 and whether its targets are met (with poses: a keyframe every 10th frame
mean IoU >= 0.946 and leak <= 2 %, every 30th >= 0.93, once per appearance >= 0.90, never below
2-D interpolation; dense >= 0.96; propose precision and recall >= 0.7), and for every sparse row
with poses where it loses against the dense row, by ground-truth plane (:func:`plane_deficits`),
and how much of what it misses (of what the dense row labels right) lies where a nearby keyframe's
labeller left the plane out (:func:`real_losses.excluded_misses`), and how many of the carried
planes that lose most the run's list of planes to check holds (:func:`real_losses.review_scores`).

``--trajectory FILE`` gives the runs with poses another trajectory than ``seq/groundtruth.txt``.
With the kit's ICP-refined poses (``SCENE/gt_work/poses_2.txt``, those the ground truth was
ray-cast from, after one more ICP per frame: ``SCENE/eval/gt/render_poses.txt``) the rows with
poses score what they would with poses as consistent as the ground truth's own, and so how much of
each row's loss is pose error. Each run's scores record the trajectory it read; ``--reuse`` keeps
only runs of the same one.

Without the kit or the scene it prints one line and exits 0.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from real_losses import (  # noqa: E402  (the per-pixel analyses of the runs)
    EXCLUDED_INNER_PX, excluded_misses, review_scores,
)

ROOT = Path(__file__).resolve().parent.parent
KIT = ROOT.parent / "shared" / "realdata_kit"
#: Variant name -> the keyframe spacing given to thin_keyframes.py (None: the dense export).
SPACINGS = {"full": None, "every10": 10, "every30": 30, "every100": 100, "once": 100000}
LABELS = {"full": "every frame", "every10": "every 10th frame", "every30": "every 30th",
          "every100": "every 100th", "once": "once per appearance"}
#: Issue 26's targets, with poses: variant -> smallest mean IoU (and largest leak).
TARGETS = {"full": (0.96, None), "every10": (0.946, 0.02), "every30": (0.93, None), "once": (0.90, None)}
PROPOSE_TARGET = 0.7


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scene", type=Path, nargs="?", default=None)
    parser.add_argument("--kit", type=Path, default=KIT)
    parser.add_argument("--gt", default="gt_strict", help="ground-truth folder under SCENE/eval")
    parser.add_argument("--out", type=Path, default=None, help="runs go here (default: a folder in the temp dir)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--variants", nargs="+", default=[*SPACINGS, "propose"], choices=[*SPACINGS, "propose"])
    parser.add_argument("--poses-only", action="store_true", help="skip the runs without poses")
    parser.add_argument("--trajectory", type=Path, default=None,
                        help="the runs with poses read this trajectory (TUM format) instead of SCENE/seq/groundtruth.txt")
    parser.add_argument("--reuse", action="store_true", help="keep runs whose scores exist in --out")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="a configuration override for every run (repeatable)")
    args = parser.parse_args()
    if args.trajectory is not None and not args.trajectory.is_file():  # a typo, not a machine without the kit
        parser.error(f"--trajectory {args.trajectory}: no such file")
    missing = _missing(args.kit, args.scene, args.gt)
    if missing:
        print(f"bench_real: skipped ({missing})")
        return
    scene = args.scene.resolve()
    trajectory = (args.trajectory or scene / "seq" / "groundtruth.txt").resolve()
    out = (args.out or Path(tempfile.gettempdir()) / "annotate-rgbd-bench-real" / scene.name).resolve()
    (out / "xml").mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    results = {}
    for variant in args.variants:
        if variant == "propose":
            results["propose"] = _run(out, "propose", ["propose", str(scene / "seq")], scene, args, reuse=args.reuse)
            continue
        export, polygons = _thin(args.kit, scene, out, variant)
        for poses in ((True,) if args.poses_only else (False, True)):
            name = f"{variant}_{'pose' if poses else 'nopose'}"
            command = ["cvat2mask", str(scene / "seq"), str(export)]
            if poses:
                command += ["--poses", str(trajectory)]
            results[name] = _run(out, name, command, scene, args, reuse=args.reuse,
                                 trajectory=str(trajectory) if poses else None)
            results[name]["polygons"] = polygons
    table = effort_table(results)
    (out / "table.md").write_text(table + "\n", encoding="utf-8")
    (out / "results.json").write_text(json.dumps(results, indent=1), encoding="utf-8")
    source = "" if args.trajectory is None else f", poses from {trajectory}"
    print(f"\n{scene.name}, ground truth {args.gt}, --jobs {args.jobs}{source}; runs in {out}\n")
    print(table)
    print()
    for line in target_lines(results):
        print(line)
    losses = deficit_lines(results)
    if losses:
        print("\nwhere each row with poses loses against the dense row, per ground-truth plane (frames x IoU "
              "lost, as a share of the summed losses; planes that gained left out):")
        for line in losses:
            print(line)
    explained = excluded_lines(scene / "eval" / args.gt, out / "runs", results)
    if explained:
        print("\nwhat each row with poses misses of what the dense row labels right, on the planes the poses carried:")
        for line in explained:
            print(line)
    review = review_lines(scene / "eval" / args.gt, out / "runs", results)
    if review:
        print("\nthe carried planes the runs list to check (keyframes before and after disagree), against the "
              "dense row: how many of those that lose most they hold:")
        for line in review:
            print(line)
    print(f"\nbenchmark took {time.perf_counter() - started:.0f} s")


def _missing(kit: Path, scene: Path | None, gt: str) -> str:
    """Why the benchmark cannot run ('' when it can)."""
    if not (kit / "evaluate.py").is_file() or not (kit / "thin_keyframes.py").is_file():
        return f"no ground-truth kit at {kit}"
    if scene is None:
        return "no scene folder given (make one with the kit's build_gt.sh, see its README)"
    for needed in ("seq/camera.toml", "seq/groundtruth.txt", f"eval/{gt}/planes.json", "eval/full.xml"):
        if not (scene / needed).exists():
            return f"{scene / needed} is missing"
    return ""


def _thin(kit: Path, scene: Path, out: Path, variant: str) -> tuple[Path, int]:
    """The variant's export (thinned by the kit) and the number of polygons drawn in it."""
    full = scene / "eval" / "full.xml"
    spacing = SPACINGS[variant]
    if spacing is None:
        return full, full.read_text(encoding="utf-8").count('outside="0"')
    export = out / "xml" / f"{variant}.xml"
    drawn = subprocess.run([sys.executable, str(kit / "thin_keyframes.py"), str(full), str(export), "--every",
                            str(spacing)], check=True, capture_output=True, text=True).stdout
    return export, int(drawn.split()[-1])


def _run(out: Path, name: str, command: list[str], scene: Path, args, reuse: bool, trajectory: str | None = None) -> dict:
    """Run one variant with ``annotate-rgbd`` and score it with the kit's evaluate.py; with
    ``reuse``, the scores an earlier run of the same variant (and ``trajectory``) left in ``out``.
    The scores record the trajectory the run read (None: no poses)."""
    scores = out / f"{name}.json"
    if reuse and scores.is_file():
        earlier = json.loads(scores.read_text(encoding="utf-8"))
        if earlier.get("trajectory") == trajectory:
            return earlier
    target = out / "runs" / name
    shutil.rmtree(target, ignore_errors=True)
    full = [sys.executable, "-m", "annotate_rgbd", *command, "--config", str(scene / "seq" / "camera.toml"),
            "--out", str(target), "--jobs", str(args.jobs)]
    full += ["--force"] if command[0] == "cvat2mask" else []
    for setting in args.set:
        full += ["--set", setting]
    began = time.perf_counter()
    with open(out / f"{name}.log", "w", encoding="utf-8") as log:
        code = subprocess.run(full, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT).returncode
    seconds = time.perf_counter() - began
    evaluated = subprocess.run([sys.executable, str(args.kit / "evaluate.py"), str(scene / "eval" / args.gt),
                                str(target / "masks"), "--json"], capture_output=True, text=True)
    try:
        result = json.loads(evaluated.stdout)
    except json.JSONDecodeError:
        result = {"error": (evaluated.stderr.strip().splitlines() or ["evaluate.py failed"])[-1]}
    result.update(seconds=round(seconds, 1), returncode=code, trajectory=trajectory)
    scores.write_text(json.dumps(result), encoding="utf-8")
    print(f"{name}: {seconds:.0f} s, mean IoU {result.get('mean_iou', float('nan')):.3f}", flush=True)
    return result


def _cell(result: dict | None) -> str:
    if not result:
        return ""
    if "error" in result or result.get("returncode"):
        return f"failed ({result.get('error', 'exit ' + str(result.get('returncode')))})"
    return (f"{result['mean_iou']:.3f}, P/R {result['precision']:.3f}/{result['recall']:.3f}, "
            f"leak {100 * result['leak']:.1f} %")


def effort_table(results: dict) -> str:
    """Issue 26's table: per variant the polygons drawn and the scores without and with poses."""
    lines = ["| labeller drew | polygons | 2-D interpolation (no poses) | `--poses` | ms/frame (no poses / poses) |",
             "|---|---|---|---|---|"]
    for variant, label in LABELS.items():
        flat, posed = results.get(f"{variant}_nopose"), results.get(f"{variant}_pose")
        if not (flat or posed):
            continue
        polygons = (flat or posed)["polygons"]
        times = " / ".join(f"{1000 * r['seconds'] / max(r.get('frames', 1), 1):.0f}" if r else "-" for r in (flat, posed))
        lines.append(f"| {label} | {polygons:,} | {_cell(flat)} | {_cell(posed)} | {times} |")
    if "propose" in results:
        r = results["propose"]
        lines.append(f"| nothing (`propose`) | 0 | {_cell(r)} | | {1000 * r['seconds'] / max(r.get('frames', 1), 1):.0f} |")
    return "\n".join(lines)


def target_lines(results: dict) -> list[str]:
    """Issue 26's targets, met or not, for the variants that ran."""
    lines = []
    for variant, (least, leak) in TARGETS.items():
        posed = results.get(f"{variant}_pose")
        if posed and "mean_iou" in posed:
            ok = posed["mean_iou"] >= least and (leak is None or posed["leak"] <= leak)
            rule = f"mean IoU >= {least}" + (f", leak <= {100 * leak:.0f} %" if leak is not None else "")
            lines.append(f"target: {LABELS[variant]}, with poses, {rule}: {'met' if ok else 'NOT met'} "
                         f"({posed['mean_iou']:.3f}, leak {100 * posed['leak']:.1f} %)")
    for variant, label in LABELS.items():
        flat, posed = results.get(f"{variant}_nopose"), results.get(f"{variant}_pose")
        if flat and posed and "mean_iou" in flat and "mean_iou" in posed:
            ok = posed["mean_iou"] >= flat["mean_iou"]
            lines.append(f"target: {label}, poses not worse than 2-D interpolation: {'met' if ok else 'NOT met'} "
                         f"({posed['mean_iou']:.3f} against {flat['mean_iou']:.3f})")
    proposed = results.get("propose")
    if proposed and "precision" in proposed:
        ok = proposed["precision"] >= PROPOSE_TARGET and proposed["recall"] >= PROPOSE_TARGET
        lines.append(f"target: propose precision and recall >= {PROPOSE_TARGET}: {'met' if ok else 'NOT met'} "
                     f"({proposed['precision']:.3f} / {proposed['recall']:.3f})")
    return lines


def plane_deficits(result: dict, dense: dict) -> list[tuple[str, str, int, float, float, float]]:
    """Where a run loses mean IoU against the dense row, by ground-truth plane.

    Both are the kit's ``evaluate.py --json`` results, whose ``planes`` give each ground-truth
    plane's frames and mean IoU; the run's mean IoU is the mean over all (frame, plane) pairs,
    so a plane's part of the deficit is its frames times its IoU lost.

    Returns
    -------
    list of (plane, name, frames, dense IoU, IoU, share)
        Planes that lost IoU, the largest share first; ``share`` is the plane's part of the
        summed losses (planes that gained are left out of the sum).
    """
    lost = []
    for plane, entry in result.get("planes", {}).items():
        reference = dense.get("planes", {}).get(plane)
        if reference is None:
            continue
        loss = entry["frames"] * (reference["mean_iou"] - entry["mean_iou"])
        if loss > 0:
            lost.append((plane, entry["name"], entry["frames"], reference["mean_iou"], entry["mean_iou"], loss))
    total = sum(row[-1] for row in lost)
    return [(*row[:-1], row[-1] / total) for row in sorted(lost, key=lambda row: -row[-1])]


def deficit_lines(results: dict, top: int = 4) -> list[str]:
    """One line per sparse variant with poses: its ``top`` planes of :func:`plane_deficits`."""
    dense = results.get("full_pose") or results.get("full_nopose")
    if not dense or "planes" not in dense:
        return []
    lines = []
    for variant, label in LABELS.items():
        posed = results.get(f"{variant}_pose")
        if variant == "full" or not posed or "planes" not in posed:
            continue
        parts = [f"{name} {share:.0%} ({iou:.2f} against {reference:.2f} on {frames} frames)"
                 for _, name, frames, reference, iou, share in plane_deficits(posed, dense)[:top]]
        if parts:
            lines.append(f"  {label}: " + "; ".join(parts))
    return lines


def _scored_rows(results: dict, dense_names: tuple[str, ...]) -> tuple[str | None, list[tuple[str, str]]]:
    """The dense row to compare with (the first of ``dense_names`` that was scored; None) and the
    ``(variant, label)`` of the sparse rows with poses that were scored (a run folder whose row is
    not in ``results``, or failed, is not read)."""
    ran = {name for name, result in results.items() if "mean_iou" in result and not result.get("returncode")}
    dense = next((name for name in dense_names if name in ran), None)
    return dense, [(variant, label) for variant, label in LABELS.items() if variant != "full" and f"{variant}_pose" in ran]


def excluded_lines(gt_dir: Path, runs: Path, results: dict) -> list[str]:
    """One line per sparse variant with poses: :func:`excluded_misses` against the dense row,
    for the rows in ``results`` that were scored (a run folder whose row is not there, or failed,
    is not read)."""
    from annotate_rgbd.errors import InputError

    dense, rows = _scored_rows(results, ("full_pose", "full_nopose"))
    if dense is None:
        return []
    lines = []
    for variant, label in rows:
        try:
            counts = excluded_misses(gt_dir, runs / f"{variant}_pose", runs / dense, EXCLUDED_INNER_PX)
        except InputError as exc:
            lines.append(f"  {label}: not measured ({exc})")
            continue
        missed = max(counts["missed"], 1)
        lines.append(f"  {label}: {counts['missed']:,} pixels; {counts['excluded'] / missed:.0%} where a nearby "
                     f"keyframe left the plane out, {counts['deep'] / missed:.0%} more than {EXCLUDED_INNER_PX} px "
                     "inside such a region")
    return lines


def review_lines(gt_dir: Path, runs: Path, results: dict) -> list[str]:
    """One line per sparse variant with poses: :func:`review_scores` against the dense row with
    poses, for the rows in ``results`` that were scored."""
    from annotate_rgbd.errors import InputError

    dense, rows = _scored_rows(results, ("full_pose",))
    if dense is None:
        return []
    lines = []
    for variant, label in rows:
        try:
            scores = review_scores(gt_dir, runs / f"{variant}_pose", runs / dense)
        except InputError as exc:
            lines.append(f"  {label}: not measured ({exc})")
            continue
        if not scores["carried"]:
            continue
        carried, bad = scores["carried"], max(scores["bad"], 1)
        lines.append(f"  {label}: {carried:,} carried plane-frames, {scores['bad']} lose more than 0.15 IoU; "
                     f"{scores['listed']} listed ({scores['listed'] / carried:.0%}) hold {scores['listed_bad']} of "
                     f"them ({scores['listed_bad'] / bad:.0%}) and {scores['listed_loss'] / max(scores['loss'], 1e-9):.0%} "
                     f"of the IoU lost; ranking AUC {scores['auc']:.2f}")
    return lines


if __name__ == "__main__":
    main()

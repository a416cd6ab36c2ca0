"""Relabel whole scenes in one command: a manifest of scenes, one pool of workers.

A manifest is a TOML file with one ``[[scene]]`` table per scene; paths are relative to the
manifest::

    jobs = 2                       # optional; default: all cores (--jobs overrides)

    [[scene]]
    name = "fr1_desk"              # optional; default: the output folder's name
    sequence = "data/rgbd_dataset_freiburg1_desk"
    annotations = ["labels/fr1_desk/0-299.xml", "labels/fr1_desk/295-573.xml"]
    config = "fr1_desk"            # a preset name or a TOML file; optional
    out = "out/fr1_desk"
    parts = ["0-299.xml:0"]        # optional, as --part FILE:OFFSET
    set = ["ransac.distance_threshold=0.01"]   # optional, as --set
    raw_masks = false              # optional, as --raw-masks

Scenes are planned one after the other (a scene whose inputs are broken fails alone), then
the frames of all scenes are made by one pool of processes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from .config import load_config, tomllib
from .errors import InputError
from .execute import start_helpers
from .pipeline import RunReport, SceneRun, execute_scenes, finish_scene, plan_run

SCENE_KEYS = {"name", "sequence", "annotations", "config", "out", "parts", "set", "raw_masks"}


@dataclass(frozen=True)
class SceneSpec:
    """One ``[[scene]]`` of a manifest, with paths resolved against the manifest's folder."""

    name: str
    sequence: Path
    annotations: tuple[Path, ...]
    out: Path
    config: str | None = None
    offsets: dict[str, int] = field(default_factory=dict)
    overrides: dict[str, Any] = field(default_factory=dict)
    raw_masks: bool = False


@dataclass
class SceneOutcome:
    """How one scene of a batch ended."""

    name: str
    out: Path
    report: RunReport | None = None
    error: str | None = None

    @property
    def failed_frames(self) -> list[str]:
        """Depth frames that failed, with the reason."""
        if self.report is None:
            return []
        return [f"{f['depth']}: {f.get('error', f['reason'])}" for f in self.report.frames if f["status"] == "failed"]


def read_manifest(path: str | Path) -> tuple[list[SceneSpec], int | None]:
    """Read a batch manifest.

    Parameters
    ----------
    path : str or Path
        The TOML manifest.

    Returns
    -------
    scenes : list of SceneSpec
    jobs : int or None
        The manifest's ``jobs``, if given.

    Raises
    ------
    InputError
        Unreadable or invalid TOML, no scenes, unknown or missing keys, values of the wrong
        type, or two scenes writing to one output folder.
    """
    from .cli import parse_part_offsets, parse_settings

    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise InputError(path, f"cannot read manifest: {exc.strerror or exc}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(path, f"invalid TOML: {exc}") from None
    unknown = set(data) - {"scene", "jobs"}
    if unknown:
        raise InputError(path, f"unknown key '{sorted(unknown)[0]}' (a manifest has 'jobs' and [[scene]] tables)")
    jobs = data.get("jobs")
    if jobs is not None and (not isinstance(jobs, int) or isinstance(jobs, bool) or jobs < 1):
        raise InputError(path, "'jobs' must be a positive integer")
    tables = data.get("scene")
    if not isinstance(tables, list) or not tables:
        raise InputError(path, "no scenes: add one [[scene]] table per scene")
    base = path.parent
    scenes = []
    for number, table in enumerate(tables, start=1):
        where = f"[[scene]] {number}"
        if not isinstance(table, dict):
            raise InputError(path, f"{where}: must be a table")
        extra = set(table) - SCENE_KEYS
        if extra:
            raise InputError(path, f"{where}: unknown key '{sorted(extra)[0]}' (known: {', '.join(sorted(SCENE_KEYS))})")
        for key in ("sequence", "annotations", "out"):
            if key not in table:
                raise InputError(path, f"{where}: '{key}' is missing")
        annotations = table["annotations"]
        if isinstance(annotations, str):
            annotations = [annotations]
        strings = {"sequence": table["sequence"], "out": table["out"], "name": table.get("name", ""),
                   "config": table.get("config", "")}
        lists = {"annotations": annotations, "parts": table.get("parts", []), "set": table.get("set", [])}
        if not all(isinstance(v, str) for v in strings.values()) or not all(
            isinstance(v, list) and all(isinstance(x, str) for x in v) for v in lists.values()
        ) or not isinstance(table.get("raw_masks", False), bool):
            raise InputError(path, f"{where}: wrong type (paths and names are strings; annotations, parts and set are lists of strings)")
        config = table.get("config")
        if config is not None and (base / config).is_file():
            config = str(base / config)
        out = base / table["out"]
        try:
            offsets = {str(base / k) if (base / k).exists() else k: v for k, v in parse_part_offsets(lists["parts"]).items()}
            overrides = parse_settings(lists["set"])
        except InputError as exc:
            raise InputError(path, f"{where}: {exc.message}") from None
        scenes.append(SceneSpec(
            name=table.get("name") or out.name,
            sequence=base / table["sequence"],
            annotations=tuple(base / a for a in annotations),
            out=out,
            config=config,
            offsets=offsets,
            overrides=overrides,
            raw_masks=table.get("raw_masks", False),
        ))
    outs = [s.out.resolve() for s in scenes]
    for out in set(outs):
        if outs.count(out) > 1:
            raise InputError(path, f"two scenes write to {out}: give each scene its own 'out'")
    return scenes, jobs


def run_batch(
    scenes: list[SceneSpec],
    workers: int,
    force: bool = False,
    progress_for: Callable[[str], Callable[[int, int], None]] | None = None,
) -> list[SceneOutcome]:
    """Relabel every scene; a scene with broken input fails alone.

    Parameters
    ----------
    scenes : list of SceneSpec
    workers : int
        Worker processes shared by all scenes.
    force : bool
        Redo every frame, even those unchanged since the last run.
    progress_for : callable, optional
        ``progress_for(scene name)`` returns that scene's ``progress(done, total)`` callback.

    Returns
    -------
    list of SceneOutcome
        One per scene, in manifest order.
    """
    outcomes = [SceneOutcome(spec.name, spec.out) for spec in scenes]
    runs: list[tuple[SceneOutcome, SceneRun]] = []
    helpers = start_helpers(workers)  # they start while the scenes are planned
    try:
        for spec, outcome in zip(scenes, outcomes):
            try:
                config = load_config(spec.config, spec.overrides)
                plan = plan_run(spec.sequence, spec.annotations, spec.out, config, spec.offsets, spec.raw_masks)
            except InputError as exc:
                outcome.error = str(exc)
                continue
            progress = progress_for(spec.name) if progress_for else None
            runs.append((outcome, SceneRun(spec.name, plan, spec.out, config, progress)))
        execute_scenes([run for _, run in runs], helpers, force=force)
    finally:
        if helpers is not None:
            helpers.shutdown(cancel_futures=True)
    for outcome, run in runs:
        if run.error is not None:
            outcome.error = str(run.error)
            continue
        try:
            outcome.report = finish_scene(run)
        except InputError as exc:
            outcome.error = str(exc)
    return outcomes


def summary_lines(outcomes: list[SceneOutcome]) -> list[str]:
    """A per-scene summary: frames written, unchanged, failed; planes kept and dropped."""
    lines = []
    for outcome in outcomes:
        if outcome.error is not None:
            lines.append(f"{outcome.name}: FAILED: {outcome.error}")
            continue
        report = outcome.report
        written = [f for f in report.frames if f["status"] == "written"]
        kept = sum(len(f["kept"]) for f in written)
        dropped = sum(len(f["dropped"]) for f in written)
        skipped = sum(1 for f in report.frames if f["status"] == "skipped")
        lines.append(
            f"{outcome.name}: {len(written)} masks ({report.counts['made']} made, {report.counts['reused']} unchanged), "
            f"{skipped} skipped, {report.counts['failed']} failed; {kept} planes kept, {dropped} dropped"
        )
        lines.extend(f"  failed: {line}" for line in outcome.failed_frames)
    return lines

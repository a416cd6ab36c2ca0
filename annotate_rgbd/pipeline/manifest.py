"""Batch manifests: the scenes of a batch run, read from one TOML file.

A manifest has one ``[[scene]]`` table per scene; paths are relative to the manifest::

    jobs = 2                       # optional; default: all cores (--jobs overrides)

    [[scene]]
    name = "fr1_desk"              # optional; default: the output folder's name ('out' as written when several share it); names must differ
    sequence = "data/rgbd_dataset_freiburg1_desk"
    annotations = ["labels/fr1_desk/0-299.xml", "labels/fr1_desk/295-573.xml"]
    config = "fr1_desk"            # a preset name or a TOML file; optional
    out = "out/fr1_desk"
    parts = ["0-299.xml:0"]        # optional, as --part FILE:OFFSET
    set = ["ransac.distance_threshold=0.01"]   # optional, as --set
    raw_masks = false              # optional, as --raw-masks
    overlays = false               # optional, as --overlays (overlays/, review.html, contact sheet)
    instance_ids = false           # optional, as --instance-ids (masks_id/)
    poses = "data/rgbd_dataset_freiburg1_desk/groundtruth.txt"  # optional, as --poses

Reading one is light (no pipeline imports), so that the command line knows the number of
workers before it starts any.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from annotate_rgbd.config.command_line import parse_part_offsets, parse_settings
from annotate_rgbd.config.settings import COMMAND_LINE, Config
from annotate_rgbd.config.toml_input import read_toml
from annotate_rgbd.errors import InputError
from annotate_rgbd.io.bounded import read_input

#: Largest manifest read: a thousand scenes take some 500 KiB.
MAX_MANIFEST_BYTES = 16 << 20
SCENE_KEYS = {"name", "sequence", "annotations", "config", "out", "parts", "set", "raw_masks", "overlays",
              "instance_ids", "poses"}
FLAGS = ("raw_masks", "overlays", "instance_ids")


@dataclass(frozen=True)
class SceneSpec:
    """One ``[[scene]]`` of a manifest, with paths resolved against the manifest's folder; also
    what ``cvat2mask`` runs (one scene, its configuration already loaded as a ``Config``)."""

    name: str
    sequence: Path
    annotations: tuple[Path, ...]
    out: Path
    config: str | Config | None = None
    offsets: dict[str, int] = field(default_factory=dict)
    overrides: dict[str, Any] = field(default_factory=dict)
    raw_masks: bool = False
    overlays: bool = False
    instance_ids: bool = False
    poses: Path | None = None
    #: Warnings of what came before the run (loading a ``Config`` given here), for its report.
    warnings: tuple[str, ...] = ()
    #: Where ``overrides`` come from, for the messages about them.
    overrides_from: str = COMMAND_LINE


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
    path = Path(path)
    try:
        text = read_input(path, MAX_MANIFEST_BYTES).decode("utf-8")
    except OSError as exc:
        raise InputError(path, f"cannot read manifest: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise InputError(path, f"invalid TOML: {exc}") from None
    data = read_toml(text, path)
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
            keys = ", ".join(f"'{key}'" for key in sorted(extra))  # all of them: one round trip
            raise InputError(path, f"{where}: unknown key{'s' if len(extra) > 1 else ''} {keys} "
                                   f"(known: {', '.join(sorted(SCENE_KEYS))})")
        for key in ("sequence", "annotations", "out"):
            if key not in table:
                raise InputError(path, f"{where}: '{key}' is missing")
        if isinstance(table["out"], str) and not table["out"].strip():
            raise InputError(path, f"{where}: 'out' is empty: name the scene's output folder")
        annotations = table["annotations"]
        if isinstance(annotations, str):
            annotations = [annotations]
        strings = {"sequence": table["sequence"], "out": table["out"], "name": table.get("name", ""),
                   "config": table.get("config", ""), "poses": table.get("poses", "")}
        lists = {"annotations": annotations, "parts": table.get("parts", []), "set": table.get("set", [])}
        if not all(isinstance(v, str) for v in strings.values()) or not all(
            isinstance(v, list) and all(isinstance(x, str) for x in v) for v in lists.values()
        ) or not all(isinstance(table.get(flag, False), bool) for flag in FLAGS):
            raise InputError(path, f"{where}: wrong type (paths and names are strings; annotations, parts and set are "
                                   f"lists of strings; {', '.join(FLAGS)} are true or false)")
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
            overlays=table.get("overlays", False),
            instance_ids=table.get("instance_ids", False),
            poses=base / table["poses"] if table.get("poses") else None,
            overrides_from=f"{path}: {where}: set",
        ))
    outs = [s.out.resolve() for s in scenes]
    for out in set(outs):
        if outs.count(out) > 1:
            raise InputError(path, f"two scenes write to {out}: give each scene its own 'out'")
    # Summaries, warnings and --merge name scenes: two of one name could not be told apart. A
    # default name (the output folder's) shared with another scene is its 'out' as written
    # (scans/scene0000_00/annotate, scans/scene0001_00/annotate); given names must differ.
    defaults = [scene.name for scene, table in zip(scenes, tables) if not table.get("name")]
    scenes = [replace(scene, name=table["out"]) if not table.get("name") and defaults.count(scene.name) > 1 else scene
              for scene, table in zip(scenes, tables)]
    names = [scene.name for scene in scenes]
    for number, name in enumerate(names, start=1):
        first = names.index(name) + 1
        if first < number:
            raise InputError(path, f"[[scene]] {first} and {number} are both named '{name}': give each scene a 'name' "
                                   "of its own")
    for out in outs:  # a scene's output folder inside another's: each run would see the other's files
        outer = next((other for other in outs if other in out.parents), None)
        if outer is not None:
            raise InputError(path, f"the output folder {out} is inside another scene's, {outer}: give each scene "
                                   "a folder of its own, side by side")
    return scenes, jobs

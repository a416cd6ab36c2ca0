"""Run configuration: defaults, TOML files, scene presets and command-line overrides.

Every default lives here, with its source. A configuration file has the sections below; a key
that is not listed is an error, so a typo never goes unnoticed::

    [camera]            # pinhole intrinsics of the depth camera
    fx = 517.3
    fy = 516.5
    cx = 318.6
    cy = 255.3
    depth_scale = 5000.0
    [colour_camera]     # colour on a grid of its own: fx, fy, cx, cy, width, height, extrinsic
    [sequence]
    max_time_diff = 0.02
    [annotation]
    labels = []         # CVAT labels to use; empty: all
    [filter]
    max_invalid_ratio = 0.8
    max_mean_distance = 3.5
    min_valid_pixels = 50
    [ransac]
    distance_threshold = 0.0   # > 0: a fixed inlier band instead of [noise]
    num_iterations = 1000
    seed = 0
    max_points = 1000
    band_share = 0.5    # ... and the fit's tunables (annotate_rgbd.config.masks.RansacConfig)
    [noise]             # the inlier band: clip(k sigma(z), floor, cap) (annotate_rgbd.geometry.noise)
    model = "kinect_v1" # or icl_nuim, realsense_d435, quadratic (a, b, c), constant (sigma)
    k = 3.0
    floor = 0.002
    cap = 0.1
    [refine]
    grow_pixels = 3
    rim_pixels = 2
    coherence_limit = 5.0   # ... and the window test's tunables (masks.RefineConfig)
    [stitch]            # several annotation parts of one sequence
    min_iou = 0.5
    [propagate]         # --poses: keyframes carried to every frame (masks.PropagateConfig)
    same_surface_angle = 5.0
    time_offset = 0.0
    time_offset_search = 0.1
    time_offset_step = 0.005
    keyframes_each_side = 3
    exclude = true      # carry what keyframe outlines left out, too
    exclude_margin = 0
    outline_tolerance = 1.0
    [[parts]]           # where a part starts in the RGB list (repeat per part)
    file = "950-1900.xml"
    offset = 950
    [[matches]]         # manual fix of the automatic track matching (repeat per fix)
    part = "950-1900.xml"
    track = 3
    plane = 7           # or: with_part = "0-953.xml" and with_track = 5, or: new = true
    [detect]            # propose's plane detector (annotate_rgbd.config.propose)
    [propose]           # propose: label, every, merging and outlines of the detections
    [link]              # propose: linking detections of successive frames into tracks
    [evaluate]          # evaluate: IoU thresholds (annotate_rgbd.config.evaluate)

``--config`` takes a file path or the name of a preset in ``configs/`` (``fr1_desk``, ...). The
sections that change how a mask is made (``[filter]``, ``[ransac]``, ``[refine]``,
``[propagate]``) are defined, with their sources, in :mod:`annotate_rgbd.config.masks`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import types
import typing
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Iterable, Mapping

from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.errors import InputError
from annotate_rgbd.io.bounded import read_input
from annotate_rgbd.geometry.noise import NoiseSettings, noise_settings_from_mapping
from annotate_rgbd.geometry.registration import ColourCamera, colour_camera_from_mapping
from .camera_checks import partial_intrinsics
from .annotation import AnnotationConfig, MatchConfig, PartConfig, SequenceConfig, StitchConfig
from .evaluate import EvaluateConfig
from .masks import FilterConfig, PropagateConfig, RansacConfig, RefineConfig, range_checks
from .propose import DetectorConfig, LinkConfig, ProposeConfig
from .toml_input import NestedTooDeep, read_toml

log = logging.getLogger("annotate_rgbd")


#: Default camera: the ROS default calibration that TUM RGB-D recommends for its registered
#: depth images (fx = fy = 525, cx = 319.5, cy = 239.5), depth in units of 1/5000 m.
DEFAULT_CAMERA = Camera(fx=525.0, fy=525.0, cx=319.5, cy=239.5, depth_scale=5000.0)


@dataclass(frozen=True)
class Config:
    """Everything the commands depend on besides their input files (``[detect]``, ``[propose]``
    and ``[link]`` are ``propose``'s alone, ``[evaluate]`` is ``evaluate``'s; ``colour_camera``:
    None for registered colour and depth, :mod:`annotate_rgbd.geometry.registration`)."""

    camera: Camera = DEFAULT_CAMERA
    colour_camera: ColourCamera | None = None
    sequence: SequenceConfig = field(default_factory=SequenceConfig)
    annotation: AnnotationConfig = field(default_factory=AnnotationConfig)
    filter: FilterConfig = field(default_factory=FilterConfig)
    ransac: RansacConfig = field(default_factory=RansacConfig)
    noise: NoiseSettings = field(default_factory=NoiseSettings)
    refine: RefineConfig = field(default_factory=RefineConfig)
    propagate: PropagateConfig = field(default_factory=PropagateConfig)
    stitch: StitchConfig = field(default_factory=StitchConfig)
    parts: tuple[PartConfig, ...] = ()
    matches: tuple[MatchConfig, ...] = ()
    detect: DetectorConfig = field(default_factory=DetectorConfig)
    propose: ProposeConfig = field(default_factory=ProposeConfig)
    link: LinkConfig = field(default_factory=LinkConfig)
    evaluate: EvaluateConfig = field(default_factory=EvaluateConfig)

    def inlier_band(self) -> NoiseSettings:
        """The inlier band refinement uses: a fixed ``ransac.distance_threshold`` when one is
        set, else the ``[noise]`` model's."""
        if self.ransac.distance_threshold > 0:
            return NoiseSettings.fixed(self.ransac.distance_threshold)
        return self.noise


def preset_names() -> list[str]:
    """Names of the scene presets shipped in ``configs/``."""
    folder = resources.files("annotate_rgbd.configs")
    return sorted(p.name[: -len(".toml")] for p in folder.iterdir() if p.name.endswith(".toml"))


def preset_summaries() -> list[tuple[str, str, str]]:
    """Every preset with what it is for and where its camera comes from: ``(name, what,
    camera)``, read from its TOML file's opening comment (``# what``, then ``# Camera: source``
    over one or more lines) and its ``[camera]`` values."""
    folder = resources.files("annotate_rgbd.configs")
    summaries = []
    for name in preset_names():
        text = (folder / f"{name}.toml").read_text(encoding="utf-8")
        head = []
        for line in text.splitlines():
            if not line.startswith("#"):
                break
            head.append(line.lstrip("#").strip())
        what = head[0].rstrip(".") if head else ""
        source = " ".join(head[1:]).removeprefix("Camera:").strip().rstrip(".")
        camera = load_config(name).camera
        values = (f"fx {camera.fx:g}, fy {camera.fy:g}, cx {camera.cx:g}, cy {camera.cy:g}, "
                  f"depth_scale {camera.depth_scale:g}")
        summaries.append((name, what, f"{values}; {source}" if source else values))
    return summaries


def preset_text(name: str) -> str:
    """A preset's TOML file as shipped, to start a configuration of one's own from.

    Raises
    ------
    InputError
        No preset of that name (the message lists them).
    """
    names = preset_names()
    if name not in names:
        raise InputError(None, f"no preset {name!r} (presets: {', '.join(names)})")
    return (resources.files("annotate_rgbd.configs") / f"{name}.toml").read_text(encoding="utf-8")


#: Sections that hold a list of tables (``[[parts]]``) rather than one table.
LIST_SECTIONS = {"parts": PartConfig, "matches": MatchConfig}
#: Largest configuration file read (a thousand [[matches]] take some 100 KiB).
MAX_CONFIG_BYTES = 16 << 20


#: The sections a ``cvat2mask`` run does not read: its record leaves them out.
OTHER_COMMANDS_SECTIONS = ("detect", "propose", "link", "evaluate")


def config_to_dict(config: Config, leave_out: Iterable[str] = ()) -> dict[str, Any]:
    """The configuration as nested plain values (for reports: tuples become lists), without the
    sections named in ``leave_out`` (those a command does not read)."""

    def plain(value: Any) -> Any:
        if isinstance(value, NoiseSettings):
            return value.to_mapping()
        if isinstance(value, (tuple, list)):
            return [plain(v) for v in value]
        if isinstance(value, dict):
            return {k: plain(v) for k, v in value.items() if v is not None}
        return value

    leave_out = set(leave_out)
    values = {}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if f.name in leave_out or value is None:  # no colour camera: registered data, and its reports, unchanged
            continue
        values[f.name] = value.to_mapping() if isinstance(value, ColourCamera) else plain(
            value if f.name == "noise" else dataclasses.asdict(config)[f.name])
    return values


#: Where overrides come from, as messages name it, unless the caller says (a batch manifest's ``set``).
COMMAND_LINE = "command-line option"


def load_config(source: str | Path | None = None, overrides: Mapping[str, Any] | None = None,
                overrides_from: str = COMMAND_LINE) -> Config:
    """Build the run configuration.

    Parameters
    ----------
    source : str or Path, optional
        A TOML file, or the name of a preset in ``configs/``. ``None``: defaults only.
    overrides : mapping of str to value, optional
        ``"section.key" -> value`` pairs (from command-line options) applied after the file.
    overrides_from : str
        Where the overrides come from, for the messages about them.

    Returns
    -------
    Config

    Raises
    ------
    InputError
        Unknown file or preset, invalid TOML, unknown section or key, or a value of the wrong
        type or range.
    """
    values: dict[str, dict[str, Any]] = {}
    origin: str | Path | None = None
    if source is not None:
        origin, text = _read_source(source)
        values = read_toml(text, origin)
    poses = values.get("sequence", {}).get("poses") if isinstance(values.get("sequence"), Mapping) else None
    if isinstance(poses, str) and poses and isinstance(origin, Path):
        values["sequence"]["poses"] = str(origin.parent / poses)  # relative to the file
    try:
        config = _build(values, origin)
        file_error = None
    except InputError as error:
        if not overrides:
            raise
        file_error = error  # the overrides may complete it (a model's missing parameter, a bound)
    if overrides:
        for dotted, value in overrides.items():
            section, _, key = dotted.partition(".")
            values.setdefault(section, {})[key] = value
        try:
            config = _build(values, overrides_from)
        except InputError:
            # What the file got wrong is said as the file's; what fails only now, as the command line's.
            if file_error is not None:
                raise file_error from None
            raise
    # Half-written intrinsics, with the command line's values in (--set camera.fx=... completes a file).
    problem = partial_intrinsics(values.get("camera"), DEFAULT_CAMERA)
    if problem is not None:
        log.warning("%s: %s", origin if source is not None else overrides_from, problem)
    return config


def config_from_dict(values: Mapping[str, Any], origin: str | Path | None = None) -> Config:
    """The inverse of :func:`config_to_dict` (e.g. the ``config`` recorded in ``report.json``)."""
    return _build(values, origin)


def _read_source(source: str | Path) -> tuple[Path | str, str]:
    path = Path(source)
    if path.is_file():
        try:
            return path, read_input(path, MAX_CONFIG_BYTES).decode("utf-8")
        except OSError as exc:
            raise InputError(path, f"cannot read configuration: {exc.strerror or exc}") from None
        except UnicodeDecodeError as exc:
            raise InputError(path, f"cannot read configuration: {exc}") from None
    names = preset_names()
    if str(source) in names:
        preset = resources.files("annotate_rgbd.configs") / f"{source}.toml"
        return f"preset {source}", preset.read_text(encoding="utf-8")
    raise InputError(source, f"no such configuration file or preset (presets: {', '.join(names)})")


#: Sections read by their own module (one-line ValueErrors naming the key).
SECTION_READERS = {"noise": noise_settings_from_mapping, "colour_camera": colour_camera_from_mapping}


def _build(values: Mapping[str, Any], origin: str | Path | None) -> Config:
    defaults = Config()
    sections = {f.name: getattr(defaults, f.name) for f in dataclasses.fields(Config)}
    built = {}
    for name, table in values.items():
        if name in LIST_SECTIONS:
            built[name] = _build_list(name, LIST_SECTIONS[name], table, origin)
            continue
        if name in SECTION_READERS and isinstance(table, Mapping):
            try:  # an empty [colour_camera]: registered, as without one
                built[name] = SECTION_READERS[name](table) if table or name == "noise" else None
            except ValueError as exc:
                raise InputError(origin, str(exc)) from None
            continue
        if name not in sections:
            raise InputError(origin, f"unknown section [{name}] (known: {', '.join(sections)})")
        if not isinstance(table, Mapping):
            raise InputError(origin, f"[{name}] must be a table of keys")
        built[name] = _build_section(name, sections[name], table, origin)
    config = dataclasses.replace(defaults, **built)
    _check_ranges(config, origin)
    return config


def _build_list(name: str, entry_type: type, tables: Any, origin: str | Path | None) -> tuple:
    """Read a ``[[name]]`` list of tables into a tuple of ``entry_type``."""
    if not isinstance(tables, list) or not all(isinstance(t, Mapping) for t in tables):
        raise InputError(origin, f"'{name}' must be a list of tables: write each entry as [[{name}]]")
    fields = {f.name: f for f in dataclasses.fields(entry_type)}
    kinds = _entry_types(entry_type)
    required = [f.name for f in fields.values() if f.default is dataclasses.MISSING]
    entries = []
    for number, table in enumerate(tables, start=1):
        where = f"[[{name}]] entry {number}"
        for key in table:
            if key not in fields:
                raise InputError(origin, f"{where}: unknown key '{key}' (known: {', '.join(fields)})")
        for key in required:
            if key not in table:
                raise InputError(origin, f"{where}: '{key}' is missing")
        values = {}
        for key, value in table.items():
            accepted = [kind for kind in kinds[key] if _is_a(value, kind)]
            if not accepted:
                raise InputError(origin, f"{where}: '{key}' has the wrong type ({value!r})")
            values[key] = float(value) if accepted[0] is float else value
        entries.append(entry_type(**values))
    return tuple(entries)


#: The types a ``[[list]]`` entry's field may have (alone, or in a union such as ``int | None``).
ENTRY_VALUE_TYPES = (str, bool, int, float)


def _entry_types(entry_type: type) -> dict[str, tuple[type, ...]]:
    """Field name -> the types its value may have, read from the dataclass's type hints.

    ``int | None`` gives ``(int,)``: TOML has no null, leaving a key out gives its default.
    A field of any other type is a programming error (TOML cannot say what it means).
    """
    hints = typing.get_type_hints(entry_type)
    kinds = {}
    for f in dataclasses.fields(entry_type):
        hint = hints[f.name]
        members = typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, types.UnionType) else (hint,)
        members = tuple(m for m in members if m is not type(None))
        if not members or not all(m in ENTRY_VALUE_TYPES for m in members):
            raise TypeError(f"{entry_type.__name__}.{f.name}: a [[list]] entry cannot hold a {hint}")
        kinds[f.name] = members
    return kinds


def _is_a(value: Any, kind: type) -> bool:
    """Whether a TOML value fits ``kind``: booleans are no numbers, integers are floats."""
    if isinstance(value, bool):
        return kind is bool
    if kind is float:
        return isinstance(value, (int, float))
    return isinstance(value, kind)


def _build_section(name: str, default: Any, table: Mapping[str, Any], origin: str | Path | None) -> Any:
    fields = {f.name: f for f in dataclasses.fields(default)}
    changes = {}
    for key, value in table.items():
        if key not in fields:
            raise InputError(
                origin, f"unknown key '{name}.{key}' (known in [{name}]: {', '.join(fields)})"
            )
        changes[key] = _coerce(f"{name}.{key}", getattr(default, key), value, origin)
    try:
        return dataclasses.replace(default, **changes)
    except ValueError as exc:  # a section that checks its own ranges (annotate_rgbd.config.rules)
        raise InputError(origin, str(exc)) from None


def _coerce(key: str, default: Any, value: Any, origin: str | Path | None) -> Any:
    """Check ``value`` against the type of the default and convert ints to floats where needed."""
    if isinstance(default, str):
        if not isinstance(value, str):
            raise InputError(origin, f"'{key}' must be a string, got {value!r}")
        return value
    if isinstance(default, tuple):
        if isinstance(value, str):
            value = [value]
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            raise InputError(origin, f"'{key}' must be a list of strings")
        return tuple(value)
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise InputError(origin, f"'{key}' must be true or false, got {value!r}")
        return value
    if isinstance(value, bool):
        raise InputError(origin, f"'{key}' must be a number, got {value!r}")
    if isinstance(default, int):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if not isinstance(value, int):
            raise InputError(origin, f"'{key}' must be an integer, got {value!r}")
        return value
    if not isinstance(value, (int, float)):
        raise InputError(origin, f"'{key}' must be a number, got {value!r}")
    return float(value)


def setting_problem(key: str, value: Any) -> str | None:
    """Why ``value`` cannot be the setting ``key`` (``"must be in [0, 1]"``), or None when it can:
    the checks a configuration file or ``--set`` gets, for a command-line option that sets one key
    (checked as the command line is parsed).

    Parameters
    ----------
    key : str
        ``section.key``.
    value : object

    Returns
    -------
    str or None
        The rule the value breaks, without the key.
    """
    try:
        load_config(None, {key: value})
    except InputError as problem:
        named = f"'{key}' "
        return problem.message[len(named):] if problem.message.startswith(named) else problem.message
    return None


#: Largest integer setting: a C int (OpenCV takes its sizes as C ints; beyond, surely a typo).
MAX_INT_SETTING = 2**31 - 1
#: Most RANSAC hypotheses: the exhaustive search of a carried shape scores them all, a million
#: over 1,000 points in about 4 s (measured on this project's 2-core machine) for one plane of
#: one frame; beyond, a run would seem to hang (the default is 1,000).
MAX_RANSAC_ITERATIONS = 1_000_000


def _check_ranges(config: Config, origin: str | Path | None) -> None:
    for section in dataclasses.fields(config):
        value = getattr(config, section.name)
        if not dataclasses.is_dataclass(value) or isinstance(value, (NoiseSettings, ColourCamera)):
            continue  # lists of tables are checked per entry; noise and colour camera by their readers
        for key, number in dataclasses.asdict(value).items():
            if isinstance(number, float) and not math.isfinite(number):
                raise InputError(origin, f"'{section.name}.{key}' must be a finite number, got {number!r}")
            if isinstance(number, int) and not isinstance(number, bool) and abs(number) > MAX_INT_SETTING:
                raise InputError(origin, f"'{section.name}.{key}' must be at most {MAX_INT_SETTING}, got {number}")
    checks = [
        ("camera.fx", config.camera.fx != 0, "must not be 0"),
        ("camera.fy", config.camera.fy != 0, "must not be 0"),
        ("camera.depth_scale", config.camera.depth_scale > 0, "must be > 0"),
        ("sequence.max_time_diff", config.sequence.max_time_diff >= 0, "must be >= 0"),
        ("sequence.max_pose_gap", config.sequence.max_pose_gap > 0, "must be > 0"),
        ("filter.max_invalid_ratio", 0 <= config.filter.max_invalid_ratio <= 1, "must be in [0, 1]"),
        ("filter.max_mean_distance", config.filter.max_mean_distance > 0, "must be > 0"),
        ("filter.min_valid_pixels", config.filter.min_valid_pixels >= 3, "must be >= 3"),
        ("ransac.distance_threshold", config.ransac.distance_threshold >= 0, "must be >= 0 (0: the [noise] band)"),
        ("refine.grow_pixels", 0 <= config.refine.grow_pixels <= 50, "must be in [0, 50]"),
        ("refine.rim_pixels", 0 <= config.refine.rim_pixels <= 50, "must be in [0, 50]"),
        ("refine.behind_band", 1 <= config.refine.behind_band <= 10, "must be in [1, 10]"),
        ("ransac.num_iterations", 1 <= config.ransac.num_iterations <= MAX_RANSAC_ITERATIONS,
         f"must be in [1, {MAX_RANSAC_ITERATIONS}]"),
        ("ransac.seed", config.ransac.seed >= 0, "must be >= 0"),
        ("ransac.max_points", config.ransac.max_points == 0 or config.ransac.max_points >= 3, "must be 0 or >= 3"),
        ("stitch.min_iou", 0 < config.stitch.min_iou <= 1, "must be in (0, 1]"),
        *range_checks(config),
    ]
    for key, ok, rule in checks:
        if not ok:
            raise InputError(origin, f"'{key}' {rule}")

"""Command line: parses options and calls library functions, nothing more."""

from __future__ import annotations

import logging
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, List, Optional

import typer

from . import __version__
from .errors import InputError

app = typer.Typer(
    help="Turn CVAT plane polygons on RGB-D sequences into depth-verified plane instance masks.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@contextmanager
def user_errors() -> Iterator[None]:
    """Turn input problems into one ``error:`` line and exit status 1 (2 for an interrupt)."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
    logger = logging.getLogger("annotate_rgbd")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logging.addLevelName(logging.WARNING, "warning")
    try:
        yield
    except InputError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    except KeyboardInterrupt:
        typer.echo("error: interrupted; finished files are complete, nothing partial was left", err=True)
        raise typer.Exit(130) from None
    finally:
        logger.removeHandler(handler)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"annotate-rgbd {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version."),
) -> None:
    """Turn CVAT plane polygons on RGB-D sequences into depth-verified plane instance masks."""


def parse_settings(settings: List[str]) -> dict:
    """``section.key=value`` strings -> overrides; values are read as TOML (numbers, lists...)."""
    from .config import tomllib

    overrides = {}
    for setting in settings:
        key, sep, text = setting.partition("=")
        if not sep or "." not in key:
            raise InputError(None, f"--set {setting!r}: expected SECTION.KEY=VALUE, e.g. ransac.distance_threshold=0.01")
        try:
            value = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text
        overrides[key.strip()] = value
    return overrides


@app.command()
def cvat2mask(
    sequence_dir: Path = typer.Argument(..., help="TUM RGB-D or ICL-NUIM (TUM format) sequence folder."),
    annotations: List[Path] = typer.Argument(..., help="CVAT export(s): 'CVAT for video 1.1' or 'CVAT for images 1.1' XML."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder for masks/, planes.csv and report.json."),
    config: Optional[str] = typer.Option(None, "--config", "-c", help="TOML file or preset name (see 'annotate-rgbd presets')."),
    label: List[str] = typer.Option([], "--label", help="Use only shapes with this CVAT label (repeatable)."),
    distance_threshold: Optional[float] = typer.Option(None, help="RANSAC inlier distance in metres."),
    max_invalid_ratio: Optional[float] = typer.Option(None, help="Drop a plane with a larger share of invalid depth."),
    max_mean_distance: Optional[float] = typer.Option(None, help="Drop a plane farther than this on average (m)."),
    max_time_diff: Optional[float] = typer.Option(None, help="Largest depth-to-RGB time difference (s)."),
    set_: List[str] = typer.Option([], "--set", help="Override any configuration key: SECTION.KEY=VALUE."),
) -> None:
    """Write one colour-coded plane mask per depth frame, refined against the depth."""
    from .config import load_config
    from .pipeline import run_cvat2mask

    with user_errors():
        overrides = parse_settings(set_)
        named = {
            "annotation.labels": label or None,
            "ransac.distance_threshold": distance_threshold,
            "filter.max_invalid_ratio": max_invalid_ratio,
            "filter.max_mean_distance": max_mean_distance,
            "sequence.max_time_diff": max_time_diff,
        }
        overrides.update({k: v for k, v in named.items() if v is not None})
        report = run_cvat2mask(sequence_dir, annotations, out, load_config(config, overrides))
        summary = f"{report.written} masks written to {out / 'masks'}, {len(report.planes)} planes"
        if report.warnings:
            summary += f", {len(report.warnings)} warnings (see {out / 'report.json'})"
        typer.echo(summary)


@app.command()
def presets() -> None:
    """List the scene presets that --config accepts."""
    from .config import preset_names

    for name in preset_names():
        typer.echo(name)

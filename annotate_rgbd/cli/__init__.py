"""Command line: parses options and calls library functions, nothing more."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from annotate_rgbd import __version__
from .console import CheckedCommand, OneLineErrors, one_output, output_path, user_errors
from .options import OPTION_SETTINGS, polygon_budget, seconds, setting, share_of_image
from annotate_rgbd.errors import InputError
from annotate_rgbd.logs import counted, manifest_words
from annotate_rgbd.pool import STALL_TIMEOUT

app = typer.Typer(
    cls=OneLineErrors,  # a command line that cannot be parsed is one error line, as every other problem
    help="Turn CVAT plane polygons on RGB-D sequences into depth-verified plane instance masks.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
    # Plain help, like a Unix tool's: rich mode (typer >= 0.29) prints '--force <bool>' and
    # '<list[Path]>'. Every parameter that takes a value names it with a metavar below.
    rich_markup_mode=None,
)


def _load_config(sequence_dir: Path, config: Optional[str], overrides: dict):
    """The run's configuration: ``--config`` (else the defaults and the cameras the sequence's
    layout states, each said in one line) with the overrides
    (:func:`annotate_rgbd.config.layout.load_run_config`)."""
    from annotate_rgbd.config.layout import load_run_config

    return load_run_config(sequence_dir, config, overrides)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"annotate-rgbd {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version."),
) -> None:
    """Turn CVAT plane polygons on RGB-D sequences into depth-verified plane instance masks."""


@app.command(cls=CheckedCommand)
def cvat2mask(
    sequence_dir: Path = typer.Argument(
        ..., metavar="SEQUENCE_DIR", help="Sequence folder: TUM RGB-D, ICL-NUIM (TUM format), ScanNet export or 7-Scenes."
    ),
    annotations: List[Path] = typer.Argument(..., metavar="ANNOTATIONS...", help="CVAT export(s): 'CVAT for video 1.1' or 'CVAT for images 1.1' XML, or CVAT's .zip of it."),
    out: str = typer.Option(..., "--out", "-o", metavar="DIR", help="Output folder for masks/, planes.csv and report.json."),
    config: Optional[str] = typer.Option(
        None, "--config", "-c", metavar="FILE|PRESET",
        help="TOML file or preset name (see 'annotate-rgbd presets'); without it: the camera the layout states "
        "(ScanNet's intrinsic_depth.txt, 7-Scenes'), else a Kinect v1 at 640x480 (fx = fy = 525, depth in 1/5000 m, TUM's default) with the kinect_v1 noise model.",
    ),
    label: List[str] = typer.Option([], "--label", metavar="LABEL", help="Use only shapes with this CVAT label (repeatable)."),
    distance_threshold: Optional[float] = typer.Option(
        None, metavar="METRES", callback=setting,
        help="A fixed inlier band in metres at every depth, instead of the [noise] model's (0: the model's).",
    ),
    max_invalid_ratio: Optional[float] = typer.Option(
        None, metavar="SHARE", callback=setting, help="Drop a plane with a larger share of invalid depth."
    ),
    max_mean_distance: Optional[float] = typer.Option(
        None, metavar="METRES", callback=setting, help="Drop a plane farther than this on average (m)."
    ),
    max_time_diff: Optional[float] = typer.Option(
        None, metavar="SECONDS", callback=setting, help="Largest depth-to-RGB time difference (s)."
    ),
    set_: List[str] = typer.Option([], "--set", metavar="SECTION.KEY=VALUE", help="Override any configuration key: SECTION.KEY=VALUE."),
    part: List[str] = typer.Option(
        [], "--part", metavar="FILE:OFFSET", help="Where an annotation part starts: FILE:OFFSET, the RGB index of its frame 0 (repeatable)."
    ),
    jobs: Optional[int] = typer.Option(None, "--jobs", "-j", min=1, metavar="N", help="Worker processes (default: all cores)."),
    force: bool = typer.Option(False, "--force", help="Redo every frame, even those unchanged since the last run."),
    raw_masks: bool = typer.Option(False, "--raw-masks", help="Also write masks_raw/: the shapes as drawn, unrefined."),
    overlays: bool = typer.Option(False, "--overlays", help="Also write overlays/, review.html and contact_sheet.png."),
    instance_ids: bool = typer.Option(
        False, "--instance-ids", help="Also write masks_id/: plane ids as pixel values (8/16-bit, as in planes.csv)."
    ),
    job_timeout: float = typer.Option(
        STALL_TIMEOUT, "--job-timeout", min=1.0, metavar="SECONDS", callback=seconds, help="Seconds without a frame finished by the helpers before they are replaced."
    ),
    poses: Optional[Path] = typer.Option(
        None, "--poses", metavar="FILE|DIR",
        help="Camera trajectory (TUM, KITTI rows, or a folder of per-frame pose files; default: the layout's own poses): "
        "carry keyframe shapes to every frame by the poses.",
    ),
) -> None:
    """Write one colour-coded plane mask per depth frame, refined against the depth.

    Several exports are annotation parts of one sequence: their tracks are matched into one plane id per physical plane (see tracks.csv).
    """
    with user_errors():
        out = Path(out)  # never empty (CheckedCommand)
        from annotate_rgbd.pipeline.execute import default_workers, prepare_process

        workers = jobs or default_workers()
        prepare_process(workers)  # the helpers' server imports OpenCV and numpy while this process does

        from annotate_rgbd.config.command_line import parse_part_offsets, parse_settings
        from annotate_rgbd.pipeline.scene import run_cvat2mask
        from annotate_rgbd.progress import Progress

        overrides = parse_settings(set_)
        options = {"distance_threshold": distance_threshold, "max_invalid_ratio": max_invalid_ratio,
                   "max_mean_distance": max_mean_distance, "max_time_diff": max_time_diff}
        named = {"annotation.labels": label or None, **{OPTION_SETTINGS[name]: v for name, v in options.items()}}
        overrides.update({k: v for k, v in named.items() if v is not None})
        offsets = parse_part_offsets(part)
        progress = Progress({sequence_dir.name: 0})
        from annotate_rgbd.logs import collect_warnings

        with collect_warnings() as loading:  # printed now, and kept in the report
            run_config = _load_config(sequence_dir, config, overrides)
        report = run_cvat2mask(
            sequence_dir, annotations, out, run_config, offsets=offsets,
            workers=workers, force=force, raw_masks=raw_masks, overlays=overlays, instance_ids=instance_ids,
            progress=progress.callback(sequence_dir.name), job_timeout=job_timeout, poses=poses, warnings=loading,
        )
        progress.finish()
        hint = report.drop_hint()
        if hint:  # advice on the run as a whole, not one of the report's warnings
            typer.echo(f"hint: {hint}", err=True)
        typer.echo(report.summary())
        failures = report.failures()
        for line in failures:
            typer.echo(f"  failed: {line}")
        if report.review_page is not None:
            typer.echo(f"review page: {report.review_page}")
        if failures:
            raise typer.Exit(1)  # every mask that could be made is written


@app.command(cls=CheckedCommand)
def batch(
    manifest: Path = typer.Argument(..., metavar="MANIFEST", help="TOML manifest: one scene table per scene (see docs/batch.md)."),
    jobs: Optional[int] = typer.Option(None, "--jobs", "-j", min=1, metavar="N", help="Worker processes (default: the manifest's jobs, else all cores)."),
    force: bool = typer.Option(False, "--force", help="Redo every frame, even those unchanged since the last run."),
    job_timeout: float = typer.Option(
        STALL_TIMEOUT, "--job-timeout", min=1.0, metavar="SECONDS", callback=seconds, help="Seconds without a frame finished by the helpers before they are replaced."
    ),
    shard: Optional[str] = typer.Option(
        None, "--shard", metavar="K/N", help="Run only the K-th of N disjoint shards of the scenes (by a hash of their names)."
    ),
    merge: bool = typer.Option(False, "--merge", help="Run nothing: one summary of the scenes' finished runs (e.g. of all shards)."),
    as_json: bool = typer.Option(False, "--json", help="With --merge: print one JSON object."),
) -> None:
    """Relabel several scenes with one pool of workers; only changed frames are redone."""
    with user_errors():
        from annotate_rgbd.pipeline.execute import default_workers, prepare_process
        from annotate_rgbd.pipeline.manifest import read_manifest

        if as_json and not merge:  # a run prints its summary lines: there is no JSON of it to print
            raise InputError(None, "--json is for --merge (a summary of finished runs); a run's summary is its "
                                   "report.json, and `annotate-rgbd stats OUT --json` prints one scene's")
        scenes, manifest_jobs = read_manifest(manifest)
        if shard is not None:
            from annotate_rgbd.pipeline.shards import parse_shard, select_shard

            k, n = parse_shard(shard)
            scenes = select_shard(scenes, k, n)
            typer.echo(f"shard {k}/{n}: {counted(len(scenes), 'scene')}"
                       + (f" ({', '.join(s.name for s in scenes)})" if scenes else ""))
        if merge:
            _merge_batch(scenes, as_json)
            return
        if not scenes:
            return
        workers = jobs or manifest_jobs or default_workers()
        prepare_process(workers)  # the helpers' server imports OpenCV and numpy while this process does

        from annotate_rgbd.pipeline.batch import run_batch, summary_lines
        from annotate_rgbd.progress import Progress

        progress = Progress({scene.name: 0 for scene in scenes})
        outcomes = run_batch(scenes, workers, force, progress.callback, job_timeout=job_timeout)
        progress.finish()
        for line in summary_lines(outcomes):
            typer.echo(line)
        for outcome in outcomes:  # also where errors go: a log of standard error alone has them
            if outcome.error is not None:
                typer.echo(f"error: {outcome.name}: {manifest_words(outcome.error)}", err=True)
        if any(o.error is not None or o.failed_frames for o in outcomes):
            raise typer.Exit(1)


def _merge_batch(scenes: list, as_json: bool) -> None:
    """Print one summary of the scenes' finished runs; exit 1 when a scene has none."""
    from annotate_rgbd.report.run_folder import read_report
    from annotate_rgbd.report.stats import format_stats, format_stats_json, merge_stats, run_stats

    found, ran, missing, without_run = [], [], [], []
    for scene in scenes:
        try:
            found.append(run_stats(read_report(scene.out)))
            ran.append(scene.name)
        except InputError as exc:
            missing.append(f"{scene.name}: {exc}")
            without_run.append(scene.name)
    merged = merge_stats(found, ran)  # the lists name their scene
    # The JSON names the scenes left out: a script reading it alone can tell the summary is partial.
    typer.echo(format_stats_json({**merged, "scenes_without_a_run": without_run}) if as_json else format_stats(merged))
    for line in missing:
        typer.echo(f"error: {line}", err=True)
    if missing:
        raise typer.Exit(1)


@app.command(cls=CheckedCommand)
def presets(
    name: Optional[str] = typer.Argument(
        None, metavar="[NAME]", help="Print this preset's TOML file (to start your own from: > my_camera.toml)."
    ),
) -> None:
    """List the scene presets that --config accepts, with their cameras, noise models and drop rules."""
    from annotate_rgbd.config.settings import load_config, preset_summaries, preset_text

    with user_errors():
        if name is not None:
            typer.echo(preset_text(name), nl=False)
            return
        lines = []
        for preset, what, camera in preset_summaries():
            config = load_config(preset)
            rules = config.filter
            lines += [f"{preset}: {what}", f"    camera: {camera}",
                      f"    noise: {config.noise.to_mapping()['model']}; planes dropped above "
                      f"{rules.max_invalid_ratio:g} invalid depth or beyond {rules.max_mean_distance:g} m on average"]
        typer.echo("\n".join(lines))  # one write: a reader that stops early (| head) meets no broken pipe


@app.command(cls=CheckedCommand)
def evaluate(
    ctx: typer.Context,
    gt: Path = typer.Argument(..., metavar="GT", help="Ground-truth masks: a folder of label files, or one file."),
    pred: Path = typer.Argument(..., metavar="PRED", help="Predicted masks, matched to GT by file name; or one file."),
    full: Optional[float] = typer.Option(
        None, "--full", metavar="IOU", help="IoU for a full match (a true positive); default: the configuration's [evaluate] full."
    ),
    partial: Optional[float] = typer.Option(
        None, "--partial", metavar="IOU", help="IoU for a partial overlap (usr, osr, noise, missed); default: [evaluate] partial."
    ),
    config: Optional[str] = typer.Option(None, "--config", "-c", metavar="FILE|PRESET", help="TOML file or preset name (its [evaluate] section)."),
    set_: List[str] = typer.Option([], "--set", metavar="SECTION.KEY=VALUE", help="Override any configuration key: SECTION.KEY=VALUE."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object instead of a table."),
    # Text, not Path: Path("./-") is "-", standard output (output_path).
    per_frame_text: Optional[str] = typer.Option(
        None, "--per-frame", metavar="CSV", help="Also write each frame's statistics to this CSV ('-': standard output)."),
    ignore: Optional[int] = typer.Option(
        None, "--ignore", metavar="LABEL", help="GT label value of don't-care pixels, left out of GT and PRED "
        "(e.g. 65535); default: [evaluate] ignore (-1: none). GT must be label files, not colour masks."),
    skip_missing: bool = typer.Option(
        False, "--skip-missing", help="Score only the GT frames PRED has a mask for (e.g. a propose --every N run); "
        "without it, a GT frame without one scores as an empty prediction."),
    # The old name of --partial, kept working for scripts; cvat2mask's --part is FILE:OFFSET.
    part: Optional[float] = typer.Option(None, "--part", hidden=True),
) -> None:
    """Score plane masks against ground truth with the EVOPS metrics (sequence means)."""
    from annotate_rgbd.config.command_line import parse_settings
    from annotate_rgbd.config.settings import load_config
    from annotate_rgbd.evaluate.evaluate import (
        check_per_frame_target, evaluate_paths, format_json, format_table, write_per_frame_csv,
    )

    per_frame = None if per_frame_text is None else output_path(per_frame_text)
    with user_errors():
        if part is not None:
            # By name: typer (0.26 on) has its own copy of click, whose enum is not click's.
            if getattr(ctx.get_parameter_source("partial"), "name", None) == "COMMANDLINE":
                raise InputError(None, "give --partial only (--part is its deprecated name)")
            typer.echo("warning: evaluate --part is deprecated, use --partial (the same IoU threshold)", err=True)
            partial = part
        thresholds = load_config(config, parse_settings(set_)).evaluate
        if per_frame is not None:
            check_per_frame_target(per_frame, gt, pred)
        # The options win over the configuration; evaluate_paths checks them (naming --full, --partial).
        full = thresholds.full if full is None else full
        partial = thresholds.partial if partial is None else partial
        result = evaluate_paths(gt, pred, full=full, part=partial, skip_missing=skip_missing,
                                ignore=thresholds.ignore if ignore is None else ignore)
        if per_frame is not None:
            write_per_frame_csv(result, per_frame)
        from annotate_rgbd.io.writer import names_stdout

        # With the per-frame CSV in standard output, the means go to standard error.
        typer.echo(format_json(result) if as_json else format_table(result),
                   err=per_frame is not None and names_stdout(per_frame))


@app.command(cls=CheckedCommand)
def review(
    out_dir: Path = typer.Argument(
        ..., metavar="RUN_DIR", help="Output folder of a finished cvat2mask run, or of propose (its proposals)."
    ),
    overlays: bool = typer.Option(True, "--overlays/--no-overlays", help="Draw overlays/ from the run's records (masks, drawn shapes, RGB frames); nothing is segmented again."),
    page: bool = typer.Option(True, "--page/--no-page", help="Write review.html."),
    sheet: bool = typer.Option(True, "--sheet/--no-sheet", help="Write contact_sheet.png from overlays/."),
    jobs: Optional[int] = typer.Option(None, "--jobs", "-j", min=1, metavar="N", help="Worker processes (default: all cores)."),
    rerun: Optional[Path] = typer.Option(
        None, "--rerun", metavar="FILE.rrd",
        help="Also write a Rerun recording (view it with `rerun FILE.rrd`): per frame the RGB image, depth, plane "
        "labels and labelled 3-D points, with the camera trajectory when the run had poses. Needs the optional "
        "extra: pip install 'annotate-rgbd[viewer]'.",
    ),
    rerun_step: int = typer.Option(4, "--rerun-step", min=1, metavar="N",
                                   help="Recording: the 3-D points of every N-th pixel of every N-th row."),
    rerun_every: int = typer.Option(1, "--rerun-every", min=1, metavar="N",
                                    help="Recording: every N-th frame with a mask."),
) -> None:
    """Write review overlays, the offline review page and a contact sheet for a finished run."""
    with user_errors():
        if not (overlays or page or sheet or rerun is not None):
            raise InputError(None, "nothing to do: --no-overlays, --no-page and --no-sheet leave no output "
                                   "(add --rerun FILE.rrd for a recording only)")
        if rerun is not None:
            from annotate_rgbd.review.rerun_recording import check_recording, import_rerun

            import_rerun()  # without the SDK: one line saying how to install it, before any work
            check_recording(rerun, rerun_step, rerun_every)  # a bad path too, not after the overlays
        from annotate_rgbd.pipeline.execute import default_workers, prepare_process

        workers = (jobs or default_workers()) if overlays else 1  # only overlays take helpers
        prepare_process(workers)
        from annotate_rgbd.progress import Progress
        from annotate_rgbd.review.review import review_run

        scene = out_dir.resolve().name
        progress = Progress({scene: 0})
        output = review_run(out_dir, overlays=overlays, page=page, sheet=sheet, progress=progress.callback(scene),
                            workers=workers)
        progress.finish()
        lines = [f"{len(output.overlays)} overlays in {out_dir / 'overlays'}"] if overlays else []
        lines += [str(path) for path in (output.page, output.sheet) if path is not None]
        if rerun is not None:
            from annotate_rgbd.review.rerun_recording import write_recording

            recording = Progress({f"{scene} recording": 0})
            summary = write_recording(out_dir, rerun, step=rerun_step, every=rerun_every,
                                      progress=recording.callback(f"{scene} recording"))
            recording.finish()
            frame = "the trajectory's world frame" if summary.world else "the camera frame"
            lines.append(f"{summary.path}: Rerun recording of {summary.frames} frames, {summary.points:,} labelled "
                         f"3-D points in {frame}, {summary.size / 1e6:.1f} MB (view it: rerun {summary.path})")
        typer.echo("\n".join(lines))


@app.command(cls=CheckedCommand)
def stats(
    out_dir: Path = typer.Argument(..., metavar="RUN_DIR", help="Output folder of a finished cvat2mask run."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object instead of a table."),
) -> None:
    """Summarise a run: observations, planes per observation, dropped planes, inlier ratio."""
    from annotate_rgbd.io.outdir import reading
    from annotate_rgbd.report.run_folder import read_report
    from annotate_rgbd.report.stats import format_stats, format_stats_json, run_stats

    with user_errors():
        with reading(out_dir):
            summary = run_stats(read_report(out_dir))
        typer.echo(format_stats_json(summary) if as_json else format_stats(summary))


@app.command(cls=CheckedCommand)
def propose(
    sequence_dir: Path = typer.Argument(
        ..., metavar="SEQUENCE_DIR",
        help="Sequence folder: TUM RGB-D, ICL-NUIM (TUM format), ScanNet export, 7-Scenes, or depth only (depth.txt or depth/).",
    ),
    out: str = typer.Option(..., "--out", "-o", metavar="DIR", help="Output folder for proposals.xml, masks/ and report.json."),
    config: Optional[str] = typer.Option(
        None, "--config", "-c", metavar="FILE|PRESET",
        help="TOML file or preset name (see 'annotate-rgbd presets'); without it: the camera the layout states "
        "(ScanNet's intrinsic_depth.txt, 7-Scenes'), else a Kinect v1 at 640x480 (fx = fy = 525, depth in 1/5000 m, TUM's default) with the kinect_v1 noise model.",
    ),
    poses: Optional[Path] = typer.Option(
        None, "--poses", metavar="FILE|DIR",
        help="Camera trajectory (TUM, KITTI rows, or a folder of per-frame pose files; default: the layout's own poses): "
        "link planes across frames by world plane.",
    ),
    every: Optional[int] = typer.Option(
        None, "--every", min=1, metavar="N", help="Process every N-th depth frame (CVAT keyframes); default: [propose] every."
    ),
    jobs: Optional[int] = typer.Option(None, "--jobs", "-j", min=1, metavar="N", help="Worker processes (default: all cores)."),
    label: Optional[str] = typer.Option(
        None, "--label", metavar="LABEL", help="CVAT label of the proposed tracks; default: [propose] label."
    ),
    min_area: Optional[float] = typer.Option(
        None, "--min-area", metavar="SHARE", callback=share_of_image,
        help="Smallest plane proposed, as a share of the image, in (0, 1]; default: [detect] min_area_fraction.",
    ),
    set_: List[str] = typer.Option([], "--set", metavar="SECTION.KEY=VALUE", help="Override any configuration key: SECTION.KEY=VALUE."),
) -> None:
    """Detect planes on the depth frames and write them as CVAT polygon tracks to correct."""
    with user_errors():
        out = Path(out)  # never empty (CheckedCommand); the options first, before any work
        from annotate_rgbd.pool import default_workers, prepare_helpers, reuse_freed_memory

        workers = jobs or default_workers()
        prepare_helpers(workers, ["annotate_rgbd.propose.detect_job"])
        reuse_freed_memory()

        from annotate_rgbd.config.command_line import parse_settings
        from annotate_rgbd.progress import Progress
        from annotate_rgbd.config.propose import label_problem
        from annotate_rgbd.propose import run_propose

        if label is not None and label_problem(label) is not None:
            raise InputError(None, f"--label {label!r} {label_problem(label)}: give the CVAT label of the proposed planes")
        overrides = parse_settings(set_)
        named = {"propose.every": every, "propose.label": label, "detect.min_area_fraction": min_area}
        overrides.update({k: v for k, v in named.items() if v is not None})
        progress = Progress({sequence_dir.name: 0})
        from annotate_rgbd.logs import collect_warnings

        with collect_warnings() as loading:  # printed now, and kept in the report
            run_config = _load_config(sequence_dir, config, overrides)
        result = run_propose(sequence_dir, out, run_config, poses=poses, workers=workers,
                             progress=progress.callback(sequence_dir.name), warnings=loading)
        progress.finish()
        typer.echo(result.summary(out))
        hint = result.drop_hint(run_config.camera.depth_scale, run_config.filter)
        if hint:  # advice on the run as a whole
            typer.echo(f"hint: {hint}", err=True)
        if result.failed:
            typer.echo(f"  {counted(len(result.failed), 'frame')} failed (see the warnings above)")
            raise typer.Exit(1)


@app.command("export-cvat", cls=CheckedCommand)
def export_cvat_command(
    run_dir: Path = typer.Argument(..., metavar="RUN_DIR", help="Output folder of a finished cvat2mask run."),
    # Text, not Path: Path("./-") is "-", standard output (one_output).
    xml: Optional[str] = typer.Argument(None, metavar="FILE.xml", help="The CVAT for video 1.1 XML file to write."),
    xml_option: Optional[str] = typer.Option(None, "--out", "-o", metavar="FILE.xml", help="The same as FILE.xml."),
    tolerance: Optional[float] = typer.Option(
        None, "--tolerance", min=0.0, metavar="PX", callback=polygon_budget,
        help="Largest distance of a polygon from its mask's outline, pixels (default 0.5).",
    ),
    max_vertices: Optional[int] = typer.Option(
        None, "--max-vertices", metavar="N", callback=polygon_budget,
        help="Vertex budget of each polygon: 0 for none, else at least 3 (default 200).",
    ),
    jobs: Optional[int] = typer.Option(None, "--jobs", "-j", min=1, metavar="N", help="Worker processes (default: all cores)."),
) -> None:
    """Write a run's refined masks as CVAT polygon tracks, for a correction round."""
    with user_errors():
        xml = one_output(xml, xml_option, "XML file", "FILE.xml")
        from annotate_rgbd.pipeline.execute import default_workers, prepare_process

        workers = jobs or default_workers()
        prepare_process(workers)
        from annotate_rgbd.export.cvat import export_cvat
        from annotate_rgbd.io.writer import names_stdout
        from annotate_rgbd.progress import Progress

        polygons = {k: v for k, v in (("tolerance_px", tolerance), ("max_vertices", max_vertices)) if v is not None}
        scene = run_dir.resolve().name
        progress = Progress({scene: 0})
        count = export_cvat(run_dir, xml, **polygons, workers=workers, progress=progress.callback(scene))
        progress.finish()
        # Into standard output the XML goes alone: the summary to standard error.
        typer.echo(f"{counted(count, 'plane track')}: {xml}", err=names_stdout(xml))


@app.command("export", cls=CheckedCommand)
def export_command(
    run_dir: Path = typer.Argument(..., metavar="RUN_DIR", help="Output folder of a finished cvat2mask run."),
    # Text, not Path: Path("./-") is "-", which export refuses as standard output (one_output).
    out: Optional[str] = typer.Argument(None, metavar="OUT_DIR", help="The export folder (empty, or an earlier export's)."),
    fmt: str = typer.Option(..., "--format", "-f", metavar="FORMAT", help="planercnn, planes, evops or coco."),
    out_option: Optional[str] = typer.Option(None, "--out", "-o", metavar="OUT_DIR", help="The same as OUT_DIR."),
    poses: Optional[Path] = typer.Option(
        None, "--poses", metavar="FILE",
        help="Camera trajectory (TUM format) for world-frame planes; default: the poses the run made its masks with "
        "(report.json), else the run's trajectory.",
    ),
) -> None:
    """Export a run's plane ground truth: PlaneRCNN layout, per-frame plane parameters, EVOPS labels, COCO."""
    from annotate_rgbd.export import WORLD_FORMATS, export_run

    with user_errors():
        out = one_output(out, out_option, "export folder", "OUT_DIR")
        result = export_run(run_dir, fmt, out, poses)  # its removals of an earlier export's files: info lines
        # Only the world-frame formats read the trajectory: the others' frames have no pose to count.
        posed = f" ({result.posed} with a pose)" if fmt in WORLD_FORMATS else ""
        typer.echo(f"{fmt}: {result.frames} frames{posed}, {len(result.files)} files in {out}")

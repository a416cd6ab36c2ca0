"""Exports of a finished run for other tools: CVAT for corrections (:mod:`.cvat`), and plane
ground truth in the layouts plane-segmentation codebases read (:func:`export_run`):

``planercnn``
    PlaneRCNN's ScanNet layout: ``planes.npy`` (world frame) and ``segmentation/<frame>.png``.
``planes``
    ``frames/<frame>.json``: every kept plane's equation in the camera and the world frame.
``evops``
    ``labels/<frame>.npy``: per-point label arrays that the ``evops`` package scores directly.
``coco``
    ``annotations.json``: COCO instances with PlaneRecNet's ``plane_paras``.

Every export also writes ``export.json``: the format, the run, the trajectory, the conventions
(frames, sign of the offset, units) and the files written. An export folder holds one export: a
folder with files no export wrote is refused, and a re-export removes the files of the earlier
export that it does not write again. The files are written into a staging folder inside it and
moved in at the end: an export that fails into a new or empty folder leaves it as it was (and
removes the folders it made); one that fails over an earlier export before its first file is
moved in leaves the earlier export whole, after that ``export.json`` is marked incomplete and names
the files of both, which the next export into the folder replaces.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from annotate_rgbd import __version__
from annotate_rgbd.errors import InputError, OutputError
from annotate_rgbd.io.outdir import EXPORT_RECORD, OutputLock, check_not_link, read_bounded, reading
from annotate_rgbd.io.writer import prepare_output, write_bytes_atomic, write_json
from annotate_rgbd.logs import counted
from .coco import write_coco
from .evops import write_evops
from .frames import ExportRun, read_run
from .planercnn import check_planercnn, write_planercnn
from .planes import write_frame_planes

log = logging.getLogger("annotate_rgbd")

FORMATS = {"planercnn": write_planercnn, "planes": write_frame_planes, "evops": write_evops, "coco": write_coco}
#: The formats that hold world-frame planes, so read the camera poses (the others never look at them).
WORLD_FORMATS = ("planercnn", "planes")
#: Folders the formats write into, inside the export folder.
SUBFOLDERS = ("segmentation", "frames", "labels")
RECORD = EXPORT_RECORD
#: Where the format writes before its files are moved into the export folder: a failed export
#: removes this folder, never a file it did not write.
STAGING = ".export-in-progress"
#: What a format checks of the run before the export folder is touched.
CHECKS = {"planercnn": check_planercnn}
#: What each format's files mean, stated in ``export.json``.
DESCRIPTIONS = {
    "planercnn": "planes.npy: N x 3 float64, row k = plane k + 1 of planes.csv, normal * offset with normal . X = "
                 "offset (the plane's point nearest the origin), world frame, metres; 0 0 0 for a plane never kept "
                 "on a frame with a pose. segmentation/<frame>.png: 24-bit RGB on the depth grid, "
                 "(R * 65536 + G * 256 + B) // 100 - 1 = row in planes.npy, -1 = no plane",
    "planes": "frames/<frame>.json: per kept plane its id (planes.csv), label, mask pixels and equation in the camera "
              "frame ('camera') and, with a pose, the world frame ('world'); camera_to_world: the frame's 4 x 4 pose",
    "evops": "labels/<frame>.npy: int32, shape (H * W,), the depth image's pixels row-major (point i = pixel "
             "(i // W, i % W)); plane ids of planes.csv, 0 = unsegmented",
    "coco": "annotations.json: COCO instances on the depth grid (uncompressed RLE), plane_paras [nx, ny, nz, offset]: "
            "camera frame, metres, normal away from the camera, normal . X = offset > 0",
}


@dataclass(frozen=True)
class ExportResult:
    """What :func:`export_run` wrote.

    Parameters
    ----------
    files : list of Path
        The files written (``export.json`` last).
    frames : int
        Written frames of the run.
    posed : int
        Of these, frames with a camera pose.
    removed : list of str
        Files of an earlier export in the folder that this one did not write again, removed
        (said in one ``info`` line of the package's log).
    """

    files: list[Path]
    frames: int
    posed: int
    removed: list[str]


def export_run(run_dir: str | Path, fmt: str, out: str | Path, poses: str | Path | None = None) -> ExportResult:
    """Export a finished run's plane ground truth.

    Parameters
    ----------
    run_dir : str or Path
        Output folder of a finished ``cvat2mask`` run.
    fmt : str
        One of :data:`FORMATS`.
    out : str or Path
        The export folder (created; empty, or the folder of an earlier export).
    poses : str or Path, optional
        A camera trajectory (TUM format) for world-frame planes (:data:`WORLD_FORMATS`; the other
        formats do not read it); default: the poses the run made its masks with (``report.json``),
        else the run's trajectory (:func:`annotate_rgbd.export.frames.read_run`).

    Returns
    -------
    ExportResult

    Raises
    ------
    InputError
        Unknown format, no report, a missing or unreadable mask, no pose for a world-frame layout.
    OutputError
        The folder holds files no export wrote, is the run's folder, or cannot be written; a
        run is writing to ``run_dir``.
    """
    if fmt not in FORMATS:
        raise InputError(None, f"unknown export format {fmt!r} (formats: {', '.join(FORMATS)})")
    if str(out) == "-":  # export-cvat's standard output; a layout of several files cannot go there
        raise OutputError(out, "an export is a folder of files, not a stream: name the folder to write")
    out = Path(out)
    # The folder first: a refused one is the only line (no warning about the run's poses before it).
    if out.resolve() == Path(run_dir).resolve():
        raise OutputError(out, "is the run's folder: export into a folder of its own")
    _previous_files(out)  # a folder of other files is refused before anything is read or made
    if poses is not None and fmt not in WORLD_FORMATS:
        log.warning("%s: not used: the %s export holds no world-frame plane (only %s do)", poses, fmt,
                    " and ".join(WORLD_FORMATS))
    with reading(Path(run_dir)):  # never a run half-way through
        return _export(read_run(run_dir, poses, world=fmt in WORLD_FORMATS), fmt, out)


def _export(run: ExportRun, fmt: str, out: Path) -> ExportResult:
    if fmt in CHECKS:
        CHECKS[fmt](run)
    made = [folder for folder in (out, *out.parents) if not folder.exists()]  # deepest first
    prepare_output(out)
    with OutputLock(out, owner_file=False):  # one export at a time; what it found stays so
        return _write(run, fmt, out, _previous_files(out), made, not any(out.iterdir()))


def _write(run: ExportRun, fmt: str, out: Path, previous: set[str], made: list[Path], fresh: bool) -> ExportResult:
    for name in SUBFOLDERS + (RECORD, STAGING):
        check_not_link(out / name)
    earlier = None if fresh else (out / RECORD).read_bytes()
    record = {"tool": {"name": "annotate-rgbd", "version": __version__}, "format": fmt, "complete": False,
              "files": sorted(previous)}
    staging, placed = out / STAGING, []
    try:
        write_json(out / RECORD, record)  # an interrupted export's folder is still recognised as one
        shutil.rmtree(staging, ignore_errors=True)  # left by an export that was killed
        staging.mkdir()
        names = sorted(str(path.relative_to(staging)) for path in FORMATS[fmt](run, staging))
        # From the first file moved in, the folder may hold files of both exports: the record
        # names them all, so that the next export removes what this one leaves.
        write_json(out / RECORD, {**record, "files": sorted(previous | set(names))})
        for name in names:
            (out / name).parent.mkdir(exist_ok=True)
            os.replace(staging / name, out / name)
            placed.append(name)
        shutil.rmtree(staging)
        removed = _remove(out, previous - set(names))
        if removed:  # as a run says the files it removed: an info line
            log.info("removed %s of an earlier export (%s%s)", counted(len(removed), "file"), removed[0],
                     ", ..." if len(removed) > 1 else "")
        record.update(
            complete=True, run=str(run.run_dir.resolve()), trajectory=run.trajectory,
            trajectory_time_offset_s=run.time_offset if run.trajectory else None, poses=run.poses_from,
            conventions={"files": DESCRIPTIONS[fmt], "plane_equation": run.equation_convention},
            frames=len(run.frames), frames_with_pose=sum(f.pose is not None for f in run.frames), files=names,
        )
        write_json(out / RECORD, record)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        if fresh:
            _undo(out, placed, made)
        elif not placed and earlier is not None:
            write_bytes_atomic(out / RECORD, earlier)  # the earlier export is whole: its record stays
        raise
    files = [out / name for name in names]
    return ExportResult(files + [out / RECORD], len(run.frames), record["frames_with_pose"], removed)


def _undo(out: Path, placed: list[str], made: list[Path]) -> None:
    """Remove what a failed export wrote into a folder that was new or empty: its record, the
    files it moved in and the folders they emptied, and the folders it made (``out`` and the
    parents), when nothing else is in them."""
    _remove(out, {RECORD, *placed})
    for folder in made:  # the deepest first
        try:
            folder.rmdir()  # only when empty
        except OSError:
            pass


def _previous_files(out: Path) -> set[str]:
    """The files an earlier export recorded in ``out`` (empty for a new or empty folder).

    Raises
    ------
    OutputError
        The folder holds files and no export record.
    """
    if not out.is_dir() or not any(out.iterdir()):
        return set()
    try:
        record = json.loads(read_bounded(out / RECORD, 64 << 20).decode("utf-8"))
        files = record["files"]
        if record.get("tool", {}).get("name") != "annotate-rgbd" or not all(isinstance(f, str) for f in files):
            raise ValueError
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        raise OutputError(out, f"holds files that no export wrote (no {RECORD}): export into an empty folder") from None
    return {f for f in files if _inside(f)}


def _inside(name: str) -> bool:
    """Whether a recorded name stays inside the export folder (a relative path without '..')."""
    path = Path(name)
    return not path.is_absolute() and ".." not in path.parts and name not in ("", ".")


def _remove(out: Path, stale: set[str]) -> list[str]:
    """Remove an earlier export's files this one did not write again, then the folders of theirs
    that are left empty (``labels/`` of an evops export replaced by a planes export)."""
    removed = []
    for name in sorted(stale):
        path = out / name
        if os.path.islink(path.parent) or not path.is_file() or os.path.islink(path):
            continue
        path.unlink()
        removed.append(name)
    folders = {parent for name in removed for parent in Path(name).parents if parent != Path(".")}
    for folder in sorted(folders, key=lambda f: -len(f.parts)):  # the deepest first
        path = out / folder
        if path.is_dir() and not path.is_symlink() and not any(path.iterdir()):
            path.rmdir()
    return removed

"""Score predicted plane masks against ground-truth masks over a sequence (``annotate-rgbd evaluate``).

Ground truth (GT) and prediction (PRED) are two folders of per-frame label files, or two single files.
Frames are matched by file name without its suffix, so ``1305031102.175304.png`` in GT pairs with
``1305031102.175304.png``, ``.npy`` or ``.csv`` in PRED. A GT frame without a PRED file counts as an
empty prediction (every plane missed) and is listed in ``frames_missing``, or, with
``skip_missing`` (``--skip-missing``: a run that masked only some frames, as ``propose --every N``),
is left out of the score and listed in ``frames_skipped``; PRED files without a GT frame are ignored
and listed in ``predictions_unmatched``. The sequence score of each statistic is its mean over the
GT frames scored.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from annotate_rgbd.config.evaluate import EvaluateConfig
from annotate_rgbd.errors import InputError
from annotate_rgbd.io.writer import csv_bytes, write_output
from annotate_rgbd.io.labelmaps import LABEL_SUFFIXES, read_label_map
from annotate_rgbd.io.outdir import EXPORT_RECORD, OUTPUT_FOLDERS, check_output_file
from annotate_rgbd.report.run_folder import check_finished
from .metrics import METRIC_NAMES, FrameStatistics, frame_statistics

log = logging.getLogger("annotate_rgbd")


@dataclass(frozen=True)
class FramePair:
    """One GT frame and the PRED file scored against it (``None`` when PRED has none)."""

    name: str
    gt: Path
    pred: Path | None


@dataclass(frozen=True)
class FrameScore:
    """The statistics of one frame; ``missing`` when PRED had no file for it."""

    name: str
    statistics: FrameStatistics
    missing: bool
    #: Its label files that look like photographs (:func:`looks_like_a_photograph`).
    unlikely_masks: tuple[str, ...] = ()
    #: Without ``ignore``: ``(GT file, label, share of its pixels)`` when GT holds its type's largest
    #: value (255, 65535), a common "don't care" mark, beside other planes; else None.
    dont_care: tuple[str, int, float] | None = None
    #: With ``ignore``: the GT pixels that held it (left out of both), else 0.
    ignored_pixels: int = 0


@dataclass(frozen=True)
class EvaluationResult:
    """Per-frame statistics of a sequence and their means.

    Attributes
    ----------
    frames : tuple of FrameScore
        One per GT frame, in file name order.
    full, part : float
        The IoU thresholds used.
    predictions_unmatched : tuple of str
        Names of PRED files that have no GT frame (not scored).
    frames_skipped : tuple of str
        Names of the GT frames PRED has no file for, left out of the score (``skip_missing``).
    """

    frames: tuple[FrameScore, ...]
    full: float
    part: float
    predictions_unmatched: tuple[str, ...] = ()
    frames_skipped: tuple[str, ...] = ()

    @property
    def means(self) -> dict[str, float]:
        """Sequence mean of each statistic, in :data:`~annotate_rgbd.evaluate.metrics.METRIC_NAMES` order."""
        table = np.array([[getattr(f.statistics, name) for name in METRIC_NAMES] for f in self.frames])
        return dict(zip(METRIC_NAMES, table.mean(axis=0).tolist()))

    @property
    def frames_missing(self) -> list[str]:
        """Names of the GT frames that PRED has no file for."""
        return [f.name for f in self.frames if f.missing]

    def to_dict(self) -> dict:
        """The means plus ``frames`` (the frames scored), ``frames_missing`` and ``frames_skipped``
        (their names)."""
        return {**self.means, "frames": len(self.frames), "frames_missing": self.frames_missing,
                "frames_skipped": list(self.frames_skipped)}


def evaluate_paths(
    gt: str | Path,
    pred: str | Path,
    full: float = EvaluateConfig.full,
    part: float = EvaluateConfig.partial,
    measure: str = "iou",
    skip_missing: bool = False,
    ignore: int = EvaluateConfig.ignore,
) -> EvaluationResult:
    """Score a prediction against the ground truth, frame by frame.

    Parameters
    ----------
    gt, pred : str or Path
        Two folders of label files matched by name (see the module docstring), or two label files.
    full, part : float, optional
        IoU thresholds for a full match and a partial overlap, in ``(0, 1]``.
    measure : {"iou", "dice"}, optional
        What ``mean`` and ``panoptic`` average over the matched planes.
    skip_missing : bool, optional
        Leave the GT frames PRED has no file for out of the score (they are listed in
        ``frames_skipped``) instead of scoring them as empty predictions. Without it, a warning
        is logged when PRED misses more than half of the GT frames.
    ignore : int, optional
        GT label value of "don't care" pixels, left out of both GT and PRED (-1: none). GT must
        then be label files, not colour masks. Without it, a warning is logged when GT holds
        its type's largest value (255, 65535), a common "don't care" mark, that would be scored
        as a plane.

    Returns
    -------
    EvaluationResult
        Per-frame statistics and their sequence means.

    Raises
    ------
    InputError
        For a missing path, a GT folder without label files, an unreadable label file, or a PRED
        frame whose size differs from its GT frame.
    """
    for value, name in ((full, "full"), (part, "partial")):  # as the command line names them
        if not 0.0 < value <= 1.0:
            raise InputError(None, f"--{name} must be in (0, 1], not {value}")
    if part > full:  # a partial overlap above a full match: usr, osr and noise would overlap precision
        raise InputError(None, f"--partial ({part}) must be at most --full ({full}): a partial overlap is a weaker match")
    pairs, unmatched = match_frames(gt, pred)
    absent = [pair.name for pair in pairs if pair.pred is None]
    if ignore < -1:
        raise InputError(None, f"--ignore must be a label value >= 0 (or -1: none), not {ignore}")
    frames = tuple(score_frame(pair, full=full, part=part, measure=measure, ignore=ignore) for pair in pairs
                   if pair.pred is not None or not skip_missing)
    if ignore == 0:
        log.warning("--ignore 0: label 0 is \"no plane\" in every label format, so every pixel without a ground-truth "
                    "plane is left out: a predicted plane that spills over them costs nothing")
    if ignore >= 0 and frames and not any(frame.ignored_pixels for frame in frames):
        log.warning(
            "%s: --ignore %d: no ground-truth pixel holds that label in any of the %d frames scored, so nothing was "
            "left out%s", gt, ignore, len(frames),
            "" if ignore == 65535 else " (16-bit label files often mark don't-care pixels 65535)",
        )
    marked = [frame.dont_care for frame in frames if frame.dont_care is not None]
    if marked:
        (path, label, _), share = marked[0], float(np.mean([share for _, _, share in marked]))
        log.warning(
            "%s: label %d (its type's largest value, a common \"don't care\" mark) covers %.0f %% of the pixels of "
            "%d ground-truth frames and is scored as a plane; if it marks pixels to leave out, add --ignore %d",
            path, label, 100 * share, len(marked), label,
        )
    if not skip_missing and 2 * len(absent) > len(pairs):  # after the scores: an unreadable file is the error
        log.warning(
            "%s: no mask for %d of the %d ground-truth frames; they score as empty (every plane missed). "
            "To score only the frames it has (a `propose --every N` run masks every Nth frame), add --skip-missing",
            pred, len(absent), len(pairs),
        )
    unlikely = [path for frame in frames for path in frame.unlikely_masks]
    if unlikely:
        log.warning(
            "%s: made mostly of tiny labels or of hundreds of them (every shade a plane): a photograph or a "
            "depth image rather than a mask?%s",
            unlikely[0], f" (and {len(unlikely) - 1} more label files)" if len(unlikely) > 1 else "",
        )
    return EvaluationResult(frames=frames, full=full, part=part, predictions_unmatched=tuple(unmatched),
                            frames_skipped=tuple(absent) if skip_missing else ())


def label_folder(path: Path, say: bool = True) -> Path:
    """The label files a path stands for: a run's output folder (``report.json`` beside
    ``masks/``) stands for its ``masks/``, an ``export --format evops`` folder for its
    ``labels/`` (an info line says so, unless ``say`` is False); anything else for itself.

    A folder where a ``cvat2mask`` or ``propose`` run did not finish (its first run too, before
    it has a report), or one of its mask folders, is refused
    (:func:`annotate_rgbd.report.run_folder.check_finished`): its masks may be incomplete or mix
    two runs."""
    if path.is_dir():
        check_finished(path)
        if path.name in OUTPUT_FOLDERS:  # masks/, masks_id/, masks_raw/ of such a run
            check_finished(path.parent)
    if path.is_dir() and (path / "report.json").is_file() and (path / "masks").is_dir():
        if say:
            log.info("%s: a run's output folder: scoring its masks/", path)
        return path / "masks"
    if path.is_dir() and (path / EXPORT_RECORD).is_file() and (path / "labels").is_dir():
        if say:
            log.info("%s: an EVOPS export: scoring its labels/", path)
        return path / "labels"
    return path


def match_frames(gt: str | Path, pred: str | Path) -> tuple[list[FramePair], list[str]]:
    """Pair GT frames with PRED files by name.

    Parameters
    ----------
    gt, pred : str or Path
        Two folders, or two files (paired whatever their names); a run's output folder stands
        for its ``masks/`` (:func:`label_folder`).

    Returns
    -------
    pairs : list of FramePair
        One per GT label file, sorted by name.
    unmatched : list of str
        PRED file names without a GT frame.
    """
    gt, pred = label_folder(Path(gt)), label_folder(Path(pred))
    for path in (gt, pred):
        if not path.exists():
            raise InputError(path, "not found")
    if gt.is_file() and pred.is_file():
        return [FramePair(gt.stem, gt, pred)], []
    if gt.is_file() or pred.is_file():
        raise InputError(pred if gt.is_dir() else gt, "GT and PRED must both be folders or both be files")
    gt_files = _label_files(gt)
    if not gt_files:
        raise InputError(gt, f"no label files ({', '.join(LABEL_SUFFIXES)}) in the ground-truth folder")
    pred_files = _label_files(pred)
    if not pred_files:
        raise InputError(pred, f"no label files ({', '.join(LABEL_SUFFIXES)}) in the prediction folder")
    if not pred_files.keys() & gt_files.keys():
        raise InputError(
            pred,
            f"no file name in common with the ground truth (PRED has e.g. {min(pred_files)}, GT "
            f"{min(gt_files)}): frames are matched by file name without its suffix",
        )
    pairs = [FramePair(name, path, pred_files.get(name)) for name, path in sorted(gt_files.items())]
    unmatched = sorted(pred_files[name].name for name in pred_files.keys() - gt_files.keys())
    return pairs, unmatched


#: A label covering less than this share of the image is a speck, not a plane (0.05 %: 38 pixels
#: at 320x240). In a plane mask specks hold almost no pixels; in a photograph, whose every shade
#: is a "label", they hold most (82 % on a TUM RGB frame, 4.7 % on the flat-shaded sample frames).
SPECK_SHARE = 0.0005
#: Share of pixels in specks above which a label file is taken for an image rather than a mask.
MAX_SPECK_PIXELS = 0.02
#: More distinct labels than this in one frame is a depth image, not a plane mask: a raw TUM depth
#: frame holds ~350 distinct values (Kinect's quantised depth), a RealSense one ~700, while plane
#: ground truth shows a few dozen planes per frame (EVOPS, ScanNet-derived sets).
MAX_LABELS_PER_FRAME = 256


def looks_like_a_photograph(labels: np.ndarray) -> bool:
    """Whether a label map is more likely an image given by mistake than a plane mask.

    Parameters
    ----------
    labels : ndarray of int, shape (height, width)

    Returns
    -------
    bool
        True when more than :data:`MAX_SPECK_PIXELS` of the pixels carry labels that each cover
        less than :data:`SPECK_SHARE` of the image, or when it holds more than
        :data:`MAX_LABELS_PER_FRAME` distinct labels (a depth image).
    """
    values = labels.ravel()
    if values.size and values.dtype.kind in "iub" and 0 <= values.min() and values.max() < 1 << 20:
        counts = np.bincount(values)  # label maps of ids: a count per id, no sort
        counts = counts[counts > 0]
    else:
        counts = np.unique(values, return_counts=True)[1]
    if len(counts) > MAX_LABELS_PER_FRAME + 1:  # + 1: unsegmented
        return True
    # The share of pixels whose label covers less than SPECK_SHARE of the image.
    return bool(counts[counts < SPECK_SHARE * labels.size].sum() / max(labels.size, 1) > MAX_SPECK_PIXELS)


def score_frame(pair: FramePair, *, full: float, part: float, measure: str = "iou", ignore: int = -1) -> FrameScore:
    """Read one frame pair and compute its statistics (an absent PRED file is an empty prediction);
    GT pixels labelled ``ignore`` (>= 0) are left out of both."""
    gt = read_label_map(pair.gt, f"--ignore {ignore}" if ignore >= 0 else None)
    pred = np.zeros_like(gt) if pair.pred is None else read_label_map(pair.pred)
    if gt.ndim != pred.ndim and gt.size == pred.size:  # a flat .npy array (EVOPS): row-major, the other's shape
        gt, pred = (gt, pred.reshape(gt.shape)) if gt.ndim == 2 else (gt.reshape(pred.shape), pred)
    if pred.shape != gt.shape:
        raise InputError(pair.pred, f"frame is {_size(pred)} but ground truth {pair.gt.name} is {_size(gt)}")
    dont_care, ignored_pixels = None, 0
    if ignore >= 0:
        ignored = gt == ignore
        ignored_pixels = int(np.count_nonzero(ignored))
        if ignored_pixels:  # no plane in either: neither a hit nor a miss
            gt, pred = np.where(ignored, 0, gt), np.where(ignored, 0, pred)
    elif gt.dtype in (np.uint8, np.uint16):
        # Beside other planes (a 0/255 mask of one plane is no "don't care" mark).
        label = int(np.iinfo(gt.dtype).max)
        count = int(np.count_nonzero(gt == label))
        if count and np.any((gt > 0) & (gt < label)):
            dont_care = (str(pair.gt), label, count / gt.size)
    unlikely = tuple(str(path) for path, labels in ((pair.gt, gt), (pair.pred, pred)) if looks_like_a_photograph(labels))
    statistics = frame_statistics(gt, pred, full=full, part=part, measure=measure)
    return FrameScore(pair.name, statistics, missing=pair.pred is None, unlikely_masks=unlikely,
                      dont_care=dont_care, ignored_pixels=ignored_pixels)


def _size(labels: np.ndarray) -> str:
    """A label image's size as the messages say it: ``640x480``, or ``307200 labels`` when flat."""
    return f"{labels.shape[1]}x{labels.shape[0]}" if labels.ndim == 2 else f"{labels.size} labels"


def format_table(result: EvaluationResult) -> str:
    """The sequence means as a two-column text table, with the frame counts below."""
    width = max(len(name) for name in METRIC_NAMES)
    lines = [f"{'metric':<{width}}  mean", f"{'-' * width}  ------"]
    lines += [f"{name:<{width}}  {value:.4f}" for name, value in result.means.items()]
    lines.append(f"frames: {len(result.frames)} (full IoU >= {result.full}, partial IoU >= {result.part})")
    for names, what in ((result.frames_missing, "missing in PRED (scored as empty)"),
                        (result.frames_skipped, "missing in PRED (not scored: --skip-missing)"),
                        (result.predictions_unmatched, "PRED files without a GT frame (ignored)")):
        if names:  # the first ten
            lines.append(f"{what}: {len(names)}: " + ", ".join(names[:10]) + (", ..." if len(names) > 10 else ""))
    return "\n".join(lines)


#: The columns of ``--per-frame``'s CSV: the frame's name, its statistics, whether PRED was missing.
PER_FRAME_COLUMNS = ("frame", *METRIC_NAMES, "missing")


def format_json(result: EvaluationResult) -> str:
    """The result as one JSON object (see :meth:`EvaluationResult.to_dict`)."""
    return json.dumps(result.to_dict(), indent=2)


def check_per_frame_target(path: str | Path, gt: str | Path, pred: str | Path) -> None:
    """Refuse a per-frame CSV path that would replace what is being scored or a run's files
    (:func:`annotate_rgbd.io.outdir.check_output_file`): a folder, a missing folder, a file
    inside the ground truth or the predictions, a file of an annotate-rgbd output folder (its
    ``report.json``, ``planes.csv``, masks), an existing file that is not a per-frame CSV (its
    first line ``frame,...``: a run's export or frame list named by mistake). Checked before the
    scoring, not after it.

    Raises
    ------
    OutputError
    """
    # Quietly: the scoring says which folder it reads (match_frames).
    roles = ((label_folder(Path(gt), say=False), "the ground truth being scored"),
             (label_folder(Path(pred), say=False), "the masks being scored"))
    check_output_file(Path(path), "per_frame.csv", "the per-frame CSV", "CSV file", roles,
                      ours=(looks_like_per_frame_csv, "a per-frame CSV of evaluate"))


def looks_like_per_frame_csv(head: bytes) -> bool:
    """Whether the first bytes of a file are those of a per-frame CSV (:func:`write_per_frame_csv`:
    its header begins with :data:`PER_FRAME_COLUMNS`' first column)."""
    return head.startswith(f"{PER_FRAME_COLUMNS[0]},".encode())


def write_per_frame_csv(result: EvaluationResult, path: str | Path) -> None:
    """Write one CSV row per frame: its name, the statistics, and whether PRED was missing.

    A file is written atomically; ``-``, ``/dev/stdout``, a device or a FIFO is written into as it
    is, never replaced (:func:`annotate_rgbd.io.writer.open_output`).
    """
    rows = [
        (frame.name, *(repr(getattr(frame.statistics, name)) for name in METRIC_NAMES), int(frame.missing))
        for frame in result.frames
    ]
    write_output(Path(path), csv_bytes(PER_FRAME_COLUMNS, rows))


def _label_files(folder: Path) -> dict[str, Path]:
    """Label files of a folder by name without suffix; two files of one name are ambiguous."""
    files: dict[str, Path] = {}
    for path in sorted(folder.iterdir()):
        if not path.is_file() or path.suffix.lower() not in LABEL_SUFFIXES:
            continue
        if path.stem in files:
            raise InputError(path, f"same frame name as {files[path.stem].name}: which to score is ambiguous")
        files[path.stem] = path
    return files

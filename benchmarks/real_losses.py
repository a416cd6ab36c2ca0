"""What bench_real.py's runs lose, pixel by pixel, against the kit's ground truth and the dense row.

:func:`excluded_misses`: how much of what a run with poses misses lies where a nearby keyframe's
labeller left the plane out; :func:`review_scores`: how many of the carried planes that lose most
against the dense row the run's list of planes to check holds (:func:`pair_ious` matches them).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: The kit's ground-truth value for "don't care" pixels (boundary bands, ambiguous depth).
GT_IGNORE = 65535
#: Pixels inside a left-out region beyond which a miss is not an outline or pose a few pixels off.
EXCLUDED_INNER_PX = 5


def excluded_misses(gt_dir: Path, run_dir: Path, dense_dir: Path, inner_px: int = EXCLUDED_INNER_PX) -> dict[str, int]:
    """Of what a run with poses misses, how much lies where its keyframes left the plane out.

    On every frame, for every plane the poses carried there (the run's shapes record), the
    *missed* pixels are those of the plane's ground-truth plane that the dense run gives the plane
    and this run does not. Of them, *excluded* are those the carried layers mark as left out of
    the plane (what a nearby keyframe's labeller saw touching the plane and did not draw:
    :mod:`annotate_rgbd.propagate.evidence`), and *deep* those more than ``inner_px`` pixels
    inside such a region (not an outline or pose a few pixels off). Each plane of the run stands
    for the ground-truth plane it overlaps most in the dense run over all frames (the two exports,
    thinned from one file, number their tracks, and so their planes, alike).

    Parameters
    ----------
    gt_dir : Path
        The kit's per-frame ground truth (uint16 PNGs: plane ids, 0 none, :data:`GT_IGNORE`).
    run_dir, dense_dir : Path
        Finished ``cvat2mask`` output folders (masks, report, shapes record) of the run with
        poses and of the dense row.
    inner_px : int
        How far inside a left-out region (pixels) a miss counts as *deep*.

    Returns
    -------
    dict of str to int
        ``missed``, ``excluded`` and ``deep`` pixel counts, summed over the frames.

    Raises
    ------
    InputError
        A folder without a report or shapes record, or an image that cannot be read or is not
        the size of the ground truth.
    """
    import cv2
    from annotate_rgbd.evaluate.metrics import plane_overlaps
    from annotate_rgbd.report.run_folder import colour_table, read_drawn_shapes, read_report
    from annotate_rgbd.segment.rasterize import paint_layers

    names = sorted(path.name for path in (run_dir / "masks").glob("*.png") if (gt_dir / path.name).is_file())
    run_ids, dense_ids = colour_table(read_report(run_dir)), colour_table(read_report(dense_dir))
    drawn = read_drawn_shapes(run_dir, {f"masks/{name}" for name in names})
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * inner_px + 1, 2 * inner_px + 1))
    # One pass: per (run plane, ground-truth value) the dense run's overlap, and the three counts
    # as if that value were the plane's ground-truth plane; the correspondence is chosen at the end.
    overlap: dict[tuple[int, int], int] = {}
    counts: dict[tuple[int, int], np.ndarray] = {}
    for name in names:
        truth = _read_truth(gt_dir / name)
        dense = _plane_labels(dense_dir / "masks" / name, dense_ids, truth.shape)
        known = (truth != 0) & (truth != GT_IGNORE)
        table = plane_overlaps(np.where(known, truth, 0), dense)
        for plane, value, count in zip(table.pred_labels[table.pred_index].tolist(),
                                       table.gt_labels[table.gt_index].tolist(), table.intersection.tolist()):
            overlap[plane, value] = overlap.get((plane, value), 0) + count
        left_out: dict[int, np.ndarray] = {}
        for _, plane, _, layers, _ in drawn[f"masks/{name}"].carried:  # a plane's entries together
            painted = paint_layers(layers, *truth.shape)[1]
            left_out[plane] = left_out[plane] | painted if plane in left_out else painted
        if not left_out:
            continue
        labels = _plane_labels(run_dir / "masks" / name, run_ids, truth.shape)
        for plane, region in left_out.items():
            missed = known & (dense == plane) & (labels != plane)
            inner = cv2.erode(region.view(np.uint8), kernel).view(bool)
            for kind, where in enumerate((missed, missed & region, missed & inner)):
                values, found = np.unique(truth[where], return_counts=True)
                for value, count in zip(values.tolist(), found.tolist()):
                    counts.setdefault((plane, value), np.zeros(3, np.int64))[kind] += count
    truth_of: dict[int, tuple[int, int]] = {}  # plane -> (overlap, ground-truth plane); a tie: the lower id
    for (plane, value), count in overlap.items():
        truth_of[plane] = max(truth_of.get(plane, (0, 0)), (count, -value))
    totals = np.zeros(3, np.int64)
    for (plane, value), found in counts.items():
        if plane in truth_of and -truth_of[plane][1] == value:
            totals += found
    return dict(zip(("missed", "excluded", "deep"), totals.tolist()))


def _read_truth(path: Path) -> np.ndarray:
    """One frame of the kit's ground truth, as int64."""
    import cv2
    from annotate_rgbd.errors import InputError

    truth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if truth is None or truth.ndim != 2:
        raise InputError(path, "not a one-channel ground-truth image")
    return truth.astype(np.int64)


def _plane_labels(path: Path, colours: tuple[np.ndarray, np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    """Plane id of every pixel of a run's colour mask (0: black), of the ground truth's size."""
    import cv2
    from annotate_rgbd.errors import InputError
    from annotate_rgbd.report.run_folder import mask_plane_ids

    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None or image.shape[:2] != shape:
        raise InputError(path, "unreadable, or not the size of the ground truth")
    return mask_plane_ids(image, *colours, path)


def pair_ious(truth: np.ndarray, labels: np.ndarray, min_pixels: int) -> dict[int, tuple[int, float]]:
    """For every ground-truth plane of at least ``min_pixels`` pixels on a frame, the run's plane
    that overlaps it most and their IoU (the ground truth's "don't care" pixels left out).

    Returns
    -------
    dict of int to (int, float)
        Ground-truth plane -> (run plane, IoU); run plane 0 with IoU 0 where none overlaps it.
    """
    from annotate_rgbd.evaluate.metrics import plane_overlaps

    known = truth != GT_IGNORE
    table = plane_overlaps(truth[known], labels[known])
    ious = table.iou()
    found = {}
    for g, (value, size) in enumerate(zip(table.gt_labels.tolist(), table.gt_sizes.tolist())):
        if size < min_pixels:
            continue
        pairs = np.flatnonzero(table.gt_index == g)  # in ascending run plane: a tie goes to the lower id
        if pairs.size == 0:
            found[value] = (0, 0.0)
            continue
        best = pairs[np.argmax(table.intersection[pairs])]
        found[value] = (int(table.pred_labels[table.pred_index[best]]), float(ious[best]))
    return found


def review_scores(gt_dir: Path, run_dir: Path, dense_dir: Path, bad_loss: float = 0.15,
                  min_pixels: int = 1000) -> dict[str, float]:
    """How well a run's list of carried planes to check (``stats``' ``carried_to_check``) finds
    the carried planes that lose most against the dense row.

    A *pair* is a ground-truth plane of at least ``min_pixels`` pixels on a frame and the run's
    plane that overlaps it most (:func:`pair_ious`); it is *carried* when the poses carried that
    plane to the frame (its record says ``propagated``), and *bad* when its IoU is more than
    ``bad_loss`` below the dense run's on the same ground-truth plane and frame.

    Returns
    -------
    dict
        ``carried``, ``bad`` and ``listed`` pairs, ``listed_bad``, ``loss`` (the carried pairs'
        summed IoU lost), ``listed_loss``, and ``auc``: how well the keyframes' agreement ranks
        the bad pairs first (0.5: no better than chance; pairs without one rank as agreeing).

    Raises
    ------
    InputError
        A folder without a report, or an image that cannot be read or is not the size of the
        ground truth.
    """
    from annotate_rgbd.report.run_folder import colour_table, read_report
    from annotate_rgbd.report.stats import carried_to_check

    report = read_report(run_dir)
    listed = {(Path(c["depth"]).name, c["plane"]) for c in carried_to_check(report)}
    run_ids, dense_ids = colour_table(report), colour_table(read_report(dense_dir))
    rows = []  # (loss, agreement, listed)
    for frame in report.frames:
        name = Path(frame.depth).name
        carried = {r.plane for r in frame.kept if r.propagated}
        if not carried or not (gt_dir / name).is_file() or not (dense_dir / "masks" / name).is_file():
            continue
        truth = _read_truth(gt_dir / name)
        ours = pair_ious(truth, _plane_labels(run_dir / "masks" / name, run_ids, truth.shape), min_pixels)
        dense = pair_ious(truth, _plane_labels(dense_dir / "masks" / name, dense_ids, truth.shape), min_pixels)
        agree = frame.keyframes_agree or {}
        for value, (plane, iou) in ours.items():
            if plane in carried and value in dense:
                rows.append((dense[value][1] - iou, agree.get(plane, 1.0), (name, plane) in listed))
    if not rows:
        return {"carried": 0}
    loss, agreement, on_list = (np.array(column) for column in zip(*rows))
    bad = loss > bad_loss
    # Rank-sum AUC of "low agreement" for the bad pairs, ties counted half.
    below = (agreement[bad][:, None] < agreement[~bad][None, :]).mean() if bad.any() and (~bad).any() else float("nan")
    ties = (agreement[bad][:, None] == agreement[~bad][None, :]).mean() if bad.any() and (~bad).any() else 0.0
    positive = np.clip(loss, 0, None)
    return {"carried": len(rows), "bad": int(bad.sum()), "listed": int(on_list.sum()),
            "listed_bad": int((on_list & bad).sum()), "loss": float(positive.sum()),
            "listed_loss": float(positive[on_list].sum()), "auc": float(below + ties / 2)}

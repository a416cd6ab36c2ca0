"""EVOPS evaluation input: one per-point label array per frame.

The ``evops`` package scores a segmentation by two label arrays over the same points
(``evops.metrics.full_statistics(pred_labels, gt_labels, ...)``: 1-D integer arrays, 0 = the
point is unsegmented). Here the points of a frame are its depth image as an organised point
cloud: point ``i`` is pixel ``(i // W, i % W)`` (row-major), whether it has depth or not (a pixel
without depth is unsegmented in every mask of this tool, and points unsegmented in both arrays
change no score). ``labels/<frame>.npy`` holds ``int32`` labels of shape ``(H * W,)``: the plane ids of
``planes.csv``, 0 for no plane. Two exports of the same frames (a ground truth and a
segmentation, in this layout) are scored by ``evops`` directly, file by file.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from annotate_rgbd.io.writer import write_bytes_atomic
from .frames import ExportRun


def point_labels(ids: np.ndarray) -> np.ndarray:
    """A mask's plane ids as EVOPS's per-point labels: int32, shape (H * W,), row-major."""
    return np.ascontiguousarray(ids, dtype=np.int32).reshape(-1)


def write_evops(run: ExportRun, out: Path) -> list[Path]:
    """Write ``labels/<frame>.npy`` per written frame; returns the files written."""
    written = []
    for frame in run.frames:
        buffer = io.BytesIO()
        np.save(buffer, point_labels(run.plane_ids(frame)))
        path = out / "labels" / f"{frame.name}.npy"
        write_bytes_atomic(path, buffer.getvalue())
        written.append(path)
    return written

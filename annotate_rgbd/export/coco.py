"""COCO instance annotations with per-instance plane parameters (PlaneRecNet's convention).

One ``annotations.json`` per run: an image per written frame (``file_name`` the RGB file,
``depth_file_name`` the depth file, both relative to the sequence folder; ``width`` and
``height`` those of the masks, the depth grid), an annotation per kept plane of a frame (its
mask pixels as uncompressed RLE, column-major runs starting with background as COCO counts
them; ``bbox`` ``[x, y, w, h]``, ``area`` in pixels, ``plane_id`` and ``label`` from
``planes.csv``) with ``plane_paras`` ``[nx, ny, nz, offset]``: camera frame, metres, normal
pointing away from the camera, ``normal . X = offset`` for the plane's points (``offset > 0``),
as PlaneRecNet's ScanNet loader reads them. One category, ``plane``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from annotate_rgbd.io.writer import write_json
from .frames import ExportRun
from .planes import plane_paras

CATEGORY = {"id": 1, "name": "plane", "supercategory": "plane"}


def rle_counts(mask: np.ndarray) -> list[int]:
    """COCO's uncompressed RLE of a boolean mask: run lengths over the column-major pixels,
    starting with a (possibly empty) run of background."""
    flat = np.asarray(mask, dtype=np.int8).ravel(order="F")
    if flat.size == 0:
        return []
    bounds = np.concatenate([[0], np.flatnonzero(np.diff(flat)) + 1, [flat.size]])
    counts = np.diff(bounds)
    return ([0] if flat[0] else []) + counts.tolist()


def write_coco(run: ExportRun, out: Path) -> list[Path]:
    """Write ``annotations.json``; returns the files written."""
    labels = run.labels
    images, annotations = [], []
    for image_id, frame in enumerate(run.frames, start=1):
        ids = run.plane_ids(frame)
        height, width = ids.shape
        images.append({"id": image_id, "file_name": frame.rgb, "depth_file_name": frame.depth, "frame": frame.name,
                       "width": width, "height": height})
        for record in frame.planes:
            mask = ids == record.plane
            if record.equation is None or not mask.any():
                continue
            rows, cols = np.nonzero(mask)
            x0, y0 = int(cols.min()), int(rows.min())
            annotations.append({
                "id": len(annotations) + 1, "image_id": image_id, "category_id": CATEGORY["id"],
                "segmentation": {"size": [height, width], "counts": rle_counts(mask)},
                "area": int(mask.sum()), "bbox": [x0, y0, int(cols.max()) - x0 + 1, int(rows.max()) - y0 + 1],
                "iscrowd": 0, "plane_id": record.plane, "label": labels.get(record.plane, ""),
                "plane_paras": plane_paras(record.equation),
            })
    document = {
        "info": {"description": "annotate-rgbd plane instances", "plane_paras": "[nx, ny, nz, offset]: camera frame, "
                 "metres, normal away from the camera, normal . X = offset (offset > 0); " + run.equation_convention},
        "images": images, "annotations": annotations, "categories": [CATEGORY],
    }
    path = out / "annotations.json"
    write_json(path, document)
    return [path]

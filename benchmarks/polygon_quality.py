"""How labeller-friendly the polygons of a ``propose`` folder (or any CVAT video export beside
colour masks) are: vertex counts, self-crossings, and how well each polygon's pixels match its
plane's mask.

Run from the repository root::

    python benchmarks/polygon_quality.py PROPOSE_DIR [--xml FILE] [--json OUT]

For every drawn keyframe polygon of ``proposals.xml`` (or ``--xml``) on an RGB frame whose mask
``report.json`` names (``propose``'s and ``cvat2mask``'s reports both do):

* vertices;
* crossing: two edges that are not neighbours share a point (a proper crossing, a touch, an
  overlap: the ring is not simple), by an all-pairs segment test independent of the package;
* IoU of the polygon's pixels (centres inside, even-odd: what CVAT and ``cvat2mask`` fill) with
  the pixels of the track's colour in the mask.

Prints median / max vertices, the count of crossing polygons and the mean / median / minimum
IoU. With shapely installed (a test tool, not a dependency) it also counts the polygons
``shapely`` calls invalid.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from annotate_rgbd.cvat import read_cvat
from annotate_rgbd.io.sequence import read_image
from annotate_rgbd.report.palette import plane_colours


def segments_meet(points: np.ndarray) -> bool:
    """Whether two non-neighbouring edges of the closed polygon share a point (all pairs, exact
    orientation tests on the coordinates as given)."""
    p = np.asarray(points, dtype=np.float64)
    n = len(p)
    if n < 4:
        return False
    a, b = p, np.roll(p, -1, axis=0)
    i, j = np.triu_indices(n, 2)
    keep = ~((i == 0) & (j == n - 1))  # the closing edge neighbours the first
    i, j = i[keep], j[keep]

    def orient(o, q, r):
        return np.sign((q[:, 0] - o[:, 0]) * (r[:, 1] - o[:, 1]) - (q[:, 1] - o[:, 1]) * (r[:, 0] - o[:, 0]))

    def on(o, q, r):  # r on the segment o-q, given collinear
        return ((np.minimum(o[:, 0], q[:, 0]) <= r[:, 0]) & (r[:, 0] <= np.maximum(o[:, 0], q[:, 0]))
                & (np.minimum(o[:, 1], q[:, 1]) <= r[:, 1]) & (r[:, 1] <= np.maximum(o[:, 1], q[:, 1])))

    for low in range(0, len(i), 1 << 22):
        s, t = i[low:low + (1 << 22)], j[low:low + (1 << 22)]
        p1, q1, p2, q2 = a[s], b[s], a[t], b[t]
        o1, o2, o3, o4 = orient(p1, q1, p2), orient(p1, q1, q2), orient(p2, q2, p1), orient(p2, q2, q1)
        meet = (o1 != o2) & (o3 != o4) & (o1 * o2 <= 0) & (o3 * o4 <= 0) & ~((o1 == 0) & (o2 == 0))
        meet |= (o1 == 0) & on(p1, q1, p2)
        meet |= (o2 == 0) & on(p1, q1, q2)
        meet |= (o3 == 0) & on(p2, q2, p1)
        meet |= (o4 == 0) & on(p2, q2, q1)
        if meet.any():
            return True
    return False


def polygon_pixels(points: np.ndarray, height: int, width: int) -> np.ndarray:
    """Pixels whose centre lies inside the polygon (even-odd), computed row by row from the edge
    crossings of each row's centre line (independent of the package's rasteriser)."""
    p = np.asarray(points, dtype=np.float64)
    q = np.roll(p, -1, axis=0)
    out = np.zeros((height, width), dtype=bool)
    ys = np.arange(height) + 0.5
    y0, y1 = p[:, 1][None, :], q[:, 1][None, :]
    crosses = (y0 <= ys[:, None]) != (y1 <= ys[:, None])
    with np.errstate(divide="ignore", invalid="ignore"):
        x = p[:, 0][None, :] + (ys[:, None] - y0) * (q[:, 0] - p[:, 0])[None, :] / (y1 - y0)
    centres = np.arange(width) + 0.5
    for row in np.flatnonzero(crosses.any(axis=1)):
        xs = np.sort(x[row][crosses[row]])
        out[row] = (np.searchsorted(xs, centres, side="right") % 2) == 1
    return out


def measure(folder: Path, xml: Path | None = None) -> dict:
    report = json.loads((folder / "report.json").read_text())
    annotation = read_cvat(xml or folder / "proposals.xml")
    masks = {}
    for frame in report["frames"]:
        if frame.get("status") == "written" and frame.get("mask"):
            rgb = frame["rgb_index"]
            if rgb not in masks or frame.get("cvat_keyframe", False):
                masks[rgb] = folder / frame["mask"]
    ids = [t.track_id for t in annotation.tracks]
    colours = plane_colours(max(ids, default=0))
    try:
        import shapely
    except ImportError:
        shapely = None
    rows = []
    cache: dict = {}
    for track in annotation.tracks:
        keyframes = track.keyframes if track.keyframes is not None else track.shapes
        for frame in sorted(keyframes):
            if frame not in masks:
                continue
            if frame not in cache:
                cache[frame] = read_image(masks[frame], cv2.IMREAD_COLOR)[..., ::-1]
            image = cache[frame]
            points = track.shapes[frame].points
            mask = (image == colours[track.track_id - 1]).all(axis=-1)
            filled = polygon_pixels(points, *mask.shape)
            union = np.count_nonzero(mask | filled)
            row = {"track": track.track_id, "frame": frame, "vertices": len(points),
                   "crossing": bool(segments_meet(points)),
                   "iou": float(np.count_nonzero(mask & filled) / union) if union else 1.0}
            if shapely is not None:
                row["shapely_valid"] = bool(shapely.Polygon(points).is_valid)
            rows.append(row)
    vertices = np.array([r["vertices"] for r in rows])
    iou = np.array([r["iou"] for r in rows])
    summary = {"polygons": len(rows), "median_vertices": float(np.median(vertices)) if rows else 0,
               "max_vertices": int(vertices.max(initial=0)),
               "crossing": sum(r["crossing"] for r in rows),
               "mean_iou": float(iou.mean()) if rows else None,
               "median_iou": float(np.median(iou)) if rows else None,
               "min_iou": float(iou.min()) if rows else None}
    if shapely is not None:
        summary["shapely_invalid"] = sum(not r["shapely_valid"] for r in rows)
    return {"summary": summary, "polygons": rows}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--xml", type=Path)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    result = measure(args.folder, args.xml)
    print(json.dumps(result["summary"]))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The offline review page of a run: one self-contained HTML file, ``OUT_DIR/review.html``.

No server, no network: the styles and the script are inline and the run's data (from
``report.json``, without the plane equations) is embedded as JSON. Images are never inlined:
the page shows the current frame's overlay and mask by their paths relative to the page, so a
3,000-frame run stays a small page that loads two images at a time. The per-plane timeline is
one canvas, drawn once and re-used for every frame.

The page itself (HTML, styles, script) is the template ``templates/review.html``, shipped as
package data; this module only fills in its title and data.
"""

from __future__ import annotations

import html
import json
from collections.abc import Mapping
from functools import cache
from importlib import resources
from urllib.parse import quote

from annotate_rgbd.report.records import RunRecord
from annotate_rgbd.report.stats import run_stats


def page_data(report: RunRecord, overlays: Mapping[str, str]) -> dict:
    """The data the page embeds: plane list, sequence totals and one entry per written frame.

    Parameters
    ----------
    report : RunRecord
        The run's ``report.json``.
    overlays : mapping of str to str
        Mask path (as in the report) -> overlay path relative to the page, for the frames that
        have an overlay.

    Returns
    -------
    dict
        ``planes`` (``plane``, ``colour``, ``label``), ``stats`` (:func:`run_stats`) and
        ``frames``: for every written frame its ``index`` among the depth frames, ``depth``,
        ``rgb``, ``part``, ``cvat_frame``, ``mask``, ``mask_url`` and ``overlay`` (links relative
        to the page, percent-encoded; ``overlay`` ``None`` without one) and ``planes``,
        rows ``[plane, "kept" | "dropped", reason, pixels, pixels after refinement, inlier
        ratio, shape, keyframes' agreement]`` in plane order, ``shape`` being ``propagated`` when
        camera poses carried it there (:mod:`annotate_rgbd.propagate.carry`) and ``drawn`` when
        it comes from the export (drawn on the frame, or interpolated by CVAT between keyframes),
        the agreement the frame's ``keyframes_agree`` for the plane (``None`` without one).
    """
    frames = []
    for index, frame in enumerate(report.frames):
        if not frame.written:
            continue
        agree = frame.keyframes_agree or {}
        rows = [[r.plane, "kept", None, r.pixels, r.inliers, r.inlier_ratio, _source(r), agree.get(r.plane)]
                for r in frame.kept]
        rows += [[r.plane, "dropped", r.reason, r.pixels, 0, None, _source(r), agree.get(r.plane)] for r in frame.dropped]
        frames.append({
            "index": index,
            "depth": frame.depth,
            "rgb": frame.rgb,
            "part": frame.part,
            "cvat_frame": frame.cvat_frame,
            "mask": frame.mask,
            # Links, percent-encoded: a file named with '#', '?' or '%' is still found.
            "mask_url": quote(frame.mask),
            "overlay": None if overlays.get(frame.mask) is None else quote(overlays[frame.mask]),
            "planes": sorted(rows, key=lambda row: row[0]),
        })
    planes = [{"plane": p.plane, "colour": p.colour, "label": p.label} for p in report.planes]
    return {"planes": planes, "stats": run_stats(report), "frames": frames}


def render_review_page(report: RunRecord, overlays: Mapping[str, str], title: str = "annotate-rgbd run") -> str:
    """The review page of a run.

    Parameters
    ----------
    report : RunRecord
        The run's ``report.json``.
    overlays : mapping of str to str
        Mask path -> overlay path relative to the page (see :func:`page_data`).
    title : str
        Shown in the page header and the browser tab.

    Returns
    -------
    str
        The HTML document.
    """
    # "<" as \u003c keeps "</script>" in a label or file name from ending the data block.
    data = json.dumps(page_data(report, overlays), separators=(",", ":")).replace("<", "\\u003c")
    return page_template().replace("__TITLE__", html.escape(title)).replace("__DATA__", data)



@cache
def page_template() -> str:
    """The review page with the placeholders ``__TITLE__`` and ``__DATA__``.

    Read once from the package data (through :mod:`importlib.resources`, so that it is found
    in any installation, zipped or not).
    """
    return (resources.files(__package__) / "templates" / "review.html").read_text(encoding="utf-8")


def _source(record) -> str:
    """Where a plane's shape on a frame came from: the export, or the poses that carried it."""
    return "propagated" if record.propagated else "drawn"

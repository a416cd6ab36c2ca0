"""The offline review page of a run: one self-contained HTML file, ``OUT_DIR/review.html``.

No server, no network: the styles and the script are inline and the run's data (from
``report.json``, without the plane equations) is embedded as JSON. Images are never inlined:
the page shows the current frame's overlay and mask by their paths relative to the page, so a
3,000-frame run stays a small page that loads two images at a time. The per-plane timeline is
one canvas, drawn once and re-used for every frame.
"""

from __future__ import annotations

import html
import json
from collections.abc import Mapping

from .records import RunRecord
from .stats import run_stats


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
        ``rgb``, ``part``, ``cvat_frame``, ``mask``, ``overlay`` (or ``None``) and ``planes``,
        rows ``[plane, "kept" | "dropped", reason, pixels, pixels after refinement, inlier
        ratio]`` in plane order.
    """
    frames = []
    for index, frame in enumerate(report.frames):
        if not frame.written:
            continue
        rows = [[r.plane, "kept", None, r.pixels, r.inliers, r.inlier_ratio] for r in frame.kept]
        rows += [[r.plane, "dropped", r.reason, r.pixels, 0, None] for r in frame.dropped]
        frames.append({
            "index": index,
            "depth": frame.depth,
            "rgb": frame.rgb,
            "part": frame.part,
            "cvat_frame": frame.cvat_frame,
            "mask": frame.mask,
            "overlay": overlays.get(frame.mask),
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
    return PAGE.replace("__TITLE__", html.escape(title)).replace("__DATA__", data)


PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>Review: __TITLE__</title>
<style>
  :root { font: 14px/1.4 system-ui, sans-serif; color: #222; background: #fafafa; }
  [hidden] { display: none !important; }
  body { margin: 0 auto; padding: 12px 16px; max-width: 1400px; }
  h1 { font-size: 18px; margin: 0 0 8px; }
  h2 { font-size: 15px; margin: 16px 0 6px; }
  .bar { display: flex; gap: 10px; align-items: center; flex-wrap: wrap; }
  #slider { flex: 1; min-width: 200px; }
  #counter { font-variant-numeric: tabular-nums; min-width: 9em; }
  #files { color: #555; font-size: 12px; margin: 4px 0 8px; }
  .views { display: flex; gap: 8px; }
  figure { flex: 1; margin: 0; min-width: 0; }
  figure img { width: 100%; display: block; background: #ddd; }
  #mask { image-rendering: pixelated; }
  figcaption { font-size: 12px; color: #555; }
  .missing { display: flex; align-items: center; justify-content: center; aspect-ratio: 4 / 3;
             background: #eee; color: #777; font-size: 13px; text-align: center; padding: 8px; }
  table { border-collapse: collapse; font-variant-numeric: tabular-nums; }
  th, td { padding: 2px 8px; border-bottom: 1px solid #ddd; text-align: right; }
  th { background: #eee; }
  td.text, th.text { text-align: left; }
  tr.dropped td { color: #a00; }
  .swatch { display: inline-block; width: 12px; height: 12px; border: 1px solid #0006;
            vertical-align: -2px; margin-right: 4px; }
  .legend { display: flex; gap: 18px; flex-wrap: wrap; font-size: 12px; }
  .legend span.sample { display: inline-block; width: 28px; height: 14px; vertical-align: -3px; margin-right: 4px; }
  .tint { background: #5a8f5a; border: 1px solid #0c0; }
  .removed { background: repeating-linear-gradient(45deg, #0c0 0 2px, #333 2px 6px); }
  .dashed { border: 2px dashed #0c0; box-sizing: border-box; }
  .columns { display: flex; gap: 24px; flex-wrap: wrap; align-items: flex-start; }
  #timeline { width: 100%; display: block; cursor: pointer; }
  kbd { border: 1px solid #bbb; border-radius: 3px; padding: 0 3px; background: #fff; font-size: 12px; }
</style>
</head>
<body>
<h1>Review: __TITLE__</h1>
<div class="bar">
  <button id="prev" title="previous frame (left arrow)">&#9664;</button>
  <input id="slider" type="range" min="0" max="0" value="0" aria-label="frame">
  <button id="next" title="next frame (right arrow)">&#9654;</button>
  <span id="counter"></span>
  <span><kbd>&larr;</kbd> <kbd>&rarr;</kbd> frame, <kbd>PgUp</kbd> <kbd>PgDn</kbd> 10 frames</span>
</div>
<div id="files"></div>
<div class="views">
  <figure><img id="overlay" alt="overlay"><div id="no-overlay" class="missing" hidden><span>no overlay for this frame:
    run <code>annotate-rgbd review</code> on the output folder</span></div><figcaption>overlay</figcaption></figure>
  <figure><img id="mask" alt="mask"><figcaption>mask</figcaption></figure>
</div>
<div class="legend" style="margin-top:6px">
  <span><span class="sample tint"></span>kept: in the mask (tint and outline in the plane colour, id in a box)</span>
  <span><span class="sample removed"></span>removed: drawn by the labeller, taken out by RANSAC or missing depth</span>
  <span><span class="sample dashed"></span>dropped plane: dashed outline, "id dropped: reason"</span>
</div>
<div class="columns">
  <div>
    <h2>Planes in this frame</h2>
    <table id="planes">
      <thead><tr><th class="text">plane</th><th class="text">label</th><th class="text">status</th>
        <th class="text">reason</th><th>pixels drawn</th><th>pixels kept</th><th>inlier ratio</th></tr></thead>
      <tbody></tbody>
    </table>
  </div>
  <div>
    <h2>Sequence totals</h2>
    <table id="totals"><tbody></tbody></table>
  </div>
</div>
<h2>Plane timeline <small style="font-weight:normal;color:#555">(coloured: in the mask, dark: dropped, blank: not drawn; click to go to a frame)</small></h2>
<canvas id="timeline"></canvas>
<script type="application/json" id="run-data">__DATA__</script>
<script>
"use strict";
(function () {
  const data = JSON.parse(document.getElementById("run-data").textContent);
  const frames = data.frames;
  const planes = data.planes;
  const planeInfo = new Map(planes.map(p => [p.plane, p]));
  const $ = id => document.getElementById(id);
  const slider = $("slider"), overlayImg = $("overlay"), maskImg = $("mask");
  const timeline = $("timeline");
  const rowHeight = 12, margin = 150;
  let current = -1, base = null;

  function cell(text, cls) {
    const td = document.createElement("td");
    td.textContent = text === null || text === undefined ? "" : String(text);
    if (cls) td.className = cls;
    return td;
  }

  function fillTotals() {
    const s = data.stats, body = $("totals").tBodies[0];
    const rows = [["observations (masks)", s.observations], ["total planes", s.total_planes],
      ["planes per observation", s.planes_per_observation.toFixed(2)],
      ["distinct planes", s.distinct_planes + " of " + s.planes_annotated],
      ["depth frames", s.depth_frames]];
    for (const [reason, count] of Object.entries(s.frames_skipped)) rows.push(["skipped: " + reason, count]);
    if (s.frames_failed) rows.push(["failed (unreadable depth)", s.frames_failed]);
    rows.push(["planes dropped", s.planes_dropped]);
    for (const [reason, count] of Object.entries(s.dropped_by_reason)) rows.push(["dropped: " + reason, count]);
    rows.push(["mean inlier ratio", s.mean_inlier_ratio === null ? "-" : s.mean_inlier_ratio.toFixed(3)]);
    for (const [name, value] of rows) {
      const tr = document.createElement("tr");
      tr.append(cell(name, "text"), cell(value));
      body.append(tr);
    }
  }

  function fillPlanes(frame) {
    const body = $("planes").tBodies[0];
    body.replaceChildren();
    for (const [plane, status, reason, pixels, kept, ratio] of frame.planes) {
      const info = planeInfo.get(plane) || {colour: "#888", label: ""};
      const tr = document.createElement("tr");
      tr.className = status;
      tr.dataset.plane = plane;
      const id = cell(plane, "text");
      const swatch = document.createElement("span");
      swatch.className = "swatch";
      swatch.style.background = info.colour;
      id.prepend(swatch);
      tr.append(id, cell(info.label, "text"), cell(status, "text"), cell(reason, "text"),
                cell(pixels), cell(kept), cell(ratio === null ? "" : ratio.toFixed(3)));
      body.append(tr);
    }
  }

  function drawBase() {
    const ratio = window.devicePixelRatio || 1;
    const width = Math.max(timeline.clientWidth, margin + 100);
    const height = Math.max(planes.length, 1) * rowHeight;
    base = document.createElement("canvas");
    base.width = timeline.width = Math.round(width * ratio);
    base.height = timeline.height = Math.round(height * ratio);
    timeline.style.height = height + "px";
    const ctx = base.getContext("2d");
    ctx.scale(ratio, ratio);
    ctx.fillStyle = "#fff";
    ctx.fillRect(0, 0, width, height);
    ctx.font = "10px system-ui, sans-serif";
    ctx.textBaseline = "middle";
    const row = new Map();
    planes.forEach((p, r) => {
      row.set(p.plane, r);
      ctx.fillStyle = r % 2 ? "#f4f4f4" : "#fff";
      ctx.fillRect(0, r * rowHeight, width, rowHeight);
      ctx.fillStyle = "#222";
      ctx.fillText((p.plane + " " + p.label).slice(0, 24), 2, r * rowHeight + rowHeight / 2);
    });
    const span = width - margin, step = span / Math.max(frames.length, 1), w = Math.max(step, 1);
    // Kept first, then dropped on top: a drop stays visible where frames share a pixel column.
    for (const status of ["kept", "dropped"]) {
      frames.forEach((frame, i) => {
        for (const [plane, s] of frame.planes) {
          if (s !== status || !row.has(plane)) continue;
          ctx.fillStyle = s === "kept" ? planeInfo.get(plane).colour : "#333";
          ctx.fillRect(margin + i * step, row.get(plane) * rowHeight + 1, w, rowHeight - 2);
        }
      });
    }
  }

  function drawTimeline() {
    if (!base) return;
    const ctx = timeline.getContext("2d");
    const ratio = window.devicePixelRatio || 1;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.drawImage(base, 0, 0);
    if (current < 0) return;
    ctx.scale(ratio, ratio);
    const width = timeline.width / ratio, height = timeline.height / ratio;
    const step = (width - margin) / frames.length;
    // A frame box where frames are wide, a 2-pixel line where they are narrower than that.
    const w = Math.max(step, 2), x = margin + (current + 0.5) * step - w / 2;
    ctx.strokeStyle = "#e00";
    ctx.lineWidth = 2;
    if (step > 4) ctx.strokeRect(x + 1, 1, w - 2, height - 2);
    else { ctx.fillStyle = "#e00"; ctx.fillRect(x, 0, w, height); }
  }

  function show(i) {
    if (!frames.length) return;
    i = Math.min(Math.max(i, 0), frames.length - 1);
    if (i === current) return;
    current = i;
    const frame = frames[i];
    slider.value = i;
    $("counter").textContent = "frame " + (i + 1) + " of " + frames.length;
    $("files").textContent = frame.depth + "  \\u00b7  " + (frame.rgb || "") +
      (frame.part ? "  \\u00b7  " + frame.part + ", CVAT frame " + frame.cvat_frame : "") +
      "  \\u00b7  depth frame " + frame.index;
    overlayImg.hidden = !frame.overlay;
    $("no-overlay").hidden = !!frame.overlay;
    if (frame.overlay) overlayImg.src = frame.overlay;
    maskImg.src = frame.mask;
    fillPlanes(frame);
    drawTimeline();
    history.replaceState(null, "", "#frame=" + (i + 1));
    // Warm the cache for the neighbours only: never more than a few images in flight.
    for (const j of [i - 1, i + 1]) {
      if (j >= 0 && j < frames.length && frames[j].overlay) new Image().src = frames[j].overlay;
    }
  }

  document.addEventListener("keydown", event => {
    const moves = {ArrowLeft: -1, ArrowRight: 1, PageUp: -10, PageDown: 10};
    if (event.key in moves) show(current + moves[event.key]);
    else if (event.key === "Home") show(0);
    else if (event.key === "End") show(frames.length - 1);
    else return;
    event.preventDefault();  // also keeps a focused slider from moving a second time
  });
  slider.addEventListener("input", () => show(Number(slider.value)));
  $("prev").addEventListener("click", () => show(current - 1));
  $("next").addEventListener("click", () => show(current + 1));
  timeline.addEventListener("click", event => {
    const x = event.clientX - timeline.getBoundingClientRect().left;
    const step = (timeline.clientWidth - margin) / frames.length;
    if (x >= margin) show(Math.floor((x - margin) / step));
  });
  let resizing = 0;
  window.addEventListener("resize", () => {
    clearTimeout(resizing);
    resizing = setTimeout(() => { drawBase(); drawTimeline(); }, 150);
  });

  fillTotals();
  slider.max = Math.max(frames.length - 1, 0);
  drawBase();
  if (!frames.length) {
    $("counter").textContent = "no masks written";
    drawTimeline();
    return;
  }
  const start = /^#frame=(\\d+)$/.exec(location.hash);
  show(start ? Number(start[1]) - 1 : 0);
})();
</script>
</body>
</html>
"""

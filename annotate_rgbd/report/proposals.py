"""A ``propose`` folder's records as a run record, so that ``review`` shows proposals before they
go to CVAT as it shows a ``cvat2mask`` run.

``propose`` writes ``report.json`` (its own layout: a track per plane, a plane entry per track
and frame), the colour masks and the drawn-shapes record (every written mask's polygons,
:mod:`annotate_rgbd.report.run_folder`). :func:`proposals_record` reads the report into a
:class:`~annotate_rgbd.report.records.RunRecord`:

* each track is a plane (id = track number = its colour, label, part ``proposals.xml``);
* each proposed plane of a written frame is a kept plane record whose ``pixels`` are its
  polygon's (``valid_pixels`` too: what the polygon covers), ``inliers`` the plane's own pixels
  (its mask) inside the polygon, ``inlier_ratio`` their share of the polygon and ``grown`` the
  plane's pixels the polygon leaves out (from the report's ``polygon_pixels``, ``area`` and
  ``polygon_iou``); the detections ``propose`` did not propose carry no track and no polygon,
  and are left out;
* the overlays then show, for each proposed polygon, the plane's pixels tinted, the polygon's
  pixels that are not the plane's striped, and the plane's pixels the polygon leaves out in
  full colour, on the RGB frame (polygons and masks are on the depth grid, as ``propose`` draws
  them).
"""

from __future__ import annotations

from typing import Any

from annotate_rgbd.jsonfields import RecordError, int_field, list_field, mapping, number, numbers, text

from .records import FrameRecord, MaskRecord, PlaneInfo, RunRecord, WRITTEN
from annotate_rgbd.segment.plane_record import PlaneRecord

#: The ``tool`` of a ``propose`` report.
PROPOSE_TOOL = "annotate-rgbd propose"
#: The part every proposed track belongs to.
PROPOSALS_PART = "proposals.xml"


def is_proposals(report: Any) -> bool:
    """Whether a ``report.json`` document is ``propose``'s."""
    return isinstance(report, dict) and report.get("tool") == PROPOSE_TOOL


def proposals_record(report: Any) -> RunRecord:
    """A ``propose`` report as the run record ``review`` draws.

    Parameters
    ----------
    report : dict
        The content of a ``propose`` folder's ``report.json``.

    Returns
    -------
    RunRecord

    Raises
    ------
    RecordError
        Not a ``propose`` report, an entry of the wrong layout, or a run without RGB frames
        (a depth-only sequence: nothing to draw the review on).
    """
    report = mapping(report, "report")
    if not is_proposals(report):
        raise RecordError("not a propose report")
    inputs = mapping(report.get("inputs"), "inputs")
    planes = []
    for index, entry in enumerate(list_field(report, "tracks")):
        try:
            entry = mapping(entry, "track entry")
            track = int_field(entry, "track")
            planes.append(PlaneInfo(track, text(entry, "colour"), text(entry, "label"), PROPOSALS_PART, track))
        except RecordError as exc:
            raise RecordError(f"tracks[{index}]: {exc}") from None
    frames = []
    for index, entry in enumerate(list_field(report, "frames")):
        try:
            frames.append(_frame(mapping(entry, "frame entry")))
        except RecordError as exc:
            raise type(exc)(f"frames[{index}]: {exc}") from None
    config = mapping(report.get("config", {}), "config")
    return RunRecord(
        version=str(report.get("version", "")),
        sequence=text(inputs, "sequence"),
        parts=[],
        # Polygons and masks are on the depth grid: no colour camera to take them through.
        config={key: value for key, value in config.items() if key != "colour_camera"},
        planes=planes,
        n_planes=max((p.plane for p in planes), default=0),
        tracks=[],
        frames=frames,
        warnings=[w for w in report.get("warnings", []) if isinstance(w, str)],
        command="propose",
    )


class DepthOnlyRun(RecordError):
    """A ``propose`` run of a depth-only sequence: no RGB frame to draw the review on."""


def _frame(entry: dict) -> FrameRecord:
    status = text(entry, "status")
    rgb = entry.get("rgb")
    if rgb is None:
        raise DepthOnlyRun("no RGB frame (a depth-only sequence): review draws on the RGB frames")
    frame = FrameRecord(
        depth=text(entry, "depth"), depth_timestamp=number(entry, "depth_timestamp"), rgb=text(entry, "rgb"),
        rgb_index=int_field(entry, "rgb_index"), time_offset=number(entry, "time_offset"),
        status=status, reason=text(entry, "reason", optional=True), error=text(entry, "error", optional=True),
    )
    if status == WRITTEN:
        kept = tuple(_plane(mapping(p, "plane entry")) for p in list_field(entry, "planes"))
        frame.write(MaskRecord("", kept, ()), text(entry, "mask"))
    return frame


def _plane(entry: dict) -> PlaneRecord:
    area = int_field(entry, "area")
    if "polygon_pixels" in entry:
        pixels = int_field(entry, "polygon_pixels")
        iou = number(entry, "polygon_iou")
        # IoU = inside / (pixels + area - inside): the plane's pixels inside its polygon.
        inside = min(int(round(iou * (pixels + area) / (1.0 + iou))), pixels, area)
    else:  # a report of propose before polygons were measured: the plane's pixels stand for the polygon's
        pixels = inside = area
    return PlaneRecord(
        plane=int_field(entry, "track"), pixels=pixels, valid_pixels=pixels,
        mean_distance=number(entry, "mean_distance", optional=True),
        inliers=inside, inlier_ratio=round(inside / pixels, 4) if pixels else None,
        equation=tuple(numbers(entry.get("equation"), "equation", 4)), grown=area - inside,
    )

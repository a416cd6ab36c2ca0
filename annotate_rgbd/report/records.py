"""Typed records of a run, and the one place that turns them into JSON and back.

A run's ``report.json`` holds one :class:`FrameRecord` per depth frame (with a
:class:`PlaneRecord` per plane drawn on it), the global planes, how every track got its plane,
the inputs and the configuration. The same records carry a frame's result from the worker that
made it to the journal and the report, and back from them into a re-run, ``stats`` and
``review``; :func:`summarize` counts them once for all of these.

The JSON layout (key names and order) is the report format users and scripts read: changing a
``to_json`` here changes the file format.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from annotate_rgbd.jsonfields import RecordError, mapping as _mapping, list_field as _list, int_field as _int
from annotate_rgbd.jsonfields import number as _number, numbers as _numbers
from annotate_rgbd.jsonfields import text as _text
from annotate_rgbd.io.rotations import quaternion_matrices
from annotate_rgbd.segment.plane_record import PlaneRecord

__all__ = ["RecordError", "PlaneRecord", "MaskRecord", "FrameRecord", "RunSummary", "summarize", "PartRecord",
           "PlaneInfo", "RunRecord", "WRITTEN", "SKIPPED", "FAILED", "OUTSIDE_ANNOTATION", "NO_RGB_FRAME",
           "RGB_NOT_ANNOTATED", "UNREADABLE_DEPTH", "TIMED_OUT"]

#: A depth frame's status in the report.
WRITTEN, SKIPPED, FAILED = "written", "skipped", "failed"

#: Why a depth frame gets no mask, as written to the report.
OUTSIDE_ANNOTATION = "outside_annotated_range"
NO_RGB_FRAME = "no_rgb_frame_within_max_time_diff"
RGB_NOT_ANNOTATED = "rgb_frame_not_in_annotation"
UNREADABLE_DEPTH = "unreadable_depth"
TIMED_OUT = "timed_out"


@dataclass(frozen=True)
class MaskRecord:
    """One mask: the fingerprint of what it was made from, its plane records and the files
    written for it; what a frame job gives back, the journal holds and the report keeps.

    Parameters
    ----------
    fingerprint : str
        Of the frame's inputs (:func:`annotate_rgbd.pipeline.resume.fingerprint`).
    kept, dropped : tuple of PlaneRecord
    outputs : tuple of (str, str)
        ``(path relative to the output folder, digest of its bytes)`` of every file written for
        the frame (mask, raw mask, overlay), sorted by path; a re-run reuses them only when
        their bytes still have these digests.
    """

    fingerprint: str
    kept: tuple[PlaneRecord, ...]
    dropped: tuple[PlaneRecord, ...]
    outputs: tuple[tuple[str, str], ...] = ()

    def only(self, paths: set[str]) -> MaskRecord:
        """The same record with only the outputs among ``paths``."""
        return MaskRecord(self.fingerprint, self.kept, self.dropped, tuple(o for o in self.outputs if o[0] in paths))

    def to_json(self) -> dict[str, Any]:
        """``{"kept": [...], "dropped": [...], "outputs": {...}}`` as in the report and the journal."""
        return {"kept": [r.to_json() for r in self.kept], "dropped": [r.to_json() for r in self.dropped],
                "outputs": dict(self.outputs)}

    @classmethod
    def from_json(cls, fingerprint: Any, entry: Any) -> MaskRecord:
        """Read the ``kept`` and ``dropped`` lists of a report entry or journal record.

        Raises
        ------
        RecordError
            Wrong layout.
        """
        if not isinstance(fingerprint, str):
            raise RecordError("fingerprint is not a string")
        entry = _mapping(entry, "frame result")
        planes = [[PlaneRecord.from_json(r) for r in _list(entry, key)] for key in ("kept", "dropped")]
        if not all(r.kept for r in planes[0]) or any(r.kept for r in planes[1]):
            raise RecordError("a kept plane has a drop reason, or a dropped plane has none")
        outputs = _mapping(entry.get("outputs", {}), "outputs")  # absent in reports of earlier versions
        if not all(isinstance(k, str) and isinstance(v, str) for k, v in outputs.items()):
            raise RecordError("outputs is not an object of strings")
        return cls(fingerprint, tuple(planes[0]), tuple(planes[1]), tuple(sorted(outputs.items())))


@dataclass
class FrameRecord:
    """One depth frame of a run: which RGB frame it took its annotation from, and its outcome.

    Parameters
    ----------
    depth : str
        Depth file, relative to the sequence folder.
    depth_timestamp : float
    rgb : str
        The RGB file nearest in time, relative to the sequence folder.
    rgb_index : int
        Its index in the RGB list.
    time_offset : float
        RGB minus depth timestamp (s).
    status : str
        ``written``, ``skipped`` or ``failed``.
    part, cvat_frame : str and int, optional
        The annotation part and its CVAT frame that annotate the frame.
    reason : str, optional
        Why a frame was skipped or failed.
    error : str, optional
        A failed frame's error message.
    result : MaskRecord, optional
        A written frame's planes and fingerprint.
    mask : str, optional
        A written frame's mask, relative to the output folder (``masks/<name>``).
    pose : str, optional
        With camera poses: ``ok``, or why the frame has none (``pose_gap``,
        ``outside_trajectory``: its shapes are then interpolated in 2-D). None without poses.
    camera_pose : tuple of 7 float, optional
        With camera poses, for every frame the trajectory gives a pose: the camera-to-world pose
        the frame's masks were made with, ``(tx, ty, tz, qx, qy, qz, qw)`` as a TUM trajectory line holds it
        (metres; unit quaternion): the trajectory's pose at the frame's time (plus the run's
        clock offset), aligned to the keyframes' depth (``propagate.align_rounds``).
        ``export`` and ``review --rerun`` read these. None otherwise.
    keyframes_agree : dict of int to float, optional
        With camera poses: for each plane the poses carried to the frame between two of its
        keyframes, how much the nearest keyframe before and after agree about it there (the share
        of what both saw that both outline, :func:`annotate_rgbd.propagate.carry.keyframe_agreement`):
        the lower, the less certain what was carried. None without poses, or where no plane was carried
        between two keyframes.
    """

    depth: str
    depth_timestamp: float
    rgb: str
    rgb_index: int
    time_offset: float
    status: str = SKIPPED
    part: str | None = None
    cvat_frame: int | None = None
    reason: str | None = None
    error: str | None = None
    result: MaskRecord | None = None
    mask: str | None = None
    pose: str | None = None
    camera_pose: tuple[float, ...] | None = None
    keyframes_agree: dict[int, float] | None = None

    @property
    def written(self) -> bool:
        """Whether the frame has a mask."""
        return self.status == WRITTEN

    @property
    def kept(self) -> tuple[PlaneRecord, ...]:
        """The planes in the frame's mask (none unless written)."""
        return self.result.kept if self.result is not None else ()

    @property
    def dropped(self) -> tuple[PlaneRecord, ...]:
        """The planes drawn on the frame but dropped (none unless written)."""
        return self.result.dropped if self.result is not None else ()

    def write(self, result: MaskRecord, mask: str) -> None:
        """Mark the frame written, with its planes and mask path."""
        self.status, self.result, self.mask = WRITTEN, result, mask

    def fail(self, reason: str, error: str) -> None:
        """Mark the frame failed (its depth image could not be used)."""
        self.status, self.reason, self.error = FAILED, reason, error

    def to_json(self) -> dict[str, Any]:
        """The report's frame entry."""
        entry: dict[str, Any] = {
            "depth": self.depth,
            "depth_timestamp": self.depth_timestamp,
            "rgb": self.rgb,
            "rgb_index": self.rgb_index,
            "time_offset": self.time_offset,
            "status": self.status,
        }
        if self.part is not None:
            entry.update(part=self.part, cvat_frame=self.cvat_frame)
        if self.pose is not None:
            entry["pose"] = self.pose
        if self.camera_pose is not None:
            entry["camera_pose"] = [round(float(v), 9) for v in self.camera_pose]
        if self.keyframes_agree:
            entry["keyframes_agree"] = {str(plane): agree for plane, agree in sorted(self.keyframes_agree.items())}
        if self.reason is not None:
            entry["reason"] = self.reason
        if self.error is not None:
            entry["error"] = self.error
        if self.result is not None:
            entry["fingerprint"] = self.result.fingerprint
            entry.update(self.result.to_json())
        if self.mask is not None:
            entry["mask"] = self.mask
        return entry

    @classmethod
    def from_json(cls, entry: Any) -> FrameRecord:
        """Read a report's frame entry.

        Raises
        ------
        RecordError
            Not a frame entry.
        """
        entry = _mapping(entry, "frame entry")
        status = _text(entry, "status")
        if status not in (WRITTEN, SKIPPED, FAILED):
            raise RecordError(f"unknown frame status {status!r}")
        result = None
        if status == WRITTEN:
            result = MaskRecord.from_json(entry.get("fingerprint", ""), entry)
        return cls(
            depth=_text(entry, "depth"),
            depth_timestamp=_number(entry, "depth_timestamp"),
            rgb=_text(entry, "rgb"),
            rgb_index=_int(entry, "rgb_index"),
            time_offset=_number(entry, "time_offset"),
            status=status,
            part=_text(entry, "part", optional=True),
            cvat_frame=_int(entry, "cvat_frame") if entry.get("cvat_frame") is not None else None,
            reason=_text(entry, "reason", optional=True),
            error=_text(entry, "error", optional=True),
            result=result,
            mask=_text(entry, "mask") if status == WRITTEN else None,
            pose=_text(entry, "pose", optional=True),
            camera_pose=_camera_pose(entry),
            keyframes_agree=_agreement(entry),
        )

    def rotation_translation(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The frame's :attr:`camera_pose` as a camera-to-world rotation (3, 3) and camera
        centre (3,), or None."""
        if self.camera_pose is None:
            return None
        values = np.asarray(self.camera_pose, dtype=np.float64)
        return quaternion_matrices(values[None, 3:] / np.linalg.norm(values[3:]))[0], values[:3]


def _camera_pose(entry: dict) -> tuple[float, ...] | None:
    """A frame entry's ``camera_pose`` (absent in reports of earlier versions, of runs without
    poses and of frames without one: None); its quaternion must be a unit one, to the 1e-3 of a
    pose copied from a trajectory file with 4 decimals."""
    if entry.get("camera_pose") is None:
        return None
    values = _numbers(entry["camera_pose"], "camera_pose", 7)
    if not all(np.isfinite(values)) or abs(float(np.linalg.norm(values[3:])) - 1.0) > 1e-3:
        raise RecordError("camera_pose is not a position and a unit quaternion (tx ty tz qx qy qz qw)")
    return tuple(float(v) for v in values)


def _agreement(entry: dict) -> dict[int, float] | None:
    """A frame entry's ``keyframes_agree`` (absent in reports of earlier versions and of runs
    without poses: None)."""
    if entry.get("keyframes_agree") is None:
        return None
    agree = _mapping(entry["keyframes_agree"], "keyframes_agree")
    if not all(key.isascii() and key.isdigit() for key in agree):
        raise RecordError("keyframes_agree is not an object of plane ids")
    return {int(key): _number({f"keyframes_agree[{key}]": value}, f"keyframes_agree[{key}]") for key, value in agree.items()}


@dataclass(frozen=True)
class RunSummary:
    """The counts of a run, computed once (:func:`summarize`) for the report, ``stats`` and
    ``batch``.

    Parameters
    ----------
    depth_frames : int
    masks_written : int
    frames_skipped : dict of str to int
        Skipped frames by reason, in the order the reasons first occur along the sequence.
    frames_failed : int
    planes_kept, planes_dropped : int
        Plane records of the written frames (a plane kept on 10 frames counts 10 times).
    distinct_planes : int
        Global planes kept in at least one mask.
    dropped_by_reason : dict of str to int
        Dropped plane records by reason, reasons in alphabetical order.
    mean_inlier_ratio : float or None
        Over the kept plane records, rounded to 4 decimals; None without any.
    """

    depth_frames: int
    masks_written: int
    frames_skipped: dict[str, int]
    frames_failed: int
    planes_kept: int
    planes_dropped: int
    distinct_planes: int
    dropped_by_reason: dict[str, int]
    mean_inlier_ratio: float | None

    @property
    def skipped(self) -> int:
        """Frames skipped, whatever the reason."""
        return sum(self.frames_skipped.values())


def summarize(frames: list[FrameRecord]) -> RunSummary:
    """Count a run's frames and plane records.

    Parameters
    ----------
    frames : list of FrameRecord

    Returns
    -------
    RunSummary
    """
    written = [f for f in frames if f.written]
    kept = [r for f in written for r in f.kept]
    dropped = [r for f in written for r in f.dropped]
    ratios = [r.inlier_ratio for r in kept if r.inlier_ratio is not None]
    return RunSummary(
        depth_frames=len(frames),
        masks_written=len(written),
        frames_skipped=dict(Counter(f.reason or "unknown" for f in frames if f.status == SKIPPED)),
        frames_failed=sum(1 for f in frames if f.status == FAILED),
        planes_kept=len(kept),
        planes_dropped=len(dropped),
        distinct_planes=len({r.plane for r in kept}),
        dropped_by_reason=dict(sorted(Counter(r.reason for r in dropped).items())),
        mean_inlier_ratio=round(sum(ratios) / len(ratios), 4) if ratios else None,
    )


@dataclass(frozen=True)
class PartRecord:
    """Where one annotation part was placed in the sequence (``inputs.parts`` of the report)."""

    file: str
    name: str
    offset: int
    first_rgb: int
    last_rgb: int
    placed_by: str

    def to_json(self) -> dict[str, Any]:
        """The report's part entry."""
        return dict(vars(self))

    @classmethod
    def from_json(cls, entry: Any) -> PartRecord:
        """Read a report's part entry (raises :class:`RecordError`)."""
        entry = _mapping(entry, "part entry")
        return cls(_text(entry, "file"), _text(entry, "name"), _int(entry, "offset"), _int(entry, "first_rgb"),
                   _int(entry, "last_rgb"), _text(entry, "placed_by"))


@dataclass(frozen=True)
class PlaneInfo:
    """One global plane: its colour and where it comes from (``planes`` of the report)."""

    plane: int
    colour: str
    label: str
    part: str
    track_id: int

    def to_json(self) -> dict[str, Any]:
        """The report's plane-list entry."""
        return dict(vars(self))

    @classmethod
    def from_json(cls, entry: Any) -> PlaneInfo:
        """Read a report's plane-list entry (raises :class:`RecordError`)."""
        entry = _mapping(entry, "plane-list entry")
        return cls(_int(entry, "plane"), _text(entry, "colour"), str(entry.get("label", "")),
                   str(entry.get("part", "")), _int(entry, "track_id") if "track_id" in entry else -1)


@dataclass
class RunRecord:
    """A whole run, as ``report.json`` holds it.

    Parameters
    ----------
    version : str
        annotate-rgbd version that made the run.
    sequence : str
        The sequence folder (absolute).
    parts : list of PartRecord
    config : dict
        The effective configuration (:func:`annotate_rgbd.config.config_to_dict`).
    planes : list of PlaneInfo
    n_planes : int
        Number of global planes (ids ``1..n_planes``).
    tracks : list of dict
        How every track got its plane (``tracks.csv`` rows; see
        :class:`annotate_rgbd.annotation.stitch.TrackPlane`).
    frames : list of FrameRecord
    warnings, notes : list of str
    propagation : dict, optional
        With camera poses: the trajectory, the frames with a pose and every track's lifted
        keyframes and their agreement (:meth:`annotate_rgbd.pipeline.plan.Propagation.to_json`).
    command : str
        The command whose folder the record was read from: ``cvat2mask``, or ``propose`` for
        the view of its proposals (:mod:`annotate_rgbd.report.proposals`); not in the JSON.
    """

    version: str
    sequence: str
    parts: list[PartRecord]
    config: dict
    planes: list[PlaneInfo]
    n_planes: int
    tracks: list[dict]
    frames: list[FrameRecord]
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    propagation: dict | None = None
    command: str = "cvat2mask"

    def to_json(self) -> dict[str, Any]:
        """The content of ``report.json``."""
        summary = summarize(self.frames)
        return {
            "tool": {"name": "annotate-rgbd", "version": self.version},
            "inputs": {"sequence": self.sequence, "parts": [p.to_json() for p in self.parts]},
            "config": self.config,
            "summary": {
                "depth_frames": summary.depth_frames,
                "masks_written": summary.masks_written,
                "frames_skipped": summary.frames_skipped,
                "frames_failed": summary.frames_failed,
                "planes": self.n_planes,
                "planes_kept": summary.planes_kept,
                "planes_dropped": summary.planes_dropped,
            },
            "planes": [p.to_json() for p in self.planes],
            "tracks": self.tracks,
            "frames": [f.to_json() for f in self.frames],
            "warnings": self.warnings,
            "notes": self.notes,
            **({"propagation": self.propagation} if self.propagation is not None else {}),
        }

    @classmethod
    def from_json(cls, report: Any) -> RunRecord:
        """Read the content of ``report.json``.

        Raises
        ------
        RecordError
            Not a report, or an entry of the wrong layout (the message says which).
        """
        report = _mapping(report, "report")
        for key in ("inputs", "config", "frames", "planes"):
            if key not in report:
                raise RecordError(f"{key} missing")
        inputs = _mapping(report["inputs"], "inputs")
        frames = []
        for index, entry in enumerate(_list(report, "frames")):
            try:
                frames.append(FrameRecord.from_json(entry))
            except RecordError as exc:
                raise RecordError(f"frames[{index}]: {exc}") from None
        summary = report.get("summary")
        planes = [PlaneInfo.from_json(p) for p in _list(report, "planes")]
        n_planes = summary.get("planes") if isinstance(summary, dict) else None
        return cls(
            version=str(_mapping(report.get("tool", {}), "tool").get("version", "")),
            sequence=_text(inputs, "sequence"),
            parts=[PartRecord.from_json(p) for p in _list(inputs, "parts")],
            config=_mapping(report["config"], "config"),
            planes=planes,
            n_planes=n_planes if isinstance(n_planes, int) else len(planes),
            tracks=[_mapping(t, "track entry") for t in _list({"tracks": report.get("tracks", [])}, "tracks")],
            frames=frames,
            warnings=[_text({"warnings": w}, "warnings") for w in _list({"warnings": report.get("warnings", [])}, "warnings")],
            notes=[_text({"notes": n}, "notes") for n in _list({"notes": report.get("notes", [])}, "notes")],
            propagation=report["propagation"] if isinstance(report.get("propagation"), dict) else None,
        )

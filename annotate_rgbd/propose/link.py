"""Linking the planes proposed on successive processed frames into tracks (pure, deterministic).

Two detections are candidates for one plane when their planes agree within the noise band and
their masks overlap (see :class:`~annotate_rgbd.config.propose.LinkConfig`, the ``[link]`` section):

- **with poses**, by world plane (:func:`annotate_rgbd.geometry.lift.plane_agreement` for all of a
  frame's planes at once, at the later detection's centroid) and by the IoU of
  the later mask with the earlier polygon lifted onto its plane and reprojected into the later
  frame (:mod:`annotate_rgbd.geometry.lift`);
- **without poses** (or where a frame has none), by the camera-frame planes, allowing for what
  the camera may have turned and moved in between, and by the IoU of the two masks after the
  2-D shift that overlaps them best, among the shifts that camera motion can explain
  (:func:`shifted_iou`, on masks sampled every :data:`STRIDE` pixels): a narrow plane seen
  while the camera pans moves off its own earlier mask within a frame or two.

Among the candidates an optimal one-to-one assignment (Hungarian, maximum total IoU) links
detections to tracks; the others start new tracks, numbered 1, 2, ... in order of appearance
(frame order, then area).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from annotate_rgbd.config.propose import LinkConfig
from annotate_rgbd.geometry.camera import Camera
from annotate_rgbd.geometry.lift import lift_polygon, plane_agreement, plane_to_world, project_polygon
from annotate_rgbd.geometry.noise import NoiseSettings
from annotate_rgbd.segment.rasterize import fill_window
from .detect_job import FrameProposal

#: Masks are compared without poses on every STRIDE-th pixel along rows and columns: a plane
#: of the smallest proposed size (1 % of the image) keeps ~190 samples, and a shift search over
#: a few dozen pixels costs a few hundred microseconds.
STRIDE = 4


@dataclass
class _Last:
    """Where a track was last seen."""

    track: int
    position: int
    time: float
    label: int  # in that frame's labels
    plane: np.ndarray  # camera frame of that frame
    centroid: np.ndarray
    outline: np.ndarray
    pose: tuple[np.ndarray, np.ndarray] | None


class TrackLinker:
    """Links the proposals of processed frames, given in frame order, into tracks.

    Parameters
    ----------
    config : LinkConfig
    noise : NoiseSettings
        Gives the band ``noise.band(z)`` that plane offsets are compared against.
    camera : Camera
    """

    def __init__(self, config: LinkConfig, noise: NoiseSettings, camera: Camera):
        self.config = config
        self.noise = noise
        self.camera = camera
        self.next_track = 1
        self.last: dict[int, _Last] = {}
        self.recent: dict[int, np.ndarray] = {}  # position -> labels sampled every STRIDE pixels

    def add(
        self, proposal: FrameProposal, time: float, pose: tuple[np.ndarray, np.ndarray] | None = None
    ) -> np.ndarray:
        """Link one frame's planes (frames must come in increasing ``proposal.position``).

        Parameters
        ----------
        proposal : FrameProposal
        time : float
            The frame's timestamp, seconds.
        pose : (ndarray (3, 3), ndarray (3,)), optional
            Camera-to-world rotation and camera centre; None: no pose for this frame.

        Returns
        -------
        ndarray of int64, shape (K,)
            Track id of each of the frame's planes (label k at position k - 1).
        """
        position = proposal.position
        live = [t for t in sorted(self.last) if position - self.last[t].position <= self.config.max_gap + 1]
        k = len(proposal.areas)
        score = np.zeros((len(live), k))
        sampled = np.ascontiguousarray(proposal.labels[::STRIDE, ::STRIDE])
        counts = np.bincount(sampled.ravel(), minlength=k + 1)[1 : k + 1]  # sampled pixels per plane
        for row, track in enumerate(live):
            score[row] = self._scores(self.last[track], proposal, sampled, counts, time, pose)
        tracks = np.zeros(k, dtype=np.int64)
        if live and k:
            rows, cols = linear_sum_assignment(-score)
            for r, c in zip(rows.tolist(), cols.tolist()):
                if score[r, c] >= self.config.min_iou:
                    tracks[c] = live[r]
        for c in range(k):
            if tracks[c] == 0:
                tracks[c] = self.next_track
                self.next_track += 1
            self.last[int(tracks[c])] = _Last(
                int(tracks[c]), position, time, c + 1, proposal.planes[c], proposal.centroids[c],
                proposal.outlines[c], pose,
            )
        self.recent[position] = sampled
        # Forget what no later frame can link to.
        horizon = position - self.config.max_gap
        self.last = {t: s for t, s in self.last.items() if s.position >= horizon}
        self.recent = {p: labels for p, labels in self.recent.items() if p >= horizon}
        return tracks

    def _scores(
        self, last: _Last, proposal: FrameProposal, sampled: np.ndarray, counts: np.ndarray, time: float, pose
    ) -> np.ndarray:
        """IoU of each of the frame's planes with the track, 0 where the planes disagree."""
        config = self.config
        k = len(proposal.areas)
        if k == 0:
            return np.zeros(0)
        band_last = float(self.noise.band(np.array([last.centroid[2]]))[0])
        band = self.noise.band(proposal.centroids[:, 2]) + band_last
        if pose is not None and last.pose is not None:
            world_last = plane_to_world(last.plane, *last.pose)
            rotation, centre = pose
            angle, offset = plane_agreement(world_last, plane_to_world(proposal.planes, *pose),
                                            at=proposal.centroids @ np.asarray(rotation).T + centre)
            agree = (angle <= config.angle_deg) & (offset <= band + config.pose_error)
            if not agree.any():
                return np.zeros(k)
            return np.where(agree, self._reprojected_iou(last, sampled, counts, pose), 0.0)
        dt = abs(time - last.time)
        cosine = np.clip(proposal.planes[:, :3] @ last.plane[:3], -1.0, 1.0)
        angle = np.degrees(np.arccos(cosine))
        # Turning about its centre leaves a plane's distance from the camera unchanged;
        # moving changes it by at most the distance moved.
        offset = np.abs(proposal.planes[:, 3] - last.plane[3])
        agree = (angle <= config.angle_deg + config.max_turn_deg * dt) & (offset <= band + config.max_speed * dt)
        overlap = np.zeros(k)
        if not agree.any():
            return overlap
        previous = self.recent[last.position] == last.label
        for c in np.flatnonzero(agree).tolist():
            nearest = min(float(last.centroid[2]), float(proposal.centroids[c, 2]))
            reach = motion_px(self.camera, dt, config.max_turn_deg, config.max_speed, nearest)
            overlap[c] = shifted_iou(previous, sampled == c + 1, int(np.ceil(reach / STRIDE)))
        return overlap

    def _reprojected_iou(self, last: _Last, sampled: np.ndarray, counts: np.ndarray, pose) -> np.ndarray:
        """IoU of the track's last polygon, moved onto this frame, with each plane's mask (on
        the labels sampled every :data:`STRIDE` pixels; ``counts``: each plane's samples)."""
        k = len(counts)
        lifted = lift_polygon(last.outline, last.plane, self.camera, *last.pose)
        if not lifted.ok:
            return np.zeros(k)
        polygon = project_polygon(lifted.world, self.camera, *pose)
        if len(polygon) < 3 or not np.isfinite(polygon).all():
            return np.zeros(k)
        # Sampled pixel j has its centre where full pixel STRIDE * j has its own.
        top, left, window = fill_window((polygon - 0.5) / STRIDE + 0.5, *sampled.shape)
        rows, cols = window.shape
        covered = sampled[top : top + rows, left : left + cols][window]
        inter = np.bincount(covered, minlength=k + 1)[1 : k + 1]
        union = np.count_nonzero(window) + counts - inter
        return inter / np.maximum(union, 1)


def motion_px(camera: Camera, dt: float, max_turn_deg: float, max_speed: float, depth: float) -> float:
    """How far, in pixels, a surface's image can move in ``dt`` seconds: a turn of
    ``max_turn_deg * dt`` (at most 60 degrees) sweeps ``f tan(angle)``, a move of ``max_speed *
    dt`` shifts a surface ``depth`` metres away by ``f * distance / depth``.

    Parameters
    ----------
    camera : Camera
    dt : float
        Seconds.
    max_turn_deg, max_speed : float
        Degrees per second, metres per second.
    depth : float
        Metres (nearer surfaces move more); at least 0.1 m is assumed.

    Returns
    -------
    float
    """
    focal = max(abs(camera.fx), abs(camera.fy))
    turn = np.radians(min(max_turn_deg * dt, 60.0))
    return focal * (np.tan(turn) + max_speed * dt / max(depth, 0.1))


def shifted_iou(first: np.ndarray, second: np.ndarray, reach: int) -> float:
    """The largest IoU of two masks over the shifts of ``second`` by up to ``reach`` pixels
    along each axis (shift 0 included).

    Parameters
    ----------
    first, second : ndarray of bool, shape (H, W)
    reach : int
        >= 0.

    Returns
    -------
    float
        0 when either mask is empty.
    """
    area_first, area_second = int(np.count_nonzero(first)), int(np.count_nonzero(second))
    if area_first == 0 or area_second == 0:
        return 0.0
    rows, cols = np.flatnonzero(first.any(axis=1)), np.flatnonzero(first.any(axis=0))
    top, bottom, left, right = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    template = first[top:bottom, left:right].astype(np.float32)
    # The second mask around the first one's box, with ``reach`` pixels of zeros beyond the image.
    height, width = second.shape
    image = np.zeros((bottom - top + 2 * reach, right - left + 2 * reach), dtype=np.float32)
    r0, r1 = max(top - reach, 0), min(bottom + reach, height)
    c0, c1 = max(left - reach, 0), min(right + reach, width)
    image[r0 - (top - reach) : r1 - (top - reach), c0 - (left - reach) : c1 - (left - reach)] = second[r0:r1, c0:c1]
    inter = np.rint(cv2.matchTemplate(image, template, cv2.TM_CCORR)).astype(np.float64)  # pixel counts
    return float(np.max(inter / (area_first + area_second - inter)))


def link_proposals(
    proposals: list[FrameProposal],
    times: np.ndarray,
    config: LinkConfig,
    noise: NoiseSettings,
    camera: Camera,
    poses: list | None = None,
) -> list[np.ndarray]:
    """Track ids of every frame's planes (:class:`TrackLinker` over a whole list).

    Parameters
    ----------
    proposals : list of FrameProposal
        In frame order, ``position`` increasing.
    times : ndarray of float, shape (N,)
        Seconds.
    config : LinkConfig
    noise : NoiseSettings
    camera : Camera
    poses : list of (rotation, translation) or None, optional
        Per frame; None (or a None entry): link without poses.

    Returns
    -------
    list of ndarray of int64
    """
    linker = TrackLinker(config, noise, camera)
    return [
        linker.add(p, float(t), None if poses is None else poses[i])
        for i, (p, t) in enumerate(zip(proposals, times))
    ]

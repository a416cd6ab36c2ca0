"""The format-neutral sequence model every layout reader fills in.

Plain, immutable records: a layout reader (:mod:`annotate_rgbd.io.layouts`) turns a folder into a
:class:`Sequence`; nothing after it knows which layout the frames came from, except through the
fields below (``clock``, ``camera``, ``colour_camera``, ``poses``).
"""

from __future__ import annotations

import posixpath
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: The frames' timestamps are seconds (TUM RGB-D, ICL-NUIM, folders named by timestamps).
SECONDS = "seconds"
#: The frames' "timestamps" are frame numbers (ScanNet, 7-Scenes): frame ``i`` has time ``i``.
FRAME_NUMBERS = "frame numbers"


@dataclass(frozen=True)
class FrameList:
    """Timestamps and files of one stream, ordered by timestamp.

    Parameters
    ----------
    timestamps : ndarray of float64, shape (N,)
        Strictly increasing: seconds, or frame numbers (see :attr:`Sequence.clock`).
    files : tuple of str
        Paths relative to the sequence folder, as written in the list file (POSIX separators).
    """

    timestamps: np.ndarray
    files: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.files)


@dataclass(frozen=True)
class LayoutCamera:
    """The depth camera a layout states (a file of the sequence, or the dataset's documentation).

    Parameters
    ----------
    fx, fy, cx, cy : float
        Pinhole intrinsics of the depth images, pixels.
    depth_scale : float
        Raw depth units per metre.
    source : str
        Where the values come from, for the line that says they are used.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    depth_scale: float
    source: str

    def overrides(self) -> dict[str, float]:
        """The ``[camera]`` keys, as ``--set`` overrides (``"camera.fx" -> value``)."""
        return {f"camera.{key}": float(getattr(self, key)) for key in ("fx", "fy", "cx", "cy", "depth_scale")}

    def describe(self) -> str:
        """``fx 577.87, fy 577.87, cx 319.5, cy 239.5, depth_scale 1000``."""
        return ", ".join(f"{key} {getattr(self, key):g}" for key in ("fx", "fy", "cx", "cy", "depth_scale"))


@dataclass(frozen=True)
class ColourCamera:
    """The colour camera of a layout whose colour images are not on the depth grid (ScanNet).

    A depth pixel's point ``X_depth`` (metres, depth camera frame: x right, y down, z forward) is
    ``X_colour = R @ X_depth + t`` in the colour camera's frame, with ``[R | t]`` the top rows of
    ``depth_to_colour``, and lands on colour pixel ``(fx x / z + cx, fy y / z + cy)``.

    Parameters
    ----------
    fx, fy, cx, cy : float
        Pinhole intrinsics of the colour images, pixels.
    width, height : int
        Size of the colour images, pixels.
    depth_to_colour : ndarray of float64, shape (4, 4)
        Rigid transform from the depth camera's frame to the colour camera's, metres.
    source : str
        The files the values come from.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    depth_to_colour: np.ndarray = field(default_factory=lambda: np.eye(4))
    source: str = ""

    def on_depth_grid(self, camera: LayoutCamera | None, width: int, height: int) -> bool:
        """Whether colour and depth share one pixel grid: the depth images' size, the depth
        camera's intrinsics and no rotation or shift between the two (then nothing is to map)."""
        if camera is None or (self.width, self.height) != (width, height):
            return False
        same = np.allclose((self.fx, self.fy, self.cx, self.cy), (camera.fx, camera.fy, camera.cx, camera.cy), atol=1e-6)
        return bool(same and np.allclose(self.depth_to_colour, np.eye(4), atol=1e-9))

    def overrides(self) -> dict[str, object]:
        """The ``[colour_camera]`` keys, as ``--set`` overrides (``"colour_camera.fx" -> value``)."""
        values: dict[str, object] = {f"colour_camera.{key}": getattr(self, key) for key in ("fx", "fy", "cx", "cy")}
        values.update({"colour_camera.width": self.width, "colour_camera.height": self.height,
                       "colour_camera.extrinsic": np.asarray(self.depth_to_colour, dtype=np.float64).tolist()})
        return values

    def describe(self) -> str:
        """``1296x968, fx 1170.19, fy 1170.19, cx 647.75, cy 483.75, 2.1 cm and 0.3 degrees from the depth camera``."""
        rotation, shift = self.depth_to_colour[:3, :3], self.depth_to_colour[:3, 3]
        angle = np.degrees(np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1.0, 1.0)))
        return (f"{self.width}x{self.height}, " + ", ".join(f"{key} {getattr(self, key):g}" for key in ("fx", "fy", "cx", "cy"))
                + f", {100 * np.linalg.norm(shift):.1f} cm and {angle:.1f} degrees from the depth camera")


@dataclass(frozen=True)
class Sequence:
    """An RGB-D sequence: where it is, its streams and what its layout says about them.

    Parameters
    ----------
    root : Path
        The sequence folder.
    rgb : FrameList or None
        The colour images; ``None`` in a depth-only folder (``propose`` only).
    depth : FrameList
        The depth images.
    layout : str
        The layout's name, for messages ("TUM RGB-D", "ScanNet", ...).
    clock : str
        :data:`SECONDS` or :data:`FRAME_NUMBERS`: what the timestamps count.
    camera : LayoutCamera or None
        The depth camera the layout states (used when no configuration is given).
    colour_camera : ColourCamera or None
        The colour camera, when the layout states one (ScanNet's ``intrinsic_color.txt``,
        ``extrinsic_color.txt``, ``extrinsic_depth.txt``); ``None``: colour and depth share the
        depth grid (TUM, ICL-NUIM; 7-Scenes is not calibrated).
    poses : Path or None
        The layout's own per-frame camera-to-world poses (a folder of pose files), read by
        :func:`annotate_rgbd.io.poses.read_trajectory` like a ``--poses`` argument.
    notes : tuple of str
        What the reader noticed and a user should know (one line each).
    """

    root: Path
    rgb: FrameList | None
    depth: FrameList
    layout: str = "TUM RGB-D"
    clock: str = SECONDS
    camera: LayoutCamera | None = None
    colour_camera: ColourCamera | None = None
    poses: Path | None = None
    notes: tuple[str, ...] = ()

    def image_folders(self) -> list[Path]:
        """The folders that hold the sequence's images (depth and colour), resolved, sorted."""
        streams = [self.depth] + ([self.rgb] if self.rgb is not None else [])
        parents = {posixpath.dirname(name) for stream in streams for name in stream.files}
        return sorted({(self.root / parent).resolve() for parent in parents})

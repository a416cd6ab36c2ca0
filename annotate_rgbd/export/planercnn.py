"""PlaneRCNN's ScanNet layout: ``planes.npy`` and ``segmentation/<frame>.png`` of one scene.

PlaneRCNN (``datasets/scannet_scene.py``) reads a scene's ``annotation/planes.npy`` (N x 3, one
plane per row: normal times offset, world frame) and per frame ``annotation/segmentation/<i>.png``,
a 24-bit colour PNG whose pixel value ``(R * 65536 + G * 256 + B) // 100 - 1`` is the row of the
pixel's plane in ``planes.npy``, -1 where no plane is (it also skips the value of white,
167771). Here row ``k`` is the run's plane ``k + 1`` (``planes.csv``), so a pixel of plane ``p``
holds the value ``100 p`` and a pixel of no plane 0; a plane the run never kept on a frame with a
pose has the row ``0 0 0``, which the loader skips. The layout's world frame needs the camera
poses: the run's trajectory or one given to the export. A plane through the world origin (a floor
at ``z = 0``) has a row of length 0, which holds no normal: a warning names such planes.

The segmentation is on the depth grid (the mask's pixels). PlaneRCNN's loader also reads
``plane_info.npy`` (ScanNet's semantic labels per plane), which this export does not make.
"""

from __future__ import annotations

import io
import logging
from pathlib import Path

import numpy as np

from annotate_rgbd.errors import InputError
from annotate_rgbd.io.writer import write_bytes_atomic, write_png
from .frames import ExportRun
from .planes import foot_vector, scene_planes

log = logging.getLogger("annotate_rgbd")

#: A world plane nearer the origin than this (m) has a row ``normal * offset`` too short to hold
#: its normal: PlaneRCNN's loader takes the normal as the row divided by its length.
MIN_OFFSET_M = 0.02

#: Segmentation values are ``100 * (row + 1)``; the loader takes ``167771`` (white) for no plane.
VALUE_STEP = 100
MAX_PLANES = 0xFFFFFF // VALUE_STEP - 1


def encode_segmentation(ids: np.ndarray) -> np.ndarray:
    """Plane ids as PlaneRCNN's colour segmentation.

    Parameters
    ----------
    ids : ndarray of int, shape (H, W)
        Plane ids (``planes.csv``), 0 for no plane.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        RGB with ``R * 65536 + G * 256 + B = 100 * id``.
    """
    value = np.asarray(ids, dtype=np.int64) * VALUE_STEP
    return np.stack([(value >> 16) & 0xFF, (value >> 8) & 0xFF, value & 0xFF], axis=-1).astype(np.uint8)


def check_planercnn(run: ExportRun) -> None:
    """Whether the run fits the layout, before anything is written.

    Raises
    ------
    InputError
        No frame has a pose (the layout's planes are in the world frame), or more planes than
        the segmentation's 24 bits hold.
    """
    if not any(frame.pose is not None for frame in run.frames):
        raise InputError(run.run_dir / "report.json", "the PlaneRCNN layout holds world-frame planes, and no written "
                         "frame has a camera pose: give the camera trajectory with --poses")
    if run.report.n_planes > MAX_PLANES:
        raise InputError(run.run_dir / "report.json", f"{run.report.n_planes} planes: PlaneRCNN's segmentation holds "
                         f"at most {MAX_PLANES}")


def write_planercnn(run: ExportRun, out: Path) -> list[Path]:
    """Write ``planes.npy`` and ``segmentation/<frame>.png``.

    Parameters
    ----------
    run : ExportRun
    out : Path
        The export folder (a scene's ``annotation/`` folder in PlaneRCNN's layout).

    Returns
    -------
    list of Path
        The files written.

    Raises
    ------
    InputError
        No frame has a pose (the layout's planes are in the world frame), or more planes than
        the segmentation's 24 bits hold.
    """
    check_planercnn(run)
    planes = np.zeros((run.report.n_planes, 3), dtype=np.float64)
    world = scene_planes(run)
    for plane, equation in world.items():
        planes[plane - 1] = foot_vector(equation)
    near = sorted(plane for plane, equation in world.items() if abs(float(equation[3])) < MIN_OFFSET_M)
    if near:
        log.warning("%s: plane%s %s pass%s within %g cm of the world origin: PlaneRCNN's row normal * offset "
                    "cannot hold %s orientation (its loader reads the normal as the row over its length); a "
                    "trajectory whose origin lies off every plane avoids it", run.run_dir / "report.json",
                    "s" if len(near) > 1 else "", ", ".join(map(str, near)), "" if len(near) > 1 else "es",
                    100 * MIN_OFFSET_M, "their" if len(near) > 1 else "its")
    buffer = io.BytesIO()
    np.save(buffer, planes)
    written = [out / "planes.npy"]
    write_bytes_atomic(written[0], buffer.getvalue())
    for frame in run.frames:
        path = out / "segmentation" / f"{frame.name}.png"
        write_png(path, encode_segmentation(run.plane_ids(frame)))
        written.append(path)
    return written

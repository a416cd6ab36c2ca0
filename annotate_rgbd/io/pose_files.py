"""Per-frame pose files: one 4 x 4 camera-to-world matrix per frame, as ScanNet and 7-Scenes ship.

* ScanNet: ``pose/<frame>.txt`` (``--poses scene/pose`` or the scene folder itself); a pose whose
  values are ``-inf`` (ScanNet writes them where its tracking failed) means the frame has none.
* 7-Scenes: ``frame-000000.pose.txt`` beside the images of the sequence folder.

Each matrix maps the camera's frame to the world's (``X_world = R @ X_camera + t``, metres) and
must be a rigid transform: an orthonormal rotation and a last row ``0 0 0 1``; anything else is
one error line naming the file. The frame number is taken from the file name.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from annotate_rgbd.errors import InputError
from annotate_rgbd.io.layouts.lists import numbered_files, read_matrix
from annotate_rgbd.io.rotations import first_rigid_problem, matrix_quaternions

#: (name of the form, file names with the frame number as group 1), tried in this order.
FORMS = (
    ("ScanNet pose files", r"(\d+)\.txt"),
    ("7-Scenes pose files", r"frame-(\d+)\.pose\.txt"),
)


class FilePoses(NamedTuple):
    """The poses of a folder of pose files.

    Parameters
    ----------
    form : str
        The form's name (:data:`FORMS`).
    frames : ndarray of float64, shape (N,)
        Frame numbers of the frames with a pose, increasing.
    translations : ndarray of float64, shape (N, 3)
    quaternions : ndarray of float64, shape (N, 4)
        Unit quaternions ``(x, y, z, w)``.
    without_pose : int
        Files whose matrix holds ``-inf`` or NaN: frames without a pose.
    """

    form: str
    frames: np.ndarray
    translations: np.ndarray
    quaternions: np.ndarray
    without_pose: int


def read_pose_files(folder: Path) -> FilePoses:
    """Read a folder of per-frame pose files (a ScanNet scene's ``pose/`` is found in the scene).

    Raises
    ------
    InputError
        No pose files, more than ``MAX_FRAMES``, an unreadable or malformed file, a matrix that
        is not a rigid transform, or no frame with a pose at all.
    """
    folder = Path(folder)
    if (folder / "pose").is_dir():
        folder = folder / "pose"
    for form, pattern in FORMS:
        listing = numbered_files(folder, folder, pattern, pattern)
        if len(listing):
            break
    else:
        raise InputError(folder, "holds no pose files (ScanNet pose/<frame>.txt, 7-Scenes frame-000000.pose.txt); "
                         "a trajectory file is TUM (timestamp tx ty tz qx qy qz qw) or KITTI (12 numbers a line)")
    matrices = np.empty((len(listing), 4, 4))
    for k, name in enumerate(listing.files):
        matrices[k] = read_matrix(folder / name, finite=False)
    finite = np.isfinite(matrices).all(axis=(1, 2))
    if not finite.any():
        raise InputError(folder, f"every one of the {len(listing)} {form} holds -inf or NaN: no frame has a pose")
    row, problem = first_rigid_problem(matrices[finite])
    if problem is not None:
        name = np.asarray(listing.files, dtype=object)[finite][row]
        raise InputError(folder / name, f"{problem} (the pose of a frame, camera to world)")
    kept = matrices[finite]
    return FilePoses(form, listing.timestamps[finite], np.ascontiguousarray(kept[:, :3, 3]),
                     matrix_quaternions(kept[:, :3, :3]), int(np.count_nonzero(~finite)))

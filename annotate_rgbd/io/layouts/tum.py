"""TUM RGB-D and ICL-NUIM (TUM format) layouts, and the depth-only folders ``propose`` reads.

* ``rgb.txt`` and ``depth.txt`` (TUM): ``#`` comment lines, then ``timestamp path`` per line;
* ``associations.txt`` (ICL-NUIM in TUM format): ``depth_ts depth_path rgb_ts rgb_path`` per
  line (TUM's ``associate.py`` output: ``rgb_ts rgb_path depth_ts depth_path`` is recognised by
  the folder names in the paths);
* ``rgb/`` and ``depth/`` folders, whose file names (without extension) are the timestamps;
* depth only (``propose``): ``depth.txt`` without ``rgb.txt``, or ``depth/`` without ``rgb/``.

Frames are ordered by their timestamp as a number: sorting names as text, or by the integer part
of the timestamp only, mixes up frames within the same second (a pitfall of the original EVOPS
tooling). Timestamps are seconds; depth is in units of ``depth_scale`` per metre (5000 in TUM
and ICL-NUIM), which the layout does not state: the configuration gives it.
"""

from __future__ import annotations

from pathlib import Path

from annotate_rgbd.errors import InputError
from .lists import (
    IMAGE_SUFFIXES, MAX_FRAMES, check_inside, frame_list, listed_path, parse_timestamp, read_rows, timestamp_at,
    top_folder, unique_entries,
)
from .model import FrameList, Sequence

#: The motion-capture trajectory a TUM RGB-D sequence folder holds (its clock may be offset from
#: the camera's, so it is read only when given as ``--poses``).
TRAJECTORY = "groundtruth.txt"


def is_tum_lists(root: Path) -> bool:
    # exists(), not is_file(): a FIFO or a folder named rgb.txt is refused by name, not skipped.
    return (root / "rgb.txt").exists() and (root / "depth.txt").exists()


def read_tum_lists(root: Path) -> Sequence:
    """A TUM RGB-D folder: ``rgb.txt`` and ``depth.txt``."""
    check_inside(root, ("rgb.txt", "depth.txt"))
    return Sequence(root, read_frame_list(root / "rgb.txt"), read_frame_list(root / "depth.txt"), "TUM RGB-D")


def is_associations(root: Path) -> bool:
    return (root / "associations.txt").exists()


def read_icl(root: Path) -> Sequence:
    """An ICL-NUIM folder in TUM format (or ``associate.py`` output): ``associations.txt``."""
    check_inside(root, ("associations.txt",))
    rgb, depth = read_associations(root / "associations.txt")
    return Sequence(root, rgb, depth, "ICL-NUIM (associations.txt)")


def is_tum_folders(root: Path) -> bool:
    return (root / "rgb").is_dir() and (root / "depth").is_dir()


def read_tum_folders(root: Path) -> Sequence:
    """``rgb/`` and ``depth/`` folders of images named by their timestamps."""
    check_inside(root, ("rgb", "depth"))
    rgb = list_image_folder(root / "rgb", root)
    return Sequence(root, rgb, list_image_folder(root / "depth", root), "rgb/ and depth/ folders")


def is_depth_list(root: Path) -> bool:
    return (root / "depth.txt").exists()


def read_depth_list(root: Path) -> Sequence:
    """Depth only: ``depth.txt`` without ``rgb.txt``."""
    check_inside(root, ("depth.txt",))
    return Sequence(root, None, read_frame_list(root / "depth.txt"), "depth.txt (depth only)")


def is_depth_folder(root: Path) -> bool:
    return (root / "depth").is_dir()


def read_depth_folder(root: Path) -> Sequence:
    """Depth only: a ``depth/`` folder of images named by their timestamps."""
    check_inside(root, ("depth",))
    return Sequence(root, None, list_image_folder(root / "depth", root), "depth/ folder (depth only)")


def read_frame_list(path: Path) -> FrameList:
    """Read a TUM ``rgb.txt`` / ``depth.txt``: ``#`` comments, then ``timestamp path`` lines."""
    rows = read_rows(path, min_columns=2)
    return frame_list(path, [(timestamp_at(path, line, row[0]), listed_path(path, line, row[1]), line) for line, row in rows])


def read_associations(path: Path) -> tuple[FrameList, FrameList]:
    """Read an ICL-NUIM / ``associate.py`` ``associations.txt`` into RGB and depth lists.

    Each line pairs one depth and one RGB frame; which pair of columns is which is told by the
    folder in the path (``depth/...`` or ``rgb/...``), since both orders are in use.
    """
    rows = read_rows(path, min_columns=4)
    rgb, depth = [], []
    for line, row in rows:
        first_ts, second_ts = timestamp_at(path, line, row[0]), timestamp_at(path, line, row[2])
        pairs = [(first_ts, listed_path(path, line, row[1])), (second_ts, listed_path(path, line, row[3]))]
        if "depth" in top_folder(row[3]).lower() or "rgb" in top_folder(row[1]).lower():
            pairs.reverse()
        (d_ts, d_file), (r_ts, r_file) = pairs
        depth.append((d_ts, d_file, line))
        rgb.append((r_ts, r_file, line))
    return frame_list(path, unique_entries(rgb)), frame_list(path, unique_entries(depth))


def list_image_folder(folder: Path, root: Path) -> FrameList:
    """Image files in ``folder`` with their name (without extension) as the timestamp."""
    entries = []
    for file in folder.iterdir():
        if file.suffix.lower() not in IMAGE_SUFFIXES:
            continue
        try:
            ts = parse_timestamp(file.stem)
        except ValueError as exc:
            raise InputError(file, f"image name {exc} (expected e.g. 1305031102.175304.png)") from None
        entries.append((ts, file.relative_to(root).as_posix(), 0))
        if len(entries) > MAX_FRAMES:
            raise InputError(folder, f"more than {MAX_FRAMES} images; at most {MAX_FRAMES} frames are read")
    return frame_list(folder, entries)

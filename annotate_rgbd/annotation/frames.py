"""Where each annotated frame is in the RGB image list.

CVAT numbers frames absolutely (``start_frame + i * step``). In a "CVAT for video 1.1" export the
number is the index of the image in the RGB list (``rgb.txt`` order, by timestamp). In a
"CVAT for images 1.1" export each image names its file, which identifies the RGB frame exactly.
"""

from __future__ import annotations

from pathlib import PurePosixPath

from .model import Annotation
from annotate_rgbd.errors import InputError
from annotate_rgbd.io.sequence import FrameList


def rgb_indices(annotation: Annotation, rgb: FrameList, offset: int = 0) -> tuple[dict[int, int], list[str]]:
    """Map the annotation's frame numbers to indices in the RGB list.

    Parameters
    ----------
    annotation : Annotation
        One export.
    rgb : FrameList
        The sequence's RGB frames.
    offset : int
        RGB index of the export's frame 0 (for an annotation part that starts later in the
        sequence); ignored for frames identified by image name.

    Returns
    -------
    mapping : dict of int to int
        CVAT frame number -> RGB index, for the frames found in the sequence.
    missing : list of str
        One line per frame that is not in the sequence.

    Raises
    ------
    InputError
        None of the annotated frames is in the sequence.
    """
    mapping: dict[int, int] = {}
    missing: list[str] = []
    if annotation.image_names:
        by_name = _name_index(rgb)
        unknown = []
        for frame in annotation.frames:
            name = annotation.image_names.get(frame)
            index = _lookup(by_name, name) if name is not None else None
            if index is None:
                unknown.append((frame, name))
            else:
                mapping[frame] = index
        if len(unknown) == 1:
            missing.append(f"frame {unknown[0][0]}: image {unknown[0][1]!r} is not in the RGB list")
        elif unknown:
            names = ", ".join(repr(name) for _, name in unknown[:3]) + (", ..." if len(unknown) > 3 else "")
            missing.append(f"{frame_ranges([f for f, _ in unknown])}: their images ({names}) are not in the RGB list")
    else:
        beyond = [frame for frame in annotation.frames if not 0 <= frame + offset < len(rgb)]
        mapping = {frame: frame + offset for frame in annotation.frames if 0 <= frame + offset < len(rgb)}
        if len(beyond) == 1:
            missing.append(f"frame {beyond[0]}: RGB index {beyond[0] + offset} is beyond the {len(rgb)} RGB frames")
        elif beyond:
            shift = f" (frame {'-' if offset < 0 else '+'} {abs(offset)})" if offset else ""
            missing.append(f"{frame_ranges(beyond)}: their RGB indices{shift} are beyond the {len(rgb)} RGB frames")
    if not mapping:
        raise InputError(annotation.path, f"no annotated frame is in the sequence ({missing[0]})")
    return mapping, missing


def frame_ranges(frames: list[int], shown: int = 3) -> str:
    """Frame numbers in a line: ``"frames 11-15, 219-220 (7 frames)"``; after ``shown`` runs of
    consecutive numbers, ``", ..."``."""
    if len(frames) == 1:
        return f"frame {frames[0]}"
    runs: list[list[int]] = []
    for frame in sorted(frames):
        if runs and frame == runs[-1][1] + 1:
            runs[-1][1] = frame
        else:
            runs.append([frame, frame])
    text = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:shown])
    return f"frames {text}{', ...' if len(runs) > shown else ''} ({len(frames)} frames)"


def _name_index(rgb: FrameList) -> dict[str, int]:
    """RGB index by relative path, by file name and by file name without extension."""
    index: dict[str, int] = {}
    for key_of in (lambda p: p.as_posix(), lambda p: p.name, lambda p: p.stem):
        for i, file in enumerate(rgb.files):
            index.setdefault(key_of(PurePosixPath(file)), i)
    return index


def _lookup(by_name: dict[str, int], name: str) -> int | None:
    path = PurePosixPath(name.replace("\\", "/"))
    for key in (path.as_posix(), path.name, path.stem):
        if key in by_name:
            return by_name[key]
    return None

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
        for frame in annotation.frames:
            name = annotation.image_names.get(frame)
            index = _lookup(by_name, name) if name is not None else None
            if index is None:
                missing.append(f"frame {frame}: image {name!r} is not in the RGB list")
            else:
                mapping[frame] = index
    else:
        for frame in annotation.frames:
            index = frame + offset
            if 0 <= index < len(rgb):
                mapping[frame] = index
            else:
                missing.append(f"frame {frame}: RGB index {index} is beyond the {len(rgb)} RGB frames")
    if not mapping:
        raise InputError(annotation.path, f"no annotated frame is in the sequence ({missing[0]})")
    return mapping, missing


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

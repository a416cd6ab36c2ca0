"""A run's configuration with what the sequence's layout states: its depth camera and, when
colour lies on a grid of its own, its colour camera.

``cvat2mask``, ``propose`` and each scene of ``batch`` load their configuration here: without a
configuration file (``--config``, a manifest scene's ``config``), a ScanNet export brings its
``intrinsic_depth.txt`` (``[camera]``) and its ``intrinsic_color.txt`` with the colour images'
size and extrinsics (``[colour_camera]``), a 7-Scenes folder its documented camera; each is
said in one ``info:`` line, and overrides (``--set``) come after them.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Mapping

from annotate_rgbd.io.images import png_size, read_bytes
from annotate_rgbd.io.sequence import read_sequence
from .settings import COMMAND_LINE, DEFAULT_CAMERA, Config, load_config

log = logging.getLogger("annotate_rgbd")


def load_run_config(sequence_dir: str | Path, source: str | Path | None,
                    overrides: Mapping[str, Any] | None = None, overrides_from: str = COMMAND_LINE) -> Config:
    """The run's configuration: ``source`` (else the defaults, then the layout's cameras) with
    the overrides.

    Parameters
    ----------
    sequence_dir : str or Path
        The sequence folder (any layout, depth-only folders too).
    source : str or Path or None
        A TOML file or preset name (:func:`annotate_rgbd.config.settings.load_config`); given,
        the layout's cameras are not used.
    overrides : mapping of str to value, optional
        ``"section.key" -> value``, applied last.
    overrides_from : str
        Where the overrides come from, for the messages about them (a manifest scene's ``set``).

    Returns
    -------
    Config

    Raises
    ------
    InputError
        An unreadable sequence or layout file, a bad configuration.
    """
    overrides = dict(overrides or {})
    if source is None:
        sequence = read_sequence(sequence_dir, need_rgb=False)
        for note in sequence.notes:
            log.warning("%s", note)
        if sequence.camera is not None:
            log.info("camera: %s (%s layout): %s; give --config for another", sequence.camera.source,
                     sequence.layout, sequence.camera.describe())
            overrides = {**sequence.camera.overrides(), **overrides}
        else:
            unread = sorted(Path(sequence_dir).glob("*.toml"))
            if unread:  # a camera file beside the frames is most likely the sequence's own
                camera = DEFAULT_CAMERA
                log.warning("%s is not read (no --config): the default camera is used (fx %g, fy %g, cx %g, cy %g, "
                            "%g per metre); give --config %s for that file", unread[0], camera.fx, camera.fy,
                            camera.cx, camera.cy, camera.depth_scale, unread[0])
        colour = sequence.colour_camera
        if colour is not None and not colour.on_depth_grid(sequence.camera, *_depth_size(sequence)):
            log.info("colour camera: %s (%s layout): %s; shapes are drawn on it", colour.source, sequence.layout,
                     colour.describe())
            overrides = {**colour.overrides(), **overrides}
    return load_config(source, overrides, overrides_from)


def _depth_size(sequence) -> tuple[int, int]:
    """(width, height) of the sequence's first depth image, from its PNG header."""
    path = sequence.root / sequence.depth.files[0]
    return png_size(read_bytes(path), path)

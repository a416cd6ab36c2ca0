"""Command-line texts for the configuration: ``--set SECTION.KEY=VALUE`` and ``--part FILE:OFFSET``
(also a batch manifest's ``set`` and ``parts`` lists), read into what
:func:`annotate_rgbd.config.settings.load_config` and the annotation parts take."""

from __future__ import annotations

from typing import Any, Iterable

from annotate_rgbd.errors import InputError
from .toml_input import NestedTooDeep, read_toml


def parse_settings(settings: Iterable[str]) -> dict[str, Any]:
    """Read ``--set SECTION.KEY=VALUE`` overrides (also a manifest's ``set`` list).

    Parameters
    ----------
    settings : iterable of str
        ``"section.key=value"`` texts. A value is read as a TOML value (numbers, booleans,
        lists, quoted strings); one that is not valid TOML is kept as the plain text.

    Returns
    -------
    dict of str to value
        ``"section.key" -> value``, the ``overrides`` of :func:`~annotate_rgbd.config.settings.load_config`.

    Raises
    ------
    InputError
        A text without ``=`` or without a ``.`` in its key.
    """
    overrides = {}
    for setting in settings:
        key, sep, text = setting.partition("=")
        if not sep or "." not in key:
            raise InputError(None, f"--set {setting!r}: expected SECTION.KEY=VALUE, e.g. ransac.distance_threshold=0.01")
        try:
            value = read_toml(f"v = {text}", None)["v"]
        except NestedTooDeep as exc:
            raise InputError(None, f"--set {key.strip()}: {exc.message}") from None
        except InputError:
            value = text
        overrides[key.strip()] = value
    return overrides


def parse_part_offsets(parts: Iterable[str]) -> dict[str, int]:
    """Read ``--part FILE:OFFSET`` texts (also a manifest's ``parts`` list), the command-line
    form of a ``[[parts]]`` entry (:class:`~annotate_rgbd.config.annotation.PartConfig`).

    Parameters
    ----------
    parts : iterable of str
        ``"file:offset"`` texts; the file name may itself contain ``:``, the offset is what
        follows the last one.

    Returns
    -------
    dict of str to int
        File -> RGB index of the part's frame 0.

    Raises
    ------
    InputError
        A text without a file name or without a non-negative integer offset.
    """
    offsets = {}
    for text in parts:
        file, sep, offset = text.rpartition(":")
        if not sep or not file or not offset.strip().isdigit():
            raise InputError(None, f"--part {text!r}: expected FILE:OFFSET, e.g. --part 950-1900.xml:950")
        offsets[file] = int(offset)
    return offsets

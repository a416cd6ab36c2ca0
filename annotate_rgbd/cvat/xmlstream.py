"""Safe, incremental XML reading and the wording of its errors.

The file is parsed incrementally with entity expansion, DTD loading and network access
disabled; a document that declares a DTD is refused. Each top-level element is freed once read,
so a large export never builds up in memory. Attribute parsers name the element, its line and
the attribute in every error.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from lxml import etree

from annotate_rgbd.errors import InputError

from .archive import XmlSource
from .format import POINTS


def top_level_elements(source: XmlSource) -> Iterator[etree._Element]:
    """Yield each complete child of the root ``<annotations>`` and free it afterwards.

    A plain file is read by libxml2 itself; a zip member as the archive's bounded stream.
    """
    if source.member is None:
        yield from _top_level_elements(source, str(source.file))
    else:
        with source.open() as stream:
            yield from _top_level_elements(source, stream)


def _top_level_elements(source: XmlSource, stream) -> Iterator[etree._Element]:
    """:func:`top_level_elements` on ``stream``, a file name or a binary file."""
    path = source.path
    events = etree.iterparse(
        stream,
        events=("start", "end"),
        resolve_entities=False,
        no_network=True,
        load_dtd=False,
        dtd_validation=False,
        huge_tree=False,
        remove_comments=True,
        remove_pis=True,
    )
    depth = 0
    started = False  # whether the root element began (else a syntax error is no truncation)
    root = None  # checked at the next event, so that a file cut inside its root tag reads as cut
    try:
        for event, element in events:
            if root is not None:
                _check_root(root, path)
                root = None
            if event == "start":
                depth += 1
                if depth == 1:
                    root, started = element, True
                continue
            depth -= 1
            if depth == 1:
                yield element
                # Drop what was read so a large export never builds up in memory.
                element.clear(keep_tail=False)
                parent = element.getparent()
                while element.getprevious() is not None:
                    del parent[0]
    except etree.XMLSyntaxError as error:
        raise InputError(path, _syntax_message(error, source, started)) from None
    except OSError as error:
        raise InputError(path, f"cannot read the file: {error.strerror or error}") from None


def _syntax_message(error: etree.XMLSyntaxError, source: XmlSource, started: bool) -> str:
    """libxml2's complaint, reworded where its own words mislead the user.

    An error on the last line of a document whose root began but that does not end with
    ``</annotations>`` is reported as a cut-off file, whatever libxml2 stumbled on there.
    """
    line = max(error.lineno or 1, 1)
    message = re.sub(r", line \d+, column \d+$", "", (error.msg or "not well-formed").strip())
    message = " ".join(message.split())  # libxml2 may end a message with a newline
    if message.startswith("Excessive depth in document"):
        # libxml2's limit without XML_PARSE_HUGE; CVAT exports nest about 6 levels deep.
        return f"malformed XML at line {line}: elements nested more than 256 levels deep"
    last_line, ending = _last_line(source) if started else (0, b"")
    if started and line >= last_line and not ending.endswith(b"</annotations>"):
        return (
            f"the file ends at line {last_line} before </annotations> (a truncated export or "
            f"download?): {message}"
        )
    return f"malformed XML at line {line}: {message}"


def _last_line(source: XmlSource) -> tuple[int, bytes]:
    """Number of the last non-blank line and the file's last bytes, whitespace stripped."""
    newlines, tail = 0, b""
    with source.open() as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            newlines += chunk.count(b"\n")
            tail = (tail + chunk)[-4096:]
    stripped = tail.rstrip()
    return newlines + 1 - tail[len(stripped):].count(b"\n"), stripped


def _check_root(root: etree._Element, path: Path) -> None:
    if root.getroottree().docinfo.doctype:
        raise InputError(
            path, "the file declares a DTD (<!DOCTYPE>), which CVAT exports never do: refused"
        )
    if root.tag != "annotations":
        raise InputError(
            path, f"not a CVAT XML export: the root element is <{root.tag}>, not <annotations>"
        )


def where(element: etree._Element) -> str:
    return f"<{element.tag}> at line {element.sourceline}"


def attr(element: etree._Element, name: str, path: Path) -> str:
    value = element.get(name)
    if value is None:
        raise InputError(path, f"{where(element)}: attribute {name!r} is missing")
    return value


def int_attr(element: etree._Element, name: str, path: Path, default: int | None = None) -> int:
    return _number_attr(element, name, path, int, "an integer", default)


def float_attr(
    element: etree._Element, name: str, path: Path, default: float | None = None
) -> float:
    return _number_attr(element, name, path, float, "a number", default)


def _number_attr(element, name, path, parse, kind, default):
    """Attribute ``name`` parsed by ``parse``; ``default`` when absent (if given)."""
    value = element.get(name)
    if value is None and default is not None:
        return default
    value = attr(element, name, path)
    try:
        return parse(value)
    except ValueError:
        raise InputError(path, f"{where(element)}: attribute {name}={value!r} is not {kind}") from None


def points_attr(element: etree._Element, path: Path) -> np.ndarray:
    """``points="x,y;x,y;..."`` as an (N, 2) array."""
    text = attr(element, "points", path).strip().strip(";")
    if not POINTS.fullmatch(text):
        raise InputError(path, f"{where(element)}: attribute 'points' is not a list of x,y pairs")
    values = text.replace(";", ",").split(",")
    try:
        points = np.fromiter(map(float, values), dtype=np.float64, count=len(values))
    except ValueError:
        raise InputError(
            path, f"{where(element)}: attribute 'points' holds a non-number"
        ) from None
    return points.reshape(-1, 2)


def runs_attr(element: etree._Element, path: Path) -> np.ndarray:
    text = attr(element, "rle", path)
    try:
        return np.array([run for run in text.split(",") if run.strip()], dtype=np.int64)
    except ValueError:
        raise InputError(path, f"{where(element)}: attribute 'rle' holds a non-integer") from None


def flag(element: etree._Element, name: str) -> bool:
    return element.get(name) in ("1", "true", "True")


def int_text(element: etree._Element, path: Path) -> int:
    text = (element.text or "").strip()
    try:
        return int(text)
    except ValueError:
        raise InputError(path, f"{where(element)}: {text!r} is not an integer") from None

"""Fuzzing the CVAT reader: whatever the bytes, :func:`read_cvat` returns a usable annotation or
raises :class:`InputError` with one line naming the file; never another exception, never a hang.

Two generators: structured exports built from CVAT's own vocabulary with hostile values, and
byte-level mutations of a valid export. CI runs a few hundred examples (a few seconds); set
``ANNOTATE_RGBD_FUZZ_EXAMPLES`` for a longer run.
"""

from __future__ import annotations

import os
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from annotate_rgbd.annotation.model import Annotation
from annotate_rgbd.cvat import read_cvat
from annotate_rgbd.errors import InputError

EXAMPLES = int(os.environ.get("ANNOTATE_RGBD_FUZZ_EXAMPLES", "150"))
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=2000,  # ms per example: a hang or a quadratic blow-up fails
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    database=None,
)

NUMBERS = st.one_of(
    st.integers(-5, 60).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["", " ", "1e400", "-0", "1_0", "0x10", "9" * 30, "nan", "١٢", "1,5", "  3  "]),
)
POINTS = st.one_of(
    st.lists(st.tuples(NUMBERS, NUMBERS), min_size=0, max_size=8).map(lambda pts: ";".join(f"{x},{y}" for x, y in pts)),
    st.text(alphabet="0123456789.,;-e ", max_size=30),
)
SHAPE_KINDS = ["polygon", "box", "mask", "polyline", "points", "ellipse", "cuboid", "skeleton", "tag", "star"]
ATTRIBUTES = ["frame", "keyframe", "outside", "occluded", "points", "xtl", "ytl", "xbr", "ybr", "rotation",
              "z_order", "rle", "left", "top", "width", "height", "label", "group_id"]


@st.composite
def shape_xml(draw, video: bool) -> str:
    kind = draw(st.sampled_from(SHAPE_KINDS))
    values = {
        "label": draw(st.sampled_from(["wall", "floor", "", "a b"])),
        "frame": draw(NUMBERS) if video else None,
        "outside": draw(st.sampled_from(["0", "1", "true"])),
        "points": draw(POINTS),
        "rle": draw(st.lists(st.integers(-2, 30), max_size=8).map(lambda r: ", ".join(map(str, r)))),
    }
    for name in draw(st.lists(st.sampled_from(ATTRIBUTES), max_size=10)):
        values[name] = draw(NUMBERS)
    attributes = " ".join(f"{k}={quoteattr(v)}" for k, v in values.items() if v is not None)
    return f"<{kind} {attributes}/>"


@st.composite
def structured_export(draw) -> str:
    video = draw(st.booleans())
    meta = ""
    if draw(st.booleans()):
        start, stop = draw(NUMBERS), draw(NUMBERS)
        step = draw(st.sampled_from(["", "step=2", "step=0", "size=3", "step=x"]))
        size = "<original_size><width>40</width><height>30</height></original_size>" if draw(st.booleans()) else ""
        tag = draw(st.sampled_from(["task", "job"]))
        meta = (f"<meta><{tag}><start_frame>{start}</start_frame><stop_frame>{stop}</stop_frame>"
                f"<frame_filter>{step}</frame_filter>{size}</{tag}></meta>")
    items = []
    for _ in range(draw(st.integers(0, 4))):
        shapes = "".join(draw(st.lists(shape_xml(video), max_size=4)))
        if video:
            items.append(f'<track id="{draw(NUMBERS)}" label="wall">{shapes}</track>')
        else:
            items.append(f'<image id="{draw(NUMBERS)}" name="{draw(st.sampled_from(["a.png", "../../etc/passwd", "/abs/b.png"]))}" '
                         f'width="{draw(NUMBERS)}" height="30">{shapes}</image>')
    version = draw(st.sampled_from(["<version>1.1</version>", "<version>2</version>", ""]))
    root = draw(st.sampled_from(["annotations", "annotations", "dataset"]))
    return f'<?xml version="1.0"?>\n<{root}>{version}{meta}\n' + "\n".join(items) + f"\n</{root}>\n"


VALID = (
    b'<?xml version="1.0" encoding="utf-8"?>\n<annotations><version>1.1</version><meta><task><start_frame>0</start_frame>'
    b"<stop_frame>3</stop_frame><frame_filter></frame_filter><original_size><width>40</width><height>30</height>"
    b'</original_size></task></meta>\n<track id="0" label="wall" source="manual">'
    b'<polygon frame="0" keyframe="1" outside="0" occluded="0" points="1.00,1.00;9.00,1.00;5.00,7.00" z_order="0"/>'
    b'<box frame="2" keyframe="1" outside="0" occluded="0" xtl="2" ytl="2" xbr="30" ybr="25" z_order="0"/>'
    b'<mask frame="3" keyframe="1" outside="0" occluded="0" rle="0, 4" left="1" top="1" width="2" height="2" z_order="0"/>'
    b"</track>\n</annotations>\n"
)
TOKENS = [b"<", b">", b"/>", b"&", b"&a;", b"<!DOCTYPE annotations [<!ENTITY a \"x\">]>", b"]]>", b"<![CDATA[", b'"', b"\x00",
          b"\xff", b"<track id=\"0\" label=\"x\">", b"</track>", b"-1", b"nan", b"9999999999", b";", b","]


@st.composite
def mutated_export(draw) -> bytes:
    data = bytearray(VALID)
    for _ in range(draw(st.integers(1, 6))):
        at = draw(st.integers(0, len(data)))
        action = draw(st.sampled_from(["insert", "delete", "replace", "truncate"]))
        if action == "insert":
            data[at:at] = draw(st.sampled_from(TOKENS))
        elif action == "delete":
            del data[at : at + draw(st.integers(1, 20))]
        elif action == "replace":
            data[at : at + 1] = bytes([draw(st.integers(0, 255))])
        else:
            del data[at:]
    return bytes(data)


def check_read(path: Path) -> None:
    """The property: a usable annotation, or one clear line about this file."""
    try:
        annotation = read_cvat(path)
    except InputError as error:
        assert error.path == path
        assert error.message and "\n" not in error.message
        return
    assert isinstance(annotation, Annotation)
    assert annotation.frames == sorted(set(annotation.frames))
    for track in annotation.tracks:
        for shape in track.shapes.values():
            assert np.isfinite(shape.points).all()
            if shape.kind == "polygon":
                assert len(shape.points) >= 3
            if shape.kind == "mask":
                assert shape.bitmap is not None and shape.bitmap.ndim == 2


@FUZZ
@given(text=structured_export())
def test_structured_exports(tmp_path, text):
    path = tmp_path / "fuzz.xml"
    path.write_text(text, encoding="utf-8")
    check_read(path)


@FUZZ
@given(data=mutated_export())
def test_mutated_exports(tmp_path, data):
    path = tmp_path / "fuzz.xml"
    path.write_bytes(data)
    check_read(path)


def fuzz_with_atheris() -> None:
    """Coverage-guided fuzzing of :func:`read_cvat` with atheris (``pip install atheris``).

    Run as ``python tests/attacks/test_fuzz.py [CORPUS_DIR] -max_total_time=600``; libFuzzer options
    apply. A crash (any exception but :class:`InputError`) stops it and writes the input.
    """
    import sys
    import tempfile

    import atheris

    atheris.instrument_all()  # the reader is imported already: instrument it in place
    path = Path(tempfile.mkdtemp()) / "fuzz.xml"

    def one_input(data: bytes) -> None:
        path.write_bytes(data)
        check_read(path)

    corpus = [arg for arg in sys.argv[1:] if not arg.startswith("-")]
    for folder in corpus:
        Path(folder).mkdir(parents=True, exist_ok=True)
        (Path(folder) / "valid.xml").write_bytes(VALID)
    atheris.Setup(sys.argv, one_input)
    atheris.Fuzz()


if __name__ == "__main__":
    fuzz_with_atheris()

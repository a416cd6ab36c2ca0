"""Reading an image file's bytes (io.images.read_bytes)."""

import io

import numpy as np
import pytest

from annotate_rgbd.errors import InputError
from annotate_rgbd.io import images


def test_the_bytes_of_a_file_as_they_are(tmp_path):
    data = bytes(range(256)) * 5
    path = tmp_path / "frame.png"
    path.write_bytes(data)
    got = images.read_bytes(path)
    assert got.dtype == np.uint8 and got.tobytes() == data
    with pytest.raises(InputError, match="at most"):
        images.read_bytes(path, max_bytes=100)


class _InterruptedRead(io.BytesIO):
    def read(self, *args):
        raise KeyboardInterrupt


def test_an_interrupt_while_reading_stays_an_interrupt(tmp_path, monkeypatch):
    # numpy's fromfile turned a Ctrl-C that fell on its file handling into a TypeError, and the
    # run ended with status 1 instead of 130 (tests/attacks/test_hostile.py, interrupt mid-run).
    path = tmp_path / "frame.png"
    path.write_bytes(b"\x89PNG")
    monkeypatch.setattr(images, "open_input", lambda p, limit: _InterruptedRead(b"\x89PNG"))
    with pytest.raises(KeyboardInterrupt):
        images.read_bytes(path)


def test_a_file_that_grew_after_it_was_opened_is_refused(tmp_path, monkeypatch):
    path = tmp_path / "frame.png"
    path.write_bytes(b"x" * 10)
    monkeypatch.setattr(images, "open_input", lambda p, limit: io.BytesIO(b"x" * 1000))
    with pytest.raises(InputError, match="frame.png.*over"):
        images.read_bytes(path, max_bytes=100)

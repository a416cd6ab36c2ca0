import numpy as np
import cv2
import pytest

from annotate_rgbd.errors import InputError
from annotate_rgbd.io.association_checks import unmatched_frames
from annotate_rgbd.io.sequence import associate, read_depth, read_rgb, read_sequence

HEADER = "# color images\n# file: 'rgbd_dataset_freiburg1_rpy.bag'\n# timestamp filename\n"


def write_list(path, rows):
    path.write_text(HEADER + "".join(f"{ts} {file}\n" for ts, file in rows))


def test_tum_lists_are_sorted_by_timestamp_as_numbers(tmp_path):
    # Same integer second, listed out of order: sorting by int(ts) or by text would mix them up.
    write_list(tmp_path / "rgb.txt", [("10.5", "rgb/10.5.png"), ("10.25", "rgb/10.25.png"), ("9.75", "rgb/9.75.png")])
    write_list(tmp_path / "depth.txt", [("10.26", "depth/10.26.png")])
    sequence = read_sequence(tmp_path)
    assert sequence.rgb.files == ("rgb/9.75.png", "rgb/10.25.png", "rgb/10.5.png")
    np.testing.assert_allclose(sequence.rgb.timestamps, [9.75, 10.25, 10.5])
    assert sequence.depth.files == ("depth/10.26.png",)


def test_folders_without_lists_use_file_names_as_timestamps(tmp_path):
    for folder, names in {"rgb": ["2.5", "10.0", "2.25"], "depth": ["2.3"]}.items():
        (tmp_path / folder).mkdir()
        for name in names:
            (tmp_path / folder / f"{name}.png").write_bytes(b"")
    (tmp_path / "rgb" / "notes.txt").write_text("ignored")
    sequence = read_sequence(tmp_path)
    assert sequence.rgb.files == ("rgb/2.25.png", "rgb/2.5.png", "rgb/10.0.png")


@pytest.mark.parametrize("depth_first", [True, False])
def test_associations_txt_in_both_column_orders(tmp_path, depth_first):
    lines = []
    for i in range(3):
        depth, rgb = f"{i / 30:.6f} depth/{i}.png", f"{i / 30 + 0.001:.6f} rgb/{i}.png"
        lines.append(f"{depth} {rgb}" if depth_first else f"{rgb} {depth}")
    (tmp_path / "associations.txt").write_text("\n".join(lines) + "\n")
    sequence = read_sequence(tmp_path)
    assert sequence.depth.files == ("depth/0.png", "depth/1.png", "depth/2.png")
    assert sequence.rgb.files == ("rgb/0.png", "rgb/1.png", "rgb/2.png")
    np.testing.assert_allclose(sequence.rgb.timestamps - sequence.depth.timestamps, 0.001, atol=1e-9)


def test_real_tum_lists(shared_data):
    sequence = read_sequence(shared_data / "tum_fr1_rpy")
    assert len(sequence.rgb) == 30 and len(sequence.depth) == 30
    assert np.all(np.diff(sequence.rgb.timestamps) > 0)
    nearest, diff, matched = associate(sequence.depth.timestamps, sequence.rgb.timestamps, 0.02)
    assert matched.sum() >= 28
    assert np.all(np.abs(diff[matched]) <= 0.02)
    depth = read_depth(sequence.root / sequence.depth.files[0])
    assert depth.dtype == np.uint16 and depth.shape == (480, 640)
    assert read_rgb(sequence.root / sequence.rgb.files[0]).shape == (480, 640, 3)


def test_associate_picks_the_nearest_and_flags_the_far():
    rgb = np.array([0.0, 0.033, 0.066, 0.2])
    depth = np.array([-0.5, 0.01, 0.03, 0.05, 0.14, 0.2199, 0.3])
    nearest, diff, matched = associate(depth, rgb, 0.02)
    assert nearest.tolist() == [0, 0, 1, 2, 3, 3, 3]
    assert matched.tolist() == [False, True, True, True, False, True, False]
    np.testing.assert_allclose(diff, rgb[nearest] - depth)


def test_associate_accepts_exactly_max_time_diff():
    nearest, diff, matched = associate(np.array([1.02]), np.array([1.0]), 0.02)
    assert matched.tolist() == [True]


@pytest.mark.parametrize(
    "setup, message",
    [
        (lambda p: None, "not an RGB-D sequence"),
        (lambda p: (write_list(p / "rgb.txt", []), write_list(p / "depth.txt", [("1", "d.png")])), "lists no RGB frames"),
        (lambda p: ((p / "rgb.txt").write_text("1.0\n"), write_list(p / "depth.txt", [])), "line 1: expected 2 columns"),
        (lambda p: ((p / "rgb.txt").write_text("abc x.png\n"), write_list(p / "depth.txt", [])), "'abc' is not a timestamp"),
        (
            lambda p: (write_list(p / "rgb.txt", [("1.0", "a.png"), ("1.000000", "b.png")]), write_list(p / "depth.txt", [("1", "d")])),
            "timestamp 1.000000 appears twice",
        ),
    ],
)
def test_bad_sequences_are_one_line_errors(tmp_path, setup, message):
    setup(tmp_path)
    with pytest.raises(InputError, match=message):
        read_sequence(tmp_path)


def test_missing_sequence_folder(tmp_path):
    with pytest.raises(InputError, match="sequence folder not found"):
        read_sequence(tmp_path / "nope")


def test_depth_reading_errors(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        read_depth(tmp_path / "missing.png")
    (tmp_path / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\nnot really")
    with pytest.raises(InputError, match="not a readable image"):
        read_depth(tmp_path / "corrupt.png")
    cv2.imwrite(str(tmp_path / "colour.png"), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(InputError, match="3 channels"):
        read_depth(tmp_path / "colour.png")


def test_a_truncated_png_is_one_error_and_libpng_prints_nothing(tmp_path, capfd):
    # A depth PNG cut short (a copy interrupted, a full disk): refused naming the file, without
    # handing it to the decoder, whose libpng would print "libpng error: ..." on stderr.
    depth = (np.arange(48 * 64, dtype=np.uint16).reshape(48, 64) * 7)
    ok, encoded = cv2.imencode(".png", depth)
    whole = encoded.tobytes()
    assert whole[-8:-4] == b"IEND"
    for cut in (len(whole) // 2, len(whole) - 12):
        (tmp_path / "cut.png").write_bytes(whole[:cut])
        with pytest.raises(InputError, match=r"cut.png: not a readable image \(truncated PNG"):
            read_depth(tmp_path / "cut.png")
    assert capfd.readouterr().err == ""
    # Bytes after IEND (some writers add them) are no truncation.
    (tmp_path / "tail.png").write_bytes(whole + b"\0" * 100)
    assert np.array_equal(read_depth(tmp_path / "tail.png"), depth)


def test_frames_without_an_rgb_frame_are_one_warning_and_none_matched_is_an_error(tmp_path):
    from pathlib import Path

    depth_times = np.arange(10) * 0.1
    rgb_times = depth_times + np.array([0.001, 0.03, 0.03, 0.03, 0.002, 0.03, 0.03, 0.03, 0.03, 0.003])
    nearest, diff, matched = associate(depth_times, rgb_times, 0.02)
    files = [f"depth/{i}.png" for i in range(10)]
    root = Path("seq")
    # Seven frames apart from their RGB frames: one line names three and counts the rest.
    assert unmatched_frames(root, files, diff, matched, 0.02) == [
        "seq/depth/1.png, seq/depth/2.png, seq/depth/3.png and 4 more: no RGB frame within 0.02 s; skipped"]
    # Only the frames the run considers count.
    assert unmatched_frames(root, files, diff, matched, 0.02, np.array([0, 4, 9])) == []
    assert unmatched_frames(root, files, diff, matched, 0.02, np.array([0, 5])) == [
        "seq/depth/5.png: no RGB frame within 0.02 s; skipped"]
    # None of them has one: every frame would be skipped, an error with the gaps there are.
    _, diff, matched = associate(depth_times, rgb_times, 0.0)
    with pytest.raises(InputError) as error:
        unmatched_frames(root, files, diff, matched, 0.0)
    assert str(error.value) == ("seq: no depth frame has an RGB frame within 0 s (sequence.max_time_diff): each is "
                                "0.001 to 0.03 s from the nearest (median 0.03 s)")
    # Of the frames a command would process only: the message says which.
    _, diff, matched = associate(depth_times, rgb_times, 0.02)
    with pytest.raises(InputError) as error:
        unmatched_frames(root, files, diff, matched, 0.02, np.array([1, 2]), "of the 2 that --every 5 picks")
    assert str(error.value).startswith("seq: no depth frame of the 2 that --every 5 picks has an RGB frame within 0.02 s")


def _chunk(kind: bytes, payload: bytes, crc_offset: int = 0) -> bytes:
    """One PNG chunk, its CRC off by ``crc_offset``."""
    import struct
    import zlib

    return struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", (zlib.crc32(kind + payload) + crc_offset) % 2**32)


def test_a_damaged_png_is_one_error_and_libpng_prints_nothing(tmp_path, capfd):
    # Bytes overwritten inside a depth PNG (a bad disk, a broken copy): a pixel chunk's checksum
    # fails. Refused naming the file and the chunk, without the decoder's own "libpng error" line.
    depth = (np.arange(48 * 64, dtype=np.uint16).reshape(48, 64) * 7)
    whole = cv2.imencode(".png", depth)[1].tobytes()
    idat = whole.index(b"IDAT") - 4
    damaged = bytearray(whole)
    damaged[idat + 28 : idat + 38] = bytes(10)
    (tmp_path / "damaged.png").write_bytes(bytes(damaged))
    with pytest.raises(InputError, match=r"damaged.png: not a readable image \(corrupt PNG: its IDAT chunk fails its checksum"):
        read_depth(tmp_path / "damaged.png")
    # A chunk type overwritten with control bytes: said without them.
    damaged = bytearray(whole)
    damaged[idat + 4 : idat + 8] = b"\x00\n\x1b["
    (tmp_path / "type.png").write_bytes(bytes(damaged))
    with pytest.raises(InputError, match=r"type.png: .*a chunk's type is not a PNG chunk type") as raised:
        read_depth(tmp_path / "type.png")
    assert str(raised.value).isprintable()
    # One bit of a pixel chunk's type flipped (IDAT read as iDAT): its checksum fails, and it is
    # not taken for metadata to leave out.
    damaged = bytearray(whole)
    damaged[idat + 4] ^= 0x20
    (tmp_path / "case.png").write_bytes(bytes(damaged))
    with pytest.raises(InputError, match=r"case.png: not a readable image \(corrupt PNG: its iDAT chunk fails its checksum"):
        read_depth(tmp_path / "case.png")
    # Cut inside the closing IEND chunk's checksum (its type still there).
    for cut in (1, 4):
        (tmp_path / "end.png").write_bytes(whole[:-cut])
        with pytest.raises(InputError, match=r"end.png: not a readable image \(truncated PNG"):
            read_depth(tmp_path / "end.png")
    # A length field overwritten to run past the end, IEND still there.
    damaged = bytearray(whole)
    damaged[idat : idat + 4] = b"\x7f\xff\xff\xff"
    (tmp_path / "length.png").write_bytes(bytes(damaged))
    with pytest.raises(InputError, match=r"length.png: .*its IDAT chunk's length runs past the end"):
        read_depth(tmp_path / "length.png")
    assert capfd.readouterr().err == ""
    # A metadata chunk (no pixels) failing its checksum is left out: the image reads as it is,
    # and libpng's warning line is not printed either. One with a good checksum changes nothing.
    for crc_offset in (1, 0):
        text = whole[:idat] + _chunk(b"tEXt", b"Comment\x00made by a test", crc_offset) + whole[idat:]
        (tmp_path / "text.png").write_bytes(text)
        assert np.array_equal(read_depth(tmp_path / "text.png"), depth)
    assert capfd.readouterr().err == ""

"""What ``propose`` leaves out: tracks that flicker for a frame (the persistence filter)."""

from __future__ import annotations

import numpy as np
import pytest

from annotate_rgbd.propose.persist import PersistenceFilter


def run_filter(sequence, min_frames, max_gap):
    """Feed a sequence of per-frame track lists; return {position: (keep, ids, handed back at)}."""
    gate = PersistenceFilter(min_frames, max_gap)
    out = {}
    for position, tracks in enumerate(sequence):
        for d in gate.add(position, np.array(tracks, dtype=np.int64), f"frame {position}"):
            assert d.payload == f"frame {d.position}"
            out[d.position] = (d.keep.tolist(), d.ids.tolist(), position)
    for d in gate.finish():
        out[d.position] = (d.keep.tolist(), d.ids.tolist(), len(sequence))
    return out


def test_a_track_found_once_is_left_out_and_the_others_numbered_in_order():
    sequence = [[1, 2], [1], [1, 3], [], [3]]
    out = run_filter(sequence, min_frames=2, max_gap=1)
    assert [out[p][:2] for p in range(5)] == [
        ([True, False], [1, 0]), ([True], [1]), ([True, True], [1, 2]), ([], []), ([True], [2])]
    # Frame 0 waits until track 2 can no longer be continued (position 2), frame 2 until
    # track 3 is found again (position 4).
    assert [out[p][2] for p in range(5)] == [2, 2, 4, 4, 4]


def test_min_frames_one_holds_nothing_back():
    out = run_filter([[5, 7], [7], [9]], min_frames=1, max_gap=2)
    assert out == {0: ([True, True], [1, 2], 0), 1: ([True], [2], 1), 2: ([True], [3], 2)}


def reference(sequence, min_frames):
    """Keep and ids from the whole sequence at once: a track is kept when found on at least
    ``min_frames`` frames; kept tracks numbered by first appearance."""
    found = {}
    for tracks in sequence:
        for t in tracks:
            found[t] = found.get(t, 0) + 1
    ids, result = {}, []
    for tracks in sequence:
        keep = [found[t] >= min_frames for t in tracks]
        for t, k in zip(tracks, keep):
            if k and t not in ids:
                ids[t] = len(ids) + 1
        result.append((keep, [ids[t] if k else 0 for t, k in zip(tracks, keep)]))
    return result


@pytest.mark.parametrize("min_frames, max_gap", [(2, 0), (2, 2), (3, 1), (4, 2)])
def test_streaming_decisions_equal_the_whole_sequence_ones(min_frames, max_gap):
    rng = np.random.default_rng(min_frames * 10 + max_gap)
    for _ in range(20):
        # Tracks as a linker makes them: each found on runs of frames at most max_gap + 1 apart.
        sequence = [[] for _ in range(40)]
        next_track, position = 1, 0
        for track in range(1, 30):
            position = int(rng.integers(0, 40))
            for _ in range(int(rng.integers(1, 6))):
                if position >= 40:
                    break
                sequence[position].append(track)
                position += int(rng.integers(1, max_gap + 2))
        out = run_filter(sequence, min_frames, max_gap)
        assert [out[p][:2] for p in range(40)] == reference(sequence, min_frames)
        # A frame is handed back once its tracks are decided: at the latest when each has had
        # min_frames chances (max_gap + 1 positions apart) or can no longer be continued.
        for p in range(40):
            assert out[p][2] <= p + min_frames * (max_gap + 1)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError):
        PersistenceFilter(0, 2)
    with pytest.raises(ValueError):
        PersistenceFilter(2, -1)

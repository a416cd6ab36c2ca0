"""Progress lines: what a log file (not a terminal) gets."""

import io
import itertools

from annotate_rgbd.progress import Progress


def test_the_first_line_of_a_batch_shows_the_total_of_all_scenes():
    stream = io.StringIO()
    progress = Progress({"a": 0, "b": 0}, stream=stream, interval=10.0, clock=itertools.count(0, 0.5).__next__)
    a, b = progress.callback("a"), progress.callback("b")
    # As execute_scenes does: every scene announces its frames, then frames finish.
    a(0, 3)
    b(0, 4)
    a(1, 3)
    first = stream.getvalue().splitlines()[0]
    assert first.startswith("a: 1/3 frames | all scenes: 1/7 | ")


def test_a_log_gets_a_line_per_interval_and_one_per_finished_scene():
    stream, now = io.StringIO(), [0.0]
    progress = Progress({"a": 0}, stream=stream, interval=10.0, clock=lambda: now[0])
    update = progress.callback("a")
    for done in range(6):
        now[0] = 4.0 * done  # one frame every 4 s
        update(done, 5)
    # The first finished frame (4 s), the first 10 s after it (16 s: frame 4), the last one.
    assert [line.split(" |")[0] for line in stream.getvalue().splitlines()] == ["a: 1/5 frames", "a: 4/5 frames", "a: 5/5 frames"]
    empty = io.StringIO()
    Progress({"none": 0}, stream=empty).callback("none")(0, 0)  # a scene with nothing to do still ends its line
    assert empty.getvalue().startswith("none: 0/0 frames")


def _log_lines(updates):
    """The lines a log file gets of one scene's ``(time s, frames done, frames in all)`` updates."""
    stream, now = io.StringIO(), [0.0]
    update = Progress({"a": 0}, stream=stream, interval=0.0, clock=lambda: now[0]).callback("a")
    for now[0], done, total in updates:
        update(done, total)
    return stream.getvalue().splitlines()


def test_the_rate_and_eta_count_from_the_first_frame_not_the_start_up():
    # 20 s of start-up and planning, then a frame every 0.5 s: the rate is 2 frames/s, not the
    # 0.05 the whole time since the start gives after the first frame (an ETA 40x too long).
    lines = _log_lines([(0.0, 0, 101), (20.0, 1, 101), (25.0, 11, 101)])
    assert lines[0] == "a: 1/101 frames | -- frames/s | ETA --:--"
    assert lines[1] == "a: 11/101 frames | 2.0 frames/s | ETA 00:45"


def test_a_run_slower_than_a_frame_a_second_shows_seconds_per_frame():
    # 2-pixel detector cells take ~40 s a frame: "0.0 frames/s" said nothing.
    lines = _log_lines([(0.0, 1, 30), (80.0, 3, 30), (82.0, 4, 30)])  # 3 frames in 82 s since the first
    assert lines[1] == "a: 3/30 frames | 40.0 s/frame | ETA 18:00"
    assert lines[2] == "a: 4/30 frames | 27.3 s/frame | ETA 11:51"

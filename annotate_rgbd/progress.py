"""Progress of long runs: frames per second and ETA, per scene and overall.

On a terminal one status line is redrawn in place; otherwise (a log file, CI) a plain line is
printed at most every ``interval`` seconds and at the end of each scene.
"""

from __future__ import annotations

import sys
import time
from typing import Callable, TextIO


class Progress:
    """Tracks frames done per scene and prints the status.

    Parameters
    ----------
    totals : dict of str to int
        Frames to make per scene.
    stream : text stream, optional
        Where to print (default: standard error; nothing is printed when the process has none,
        as under ``2>&-``).
    interval : float
        Seconds between plain log lines when ``stream`` is not a terminal.
    clock : callable
        Time source (for tests).
    """

    def __init__(self, totals: dict[str, int], stream: TextIO | None = None, interval: float = 10.0,
                 clock: Callable[[], float] = time.monotonic):
        self.totals = dict(totals)
        self.done = {scene: 0 for scene in totals}
        self.stream = stream if stream is not None else sys.stderr
        self.interval = interval
        self.clock = clock
        #: (time, frames done) at the first frame done: the rate is measured from there, past
        #: the run's start-up and planning (reading exports, fitting keyframes).
        self.first: tuple[float, int] | None = None
        self.last_line = -float("inf")
        self.interactive = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.drawn = False  # an unfinished in-place line is on the terminal

    def callback(self, scene: str) -> Callable[[int, int], None]:
        """A ``progress(done, total)`` function for one scene."""

        def update(done: int, total: int) -> None:
            self.totals[scene] = total
            self.done[scene] = done
            if self.first is None and done > 0:
                self.first = (self.clock(), sum(self.done.values()))
            self._show(scene, final=done >= total)

        return update

    def line(self, scene: str) -> str:
        """The status text: the scene's progress and, for several scenes, the overall one; the
        rate (seconds per frame when slower than a frame a second) and ETA from the frames done
        since the first one (none yet: ``--``)."""
        done, total = sum(self.done.values()), sum(self.totals.values())
        text = f"{scene}: {self.done[scene]}/{self.totals[scene]} frames"
        if len(self.totals) > 1:
            text += f" | all scenes: {done}/{total}"
        rate = float("nan")
        if self.first is not None and done > self.first[1]:
            rate = (done - self.first[1]) / max(self.clock() - self.first[0], 1e-9)
        eta = 0.0 if done >= total else (total - done) / rate  # NaN without a rate: "--:--"
        if rate != rate:
            speed = "-- frames/s"
        elif rate >= 1.0:
            speed = f"{rate:.1f} frames/s"
        else:  # slower than a frame a second: "0.0 frames/s" would say nothing
            speed = f"{1.0 / rate:.1f} s/frame"
        return f"{text} | {speed} | ETA {_duration(eta)}"

    def finish(self) -> None:
        """End the in-place line on a terminal (if one was drawn: e.g. ``review --no-overlays``
        reports no progress at all)."""
        if self.stream is not None and self.interactive and self.drawn:
            self.stream.write("\n")
            self.stream.flush()
            self.drawn = False

    def _show(self, scene: str, final: bool) -> None:
        if self.stream is None:  # standard error closed (``2>&-``): Python's sys.stderr is None
            return
        now = self.clock()
        if self.interactive:
            self.stream.write("\r\033[K" + self.line(scene))
            self.stream.flush()
            self.drawn = True
        elif final or (self.done[scene] > 0 and now - self.last_line >= self.interval):
            # Not at 0 frames done: a batch announces its scenes one by one, and a line printed
            # before the last one would show a total that is too small.
            self.stream.write(self.line(scene) + "\n")
            self.stream.flush()
            self.last_line = now


def _duration(seconds: float) -> str:
    if seconds != seconds or seconds == float("inf"):
        return "--:--"
    seconds = int(round(seconds))
    hours, rest = divmod(seconds, 3600)
    return f"{hours}:{rest // 60:02d}:{rest % 60:02d}" if hours else f"{rest // 60:02d}:{rest % 60:02d}"

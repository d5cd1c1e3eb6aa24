"""Progress of a long job as the user sees it: one line rewritten in place on a terminal, a line every few
seconds in a log.

Used by ``cgp-sim-render`` (frames rendered) and by the node in batch runs (``realtime:=false`` with a
``duration``: simulated time, ticks/s, real-time factor, ETA, bag size).  No ROS import here.

On a terminal (``stream.isatty()``) the line is redrawn at most every :attr:`ProgressLine.tty_interval_s`
with a carriage return and "erase to end of line" (ANSI ``ESC [ K``, understood by every terminal emulator
since the VT100), so it never scrolls; :meth:`ProgressLine.finish` ends it with a newline.  Anywhere else
(a pipe, a file, CI, ``ros2 launch`` capturing output) a carriage return would pile up in one huge line, so a
complete line goes out every :attr:`ProgressLine.log_interval_s` through ``log`` (a logger's ``info``, or
``print`` to the stream).
"""

from __future__ import annotations

import collections
import math
import sys
import time
from collections.abc import Callable

_ERASE_LINE = "\r\x1b[K"


def format_duration(seconds: float) -> str:
    """``0:07``, ``3:25``, ``1:02:03``; ``--:--`` for an unknown (non-finite or negative) duration."""
    if not math.isfinite(seconds) or seconds < 0:
        return "--:--"
    seconds = int(round(seconds))
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


def format_bytes(count: float) -> str:
    """``512 B``, ``12.3 kB``, ``1.50 MB``, ``2.10 GB`` (SI units, as ``ls -lh --si`` and ``du --si``)."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if count >= scale:
            value = count / scale
            return f"{value:.2f} {unit}" if value < 10 else f"{value:.1f} {unit}"
    return f"{int(count)} B"


def bar(fraction: float, width: int = 24) -> str:
    """``[#########---------------]`` for a fraction in [0, 1]."""
    fraction = min(max(fraction, 0.0), 1.0) if math.isfinite(fraction) else 0.0
    filled = int(fraction * width + 1e-9)
    return "[" + "#" * filled + "-" * (width - filled) + "]"


class ProgressLine:
    """Shows a status text that the caller recomputes; decides when and how it is shown.

    Args:
        stream: where the terminal line goes (default ``sys.stderr``); its ``isatty()`` picks the mode.
        log: where log-mode lines go (default: a line printed to ``stream``).
        tty_interval_s, log_interval_s: the least time between two updates in each mode.
        clock: a monotonic clock (tests pass their own).
    """

    def __init__(self, stream=None, log: Callable[[str], None] | None = None, *, tty_interval_s: float = 0.1,
                 log_interval_s: float = 5.0, clock: Callable[[], float] = time.monotonic) -> None:
        self.stream = sys.stderr if stream is None else stream
        try:
            self.is_tty = bool(self.stream.isatty())
        except (AttributeError, ValueError):  # no isatty, or a closed stream
            self.is_tty = False
        self._log = log or (lambda text: print(text, file=self.stream, flush=True))
        self.interval_s = tty_interval_s if self.is_tty else log_interval_s
        self._clock = clock
        self._last: float | None = None
        self._drawn = False

    def due(self) -> bool:
        """True when an :meth:`update` now would be shown (lets the caller skip building the text)."""
        return self._last is None or self._clock() - self._last >= self.interval_s

    def update(self, text: str, force: bool = False) -> bool:
        """Show ``text`` if the interval has passed (or ``force``); returns whether it was shown."""
        if not force and not self.due():
            return False
        self._last = self._clock()
        if self.is_tty:
            self.stream.write(_ERASE_LINE + text)
            self.stream.flush()
            self._drawn = True
        else:
            self._log(text)
        return True

    def finish(self, text: str | None = None) -> None:
        """Show the final state (if given) and end the terminal line."""
        if text is not None:
            self.update(text, force=True)
        if self.is_tty and self._drawn:
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False


class BatchProgress:
    """The progress of a simulation run as fast as possible (the node with ``realtime:=false``): simulated
    time (of ``duration``), ticks per wall second and the real-time factor over the last
    :attr:`window_s` seconds (over the whole run in the final line), the time left (from the average rate
    since the start), the bag's size.

    ``status(sim_time_s, ticks, bag_bytes)`` returns the line; call it as often as you like."""

    window_s = 2.0

    def __init__(self, duration_s: float = 0.0, clock: Callable[[], float] = time.monotonic) -> None:
        self.duration_s = duration_s
        self._clock = clock
        self._samples: collections.deque[tuple[float, float, int]] = collections.deque()  # (wall, sim, ticks)

    def status(self, sim_time_s: float, ticks: int, bag_bytes: int | None = None, final: bool = False) -> str:
        now = self._clock()
        if not self._samples:
            self._samples.append((now, sim_time_s, ticks))
        first = self._samples[0]
        while len(self._samples) > 1 and now - self._samples[1][0] >= self.window_s:
            self._samples.popleft()
        wall0, sim0, ticks0 = first if final else self._samples[0]
        self._samples.append((now, sim_time_s, ticks))
        elapsed = now - wall0
        tick_rate = (ticks - ticks0) / elapsed if elapsed > 0 else math.nan
        factor = (sim_time_s - sim0) / elapsed if elapsed > 0 else math.nan
        parts = [f"t = {sim_time_s:.2f} s" + (f" of {self.duration_s:g} s" if self.duration_s > 0 else "")]
        if self.duration_s > 0:
            parts[0] = f"{bar(sim_time_s / self.duration_s, 20)} " + parts[0]
        parts.append(f"{tick_rate:.0f} ticks/s" if math.isfinite(tick_rate) else "-- ticks/s")
        parts.append(f"{factor:.2f}x real time" if math.isfinite(factor) else "--x real time")
        if self.duration_s > 0 and not final:
            total_elapsed = now - first[0]
            rate = (sim_time_s - first[1]) / total_elapsed if total_elapsed > 0 else 0.0
            left = (self.duration_s - sim_time_s) / rate if rate > 0 else math.inf
            parts.append(f"ETA {format_duration(max(left, 0.0))}")
        elif final:
            parts.append(f"took {format_duration(now - first[0])}")
        if bag_bytes is not None:
            parts.append(f"bag {format_bytes(bag_bytes)}")
        return ", ".join(parts)

"""Is the tick keeping up: the real-time rate check ("falling behind real time", logged) and the progress of
a batch run (``realtime:=false``: :mod:`cgp_sim_ros.progress`)."""

from __future__ import annotations

import collections
import sys
import time
from collections.abc import Callable

import numpy as np

from .. import interface as itf
from ..progress import BatchProgress, ProgressLine


class RateCheck:
    """Ticks per wall second over windows of :data:`~cgp_sim_ros.interface.REPORT_PERIOD_S`, against the target
    rate.  A window opens at the first tick after start-up, a pause or a change of rate (:meth:`restart`)."""

    def __init__(self, warn: Callable[[str], None]):
        self._warn = warn
        self._tick_wall_times: collections.deque = collections.deque(maxlen=512)  # [s], the last ticks'
        self._window_start: float | None = None
        self._window_ticks = 0

    def restart(self) -> None:
        """Time spent paused, or at another rate, is not "falling behind": the next tick opens a new window."""
        self._window_start = None

    def ticked(self, wall_s: float) -> None:
        """A tick took ``wall_s`` seconds of wall time."""
        self._tick_wall_times.append(wall_s)
        self._window_ticks += 1

    def window_closed(self, *, rate_hz: float, realtime: bool, paused: bool, dt: float) -> bool:
        """After a tick: True when a window closed (every REPORT_PERIOD_S) — having warned if a real-time run
        achieved less than 95 % of ``rate_hz`` in it."""
        now = time.monotonic()
        if self._window_start is None:  # the first tick since start-up or a pause: the window opens here
            self._window_start, self._window_ticks = now, 0
            return False
        elapsed = now - self._window_start
        if elapsed < itf.REPORT_PERIOD_S:
            return False
        achieved = self._window_ticks / elapsed
        if realtime and not paused and achieved < 0.95 * rate_hz:
            times = self._tick_wall_times
            median_ms = 1e3 * float(np.median(times)) if times else float("nan")
            self._warn(
                f"falling behind real time: {achieved:.1f} Hz achieved of {rate_hz:g} Hz (median tick "
                f"{median_ms:.1f} ms); dt stays {dt * 1e3:.3f} ms, so simulated time runs slower "
                "than the wall clock")
        self._window_start, self._window_ticks = now, 0
        return True


class BatchReport:
    """The progress of a batch run: one updating line on a terminal, log lines otherwise."""

    def __init__(self, duration_s: float, log_info: Callable[[str], None]):
        self._line = ProgressLine(sys.stderr, log=lambda text: log_info(f"progress: {text}"))
        self._status = BatchProgress(duration_s)

    def due(self) -> bool:
        return self._line.due()

    def show(self, sim_time_s: float, ticks: int, bag_bytes: int | None, final: bool = False) -> None:
        text = self._status.status(sim_time_s, ticks, bag_bytes, final=final)
        if final:
            self._line.finish(text)
        else:
            self._line.update(text)

    def finish(self) -> None:
        self._line.finish()

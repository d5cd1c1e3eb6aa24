"""Progress on long runs, as the user sees it: a batch run (`realtime:=false`, `duration`) on a terminal
redraws one line (simulated time, ticks/s, real-time factor, ETA, bag size) and ends it with a newline; with
its output in a pipe or a file it writes whole log lines instead (no carriage returns).  The node runs as its
own process, once under a pseudo-terminal and once with stderr a pipe."""

from __future__ import annotations

import os
import pty
import re
import select
import subprocess
import time

from conftest import cgp_sim_executable

from cgp_sim_ros.progress import BatchProgress, ProgressLine, format_bytes, format_duration

LINE = re.compile(r"t = (\d+\.\d\d) s of 1 s, (\d+) ticks/s, (\d+\.\d\d)x real time, ETA (\d+:\d\d), "
                  r"bag ([\d.]+ [kMG]?B)")


def _run_in_pty(args: list[str], timeout: float = 120.0) -> str:
    """Run a command with stdout and stderr on a pseudo-terminal; returns everything it wrote."""
    master, slave = pty.openpty()
    proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=slave, stderr=slave, start_new_session=True)
    os.close(slave)
    chunks, deadline = [], time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.5)
            if ready:
                try:
                    data = os.read(master, 65536)
                except OSError:  # EIO: the other side is closed
                    break
                if not data:
                    break
                chunks.append(data)
            elif proc.poll() is not None:
                break
        assert proc.wait(timeout=max(1.0, deadline - time.monotonic())) == 0
    finally:
        os.close(master)
        if proc.poll() is None:
            proc.kill()
    return b"".join(chunks).decode(errors="replace")


def test_batch_run_on_a_terminal_redraws_one_progress_line(tmp_path):
    out = _run_in_pty([cgp_sim_executable(), "--scene", "ramp", "--realtime", "false", "--duration", "1",
                       "--bag", str(tmp_path / "bag")])
    redraws = out.split("\r\x1b[K")[1:]
    assert len(redraws) >= 2, out[-2000:]
    assert re.match(r"\[-{20}\] t = 0\.02 s of 1 s, -- ticks/s, --x real time, ETA --:--, bag ", redraws[0])
    # the redraws in between (as many as the run's wall time allows: none if it is quick; their format is
    # tested with a clock of our own below) show the rate
    shown = [LINE.search(r) for r in redraws[1:-1]]  # the first tick has no rate yet
    assert all(shown), redraws[:3]
    times = [float(m.group(1)) for m in shown]
    assert times == sorted(times) and all(t <= 1.0 for t in times)
    # the last one is the summary, then the line is ended before anything else is printed
    final = redraws[-1]
    assert re.match(r"\[#{20}\] t = 1\.00 s of 1 s, \d+ ticks/s, \d+\.\d\dx real time, took \d+:\d\d, bag ", final)
    assert "cgp-sim: bag in" in final.split("\n", 1)[1]  # on a line of its own


def test_batch_run_into_a_pipe_logs_whole_lines(tmp_path):
    proc = subprocess.run([cgp_sim_executable(), "--scene", "ramp", "--realtime", "false", "--duration", "1"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "\r" not in proc.stderr and "\x1b[K" not in proc.stderr
    progress = [line for line in proc.stderr.splitlines() if "progress: " in line]
    assert len(progress) >= 2, proc.stderr  # the first one at once, the summary at the end (5 s apart between)
    assert "[INFO]" in progress[0] and re.search(r"progress: \[-{20}\] t = 0\.02 s of 1 s, ", progress[0])
    assert re.search(r"progress: \[#{20}\] t = 1\.00 s of 1 s, \d+ ticks/s, \d+\.\d\dx real time, took ",
                     progress[-1])


def test_a_realtime_run_shows_no_progress(start_node):
    node = start_node("--scene", "ramp", "--duration", "0.2")
    assert node.wait(120) == 0
    assert "progress:" not in node.log() and "\x1b[K" not in node.log()


# ---- the pieces, with a clock of our own ----------------------------------------------------------------


class _Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class _Stream:
    def __init__(self, tty: bool) -> None:
        self.tty, self.text = tty, ""

    def isatty(self) -> bool:
        return self.tty

    def write(self, text: str) -> None:
        self.text += text

    def flush(self) -> None:
        pass


def test_batch_progress_rates_and_eta_follow_the_clock():
    clock = _Clock()
    status = BatchProgress(duration_s=60.0, clock=clock)
    status.status(0.0, 0)
    clock.now += 1.0
    text = status.status(2.0, 120, bag_bytes=3_400_000)  # 2 s simulated in 1 s of wall time
    assert "t = 2.00 s of 60 s, 120 ticks/s, 2.00x real time, ETA 0:29, bag 3.40 MB" in text
    clock.now += 9.0
    text = status.status(20.0, 1200, final=True)
    assert "t = 20.00 s of 60 s, 120 ticks/s, 2.00x real time, took 0:10" in text


def test_progress_line_modes():
    clock = _Clock()
    tty = _Stream(True)
    line = ProgressLine(tty, clock=clock)
    assert line.update("a") and not line.update("b")  # within the redraw interval: not shown
    clock.now += 0.2
    assert line.update("c")
    line.finish("d")
    assert tty.text == "\r\x1b[Ka\r\x1b[Kc\r\x1b[Kd\n"
    logged = []
    line = ProgressLine(_Stream(False), log=logged.append, clock=clock)
    line.update("x")
    clock.now += 1.0
    line.update("y")  # within the 5 s log interval
    clock.now += 5.0
    line.update("z")
    line.finish()
    assert logged == ["x", "z"]


def test_formats():
    assert [format_duration(s) for s in (0, 7.4, 205, 3723, float("inf"))] == ["0:00", "0:07", "3:25", "1:02:03",
                                                                                "--:--"]
    assert [format_bytes(b) for b in (512, 12_345, 1_500_000, 2.1e9)] == ["512 B", "12.3 kB", "1.50 MB", "2.10 GB"]

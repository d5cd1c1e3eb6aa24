"""What recording costs the 15k-fish real-time tick, and which part of the recording it is: one node, one run, the
ways of recording interleaved every few seconds.

Why interleaved: this machine's speed drifts by up to ~1.6x within minutes, so runs in separate processes, one
after the other, cannot tell a 2 ms difference in p99 apart (alternating 25 s runs measured p99 spreads of
3-5 ms for the same code).  Here every mode gets a share of every minute of the same run: the same node, the
same flock, the same bag file, the same phase of the machine.

Modes, switched in turn every ``--segment`` ticks of the node's own 60 Hz timer (the first
:data:`SETTLE_TICKS` ticks after a switch are not counted: the writer's backlog from the mode before drains):

- ``record``: as the node records — the bag writer thread frames each message into MCAP chunks (mcap-python's
  ``Writer``: Python, copying the data into its buffers), compresses (lz4), checksums (CRC32), writes
  (``pwritev``) and syncs (the sync thread's fsync) each chunk (``cgp_sim_ros/wire/bag.py``);
- ``unpinned``: ``record`` with the node's ``pin_threads`` off (the tick's thread not on a CPU of its own: the
  OS places every thread; ``cgp_core.jit.ThreadPlacement``);
- ``framing``: the same framing, but the chunks are neither compressed, checksummed, written nor synced;
- ``drain``: the writer thread takes every message off its queue and drops it (what is left: the tick's
  ``recorder.write`` and the queue);
- ``off``: the node hands nothing to the recorder;
- ``pipe`` (not in the default set: ``--modes record pipe drain``): the writer thread hands each message (a
  header and the bytes) to a child process through a pipe, with ``os.write``, and the child reads and drops it —
  what the tick would still pay if the MCAP writer ran in a process of its own.

Measured 2026-12-02, this script (250 s, the machine at a tick median of ~13.4 ms): p99 ``record`` 20.3 ms,
``framing`` 20.2 ms, ``drain`` 17.2 ms, ``off`` 17.1 ms (medians 13.3-13.5 ms in every mode).  Earlier runs of the
same design, two or three modes each, 100-220 s, agreed: ``record`` − ``drain`` 2.7-3.8 ms at p99 (three runs),
``record`` − ``off`` 1.2-4.7 ms (four runs), ``framing`` ≈ ``record`` (one run).  No better than ``record`` either:
compression alone off (within 0.7 ms), the writer thread at nice 0, a 0.2 ms GIL switch interval.  A stand-in for a
leaner writer — chunks assembled from the messages' own bytes (headers built with ``struct``, one join, CRC, lz4
and one ``pwritev`` per 1 MB chunk, no fsync), as a mode of its own: p99 ``record`` 22.1, lean 20.9, ``drain`` 17.2
ms (200 s, medians 12.7-13.1 ms).  But a seventh run, shorter (160 s) and in a slightly faster phase (medians
12.0-12.6 ms), showed no cost at all: p99 ``record`` 17.9, ``framing`` 17.6, ``drain`` 19.2 ms.  A p99 of ~3,000
ticks is their ~30th slowest: still noisy; run it long. In that run the writer thread was inside a tick 0.28 ms per
tick on average (2.0 ms in the slowest 2 % of ticks) with ``record``, and almost never (0.01 ms per tick) with
``framing``.

So, where recording costs the tick, no one part of it is the cost, and the mechanism is not pinned down: the
framing alone (~0.7 ms of the writer's ~2 ms per tick when profiled alone, the rest being lz4, CRC and ``pwritev``,
which release the GIL) costs the tick as much as all of it, and the lean stand-in for all of it still ~3.7 ms.
What is known: in the machine's slower phases the gap between ticks (~3.4 ms at a 13.3 ms median) barely holds the
writer's work, and its items are indivisible (``BagWriter.hold`` is checked between messages; one chunk's lz4 takes
~2 ms), so the writer works during ticks — though the ``framing`` mode's ~0.7 ms per tick would fit the gap, and
costs as much. The next things to try, measured with this script: writer work that yields to a tick mid-item
(chunks compressed and written block by block, the hold checked between blocks); the writer in a process of its own
(no GIL, no allocator or cache shared with the tick's thread).

``--modes record pipe drain``, 2026-12-02, two runs of 240 s: p99 ``record`` 21.8 / 18.7, ``pipe`` 19.3 / 17.4,
``drain`` 19.0 / 17.1 ms (medians 14.0-14.5 / 12.8-12.9 ms): handing the bytes to another process cost the tick
~0.3 ms at p99 of the 1.6-2.8 ms that recording cost in those runs.  An indication that the MCAP writer in a
process of its own would take most of recording off the tick, not a measurement of such a writer (which would
also need its errors, roll-over and crash safety carried across the process boundary).

What it was (found 2026-12-02, after the runs above): not the writer's work inside the ticks — timed, it no
longer fell in them — but where the scheduler put the threads after it.  The poses are recorded every 2nd tick,
and the tick after the writer had framed them was the slow one (mean 9.6 against 8.7 ms, p90 12.6 against
9.2 ms; without recording both 8.7 ms).  In those ticks the numba pool's worker waited ~1.1 ms for a core
(``/proc/<pid>/task/<tid>/schedstat``: 0.1 ms in the other ticks, 0.02 ms without recording): in one of five it
had last run on the tick's own core.  Stand-ins for the writer's work between ticks (a thread that spins, copies
or lz4-compresses the same bytes, or writes them to a file) did not reproduce it; a writer that wrote nothing to
the file, or compressed nothing, or polled less, still did.  Pinning the tick's thread to one core and every
other thread to the other removed it: real-time p99 13.2 / 13.0 ms unpinned against 9.8 / 10.0 ms pinned
(alternating 30 s runs, separate processes), as without recording.  The node does so by default now
(``pin_threads``; the ``unpinned`` mode here is the comparison).

The ``framing`` mode leaves the bag unreadable (the file's offsets advance without data); the bag is deleted
after the run.

    .venv/bin/python benchmarks/bench_recording.py [--seconds 250] [--segment 300] [--quick] [--modes ...]

Prints a table, writes benchmarks/results/recording.json; asserts nothing.  Part of ``run.py --extras``.
"""

from __future__ import annotations

import argparse
import fcntl
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_tick  # noqa: E402  (sets this process's ROS domain before rclpy loads)
from common import Results  # noqa: E402

#: every way of recording the script knows, and the ones a run interleaves unless told (--modes)
ALL_MODES = ("record", "unpinned", "framing", "drain", "off", "pipe")
DEFAULT_MODES = ("record", "unpinned", "framing", "drain", "off")
#: ticks not counted after each switch (the writer's backlog from the previous mode drains)
SETTLE_TICKS = 30
#: the run's first seconds are not counted (start-up; the bodies are dropped at t = 0)
SKIP_S = 10.0


class Modes:
    """The switch the patched recording looks at, and the patches (made once, before the node exists)."""

    def __init__(self, names: tuple[str, ...]):
        self.mode = names[0]
        import zlib

        import lz4.frame
        import mcap.writer

        from cgp_sim_ros.ros import recorder
        from cgp_sim_ros.wire import bag

        modes = self
        write, write_message = recorder.Recorder.write, bag.BagWriter._write_message
        commit, sync_in_background = bag._CommittingFile.commit, bag.BagWriter._sync_in_background
        compress = lz4.frame.compress
        # 'pipe': a child process that reads and drops, its pipe 1 MB deep (as a writer process's would be)
        self.pipe_reader = None
        if "pipe" in names:
            self.pipe_reader = subprocess.Popen([sys.executable, "-c", _PIPE_READER], stdin=subprocess.PIPE)
            pipe = self.pipe_reader.stdin.fileno()
            fcntl.fcntl(pipe, fcntl.F_SETPIPE_SZ, 1 << 20)

        def recorder_write(self, topic, data, stamp_ns):
            if modes.mode != "off":
                write(self, topic, data, stamp_ns)

        def writer_write_message(self, topic, data, log_time, publish_time):
            if modes.mode == "pipe":
                os.write(pipe, struct.pack("<QQI32s", log_time, publish_time, len(data), topic.name.encode()[:32]))
                view = memoryview(data)
                while view:
                    view = view[os.write(pipe, view):]
            elif modes.mode != "drain":
                write_message(self, topic, data, log_time, publish_time)

        def file_commit(self, final=False):
            if modes.mode != "framing":
                return commit(self, final)
            self.committed += len(self.pending)  # as if written: the offsets mcap keeps stay consistent
            self.pending.clear()

        def writer_sync(self):
            if modes.mode != "framing":
                sync_in_background(self)

        class _Checksums:  # mcap.writer's zlib, for its chunk CRCs
            @staticmethod
            def crc32(data, value=0):
                return 0 if modes.mode == "framing" else zlib.crc32(data, value)

        recorder.Recorder.write = recorder_write
        bag.BagWriter._write_message = writer_write_message
        bag._CommittingFile.commit = file_commit
        bag.BagWriter._sync_in_background = writer_sync
        lz4.frame.compress = lambda data, *a, **k: data if modes.mode == "framing" else compress(data, *a, **k)
        mcap.writer.zlib = _Checksums

    def close(self) -> None:
        if self.pipe_reader is not None:
            self.pipe_reader.stdin.close()
            self.pipe_reader.wait()


_PIPE_READER = """
import os
while os.read(0, 1 << 20):
    pass
"""


def run(seconds: float, segment: int, names: tuple[str, ...] = DEFAULT_MODES) -> Results:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    out = Results("recording", options={"seconds": seconds, "segment": segment, "modes": list(names)})
    modes = Modes(names)
    rclpy.init(domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    work = Path(tempfile.mkdtemp(prefix="bench_recording_"))
    node = bench_tick.make_node(bench_tick.SCENE, work / "bag", "bench_recording", realtime=True)
    total = int(seconds * 60)
    mode_of, tick_ms = np.empty(total, np.int64), np.empty(total)
    done = 0
    tick = node.tick

    def timed_tick():
        nonlocal done
        if done >= total:
            return tick()
        mode = names[(done // segment) % len(names)]
        if mode != modes.mode or done == 0:
            modes.mode = mode
            node.set_parameters([Parameter("pin_threads", value=mode != "unpinned")])  # the node's own callback
        start = time.perf_counter()
        tick()
        tick_ms[done] = (time.perf_counter() - start) * 1e3
        mode_of[done] = names.index(modes.mode)
        done += 1

    node.tick = timed_tick  # what the node's timer callback calls
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        while done < total:
            executor.spin_once(timeout_sec=0.1)
    finally:
        modes.mode = names[0]
        node.close()
        node.destroy_node()
        rclpy.try_shutdown()
        modes.close()
        shutil.rmtree(work, ignore_errors=True)

    counted = (np.arange(total) >= SKIP_S * 60) & (np.arange(total) % segment >= SETTLE_TICKS)
    rows = []
    for index, mode in enumerate(names):
        ms = tick_ms[counted & (mode_of == index)]
        row = {"mode": mode, **bench_tick.window_stats(ms), "p95": float(np.percentile(ms, 95))}
        rows.append(row)
        out.figure(f"recording_{mode}_p99", f"15k-fish real-time tick p99, recording mode '{mode}' (median, p95 in "
                   "the JSON)", row["p99"], "ms", "(comparison)", None, median=row["median"], p95=row["p95"])
    out.data["rows"] = rows
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=250.0, help="length of the run (wall ≈ simulated)")
    parser.add_argument("--segment", type=int, default=300, help="ticks per mode before switching to the next")
    parser.add_argument("--quick", action="store_true", help="100 s instead of --seconds")
    parser.add_argument("--modes", nargs="+", choices=ALL_MODES, default=list(DEFAULT_MODES),
                        help="the ways of recording to interleave (the module docstring says what each is)")
    args = parser.parse_args(argv)
    out = run(100.0 if args.quick else args.seconds, args.segment, tuple(args.modes))
    print(f"{'mode':10s} {'ticks':>6s} {'median':>8s} {'p95':>8s} {'p99':>8s}   (ms, 15k fish, real time)")
    for row in out.data["rows"]:
        print(f"{row['mode']:10s} {row['ticks']:6d} {row['median']:8.2f} {row['p95']:8.2f} {row['p99']:8.2f}")
    print(f"wrote {out.write()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

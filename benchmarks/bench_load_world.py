"""``load_world`` while running (issue 36): does the node keep ticking while another scene is found, read,
validated and built, and is the new world's first tick an ordinary one?

The node runs as ``cgp-sim`` would (the installed script, its own process, real time at 60 Hz).  This process
counts the node's ``/clock`` messages with their arrival times, asks ``~/load_world`` for another scene, sets
it playing, and reports, per switch:

- the reply's latency (request → reply);
- the largest gap between two ``/clock`` arrivals from the request to the reply (the old world ticking while the
  new one is prepared: 16.7 ms is one tick, DDS delivery adds its own jitter);
- the new world's first tick: from the PLAYING reply to the first ``/clock`` after it (the world is left STOPPED
  after a load, so the gap across the pause is the client's own round trip, not the node's; the
  ``set_simulation_state`` client is made and used once before the load, as a new client's discovery alone took
  ~100 ms in one run of six); its kernels were loaded beforehand, on a helper thread;
- the largest gap between two of the new world's ticks over the following 300 ticks;
- that ``/clock`` never went backwards or stood still.

Switches: ``arm -> fish_school`` (a flock where the old world had none: the case whose first tick used to load
the flock's kernels, 183 ms), ``default -> arm`` (robots), ``default -> convex_pile`` (hulls).

Usage: ``.venv/bin/python benchmarks/bench_load_world.py`` (writes ``benchmarks/results/load_world.json``).
``CGP_SIM_BENCH_DOMAIN`` as for the other ROS benchmarks.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if "CGP_SIM_BENCH_DOMAIN" not in os.environ:
    os.environ["CGP_SIM_BENCH_DOMAIN"] = str(random.Random(os.getpid() ^ time.time_ns()).randint(1, 101))
os.environ["ROS_DOMAIN_ID"] = os.environ["CGP_SIM_BENCH_DOMAIN"]

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from common import Results, format_figures  # noqa: E402

SWITCHES = (("arm", "fish_school"), ("default", "arm"), ("default", "convex_pile"))
#: a tick later than this (two periods at 60 Hz, plus delivery) is a stall a viewer would see
GAP_TARGET_MS = 50.0


def switch(start: str, target: str) -> dict:
    """One node on ``start``; ``target`` loaded after 300 ticks; the figures of the module docstring."""
    from ros_probe import Probe
    from rosgraph_msgs.msg import Clock
    from simulation_interfaces.msg import SimulationState
    from simulation_interfaces.srv import GetSimulatorFeatures, LoadWorld, SetSimulationState

    log = open(Path(tempfile.gettempdir()) / f"bench_load_world_{start}_{target}.log", "w")
    node = subprocess.Popen([str(Path(sys.executable).parent / "cgp-sim"), "--scene", start], stdout=log,
                            stderr=subprocess.STDOUT, start_new_session=True)
    probe = Probe(f"bench_load_world_{os.getpid()}")
    arrivals: list[tuple[float, int]] = []
    probe.node.create_subscription(Clock, "/clock", lambda m: arrivals.append(
        (time.monotonic(), m.clock.sec * 1_000_000_000 + m.clock.nanosec)), 1000)
    try:
        probe.client(GetSimulatorFeatures, "/cgp_sim/get_simulator_features", timeout=120)
        probe.spin_until(lambda: len(arrivals) > 300, 60, "300 ticks of the first scene")
        # the client that sets the new world playing, discovered and used now (the node plays already)
        probe.call(SetSimulationState, "/cgp_sim/set_simulation_state",
                   SetSimulationState.Request(state=SimulationState(state=SimulationState.STATE_PLAYING)))
        sent = time.monotonic()
        reply = probe.call(LoadWorld, "/cgp_sim/load_world", LoadWorld.Request(uri=target), timeout=120,
                           idempotent=False)
        replied = time.monotonic()
        assert reply.result.result == 1, reply.result
        probe.call(SetSimulationState, "/cgp_sim/set_simulation_state",
                   SetSimulationState.Request(state=SimulationState(state=SimulationState.STATE_PLAYING)))
        playing = time.monotonic()
        count = len(arrivals)
        probe.spin_until(lambda: len(arrivals) > count + 300, 60, "300 ticks of the new scene")
    finally:
        node.send_signal(signal.SIGINT)
        node.wait(30)
        probe.close()
        log.close()
    gaps = [(b[0], 1000.0 * (b[0] - a[0])) for a, b in zip(arrivals, arrivals[1:])]
    during = [g for t, g in gaps if sent < t <= replied + 0.05]
    after_play = [t for t, _ in arrivals if t > playing]
    after = [1000.0 * (b - a) for a, b in zip(after_play, after_play[1:])]
    stamps = [a[1] for a in arrivals]
    return {"switch": f"{start} -> {target}", "reply_s": round(replied - sent, 2),
            "max_gap_loading_ms": round(max(during or [0.0]), 1), "ticks_while_loading": len(during),
            "first_tick_ms": round(1000.0 * (after_play[0] - playing), 1),
            "max_gap_after_ms": round(max(after), 1),
            "clock_monotonic": all(b > a for a, b in zip(stamps, stamps[1:]))}


def main() -> int:
    import rclpy

    out = Results("load_world")
    rclpy.init()
    rows = [switch(start, target) for start, target in SWITCHES]
    rclpy.try_shutdown()
    out.data["rows"] = rows
    for row in rows:
        key = row["switch"].replace(" -> ", "_to_")
        worst = max(row["max_gap_loading_ms"], row["max_gap_after_ms"], row["first_tick_ms"])
        out.figure(f"load_world_{key}_max_gap", f"load_world {row['switch']}: largest /clock gap while loading, "
                   "from PLAYING to the first tick, and over the first 300 ticks after", worst, "ms",
                   f"<= {GAP_TARGET_MS:g}", worst <= GAP_TARGET_MS and row["clock_monotonic"])
        out.figure(f"load_world_{key}_reply", f"load_world {row['switch']}: reply latency", row["reply_s"], "s",
                   "(reference)", None, note="no target: the worker's reading and the kernels' loading")
    print(format_figures(out.data["figures"]))
    for row in rows:
        print(row)
    print(f"wrote {out.write()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

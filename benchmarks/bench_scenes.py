"""Real-time factor of every built-in scene: can it run live on this machine?

For each scene in ``msgs_config/scenes`` a :class:`~cgp_sim_ros.ros.node.SimNode` (the real node, in this process,
its own ROS domain, no bag, ``realtime=false``) runs ``--seconds`` of simulated time with ``node.tick()``
called back to back: commands, ``World.step()``, every message serialized and published.  The real-time
factor is simulated time / wall time: >= 1 means the scene keeps up with the wall clock at its 60 Hz.  The
``World.step`` share of the tick is measured on the same ticks (a wrapper on the node's own world), so a
scene that misses real time says whether the physics or the publishing is short.  The first simulated second
is timed separately from the rest ("start": bodies falling, contacts being made, versus the rest, which may be
asleep).

    .venv/bin/python benchmarks/bench_scenes.py [--seconds 5] [--only pyramid ramp]

Writes ``results/scenes.json`` and prints a table.  Not a test: nothing here passes or fails a build.
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

os.environ.setdefault("CGP_SIM_BENCH_DOMAIN", str(random.Random(os.getpid()).randint(1, 101)))
os.environ["ROS_DOMAIN_ID"] = os.environ["CGP_SIM_BENCH_DOMAIN"]

from common import Results  # noqa: E402


def run_scene(name: str, seconds: float) -> dict:
    from rclpy.parameter import Parameter

    from cgp_sim_ros.ros.node import SimNode

    node = SimNode(node_name=f"bench_{name}", parameter_overrides=[
        Parameter("scene", value=name), Parameter("realtime", value=False)])
    world = node.world
    step_time = [0.0]
    original_step = world.step

    def timed_step():
        start = time.perf_counter()
        original_step()
        step_time[0] += time.perf_counter() - start

    world.step = timed_step
    ticks = round(seconds / world.dt)
    first = round(1.0 / world.dt)
    marks = []
    try:
        node.tick()  # compiles / loads numba kernels, first serialization
        start = time.perf_counter()
        step_time[0] = 0.0
        for k in range(ticks):
            node.tick()
            if k + 1 == first:
                marks.append((time.perf_counter() - start, step_time[0]))
        wall = time.perf_counter() - start
    finally:
        node.close()
        node.destroy_node()
    start_wall, start_step = marks[0] if marks else (wall, step_time[0])
    rest = ticks - first
    return {
        "scene": name, "bodies": world.body_model.count, "boids": sum(len(f.positions) for f in world.flocks),
        "seconds": ticks * world.dt, "wall_s": wall,
        "rtf": ticks * world.dt / wall,
        "rtf_start": first * world.dt / start_wall,
        "rtf_rest": rest * world.dt / (wall - start_wall) if rest > 0 else None,
        "tick_ms": 1e3 * wall / ticks, "step_ms": 1e3 * step_time[0] / ticks,
        "asleep_at_end": bool(world.bodies_asleep),
    }


def main() -> int:
    from cgp_core.scene import builtin_scene_names

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="simulated seconds per scene (default 5)")
    parser.add_argument("--only", nargs="*", default=None, help="scene names (default: every built-in scene)")
    args = parser.parse_args()
    import rclpy

    out = Results("scenes", options=vars(args))
    rclpy.init(domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    rows = []
    try:
        for name in args.only or builtin_scene_names():
            row = run_scene(name, args.seconds)
            rows.append(row)
            print(f"{name:14s} {row['bodies']:5d} bodies {row['boids']:6d} boids  RTF {row['rtf']:6.2f} "
                  f"(first s {row['rtf_start']:6.2f}, then {row['rtf_rest'] or float('nan'):6.2f})  "
                  f"tick {row['tick_ms']:6.2f} ms, of which World.step {row['step_ms']:6.2f} ms", flush=True)
    finally:
        rclpy.try_shutdown()
    out.data["rows"] = rows
    for row in rows:
        out.figure(f"scene_rtf_{row['scene']}", f"built-in scene {row['scene']}: real-time factor over "
                   f"{row['seconds']:g} s (node tick, no bag)", round(row["rtf"], 2), "x", ">= 1",
                   row["rtf"] >= 1.0)
    out.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())

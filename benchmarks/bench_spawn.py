"""Spawning while running (issue 13): does the node keep its 60 Hz while a client spawns 100 bodies, one request at
a time, and does a 1,000-boid flock spawn in one request?

The node runs as ``cgp-sim`` would (the installed script, its own process, real time at 60 Hz, the default scene:
5 bodies and 300 fish, recording a bag as ``make run`` does).  This process is the client: it counts the node's
``/clock`` messages (one per tick) and sends ``~/spawn_entity`` requests back to back, each after the reply to
the previous one: 100 boxes and spheres on a grid 1–3 m above the ground (so they land, collide with the ground
and each other, and go to sleep during the run), then one flock of 1,000 boids.  Figures:

- tick rate while spawning: ticks (``/clock`` messages) between the first request and the last reply, over that
  wall time; and the slowest 1-second window in that span;
- tick rate over the 5 s after the spawns (105 bodies landing and settling, 1,300 boids);
- the same with fixed bodies (no dynamics: what the spawning machinery itself costs the tick);
- request latency (send → reply) of the body spawns, median and max; the flock's;
- in process (no DDS peer): the node's tick split into ``World.step`` and publish + record, before and after
  the spawns, and the spawn handler's own time: where a short rate comes from.

Usage: ``.venv/bin/python benchmarks/bench_spawn.py [--quick]`` (writes ``benchmarks/results/spawn.json``).
``CGP_SIM_BENCH_DOMAIN`` as for the other ROS benchmarks.
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if "CGP_SIM_BENCH_DOMAIN" not in os.environ:
    os.environ["CGP_SIM_BENCH_DOMAIN"] = str(random.Random(os.getpid() ^ time.time_ns()).randint(1, 101))
os.environ["ROS_DOMAIN_ID"] = os.environ["CGP_SIM_BENCH_DOMAIN"]

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import Results, format_figures  # noqa: E402

RATE_HZ = 60.0
TARGET_HZ = 55.0


def body_yaml(k: int) -> str:
    if k % 2:
        return "body: {shape: sphere, radius: 0.15, mass: 1.0}"
    return "body: {shape: box, size: [0.3, 0.3, 0.3], mass: 1.5}"


def grid_position(k: int) -> tuple[float, float, float]:
    """10 x 10 positions 1 m apart, away from the scene's bodies and pillar, 1–3 m up."""
    return (-12.0 + (k % 10), -12.0 + (k // 10), 1.0 + 0.2 * (k % 11))


def run_variant(fixed: bool, bodies: int, baseline_s: float, after_s: float) -> dict:
    """One node process; ``bodies`` spawns one request at a time (``fixed``: immovable ones, so the physics of
    the world barely grows and what is measured is the spawning machinery), then the 1,000-boid flock."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from simulation_interfaces.srv import SpawnEntity

    bag_root = Path(tempfile.mkdtemp(prefix="bench_spawn_", dir=os.environ.get("BENCH_BAG_DIR")))
    executable = Path(sys.executable).parent / "cgp-sim"
    log_path = Path(tempfile.gettempdir()) / f"bench_spawn_node{'_fixed' if fixed else ''}.log"  # the node's output
    with log_path.open("wb") as log:
        node_process = subprocess.Popen([str(executable), "--scene", "default", "--rate-hz", str(RATE_HZ),
                                         "--bag", str(bag_root / "bag")], stdout=log, stderr=subprocess.STDOUT,
                                        start_new_session=True)
    rclpy.init()
    client_node = rclpy.create_node("bench_spawn_client")
    ticks: list[tuple[float, int]] = []  # (receive wall time, sim time ns)
    client_node.create_subscription(Clock, "/clock", lambda m: ticks.append(
        (time.monotonic(), m.clock.sec * 1_000_000_000 + m.clock.nanosec)),
        QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    spawn = client_node.create_client(SpawnEntity, "/cgp_sim/spawn_entity")
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(client_node)

    def spin_until(condition, timeout: float, what: str) -> None:
        end = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > end:
                raise TimeoutError(f"timed out waiting for {what}")
            executor.spin_once(timeout_sec=0.01)

    def spin_for(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.01)

    def call(request) -> tuple[float, object]:
        """(latency s, response); re-sent if the first reply is lost to the discovery race (see ros_probe)."""
        while True:
            sent = time.monotonic()
            future = spawn.call_async(request)
            end = sent + 5.0
            while not future.done() and time.monotonic() < end:
                executor.spin_once(timeout_sec=0.005)
            if future.done():
                return time.monotonic() - sent, future.result()
            spawn.remove_pending_request(future)

    def rate(t0: float, t1: float) -> float:
        stamps = [s for w, s in ticks if t0 <= w <= t1]
        return (len(stamps) - 1) / (t1 - t0) if len(stamps) > 1 else 0.0

    def slowest_window(t0: float, t1: float, width: float = 1.0) -> float:
        # never wider than the span: a window reaching past the last spawn would count the time in which this
        # process, busy with its next request, did not take the node's /clock messages (their receive times
        # are what is counted) as ticks the node did not make
        width = min(width, t1 - t0)
        starts = np.arange(t0, max(t0, t1 - width) + 1e-9, 0.1)
        return min(sum(1 for w, _ in ticks if s <= w < s + width) / width for s in starts)

    try:
        spin_until(lambda: spawn.service_is_ready() and len(ticks) > 30, 60, "the node (service and ticks)")
        call(SpawnEntity.Request())  # warm the client up (refused: no resource)
        b0 = time.monotonic()
        spin_for(baseline_s)
        baseline = rate(b0, time.monotonic())

        latencies = []
        t_first = time.monotonic()
        for k in range(bodies):
            resource = body_yaml(k)
            if fixed:
                resource = resource.replace("}", ", fixed: true}")
            request = SpawnEntity.Request(name=f"spawned_{k}", resource_string=resource)
            p = request.initial_pose.pose.position
            p.x, p.y, p.z = grid_position(k)
            latency, response = call(request)
            if response.result.result != 1:
                raise RuntimeError(f"spawn {k} refused: {response.result.error_message}")
            latencies.append(latency)
        t_last = time.monotonic()
        while_spawning = rate(t_first, t_last)
        worst_window = slowest_window(t_first, t_last)

        request = SpawnEntity.Request(name="school", resource_string=(
            "flock: {count: 1000, spawn: {extent: [10, 10, 4]}, model: sphere}"))
        request.initial_pose.pose.position.z = 10.0
        flock_latency, flock_response = call(request)
        a0 = time.monotonic()
        spin_for(after_s)
        after = rate(a0, time.monotonic())
    finally:
        executor.shutdown()
        client_node.destroy_node()
        rclpy.try_shutdown()
        if node_process.poll() is None:
            node_process.send_signal(signal.SIGINT)
            try:
                node_process.wait(30)
            except subprocess.TimeoutExpired:
                node_process.kill()
        shutil.rmtree(bag_root, ignore_errors=True)
    return {"fixed": fixed, "baseline_hz": baseline, "while_spawning_hz": while_spawning,
            "slowest_second_hz": worst_window, "after_hz": after, "spawn_span_s": t_last - t_first,
            "latency_ms_median": 1e3 * float(np.median(latencies)), "latency_ms_max": 1e3 * max(latencies),
            "flock_ms": 1e3 * flock_latency, "flock_ok": flock_response.result.result == 1,
            "flock_message": flock_response.result.error_message, "node_log": str(log_path)}


def tick_split(fixed: bool, bodies: int, settle_ticks: int, timed_ticks: int) -> dict:
    """In process (no DDS peer, no executor): the node's tick split into ``World.step`` and the rest (serialize,
    publish, record) for the default scene alone and with ``bodies`` more spawned (``fixed`` or movable), each
    after ``settle_ticks``; and what one spawn request costs the node (handler time, median).  Says whether a
    short rate comes from spawning, from the physics of more bodies, or from publishing more bodies."""
    import rclpy
    from rclpy.parameter import Parameter
    from simulation_interfaces.srv import SpawnEntity

    from cgp_sim_ros.ros.node import SimNode

    bag_root = Path(tempfile.mkdtemp(prefix="bench_spawn_split_", dir=os.environ.get("BENCH_BAG_DIR")))
    rclpy.init()
    node = SimNode(parameter_overrides=[Parameter("start_paused", value=True),
                                        Parameter("bag", value=str(bag_root / "bag"))])
    step_times: list[float] = []
    world_step = node.world.step

    def timed_step():
        t0 = time.perf_counter()
        world_step()
        step_times.append(time.perf_counter() - t0)

    node.world.step = timed_step

    def measure(settle: int) -> dict:
        for _ in range(settle):
            node.tick()
        step_times.clear()
        ticks = []
        for _ in range(timed_ticks):
            t0 = time.perf_counter()
            node.tick()
            ticks.append(time.perf_counter() - t0)
        tick_ms, step_ms = 1e3 * np.median(ticks), 1e3 * np.median(step_times)
        return {"tick_ms": tick_ms, "world_step_ms": step_ms, "publish_record_ms": tick_ms - step_ms,
                "bodies_asleep": bool(node.world.bodies_asleep)}

    try:
        alone = measure(settle_ticks)
        handler = []
        for k in range(bodies):
            resource = body_yaml(k).replace("}", ", fixed: true}") if fixed else body_yaml(k)
            request = SpawnEntity.Request(name=f"spawned_{k}", resource_string=resource)
            p = request.initial_pose.pose.position
            p.x, p.y, p.z = grid_position(k)
            t0 = time.perf_counter()
            response = _drive(node.sim._spawn_entity(request, SpawnEntity.Response()))
            handler.append(time.perf_counter() - t0)
            if response.result.result != 1:
                raise RuntimeError(f"spawn {k} refused: {response.result.error_message}")
        landing = measure(0)  # the ticks right after the spawns: the bodies fall and land
        more = measure(settle_ticks)
    finally:
        node.close()
        node.destroy_node()
        rclpy.try_shutdown()
        shutil.rmtree(bag_root, ignore_errors=True)
    return {"fixed": fixed, "alone": alone, "landing": landing, "with_spawned": more,
            "spawn_handler_ms_median": 1e3 * float(np.median(handler))}


def _drive(coroutine):
    """Run the spawn handler (a coroutine that waits for the spawn worker process by yielding) to its reply, as
    the executor would, with nothing else to do meanwhile: its time is the request's round trip through the
    worker."""
    try:
        while True:
            coroutine.send(None)
    except StopIteration as done:
        return done.value


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="shorter baseline and settling windows")
    parser.add_argument("--bodies", type=int, default=100)
    args = parser.parse_args(argv)
    out = Results("spawn", options=vars(args))
    baseline_s, after_s = (2.0, 3.0) if args.quick else (4.0, 5.0)
    settle, timed = (240, 60) if args.quick else (600, 120)
    splits = [tick_split(fixed, args.bodies, settle, timed) for fixed in (False, True)]
    rows = [run_variant(fixed, args.bodies, baseline_s, after_s) for fixed in (False, True)]
    movable, fixed = rows
    n = args.bodies
    out.figure("spawn_100_rate", f"tick rate while {n} bodies are spawned one request at a time (60 Hz, "
               "default scene, recording; they land)", movable["while_spawning_hz"], "Hz", f">= {TARGET_HZ:g}",
               movable["while_spawning_hz"] >= TARGET_HZ)
    out.figure("spawn_100_worst_second", "  slowest 1-s window while spawning", movable["slowest_second_hz"], "Hz",
               f">= {TARGET_HZ:g}", movable["slowest_second_hz"] >= TARGET_HZ)
    out.figure("spawn_100_after_rate", f"  then {after_s:g} s with the {n} bodies + a 1,000-boid flock",
               movable["after_hz"], "Hz", f">= {TARGET_HZ:g}", movable["after_hz"] >= TARGET_HZ)
    out.figure("spawn_100_fixed_rate", f"the same spawning {n} fixed bodies (the spawn machinery's own cost)",
               fixed["while_spawning_hz"], "Hz", f">= {TARGET_HZ:g}", fixed["while_spawning_hz"] >= TARGET_HZ)
    out.figure("spawn_baseline_rate", "  reference: the node before any spawn", movable["baseline_hz"], "Hz",
               f"{RATE_HZ:g}", None)
    out.figure("spawn_latency_median", "spawn_entity request -> reply, one body, median",
               movable["latency_ms_median"], "ms", "(reference)", None)
    out.figure("spawn_flock_1000", "spawn_entity of a 1,000-boid flock in one request, request -> reply",
               movable["flock_ms"], "ms", "one request", movable["flock_ok"])
    for split in splits:
        kind = "fixed" if split["fixed"] else "movable"
        out.figure(f"spawn_split_{kind}_landing", f"in process: World.step right after +{n} {kind} bodies "
                   f"({timed} ticks)", split["landing"]["world_step_ms"], "ms",
                   f"from {split['alone']['world_step_ms']:.1f}", None)
        out.figure(f"spawn_split_{kind}_step", f"in process: World.step, {settle} ticks later (asleep: "
                   f"{split['with_spawned']['bodies_asleep']})", split["with_spawned"]["world_step_ms"], "ms",
                   f"from {split['alone']['world_step_ms']:.1f}", None)
        out.figure(f"spawn_split_{kind}_publish", f"in process: publish + record, default scene -> +{n} {kind}",
                   split["with_spawned"]["publish_record_ms"], "ms",
                   f"from {split['alone']['publish_record_ms']:.1f}", None)
        out.figure(f"spawn_split_{kind}_handler", f"in process: one spawn_entity request through the spawn worker "
                   f"process ({kind} body), median",
                   split["spawn_handler_ms_median"], "ms", "(reference)", None)
    out.data["variants"] = rows
    out.data["tick_split"] = splits
    path = out.write()
    print(format_figures(out.data["figures"]))
    for row in rows:
        print(f"{'fixed' if row['fixed'] else 'movable'}: baseline {row['baseline_hz']:.1f} Hz, {n} spawns in "
              f"{row['spawn_span_s']:.2f} s at {row['while_spawning_hz']:.1f} Hz, then {row['after_hz']:.1f} Hz; "
              f"latency median {row['latency_ms_median']:.1f} ms, max {row['latency_ms_max']:.1f} ms; "
              f"node log {row['node_log']}")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

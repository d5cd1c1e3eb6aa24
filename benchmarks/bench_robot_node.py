"""Issue 36's figures: the ``arm`` scene through the node, as ``make run ARGS="--scene arm"`` runs it (the 7-DoF
arm sweeping the boxes off its table on its scene trajectory), and a controller's command latency on the
``arm_teleop`` scene (the 4-joint arm holding its pose).

**Real time.**  ``bench_realtime``'s child (``cgp-sim --scene arm --bag <dir>``: timer-driven at 60 Hz, real time,
recording; the tick and the timer callback timed) from the first tick: the achieved rate, the tick's median, p99 and
max, the tick period's p99, the "falling behind" warnings.  The real-time factor is the achieved rate over the
scene's 60 Hz (the node publishes one ``/clock`` per tick of 1/60 s).

**Command latency.**  ``cgp-sim --scene arm_teleop --bag <dir>`` runs (a robot at rest: the ``arm`` scene's
trajectory would sweep ``shoulder_pan`` at up to 1.2 rad/s, and its damping's torque would hide the effort
command's), and this process — another node, as a
controller is — publishes ``~/robots/arm/joint_commands`` the way topic_based_ros2_control does and reads
``~/robots/arm/joint_states``.  Each trial commands an effort on ``shoulder_pan`` (the vertical base joint: gravity
exerts no torque about it, so a small effort only turns the arm slowly) alternating +/- ``EFFORT`` N·m, and finds
the first ``joint_states`` whose reported effort of that joint is within half the command of the commanded one (the
joint reports what acts on it — the command less its URDF damping, a few per cent here — so the sign flip of +/-
``EFFORT`` is unmistakable).  Latency in ticks = (that message's stamp − the stamp of the newest ``joint_states``
received before the command was published) / the tick; it is >= 1 by construction (the tick after the last one
seen).  The wall-clock latency (published → received) is reported beside it.  Discovery is waited on with a
deadline, never a sleep.

**Spawning a robot while the default scene runs.**  ``cgp-sim --scene default --bag <dir>`` (60 Hz real time,
recording, 5 bodies and 300 fish), and this process, as a client, counts ``/clock`` (one per tick) while it spawns
the arm from its file (``uri``), then from its URDF text (``resource_string``), deletes the first and spawns it again
under another name, each request after the previous reply: the tick rate from the first request to the last reply,
the slowest 1-s window, each request's latency (the first spawn starts the node's spawn worker).

Writes ``benchmarks/results/robot_node.json``.  Run alone: ``.venv/bin/python benchmarks/bench_robot_node.py``
(``--quick``: 10 s of real time instead of 30, 20 latency trials instead of 60).
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from bench_realtime import TARGET_RATE_HZ, run_realtime  # noqa: E402
from common import Results, format_figures, stop_node  # noqa: E402

ROBOT = "arm"  # the robot's name in both scenes (its topics)
SCENE = "arm"  # the real-time figure's scene
LATENCY_SCENE = "arm_teleop"  # the command latency's scene
JOINT = "shoulder_pan"
EFFORT = 0.02  # N·m: turns the arm's base a few degrees over a trial
TICK_S = 1.0 / 60.0
JOINT_STATES = f"/cgp_sim/robots/{ROBOT}/joint_states"
JOINT_COMMANDS = f"/cgp_sim/robots/{ROBOT}/joint_commands"
DISCOVERY_DEADLINE_S = 60.0
TRIAL_DEADLINE_S = 5.0


def command_latency(trials: int, workdir: Path) -> dict:
    """Start the arm_teleop scene's node and measure ``trials`` effort commands' latency (module docstring)."""
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import JointState

    domain = int(os.environ.get("CGP_SIM_BENCH_DOMAIN") or random.Random(os.getpid() ^ time.time_ns()).randint(1, 101))
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED="1")
    executable = str(Path(sys.executable).with_name("cgp-sim"))
    log = open(workdir / "latency_node.log", "w")
    process = subprocess.Popen([executable, "--scene", LATENCY_SCENE, "--bag", str(workdir / "bag_latency")], env=env,
                               stdout=log, stderr=subprocess.STDOUT)
    rclpy.init(domain_id=domain)
    node = rclpy.create_node("bench_robot_latency")
    received: list[tuple[float, int, float | None]] = []  # (wall receive time, stamp ns, effort of JOINT)

    def on_state(msg):
        effort = None
        if JOINT in msg.name and len(msg.effort) == len(msg.name):
            effort = float(msg.effort[list(msg.name).index(JOINT)])
        received.append((time.perf_counter(), msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec, effort))

    node.create_subscription(JointState, JOINT_STATES, on_state, qos_profile_sensor_data)
    publisher = node.create_publisher(JointState, JOINT_COMMANDS, 10)
    ticks, walls_ms = [], []
    try:
        deadline = time.monotonic() + DISCOVERY_DEADLINE_S
        while (not received or publisher.get_subscription_count() == 0) and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        if not received or publisher.get_subscription_count() == 0:
            raise RuntimeError(f"the arm node was not discovered within {DISCOVERY_DEADLINE_S:g} s "
                               f"(log: {workdir / 'latency_node.log'})")
        for trial in range(trials):
            value = EFFORT if trial % 2 == 0 else -EFFORT
            for _ in range(20):  # drain what has arrived: the newest stamp before the command
                rclpy.spin_once(node, timeout_sec=0.0)
            last_stamp = received[-1][1]
            seen = len(received)
            msg = JointState(name=[JOINT], effort=[value])
            published = time.perf_counter()
            publisher.publish(msg)
            deadline = time.monotonic() + TRIAL_DEADLINE_S
            hit = None
            while hit is None and time.monotonic() < deadline:
                rclpy.spin_once(node, timeout_sec=0.05)
                for wall, stamp, effort in received[seen:]:
                    if effort is not None and abs(effort - value) <= 0.5 * EFFORT:
                        hit = (wall, stamp)
                        break
            if hit is None:
                raise RuntimeError(f"trial {trial}: no joint_states with effort {value} on {JOINT} within "
                                   f"{TRIAL_DEADLINE_S:g} s")
            ticks.append((hit[1] - last_stamp) * 1e-9 / TICK_S)
            walls_ms.append((hit[0] - published) * 1e3)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        stop_node(process)
        log.close()
    ticks_a, walls = np.round(np.array(ticks), 3), np.array(walls_ms)
    return {"trials": trials, "latency_ticks": ticks_a.tolist(), "latency_wall_ms": walls.tolist(),
            "ticks_median": float(np.median(ticks_a)), "ticks_max": float(ticks_a.max()),
            "wall_ms_median": float(np.median(walls)), "wall_ms_p99": float(np.percentile(walls, 99))}


def spawn_while_running(workdir: Path) -> dict:
    """The arm spawned, spawned again from text, deleted and spawned under another name while the default scene
    runs (module docstring): the tick rate over the requests, the slowest second, the latencies."""
    import rclpy
    from rosgraph_msgs.msg import Clock
    from simulation_interfaces.msg import Result
    from simulation_interfaces.srv import DeleteEntity, SpawnEntity

    urdf = ROOT / "msgs_config" / "robots" / "arm.urdf"
    domain = int(os.environ.get("CGP_SIM_BENCH_DOMAIN") or random.Random(os.getpid() ^ time.time_ns()).randint(1, 101))
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED="1")
    log = open(workdir / "spawn_node.log", "w")
    process = subprocess.Popen([str(Path(sys.executable).with_name("cgp-sim")), "--scene", "default", "--bag",
                                str(workdir / "bag_spawn")], env=env, stdout=log, stderr=subprocess.STDOUT)
    rclpy.init(domain_id=domain)
    node = rclpy.create_node("bench_robot_spawn")
    ticks: list[float] = []
    node.create_subscription(Clock, "/clock", lambda _msg: ticks.append(time.perf_counter()), 10)
    spawn = node.create_client(SpawnEntity, "/cgp_sim/spawn_entity")
    delete = node.create_client(DeleteEntity, "/cgp_sim/delete_entity")

    def call(client, request, what: str):
        started = time.perf_counter()
        future = client.call_async(request)
        deadline = time.monotonic() + 120.0
        while not future.done() and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
        if not future.done():
            raise RuntimeError(f"{what}: no reply within 120 s")
        answer = future.result()
        if answer.result.result != Result.RESULT_OK:
            raise RuntimeError(f"{what}: {answer.result.error_message}")
        return time.perf_counter() - started

    def spawn_request(name: str, **source) -> SpawnEntity.Request:
        request = SpawnEntity.Request(name=name, **source)
        request.initial_pose.pose.position.x = -8.0
        request.initial_pose.pose.position.y = {"arm_file": -8.0, "arm_text": 8.0}.get(name, 0.0)
        request.initial_pose.pose.orientation.w = 1.0
        return request

    try:
        deadline = time.monotonic() + DISCOVERY_DEADLINE_S
        while (len(ticks) < 60 or not spawn.service_is_ready() or not delete.service_is_ready()) \
                and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        if len(ticks) < 60 or not spawn.service_is_ready():
            raise RuntimeError(f"the default scene's node was not discovered within {DISCOVERY_DEADLINE_S:g} s")
        first = time.perf_counter()
        latency = {
            "spawn_file_s": call(spawn, spawn_request("arm_file", uri=f"file://{urdf}"), "spawn from the file"),
            "spawn_text_s": call(spawn, spawn_request("arm_text", resource_string=urdf.read_text()),
                                 "spawn from the text"),
            "delete_s": call(delete, DeleteEntity.Request(entity="arm_file"), "delete"),
            "spawn_again_s": call(spawn, spawn_request("arm_again", uri=str(urdf)), "spawn again"),
        }
        last = time.perf_counter()
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        stop_node(process)
        log.close()
    stamps = np.array(ticks)
    inside = stamps[(stamps >= first) & (stamps <= last)]
    span = max(last - first, 1e-9)
    windows = [int(((stamps >= t) & (stamps < t + 1.0)).sum()) for t in np.arange(first, max(last - 1.0, first) + 1e-9,
                                                                                    0.1)]
    return {"rate_hz": len(inside) / span, "span_s": span, "slowest_second_ticks": min(windows), **latency}


def run(quick: bool = False) -> dict:
    seconds, trials = (10.0, 20) if quick else (30.0, 60)
    out = Results("robot_node", options={"quick": quick, "seconds": seconds, "trials": trials})
    workdir = Path(tempfile.mkdtemp(prefix="bench_robot_node_", dir=os.environ.get("BENCH_BAG_DIR")))
    try:
        print(f"arm scene: 60 Hz real time, recording, {seconds:g} s from the first tick ...", flush=True)
        os.environ.setdefault("ROS_DOMAIN_ID", str(random.Random(os.getpid()).randint(1, 101)))
        realtime = run_realtime("arm_realtime", seconds, False, workdir, SCENE)
        print(f"  achieved {realtime['achieved_hz']:.2f} Hz; tick median {realtime['tick_ms']['median']:.2f} ms, "
              f"p99 {realtime['tick_ms']['p99']:.2f}, max {realtime['tick_ms']['max']:.1f}; "
              f"{realtime['falling_behind_warnings']} 'falling behind' warnings", flush=True)
        print(f"command latency ({LATENCY_SCENE} scene): {trials} effort commands on {JOINT} ...", flush=True)
        latency = command_latency(trials, workdir)
        print(f"  {latency['ticks_median']:g} ticks median (max {latency['ticks_max']:g}); wall "
              f"{latency['wall_ms_median']:.1f} ms median, p99 {latency['wall_ms_p99']:.1f}", flush=True)
        print("spawning the arm (file, text, delete, again) while the default scene runs ...", flush=True)
        spawned = spawn_while_running(workdir)
        print(f"  {spawned['rate_hz']:.1f} Hz over {spawned['span_s']:.1f} s of requests, slowest second "
              f"{spawned['slowest_second_ticks']} ticks; latency file {spawned['spawn_file_s']:.2f} s, text "
              f"{spawned['spawn_text_s']:.2f} s, delete {spawned['delete_s']:.2f} s, again "
              f"{spawned['spawn_again_s']:.2f} s", flush=True)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    out.data.update({"realtime": realtime, "latency": latency, "spawn": spawned})
    out.figure("arm_realtime_hz", f"arm scene, real time + recording: achieved rate over {seconds:g} s",
               realtime["achieved_hz"], "Hz", f">= {TARGET_RATE_HZ}", realtime["achieved_hz"] >= TARGET_RATE_HZ,
               rtf=realtime["achieved_hz"] * TICK_S, falling_behind_warnings=realtime["falling_behind_warnings"])
    out.figure("arm_tick_p99", "  tick duration p99 (median in the JSON)", realtime["tick_ms"]["p99"], "ms",
               "<= 16.7", realtime["tick_ms"]["p99"] <= 1e3 / 60, median=realtime["tick_ms"]["median"])
    out.figure("arm_command_latency_ticks", "  joint_commands -> joint_states effect: ticks (median)",
               latency["ticks_median"], "ticks", "(reference: 1)", None, max=latency["ticks_max"])
    out.figure("arm_command_latency_ms", "  the same in wall time, published -> received (median)",
               latency["wall_ms_median"], "ms", "(reference)", None, p99=latency["wall_ms_p99"])
    out.figure("arm_spawn_rate_hz", "default scene while the arm is spawned, re-spawned, deleted: tick rate",
               spawned["rate_hz"], "Hz", ">= 55", spawned["rate_hz"] >= 55, span_s=spawned["span_s"],
               slowest_second_ticks=spawned["slowest_second_ticks"])
    out.figure("arm_spawn_latency_s", "  spawn from the file: request -> reply (the first starts the worker)",
               spawned["spawn_file_s"], "s", "(reference)", None, text_s=spawned["spawn_text_s"],
               again_s=spawned["spawn_again_s"], delete_s=spawned["delete_s"])
    path = out.write()
    print()
    print(format_figures(out.data["figures"]))
    print(f"speed probe (ms, before / after): {out.data['speed_probe']}")
    print(f"\nwrote {path.relative_to(ROOT)}")
    return out.data


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="10 s of real time, 20 latency trials")
    args = parser.parse_args(argv)
    run(quick=args.quick)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Issues 37 and 38: the node's own cost per body — what the node adds to ``World.step`` per tick, with issue 38's
300 hulls of 1,000 vertices (``bench_spawn_rows``' ``hulls_300`` scene), 100 convex bodies (``bench_convex_pile``'s
pile) and the default scene, recording on, with and without a subscriber to ``~/markers`` in another process.

Each configuration runs in a child process that builds the node as ``cgp-sim`` does (``SimNode`` with the scene, a
bag, ``realtime: false``) and spins the executor ``cgp-sim`` spins (its zero-period timer calls ``node.tick()``
back to back); ``World.step`` is timed inside the tick, and the node's cost is the spin minus the step (the
executor's own work, commands, serializing, publishing, recording), also per body (µs), split per stage (the
executor's own work outside ``node.tick()``: its wait set; building odometry, contacts, TF, markers, poses,
/clock; DDS publish of the odometry and of the rest; ``recorder.write``),
with the bag writer thread's CPU per tick (it runs beside the tick, under the GIL).  The hulls: ticks 1–170 while
they drop and land (from the first tick), then 200–320 asleep; the pile: ticks 10–180 while it falls and piles up
(0–3 s), then ticks 300–420 (5–7 s) when it is asleep; the default scene: ticks 10–300.
The subscriber (``--subscriber``, its own process) takes ``~/markers`` and ``~/static_markers`` raw and counts
their bytes; the node's side counts the bytes it hands to each topic per tick.  After the pile's runs the same pile
is stepped in PyBullet and in MuJoCo in process (``bench_convex_pile``'s, tick by tick in turn, the same windows),
and the tick through the node is given as a ratio of theirs, measured in the same run (issue 37: <= 0.7x PyBullet).

``--realtime`` runs every configuration as ``make run`` does instead: ``realtime: true`` at 60 Hz, the bag writer
held during each tick and woken after it (:meth:`cgp_sim_ros.wire.bag.BagWriter.hold`), so that its work falls in
the sleep between ticks.  The tick figure is then the tick's own duration (``node.tick()``: what must fit in the
period to hold the rate) and the node's cost is that minus ``World.step``; the executor's own work runs in the
period's slack and is not in it.  The default (batch, ``realtime: false``) runs the ticks back to back, where the
writer thread and the executor share the tick's time.

``--before PATH`` also runs every configuration with the code of another checkout (``PYTHONPATH=PATH``: e.g. the
main branch before a change), interleaved with this one — before, after, before, after — so that both see the same
phases of the shared machine.  The speed probe (``common.speed_probe``) is taken before and after each child.

    .venv/bin/python benchmarks/bench_node_cost.py [--quick] [--before /work/main] [--only hulls300 pile default]
        [--no-subscriber-runs] [--realtime]

``--only pile_awake pile_awake_once`` runs the pile with sleeping off (solved every sub-step at rest, as the peers
are) with its contacts found every sub-step and once per tick (``world.contact_detection: once_per_tick``).

Writes ``benchmarks/results/node_cost.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

if "CGP_SIM_BENCH_DOMAIN" not in os.environ:
    os.environ["CGP_SIM_BENCH_DOMAIN"] = str(random.Random(os.getpid() ^ time.time_ns()).randint(1, 101))
os.environ["ROS_DOMAIN_ID"] = os.environ["CGP_SIM_BENCH_DOMAIN"]

PILE_WINDOWS = {"piling": (10, 180), "at rest": (300, 420)}
# issue 38's 300 hulls of 1,000 vertices drop 5 cm and are all asleep from tick ~176: moving from the first tick
HULLS_WINDOWS = {"moving": (1, 170), "asleep": (200, 320)}
HULLS_WINDOWS_QUICK = {"moving": (1, 170), "asleep": (200, 260)}
PILE_WINDOWS_QUICK = {"piling": (10, 150), "at rest": (270, 330)}
DEFAULT_WINDOWS = {"running": (10, 300)}
DEFAULT_WINDOWS_QUICK = {"running": (10, 150)}
MARKER_TOPICS = ("/cgp_sim/markers", "/cgp_sim/static_markers")


def pile_scene(path: Path, world: str = "") -> Path:
    """bench_convex_pile's 100 hulls as a scene file (sleeping on, as by default); ``world``: more of its ``world:``
    keys (e.g. ``sleep: false, contact_detection: once_per_tick``)."""
    sys.path.insert(1, str(HERE))
    from bench_convex_pile import FRICTION, SUBSTEPS, pile_hulls

    points, positions, orientations = pile_hulls()
    lines = [f"world: {{substeps: {SUBSTEPS}, ground_friction: {FRICTION}, ground_restitution: 0.0"
             f"{', ' + world if world else ''}}}", "bodies:"]
    for n, (p, x, q) in enumerate(zip(points, positions, orientations)):
        pts = ", ".join(f"[{a:.6f}, {b:.6f}, {c:.6f}]" for a, b, c in p)
        lines.append(f"  - {{name: h{n}, shape: convex, mass: 1.0, friction: {FRICTION}, restitution: 0.0, "
                     f"position: [{x[0]}, {x[1]}, {x[2]}], orientation: {q.tolist()}, points: [{pts}]}}")
    path.write_text("\n".join(lines) + "\n")
    return path


def hulls_scene(directory: Path) -> Path:
    """bench_spawn_rows' ``hulls_300`` scene: 300 convex bodies of a 1,000-vertex sphere hull (an STL beside it)."""
    sys.path.insert(1, str(HERE))
    from bench_spawn_rows import hull_sphere_stl

    stl = hull_sphere_stl(directory / "ball1000.stl")
    bodies = "\n".join(f"  - {{name: b{k}, shape: convex, mesh: {stl.name}, mass: 1, "
                       f"position: [{(k % 20) * 0.6 - 6}, {(k // 20) * 0.6 - 4}, 0.25]}}" for k in range(300))
    path = directory / "hulls300.yaml"
    path.write_text(f"description: 300 hulls of 1,000 vertices\nbodies:\n{bodies}\n")
    return path


# ---- the subscriber (its own process) ------------------------------------------------------------------------

def subscriber(out_path: str) -> int:
    """Take the marker topics raw until SIGTERM; write what arrived (messages, bytes) to ``out_path``."""
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from visualization_msgs.msg import MarkerArray

    rclpy.init()
    node = Node("bench_node_cost_subscriber")
    got = {topic: [] for topic in MARKER_TOPICS}
    for topic in MARKER_TOPICS:
        durability = DurabilityPolicy.TRANSIENT_LOCAL if "static" in topic else DurabilityPolicy.VOLATILE
        node.create_subscription(MarkerArray, topic, lambda m, t=topic: got[t].append(len(m)),
                                 QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=durability),
                                 raw=True)
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    while not stop:
        rclpy.spin_once(node, timeout_sec=0.05)
    Path(out_path).write_text(json.dumps(got))
    return 0


def thread_cpu_s(thread) -> float:
    """CPU seconds of another thread of this process (Linux: /proc/self/task/<tid>/stat), 0 if unknown."""
    try:
        with open(f"/proc/self/task/{thread.native_id}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, AttributeError, IndexError, ValueError):
        return 0.0


# ---- the child: one node, one configuration ------------------------------------------------------------------

def child(args) -> int:
    sys.path.insert(0, str(Path(args.root).resolve()))
    sys.path.insert(1, str(HERE))
    import rclpy
    from common import speed_probe
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    import cgp_sim_ros
    from cgp_sim_ros.ros.node import SimNode

    if Path(cgp_sim_ros.__file__).resolve().parents[1] != Path(args.root).resolve():
        raise SystemExit(f"imported {cgp_sim_ros.__file__}, not the code of {args.root}")
    windows = json.loads(args.windows)
    rclpy.init()
    root = Path(tempfile.mkdtemp(prefix="bench_node_cost_", dir=os.environ.get("BENCH_BAG_DIR")))
    node = SimNode(parameter_overrides=[Parameter("scene", value=args.scene), Parameter("bag", value=str(root / "bag")),
                                        Parameter("realtime", value=args.realtime)])
    sub = None
    if args.with_subscriber:
        sub_out = root / "subscriber.json"
        sub = subprocess.Popen([sys.executable, __file__, "--subscriber", str(sub_out)])
        deadline = time.monotonic() + 60
        while any(node.outputs.pub_markers.get_subscription_count() == 0 for _ in (0,)):
            if time.monotonic() > deadline:
                raise SystemExit("the subscriber never matched ~/markers")
            time.sleep(0.05)
    probe_before = speed_probe()
    world, outputs = node.world, node.outputs
    step = world.step
    step_s: list[float] = []
    sent: dict[str, int] = {}
    stage: dict[str, float] = {}

    def add(key, seconds):
        stage[key] = stage.get(key, 0.0) + seconds

    def timed_step():
        t0 = time.perf_counter()
        step()
        step_s.append(time.perf_counter() - t0)

    def timed(bound, key):
        def call(*a, **kw):
            t0 = time.perf_counter()
            try:
                return bound(*a, **kw)
            finally:
                add(key, time.perf_counter() - t0)
        return call

    for name in ("clock", "body_poses", "body_odometry", "contacts", "markers"):
        setattr(outputs.messages, name, timed(getattr(outputs.messages, name), "build " + name.replace("body_", "")))
    outputs.tf.dynamic = timed(outputs.tf.dynamic, "build tf")
    recorder = node.recorder
    recorder.write = timed(recorder.write, "recorder.write")
    writer_thread = recorder.writer._thread

    topic_names: dict = {}  # (rclpy asks rcl for a publisher's topic name at every call: ~1-2 µs, not the node's)

    def counted_publish(publisher, data, stamp_ns, record=True):
        topic = topic_names.get(publisher)
        if topic is None:
            topic = topic_names[publisher] = publisher.topic_name
        sent[topic] = sent.get(topic, 0) + len(data)
        t0 = time.perf_counter()
        publisher.publish(data)
        add("DDS publish odom" if topic.endswith("/odom") else "DDS publish other", time.perf_counter() - t0)
        if record and recorder is not None:
            recorder.write(topic, data, stamp_ns)

    world.step, outputs.publish = timed_step, counted_publish
    tick = node.tick
    ticked_s = [0.0]

    def timed_tick():
        t0 = time.perf_counter()
        tick()
        ticked_s[0] = time.perf_counter() - t0

    node.tick = timed_tick  # the timer's callback calls self.tick(): the spin outside it is the executor's own
    # driven as cgp-sim drives it: its executor's spin_once (the zero-period timer of realtime false calls
    # node.tick), so the executor's own work per tick (its wait set) is in the figures
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    last = max(end for _, end in windows.values())
    tick_s, marker_bytes, stages, writer_cpu, asleep_at = [], [], [], [], []
    while world.ticks < last:
        sent.clear()
        stage.clear()
        ticks_before, steps_before = world.ticks, len(step_s)
        ticked_s[0] = 0.0
        t0 = time.perf_counter()
        executor.spin_once(timeout_sec=0.05)
        spun = time.perf_counter() - t0
        if world.ticks == ticks_before:  # a spin that ran something else (a service, a discovery event)
            if tick_s and not args.realtime:
                tick_s[-1] += spun
                stages[-1]["executor (spin - tick)"] = stages[-1].get("executor (spin - tick)", 0.0) + spun
            continue
        if not args.realtime:  # (in real time the spin waits for the timer: its slack, not a cost)
            stage["executor (spin - tick)"] = spun - ticked_s[0]
        if len(step_s) == steps_before:
            step_s.append(0.0)
        tick_s.append(ticked_s[0] if args.realtime else spun)
        writer_cpu.append(thread_cpu_s(writer_thread))  # cumulative (the clock ticks are 10 ms: per window)
        stages.append(dict(stage))
        marker_bytes.append(sent.get("/cgp_sim/markers", 0) + sent.get("/cgp_sim/static_markers", 0))
        asleep_at.append(bool(world.bodies_asleep))
    executor.remove_node(node)
    probe_after = speed_probe()
    asleep = bool(world.bodies_asleep)
    received = None
    if sub is not None:
        sub.send_signal(signal.SIGTERM)
        sub.wait(30)
        received = json.loads(sub_out.read_text())
    node.close()
    node.destroy_node()
    rclpy.shutdown()
    tick_ms, step_ms = np.array(tick_s) * 1e3, np.array(step_s) * 1e3
    keys = sorted({k for row in stages for k in row})
    out = {"bodies": int(world.body_model.count), "asleep_at_end": asleep, "probe_before": probe_before,
           "probe_after": probe_after, "windows": {}}
    for name, (first, end) in windows.items():
        cost = tick_ms[first:end] - step_ms[first:end]
        out["windows"][name] = {
            "ticks": end - first,
            "tick_ms": {"median": float(np.median(tick_ms[first:end])),
                        "p99": float(np.percentile(tick_ms[first:end], 99))},
            "step_ms": {"median": float(np.median(step_ms[first:end]))},
            "node_ms": {"median": float(np.median(cost)), "p99": float(np.percentile(cost, 99))},
            "node_us_per_body": float(np.median(cost)) * 1e3 / max(1, int(world.body_model.count)),
            "stages_ms": {k: float(np.median([row.get(k, 0.0) for row in stages[first:end]])) * 1e3 for k in keys},
            "writer_thread_ms": (writer_cpu[end - 1] - writer_cpu[first]) * 1e3 / max(1, end - 1 - first),
            "asleep_ticks": int(sum(asleep_at[first:end])),
            "marker_bytes_per_tick": {"median": float(np.median(marker_bytes[first:end])),
                                      "max": int(max(marker_bytes[first:end]))}}
    if received is not None:
        out["received"] = {topic: {"messages": len(sizes), "bytes": int(sum(sizes)),
                                   "median_bytes": float(np.median(sizes)) if sizes else 0.0}
                           for topic, sizes in received.items()}
    Path(args.child).write_text(json.dumps(out))
    return 0


# ---- the peers' pile (its own process) -----------------------------------------------------------------------

def peers_child(out_path: str, windows: dict) -> int:
    """bench_convex_pile's pile in PyBullet and in MuJoCo, stepped tick by tick in turn (4 x 1/240 s each) for the
    node's windows, in process: what issue 37 compares the tick through the node with.  Writes each peer's
    median / p99 tick per window to ``out_path``."""
    sys.path.insert(1, str(HERE))
    from bench_convex_pile import mujoco_pile, pybullet_pile

    peers = {}
    for name, make in (("pybullet", pybullet_pile), ("mujoco", mujoco_pile)):
        try:
            peers[name] = make()
        except ImportError:  # not installed: the row says so
            pass
    last = max(end for _, end in windows.values())
    times = {name: np.empty(last) for name in peers}
    for k in range(last):
        for name, (step, _, _) in peers.items():
            t0 = time.perf_counter()
            step()
            times[name][k] = time.perf_counter() - t0
    for _, _, close in peers.values():
        close()
    Path(out_path).write_text(json.dumps({
        name: {window: {"median": float(np.median(t[first:end])) * 1e3,
                        "p99": float(np.percentile(t[first:end], 99)) * 1e3}
               for window, (first, end) in windows.items()} for name, t in times.items()}))
    return 0


# ---- the parent ----------------------------------------------------------------------------------------------

def run_peers(windows: dict, workdir: Path) -> dict:
    out = workdir / "peers.json"
    result = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--peers", str(out), "--windows",
                             json.dumps(windows)], cwd=workdir, capture_output=True, text=True, timeout=900)
    if result.returncode != 0 or not out.exists():
        raise RuntimeError(f"peers failed ({result.returncode}):\n{(result.stdout + result.stderr)[-3000:]}")
    return json.loads(out.read_text())


def run_child(code_root: Path, scene: str, windows: dict, with_subscriber: bool, workdir: Path, label: str,
              realtime: bool = False) -> dict:
    out = workdir / f"{label}.json"
    command = [sys.executable, str(Path(__file__).resolve()), "--child", str(out), "--root", str(code_root),
               "--scene", scene, "--windows", json.dumps(windows)]
    command += (["--with-subscriber"] if with_subscriber else []) + (["--realtime"] if realtime else [])
    env = dict(os.environ, PYTHONPATH=str(code_root), PYTHONUNBUFFERED="1")
    result = subprocess.run(command, cwd=workdir, env=env, capture_output=True, text=True, timeout=900)
    if result.returncode != 0 or not out.exists():
        raise RuntimeError(f"child {label} failed ({result.returncode}):\n{(result.stdout + result.stderr)[-3000:]}")
    return json.loads(out.read_text())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="shorter windows")
    parser.add_argument("--before", type=Path, default=None,
                        help="another checkout whose code is run interleaved with this one (before a change)")
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--subscriber", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--root", default=str(ROOT), help=argparse.SUPPRESS)
    parser.add_argument("--scene", default="default", help=argparse.SUPPRESS)
    parser.add_argument("--windows", default="{}", help=argparse.SUPPRESS)
    parser.add_argument("--with-subscriber", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--only", nargs="*", default=None,
                        help="scenes of hulls300, pile, default (and the extras pile_awake, pile_awake_once)")
    parser.add_argument("--no-subscriber-runs", action="store_true", help="only the runs with a subscriber")
    parser.add_argument("--peers", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--realtime", action="store_true",
                        help="as make run runs: real time at 60 Hz, the tick's own duration (see the docstring)")
    args = parser.parse_args(argv)
    if args.peers:
        return peers_child(args.peers, json.loads(args.windows))
    if args.subscriber:
        return subscriber(args.subscriber)
    if args.child:
        return child(args)
    sys.path.insert(0, str(HERE))
    from common import Results, speed_probe

    out = Results("node_cost_realtime" if args.realtime else "node_cost",
                  options={"quick": args.quick, "before": str(args.before) if args.before else None,
                           "realtime": args.realtime})
    workdir = Path(tempfile.mkdtemp(prefix="bench_node_cost_"))
    scene = str(pile_scene(workdir / "convex_pile.yaml"))
    versions = [("after", ROOT)] + ([("before", args.before.resolve())] if args.before else [])
    versions.reverse()  # before, then after, in each configuration
    pile_windows = PILE_WINDOWS_QUICK if args.quick else PILE_WINDOWS
    configs = [("hulls300", str(hulls_scene(workdir)), HULLS_WINDOWS_QUICK if args.quick else HULLS_WINDOWS),
               ("pile", scene, pile_windows),
               ("default", "default", DEFAULT_WINDOWS_QUICK if args.quick else DEFAULT_WINDOWS)]
    # extras, only when --only names them: the pile with sleeping off (solved every sub-step at rest, as the peers
    # are), its contacts found every sub-step and once per tick (world.contact_detection, cgp_core/collision/carry.py)
    extras = [("pile_awake", str(pile_scene(workdir / "pile_awake.yaml", "sleep: false")), pile_windows),
              ("pile_awake_once", str(pile_scene(workdir / "pile_awake_once.yaml",
                                                 "sleep: false, contact_detection: once_per_tick")), pile_windows)]
    configs = [c for c in configs + extras if c[0] in args.only] if args.only else configs
    rows = []
    print(f"speed probe before: {speed_probe()}", flush=True)
    for name, scene_arg, windows in configs:
        for with_subscriber in ((True,) if args.no_subscriber_runs else (False, True)):
            for version, code_root in versions:
                label = f"{name}_{'sub' if with_subscriber else 'nosub'}_{version}"
                result = run_child(code_root, scene_arg, windows, with_subscriber, workdir, label, args.realtime)
                for window, w in result["windows"].items():
                    row = {"scene": name, "bodies": result["bodies"], "window": window, "subscriber": with_subscriber,
                           "version": version, "realtime": args.realtime, **w, "probe_before": result["probe_before"],
                           "probe_after": result["probe_after"], "received": result.get("received")}
                    rows.append(row)
                    print(f"{label:22s} {window:8s} tick {w['tick_ms']['median']:6.2f} / {w['tick_ms']['p99']:6.2f}  "
                          f"step {w['step_ms']['median']:6.2f}  node {w['node_ms']['median']:5.2f} / "
                          f"{w['node_ms']['p99']:5.2f} ms  markers {w['marker_bytes_per_tick']['median'] / 1e3:7.1f} kB"
                          f"/tick  probe python {result['probe_before']['python_ms']:.0f} -> "
                          f"{result['probe_after']['python_ms']:.0f} ms", flush=True)
                    print(f"{'':31s} {w['node_us_per_body']:.1f} us/body; bag writer thread "
                          f"{w['writer_thread_ms']:.2f} ms/tick; stages (ms, median): "
                          + ", ".join(f"{k} {v:.2f}" for k, v in w["stages_ms"].items() if v >= 0.01), flush=True)
        if name.startswith("pile"):  # issue 37: the tick through the node against the peers' in-process tick
            peers = out.data.get("peers") or run_peers(windows, workdir)  # (once a run: the same pile for every one)
            out.data["peers"] = peers
            for window in windows:
                for version, _ in versions:
                    ticks = [r["tick_ms"]["median"] for r in rows
                             if r["scene"] == name and r["window"] == window and r["version"] == version]
                    node_tick = float(np.median(ticks))
                    line = (f"{name} {window:8s} {version}: through the node "
                            f"({'real time: the tick' if args.realtime else 'batch: the spin'}) {node_tick:6.2f} ms")
                    for peer, figures in peers.items():
                        ratio = node_tick / figures[window]["median"]
                        line += f"; {peer} in process {figures[window]['median']:6.2f} ms ({ratio:.2f}x)"
                        out.figure(f"{name}_{window.replace(' ', '_')}_{version}_node_vs_{peer}",
                                   f"the 100-hull pile ({name}) {window}, tick through the node "
                                   f"({'real time' if args.realtime else 'batch'}; {version}) / {peer}'s "
                                   "tick in process, same run", ratio, "x",
                                   "<= 0.7 (issue 37)" if peer == "pybullet" else "(reference)",
                                   ratio <= 0.7 if peer == "pybullet" else None)
                    print(line, flush=True)
    measured = "the tick - World.step, real time" if args.realtime else "the executor's spin - World.step"
    print(f"\nThe node's own cost ({measured}), ms per tick, median / p99; recording on:")
    print(f"  {'scene':8s} {'window':8s} {'subscriber':10s} " + " ".join(f"{v:>18s}" for v, _ in versions)
          + "  us/body " + " / ".join(v for v, _ in versions)
          + "  markers kB/tick " + " / ".join(v for v, _ in versions))
    for name, _, windows in configs:
        for window in windows:
            for with_subscriber in ((True,) if args.no_subscriber_runs else (False, True)):
                cells = [r for r in rows if r["scene"] == name and r["window"] == window
                         and r["subscriber"] == with_subscriber]
                by_version = {r["version"]: r for r in cells}
                print(f"  {name:8s} {window:8s} {'yes' if with_subscriber else 'no':10s} "
                      + " ".join(f"{by_version[v]['node_ms']['median']:8.2f} / {by_version[v]['node_ms']['p99']:6.2f}"
                                 for v, _ in versions)
                      + "  " + " / ".join(f"{by_version[v]['node_us_per_body']:.1f}" for v, _ in versions)
                      + "  " + " / ".join(f"{by_version[v]['marker_bytes_per_tick']['median'] / 1e3:.1f}"
                                         for v, _ in versions))
    for r in rows:
        heard = "sub" if r["subscriber"] else "nosub"
        out.figure(f"node_cost_{r['scene']}_{r['window'].replace(' ', '_')}_{heard}_{r['version']}",
                   f"node's own cost per body, {r['scene']} ({r['bodies']} bodies, {r['window']}, recording, "
                   f"{'a' if r['subscriber'] else 'no'} ~/markers subscriber; {r['version']})",
                   r["node_us_per_body"], "us", "(reference)", None, node_ms=r["node_ms"]["median"],
                   p99_ms=r["node_ms"]["p99"], marker_kb_per_tick=r["marker_bytes_per_tick"]["median"] / 1e3,
                   probe_python_ms=r["probe_before"]["python_ms"])
    out.data["rows"] = rows
    print(f"speed probe after: {speed_probe()}")
    print(f"wrote {out.write()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

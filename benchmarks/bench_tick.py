"""Issue 12's tick figures: 15,000 fish + 20 bodies, recorded, the real node path, timed from the first tick.

The node is built exactly as ``cgp-sim`` builds it — ``SimNode(parameter_overrides=[scene, bag,
realtime=False])``, default level of detail (``cgp_sim_ros/drawing/detail.py`` chooses how the fish are drawn and what
is recorded at what rate, and logs it) — in a process of its own ROS domain, and ``node.tick()`` is called back
to back from the very first tick (batch mode: no timer; the timer-driven real-time mode is
``bench_realtime.py``).  A tick is: commands in, ``World.step()`` (the 20 bodies × 4 sub-steps, then the flock),
every message serialized once as CDR, ``Publisher.publish(bytes)`` and the same bytes handed to the bag writer
thread (lz4-compressed MCAP written on the other core).

Scene ``benchmarks/scenes/tick_15k_fish.yaml``: 15,000 fish at the default flock's steady-state density in a
60 × 60 × 30 m box, 20 bodies of every shape — 8 placed on the ground, 9 dropped from 2-7 m at t = 0 (they
land, roll and settle in the first ~16 s, then sleep), 3 fixed that the flock swims around.

Reported:

- the tick's p99 (and median, p90, max) over the first 20 s of simulated time (1,200 ticks: the bodies fall,
  land, roll, settle) and over the next 60 s (3,600 ticks) — issue 12's targets, p99 <= 16.7 ms;
- the bag's growth: its size on disk after the node closed it (every .mcap, metadata.yaml) per simulated
  second — target <= 60 MB/s;
- that the fish are in the bag: recorded marker arrays are read back (``deserialize_message``): the flock's
  TRIANGLE_LIST parts must all come round (the flock is redrawn in parts, one per tick), and on ticks where
  the poses were recorded too, a part must draw its fish at those poses;
- the split per stage from timing wrappers on the node's own objects (installed on every tick; they cost
  microseconds): ``World.step`` (rigid bodies + obstacle set, flock), serialize (``messages.*``), publish,
  ``recorder.write``; median and p99 per window;
- the tick thread's own CPU time per tick (median, p99): what a tick costs when it does not wait for a core —
  on a busy shared machine the wall time is much longer (the numba worker's share of the parallel kernels is
  not in it);
- the bag writer thread's CPU time per tick (it runs beside the tick, sharing the cores and the GIL), its
  largest backlog and dropped messages; Python's garbage collections during the run and the longest;
- the same run timer-driven, as ``make run`` runs a scene (``realtime`` true: the node's own 60 Hz timer, spun
  by an executor; the tick timed around the same ``node.tick()``): p99 per window and the achieved rate — issue
  12 asks for the timer-driven figures too (a tick that sleeps between ticks can run slower than back to back);
  here the bag writer works between the ticks (``BagWriter.hold``), back to back it works beside them;
- the same scene with ``model: sphere`` over its first 20 s, for reference (issue 12 measured 27 ms there).

Writes ``benchmarks/results/tick.json``.  Run alone: ``.venv/bin/python benchmarks/bench_tick.py``
(``--quick``: 10 s + 20 s of simulated time, no sphere run).  ``BENCH_BAG_DIR`` puts the (deleted
afterwards) bags somewhere other than the system temp directory.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

# A ROS domain of our own before rclpy loads, so the benchmark neither sees nor disturbs other ROS processes.
if "CGP_SIM_BENCH_DOMAIN" not in os.environ:
    os.environ["CGP_SIM_BENCH_DOMAIN"] = str(random.Random(os.getpid() ^ time.time_ns()).randint(1, 101))
os.environ["ROS_DOMAIN_ID"] = os.environ["CGP_SIM_BENCH_DOMAIN"]

from common import GcWatch, Results, format_figures  # noqa: E402

SCENE = Path(__file__).resolve().parent / "scenes" / "tick_15k_fish.yaml"
TARGET_MS = 1e3 / 60.0
TARGET_BAG_MB_PER_S = 60.0
STAGES = ("world.step: rigid bodies (+ obstacle set)", "world.step: flock", "flock stats (order parameters + CDR)",
          "serialize (other messages.*)", "Publisher.publish", "recorder.write (caller)",
          "other (commands, events, reports)")


class TickTimer:
    """Timing wrappers on one node's objects (instance attributes shadowing the methods): per tick, the time
    spent in ``world.step``, in the flocks' ``step``, in ``messages.flock_stats`` (the flocks' order parameters,
    computed and serialized: issue 14), in the other ``messages.*``, in the node's publish-and-record ``_out``
    and in ``recorder.write``."""

    def __init__(self, node):
        self.node = node
        self.buckets = dict.fromkeys(("step", "flock", "stats", "serialize", "out", "record"), 0.0)
        self._targets: list = []

    def _wrap(self, bound, bucket: str):
        buckets, clock = self.buckets, time.perf_counter

        def timed(*args, **kwargs):
            start = clock()
            try:
                return bound(*args, **kwargs)
            finally:
                buckets[bucket] += clock() - start
        return timed

    def install(self) -> None:
        node = self.node
        self._targets = [(node.world, "step", "step"), (node.outputs, "publish", "out")]
        self._targets += [(flock, "step", "flock") for flock in node.world.flocks]
        self._targets += [(node.outputs.messages, name, "serialize")
                          for name in ("clock", "body_poses", "body_odometry", "flock_poses", "markers")]
        self._targets.append((node.outputs.messages, "flock_stats", "stats"))
        if node.recorder is not None:
            self._targets.append((node.recorder, "write", "record"))
        for obj, name, bucket in self._targets:
            setattr(obj, name, self._wrap(getattr(obj, name), bucket))

    def take(self, total: float) -> tuple:
        """This tick's split (seconds, in STAGES order); resets the buckets."""
        b = self.buckets
        split = (b["step"] - b["flock"], b["flock"], b["stats"], b["serialize"], b["out"] - b["record"], b["record"],
                 total - b["step"] - b["stats"] - b["serialize"] - b["out"])
        for k in b:
            b[k] = 0.0
        return split


def thread_cpu_s(native_id: int | None) -> float:
    """CPU time (user + system) of one thread of this process, from /proc (0 if unknown)."""
    if native_id is None:
        return 0.0
    try:
        fields = Path(f"/proc/self/task/{native_id}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def make_node(scene: Path, bag_dir: Path, name: str, realtime: bool = False):
    from rclpy.parameter import Parameter

    from cgp_sim_ros.ros.node import SimNode

    return SimNode(node_name=name, parameter_overrides=[
        Parameter("scene", value=str(scene)), Parameter("bag", value=str(bag_dir)),
        Parameter("realtime", value=realtime)])


class TimedTicks:
    """Times ``node.tick()`` however it is called — by this script back to back (batch) or by the node's own
    60 Hz timer (real time: ``node.tick`` is shadowed on the instance, which the timer callback calls) — into
    preallocated arrays: wall time, the tick thread's CPU time, the split (``TickTimer``), bodies awake, and
    when the tick started (for the achieved rate)."""

    def __init__(self, node, timer: TickTimer, total: int):
        self.node, self.timer, self.total, self.done = node, timer, total, 0
        self.ticks_ms, self.cpu_ms = np.empty(total), np.empty(total)
        self.split_ms = np.empty((total, len(STAGES)))
        self.awake = np.zeros(total, bool)
        self.starts = np.empty(total)
        self._tick = node.tick

    def __call__(self) -> None:
        if self.done >= self.total:  # real time: the timer may fire once more before the loop sees we are done
            return self._tick()
        k = self.done
        self.awake[k] = not self.node.world.bodies_asleep
        start, start_cpu = time.perf_counter(), time.thread_time()
        self._tick()
        elapsed = time.perf_counter() - start
        self.starts[k] = start
        self.ticks_ms[k] = elapsed * 1e3
        self.cpu_ms[k] = (time.thread_time() - start_cpu) * 1e3
        self.split_ms[k] = np.array(self.timer.take(elapsed)) * 1e3
        self.done += 1


def window_stats(ms: np.ndarray) -> dict:
    return {"ticks": int(len(ms)), "median": float(np.median(ms)), "p90": float(np.percentile(ms, 90)),
            "p99": float(np.percentile(ms, 99)), "max": float(ms.max()), "mean": float(ms.mean())}


def run_scene(scene: Path, bag_dir: Path, windows: list[tuple[str, int]], name: str,
              realtime: bool = False) -> dict:
    """Tick the node from its first tick through the windows ``[(label, ticks), ...]`` — back to back
    (``realtime`` False: this loop calls ``node.tick()``) or as ``make run`` does (True: the node's 60 Hz timer,
    spun by an executor); close the bag; return tick statistics per window, the split, the bag's size and what
    the writer thread did."""
    import rclpy

    node = make_node(scene, bag_dir, name, realtime=realtime)
    timer = TickTimer(node)
    timer.install()
    writer = node.recorder.writer
    writer_tid = writer._thread.native_id if writer._thread is not None else None
    total = sum(ticks for _, ticks in windows)
    timed = TimedTicks(node, timer, total)
    cpu0, wall0, writer_cpu0 = time.process_time(), time.perf_counter(), thread_cpu_s(writer_tid)
    try:
        with GcWatch() as gc_watch:
            if realtime:
                node.tick = timed  # the timer callback calls self.tick()
                executor = rclpy.executors.SingleThreadedExecutor()
                executor.add_node(node)
                while timed.done < total:
                    executor.spin_once(timeout_sec=0.1)
                executor.remove_node(node)
            else:
                while timed.done < total:
                    timed()
        wall = time.perf_counter() - wall0
        cpu = time.process_time() - cpu0
        writer_cpu = thread_cpu_s(writer_tid) - writer_cpu0
        backlog, dropped, payload = writer.max_queued_bytes, writer.dropped_messages, writer._enqueued_bytes
        sim_seconds = node.world.time
        plan = node.detail
        # pin_threads (cgp_core/jit.py ThreadPlacement) as the run had it: the tick's CPU and the node's log line
        threads = {"tick_cpu": node.threads.placement.cpu, "log": node.threads.said}
        boids = sum(f.count for f in node.world.flocks)
        neighbors = float(np.mean([f.mean_neighbors for f in node.world.flocks]))
    finally:
        node.close()  # finishes the bag: summary, metadata.yaml
        node.destroy_node()
    bag_bytes = sum(p.stat().st_size for p in bag_dir.iterdir() if p.is_file())
    ticks_ms, cpu_ms, split_ms, awake = timed.ticks_ms, timed.cpu_ms, timed.split_ms, timed.awake
    out = {"scene": str(scene.relative_to(ROOT)) if scene.is_relative_to(ROOT) else scene.name, "boids": boids,
           "mode": "real time (the node's 60 Hz timer)" if realtime else "back to back", "ticks": total,
           "sim_seconds": sim_seconds,
           "windows": {}, "neighbors_per_boid_at_end": neighbors, "process_cpu_cores": cpu / wall,
           "bag_MB": bag_bytes / 1e6, "bag_MB_per_sim_second": bag_bytes / 1e6 / sim_seconds,
           "bag_payload_MB_per_sim_second": payload / 1e6 / sim_seconds,
           "bag_writer_cpu_ms_per_tick": writer_cpu / total * 1e3, "bag_backlog_max_MB": backlog / 1e6,
           "bag_dropped_messages": dropped, "gc": {"collections": gc_watch.count, "longest_ms": gc_watch.longest_ms,
                                                  "total_ms": gc_watch.total_ms},
           "thread_placement": threads,
           "level_of_detail": {"fish_detail": plan.fish_detail, "markers_every": plan.markers_every,
                               "bag_flock_poses_every": plan.flock_poses_every, "lines": plan.lines}}
    first = 0
    for label, ticks in windows:
        part = slice(first, first + ticks)
        stats = window_stats(ticks_ms[part])
        stats["bodies_awake_fraction"] = float(awake[part].mean())
        starts = timed.starts[part]
        stats["achieved_hz"] = float((len(starts) - 1) / (starts[-1] - starts[0])) if len(starts) > 1 else None
        stats["tick_thread_cpu_ms"] = {"median": float(np.median(cpu_ms[part])),
                                       "p99": float(np.percentile(cpu_ms[part], 99))}
        stats["split_median_ms"] = dict(zip(STAGES, np.median(split_ms[part], axis=0).tolist()))
        stats["split_p99_ms"] = dict(zip(STAGES, np.percentile(split_ms[part], 99, axis=0).tolist()))
        # the slowest ticks' split: what a p99 tick is made of
        slow = np.argsort(ticks_ms[part])[-max(1, ticks // 100):]
        stats["split_of_slowest_1pct_ms"] = dict(zip(STAGES, split_ms[part][slow].mean(axis=0).tolist()))
        out["windows"][label] = stats
        first += ticks
    return out


def fish_in_bag(bag_dir: Path, samples: int = 6) -> dict:
    """Read the recorded marker arrays back and check that the flock's TRIANGLE_LIST parts draw every fish:
    every part (id 0 … K−1, K from the bag's metadata) comes round, and on a few ticks where the flock's poses
    were recorded too, the part draws its fish at those poses (vertex = p + R(q) t, within the marker's
    1/1024 m rounding)."""
    from geometry_msgs.msg import PoseArray
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message
    from visualization_msgs.msg import Marker, MarkerArray

    from cgp_core.rotation import quat_to_matrix
    from cgp_sim_ros.drawing.shapes import FISH_DETAILS, VERTEX_QUANTUM

    info = yaml.safe_load((bag_dir / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    parts = next(iter(json.loads(info["custom_data"]["cgp_sim.flock_markers_redrawn_every_n_ticks"]).values()))
    poses, markers = {}, {}
    for path in sorted(bag_dir.glob("*.mcap")):
        with open(path, "rb") as f:
            for _, channel, message in make_reader(f).iter_messages(topics=None):
                if channel.topic.endswith("/markers"):
                    markers[message.log_time] = message.data
                elif "/flocks/" in channel.topic and channel.topic.endswith("/poses"):
                    poses[message.log_time] = message.data
    both = sorted(set(markers) & set(poses))
    result = {"marker_arrays": len(markers), "flock_pose_arrays": len(poses), "parts": parts, "checked": 0,
              "fish_drawn": bool(both)}
    ids = set()
    for stamp in sorted(markers)[-3 * parts:]:  # the last arrays: every part must come round
        ids.update(m.id for m in deserialize_message(markers[stamp], MarkerArray).markers if m.ns.startswith("flocks/"))
    result["fish_drawn"] &= ids == set(range(parts))
    for stamp in [both[int(i)] for i in np.linspace(0, len(both) - 1, samples)] if both else []:
        (marker,) = [m for m in deserialize_message(markers[stamp], MarkerArray).markers if m.ns.startswith("flocks/")]
        pose_array = deserialize_message(poses[stamp], PoseArray)
        n = len(pose_array.poses)
        first, last = marker.id * n // parts, (marker.id + 1) * n // parts
        chosen = pose_array.poses[first:last]
        p = np.array([[o.position.x, o.position.y, o.position.z] for o in chosen])
        q = np.array([[o.orientation.x, o.orientation.y, o.orientation.z, o.orientation.w] for o in chosen])
        vertices = np.array([[v.x, v.y, v.z] for v in marker.points])
        per_fish = len(vertices) // len(p)
        detail = next(d for d, t in FISH_DETAILS.items() if len(t) == per_fish)
        expected = p[:, None, :] + np.einsum("nij,vj->nvi", quat_to_matrix(q), FISH_DETAILS[detail] * 0.3)
        error = float(np.abs(vertices.reshape(len(p), per_fish, 3) - expected).max())
        ok = marker.type == Marker.TRIANGLE_LIST and len(vertices) == len(p) * per_fish and error <= VERTEX_QUANTUM
        result["fish_drawn"] &= bool(ok)
        result["checked"] += 1
        result.update({"fish": n, "vertices_per_fish": per_fish, "detail": detail,
                       "max_vertex_error_m": max(error, result.get("max_vertex_error_m", 0.0))})
    return result


def run(quick: bool = False, first_s: float = 20.0, next_s: float = 60.0, sphere_s: float = 20.0,
        options: dict | None = None) -> dict:
    import rclpy

    if quick:
        first_s, next_s, sphere_s = 10.0, 20.0, 0.0
    out = Results("tick", options=options or {"quick": quick, "first_s": first_s, "next_s": next_s,
                                              "sphere_s": sphere_s})
    out.data["ros_domain_id"] = int(os.environ["ROS_DOMAIN_ID"])
    root = Path(tempfile.mkdtemp(prefix="bench_tick_", dir=os.environ.get("BENCH_BAG_DIR")))
    rate = 60
    windows = [(f"first {first_s:g} s", round(first_s * rate)), (f"next {next_s:g} s", round(next_s * rate))]
    rclpy.init(domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    try:
        print(f"15k fish + 20 bodies, recorded, from the first tick: {first_s:g} s + {next_s:g} s of simulated "
              f"time (ROS_DOMAIN_ID {os.environ['ROS_DOMAIN_ID']}, bag in {root})", flush=True)
        fish = run_scene(SCENE, root / "fish", windows, "cgp_sim_bench_fish")
        fish["fish_in_bag"] = fish_in_bag(root / "fish")
        shutil.rmtree(root / "fish", ignore_errors=True)
        os.sync()  # the filesystem frees the ~3 GB bag now, not during the next run's first ticks
        print(f"the same, timer-driven at 60 Hz in real time (as make run runs a scene): {first_s:g} s + {next_s:g} s "
              "...", flush=True)
        realtime = run_scene(SCENE, root / "fish_realtime", windows, "cgp_sim_bench_fish_rt", realtime=True)
        shutil.rmtree(root / "fish_realtime", ignore_errors=True)
        sphere = None
        if sphere_s > 0:
            raw = yaml.safe_load(SCENE.read_text())
            raw["flocks"][0]["model"] = "sphere"
            sphere_scene = root / "tick_15k_sphere.yaml"
            sphere_scene.write_text(yaml.safe_dump(raw))
            print(f"the same with model: sphere, first {sphere_s:g} s ...", flush=True)
            sphere = run_scene(sphere_scene, root / "sphere", [(f"first {sphere_s:g} s", round(sphere_s * rate))],
                               "cgp_sim_bench_sphere")
            sphere["scene"] = "tick_15k_fish.yaml with model: sphere"
    finally:
        rclpy.try_shutdown()
        shutil.rmtree(root, ignore_errors=True)

    out.data["fish"] = fish
    out.data["fish_realtime"] = realtime
    out.data["sphere"] = sphere
    import numba

    # which thread pool ran the flock's parallel kernels (TBB when installed, else OpenMP: cgp_core/jit.py), and
    # the GIL switch interval the node set
    out.data["numba_threading_layer"] = numba.threading_layer()
    out.data["gil_switch_interval_s"] = sys.getswitchinterval()
    print(f"  numba thread pool: {out.data['numba_threading_layer']}, {numba.get_num_threads()} threads; GIL switch "
          f"interval {sys.getswitchinterval() * 1e3:g} ms")
    first, later = (fish["windows"][label] for label, _ in windows)
    out.figure("tick_15k_fish_p99_first", f"15k fish + 20 bodies, recorded: tick p99, first {first_s:g} s (bodies "
               f"falling)", first["p99"], "ms", f"<= {TARGET_MS:.1f}", first["p99"] <= TARGET_MS, issue12=True,
               median=first["median"], max=first["max"], bodies_awake_fraction=first["bodies_awake_fraction"])
    out.figure("tick_15k_fish_p99_next", f"15k fish + 20 bodies, recorded: tick p99, next {next_s:g} s",
               later["p99"], "ms", f"<= {TARGET_MS:.1f}", later["p99"] <= TARGET_MS, issue12=True,
               median=later["median"], max=later["max"])
    rt_first, rt_later = (realtime["windows"][label] for label, _ in windows)
    out.figure("tick_15k_fish_rt_p99_first", f"  the same in real time (60 Hz timer): tick p99, first {first_s:g} s",
               rt_first["p99"], "ms", f"<= {TARGET_MS:.1f}", rt_first["p99"] <= TARGET_MS, issue12=True,
               median=rt_first["median"], max=rt_first["max"], achieved_hz=rt_first["achieved_hz"])
    out.figure("tick_15k_fish_rt_p99_next", f"  the same in real time (60 Hz timer): tick p99, next {next_s:g} s",
               rt_later["p99"], "ms", f"<= {TARGET_MS:.1f}", rt_later["p99"] <= TARGET_MS, issue12=True,
               median=rt_later["median"], max=rt_later["max"], achieved_hz=rt_later["achieved_hz"])
    out.figure("bag_15k_fish_MB_per_s", "15k fish run: bag growth per simulated second", fish["bag_MB_per_sim_second"],
               "MB/s", f"<= {TARGET_BAG_MB_PER_S:g}", fish["bag_MB_per_sim_second"] <= TARGET_BAG_MB_PER_S,
               issue12=True)
    seen = fish["fish_in_bag"]
    out.figure("bag_15k_fish_drawn", f"15k fish run: the bag's markers draw every fish at its recorded pose "
               f"({seen.get('parts', '?')} parts, {seen.get('checked', 0)} checked, {seen.get('detail', '?')} detail)",
               bool(seen["fish_drawn"]), "", "yes", seen["fish_drawn"], issue12=True)
    out.figure("tick_15k_fish_median_first", f"  15k fish: tick median, first {first_s:g} s", first["median"], "ms",
               "(reference)", None)
    out.figure("tick_15k_fish_median_next", f"  15k fish: tick median, next {next_s:g} s", later["median"], "ms",
               "(reference)", None)
    if sphere is not None:
        window = next(iter(sphere["windows"].values()))
        out.figure("tick_15k_sphere_p99_first", f"  same scene, model: sphere: tick p99, first {sphere_s:g} s",
                   window["p99"], "ms", f"<= {TARGET_MS:.1f} (reference)", window["p99"] <= TARGET_MS,
                   median=window["median"])
    path = out.write()

    print()
    for label, stats in [(f"{fish['mode']}, {k}", v) for k, v in fish["windows"].items()] + \
            [(f"{realtime['mode']}, {k}", v) for k, v in realtime["windows"].items()]:
        print(f"  {label}: achieved {stats['achieved_hz']:.1f} Hz, tick median {stats['median']:.2f} ms, "
              f"p90 {stats['p90']:.2f}, p99 {stats['p99']:.2f}, max {stats['max']:.2f}; "
              f"bodies awake {100 * stats['bodies_awake_fraction']:.0f} % of ticks; tick thread "
              f"CPU median {stats['tick_thread_cpu_ms']['median']:.2f} ms, "
              f"p99 {stats['tick_thread_cpu_ms']['p99']:.2f}")
        for stage in STAGES:
            print(f"    {stage:44} median {stats['split_median_ms'][stage]:6.2f}  p99 "
                  f"{stats['split_p99_ms'][stage]:6.2f}  slowest 1 %: {stats['split_of_slowest_1pct_ms'][stage]:6.2f}")
    print(f"  real time: writer thread {realtime['bag_writer_cpu_ms_per_tick']:.2f} ms CPU per tick, backlog max "
          f"{realtime['bag_backlog_max_MB']:.1f} MB, dropped {realtime['bag_dropped_messages']}")
    print(f"  bag: {fish['bag_MB']:.0f} MB for {fish['sim_seconds']:.0f} s = "
          f"{fish['bag_MB_per_sim_second']:.1f} MB per simulated second "
          f"(payload {fish['bag_payload_MB_per_sim_second']:.1f} MB/s); writer thread "
          f"{fish['bag_writer_cpu_ms_per_tick']:.2f} ms CPU per tick, "
          f"backlog max {fish['bag_backlog_max_MB']:.1f} MB, "
          f"dropped {fish['bag_dropped_messages']}")
    print(f"  level of detail: {' '.join(fish['level_of_detail']['lines'])}")
    print(f"  fish in the bag: {fish['fish_in_bag']}")
    print(f"  garbage collections {fish['gc']['collections']}, longest {fish['gc']['longest_ms']:.1f} ms")
    print()
    print(format_figures(out.data["figures"]))
    print(f"\nwrote {path.relative_to(ROOT)}")
    return out.data


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="10 s + 20 s of simulated time, no sphere run")
    parser.add_argument("--first", type=float, default=20.0, help="first window [s of sim time] (default 20)")
    parser.add_argument("--next", type=float, default=60.0, help="second window [s of sim time] (default 60)")
    parser.add_argument("--sphere", type=float, default=20.0, help="model: sphere reference run [s] (0: none)")
    args = parser.parse_args(argv)
    run(quick=args.quick, first_s=args.first, next_s=args.next, sphere_s=args.sphere, options=vars(args))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

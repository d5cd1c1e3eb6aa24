"""The node's full tick at 15,000 boids + 20 bodies (issue 7's first figure), in process, on this machine.

What is timed: ``SimNode.tick()`` — commands in, ``World.step()`` (20 rigid bodies × the scene's 4 sub-steps,
then the flock), every message serialized once as CDR (clock, body PoseArray, 20 Odometry, the flock's
PoseArray, the MarkerArray with the flock's 15k-point SPHERE_LIST), each published with
``Publisher.publish(bytes)`` and handed to the bag writer (``Recorder.write``; the writer thread compresses and
writes the MCAP file on the other core).  The node is built exactly as ``cgp-sim`` builds it —
``SimNode(parameter_overrides=[scene, bag, realtime=False])`` — in a process of its own ROS domain, and its
ticks are run back to back (no timer, no executor: no subscriber is connected, the publishers only serve
DDS's history).  Scene: ``benchmarks/scenes/tick_15k.yaml``.

Reported, over ``--ticks`` ticks after ``--warmup`` ticks:

- the tick's median, p90 and max (plain ticks: every other tick; target median <= 16.7 ms = 60 Hz);
- the split, measured on the other ticks by timing wrappers around the node's own objects (installed on
  every other tick only, so the plain ticks show they cost nothing): ``world.step`` (itself split into the
  rigid bodies' sub-steps and the flock's step), ``messages.*`` (serialize), ``Publisher.publish`` (the
  node's ``_out`` minus ``recorder.write``) and ``recorder.write`` (the caller's side of recording);
- the bag writer thread's CPU time per tick (it runs in parallel: it only costs the tick through the GIL and
  the shared cores), the largest backlog it had and whether it dropped anything;
- how the tick scales with the flock (``--scaling``: the same bodies, flocks of 1k, 5k, 15k at the same
  density, fewer ticks each);
- a sampling profile (pyinstrument, if installed; cProfile otherwise) of the 15k tick: the functions with the
  most cumulative time, written with the call tree to ``benchmarks/results/tick_profile.txt``.

Writes ``benchmarks/results/tick.json``.  Run alone: ``.venv/bin/python benchmarks/bench_tick.py`` (``--quick``:
fewer ticks, no scaling rows).  ``BENCH_BAG_DIR`` puts the (deleted afterwards) bags somewhere other than
the system temp directory.
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

# A ROS domain of our own before rclpy loads, so the benchmark neither sees nor disturbs other ROS processes
# (tests use 1..101 picked at random the same way).
if "CGP_SIM_BENCH_DOMAIN" not in os.environ:
    os.environ["CGP_SIM_BENCH_DOMAIN"] = str(random.Random(os.getpid() ^ time.time_ns()).randint(1, 101))
os.environ["ROS_DOMAIN_ID"] = os.environ["CGP_SIM_BENCH_DOMAIN"]

from common import RESULTS, Results, format_figures  # noqa: E402

SCENE = Path(__file__).resolve().parent / "scenes" / "tick_15k.yaml"
TARGET_MS = 1e3 / 60.0
SCALING_COUNTS = (1_000, 5_000, 15_000)
STAGES = ("world.step", "  rigid bodies (substeps) + obstacle set", "  flock step", "serialize (messages.*)",
          "Publisher.publish", "recorder.write (caller)", "other (commands, events, reports)")


def scene_with_count(count: int, directory: Path) -> Path:
    """The tick scene with ``count`` boids spawned at the same density (spawn box scaled by (n/N)^(1/3))."""
    if count == _scene_count():
        return SCENE
    raw = yaml.safe_load(SCENE.read_text())
    flock = raw["flocks"][0]
    scale = (count / flock["count"]) ** (1.0 / 3.0)
    center, extent = flock["spawn"]["center"], flock["spawn"]["extent"]
    low_z = center[2] - extent[2] / 2  # keep the flock's floor where it was (the bodies are on the ground)
    flock["spawn"]["extent"] = [e * scale for e in extent]
    flock["spawn"]["center"] = [center[0], center[1], low_z + extent[2] * scale / 2]
    flock["count"] = count
    path = directory / f"tick_{count}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def _scene_count() -> int:
    return int(yaml.safe_load(SCENE.read_text())["flocks"][0]["count"])


class TickTimer:
    """Timing wrappers on one node's objects, switchable per tick (instance attributes shadowing the methods,
    so removing them restores the original objects exactly)."""

    def __init__(self, node):
        self.node = node
        self.buckets = dict.fromkeys(("step", "flock", "serialize", "out", "record"), 0.0)
        self._targets = [(node.world, "step", "step"), (node, "_out", "out")]
        self._targets += [(flock, "step", "flock") for flock in node.world.flocks]
        self._targets += [(node.messages, name, "serialize")
                          for name in ("clock", "body_poses", "body_odometry", "flock_poses", "markers")]
        if node.recorder is not None:
            self._targets.append((node.recorder, "write", "record"))

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
        for k in self.buckets:
            self.buckets[k] = 0.0
        for obj, name, bucket in self._targets:
            setattr(obj, name, self._wrap(getattr(obj, name), bucket))

    def remove(self) -> None:
        for obj, name, _ in self._targets:
            del obj.__dict__[name]

    def split(self, total: float) -> dict[str, float]:
        b = self.buckets
        return {"world.step": b["step"], "  rigid bodies (substeps) + obstacle set": b["step"] - b["flock"],
                "  flock step": b["flock"], "serialize (messages.*)": b["serialize"],
                "Publisher.publish": b["out"] - b["record"], "recorder.write (caller)": b["record"],
                "other (commands, events, reports)": total - b["step"] - b["serialize"] - b["out"]}


def thread_cpu_s(native_id: int | None) -> float:
    """CPU time (user + system) of one thread of this process, from /proc (0 if unknown)."""
    if native_id is None:
        return 0.0
    try:
        fields = Path(f"/proc/self/task/{native_id}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def make_node(scene: Path, bag_dir: Path, name: str):
    from rclpy.parameter import Parameter

    from cgp_sim_ros.node import SimNode

    return SimNode(node_name=name, parameter_overrides=[
        Parameter("scene", value=str(scene)), Parameter("bag", value=str(bag_dir)),
        Parameter("realtime", value=False)])


def measure(scene: Path, bag_dir: Path, warmup: int, ticks: int, name: str = "cgp_sim_bench",
            profile_ticks: int = 0) -> tuple[dict, str | None]:
    """Build a node, run ``warmup`` ticks, then ``ticks`` ticks alternating plain / instrumented."""
    node = make_node(scene, bag_dir, name)
    profile_text = None
    try:
        world = node.world
        for _ in range(warmup):
            node.tick()
        writer = node.recorder.writer
        writer_tid = writer._thread.native_id if writer._thread is not None else None
        timer = TickTimer(node)
        plain, instrumented, splits = [], [], []
        writer_cpu0, cpu0, wall0 = thread_cpu_s(writer_tid), time.process_time(), time.perf_counter()
        for k in range(ticks):
            if k % 2:
                timer.install()
            start = time.perf_counter()
            node.tick()
            elapsed = time.perf_counter() - start
            if k % 2:
                timer.remove()
                instrumented.append(elapsed)
                splits.append(timer.split(elapsed))
            else:
                plain.append(elapsed)
        wall = time.perf_counter() - wall0
        cpu = time.process_time() - cpu0
        writer_cpu = thread_cpu_s(writer_tid) - writer_cpu0
        backlog_mb = writer.max_queued_bytes / 1e6
        if profile_ticks:
            profile_text = profile(node, profile_ticks)
        t_close = time.perf_counter()
        node.close()
        close_s = time.perf_counter() - t_close
        flock = world.flocks[0]
        plain_ms = np.array(plain) * 1e3
        row = {
            "boids": sum(f.count for f in world.flocks), "bodies": world.body_model.count,
            "substeps": world.substeps, "integrator": world.scene.world.integrator,
            "ticks": ticks, "warmup_ticks": warmup,
            "tick_ms_median": float(np.median(plain_ms)), "tick_ms_p90": float(np.percentile(plain_ms, 90)),
            "tick_ms_max": float(plain_ms.max()), "tick_ms_mean": float(plain_ms.mean()),
            "instrumented_tick_ms_median": float(np.median(instrumented) * 1e3),
            "split_ms_median": {stage: float(np.median([s[stage] for s in splits]) * 1e3) for stage in STAGES},
            "split_ms_mean": {stage: float(np.mean([s[stage] for s in splits]) * 1e3) for stage in STAGES},
            "neighbors_per_boid": float(flock.mean_neighbors),
            "visible_neighbors_per_boid": float(flock.mean_visible_neighbors),
            "process_cpu_cores": cpu / wall,
            "bag_writer_cpu_ms_per_tick": writer_cpu / ticks * 1e3,
            "bag_payload_MB_per_tick": _bag_payload(node) / max(1, world.ticks) / 1e6,
            "bag_backlog_max_MB": backlog_mb, "bag_dropped_messages": writer.dropped_messages,
            "bag_error": writer.error, "bag_close_s": close_s,
            "bag_file_MB": sum(f.stat().st_size for f in writer.files) / 1e6,
            "sim_seconds": world.time,
        }
        return row, profile_text
    finally:
        node.close()
        node.destroy_node()


def _bag_payload(node) -> float:
    writer = node.recorder.writer
    return float(writer._enqueued_bytes)


def profile(node, ticks: int) -> str:
    """Profile ``ticks`` ticks: pyinstrument (sampling, 1 ms) when installed, else cProfile.  Returns the
    report: functions by cumulative time, then the call tree."""
    try:
        from pyinstrument import Profiler
    except ImportError:
        Profiler = None
    if Profiler is not None:
        profiler = Profiler(interval=0.001, async_mode="disabled")
        profiler.start()
        for _ in range(ticks):
            node.tick()
        profiler.stop()
        flat = profiler.output_text(unicode=True, color=False, flat=True, flat_time="total")
        tree = profiler.output_text(unicode=True, color=False, show_all=False)
        return (f"pyinstrument, {ticks} ticks of SimNode.tick() at 15k boids + 20 bodies\n\n"
                f"== functions by cumulative (total) time ==\n{_head(flat, 45)}\n\n== call tree ==\n{tree}")
    import cProfile
    import io
    import pstats

    prof = cProfile.Profile()
    prof.enable()
    for _ in range(ticks):
        node.tick()
    prof.disable()
    out = io.StringIO()
    pstats.Stats(prof, stream=out).sort_stats("cumulative").print_stats(45)
    return f"cProfile (pyinstrument not installed), {ticks} ticks of SimNode.tick()\n\n{out.getvalue()}"


def _head(text: str, lines: int) -> str:
    return "\n".join(text.splitlines()[:lines])


def top_functions(profile_text: str, count: int = 15) -> list[str]:
    """The first ``count`` lines of the flat cumulative listing (for the summary)."""
    lines = profile_text.split("== functions by cumulative (total) time ==", 1)[-1].splitlines()
    body = [line.rstrip() for line in lines if line.strip() and not line.startswith(("==", "  _", "pyinstrument"))]
    return [line for line in body if "Recorded:" not in line and "Samples:" not in line
            and "Duration:" not in line and "Program:" not in line][:count]


def print_row(row: dict) -> None:
    print(f"  tick: median {row['tick_ms_median']:.2f} ms, p90 {row['tick_ms_p90']:.2f}, max {row['tick_ms_max']:.2f}"
          f" (instrumented ticks: median {row['instrumented_tick_ms_median']:.2f}); {row['neighbors_per_boid']:.1f}"
          f" neighbours/boid; {row['process_cpu_cores']:.2f} cores busy")
    for stage in STAGES:
        print(f"    {stage:42} {row['split_ms_median'][stage]:7.2f} ms median  {row['split_ms_mean'][stage]:7.2f} mean")
    print(f"    bag writer thread: {row['bag_writer_cpu_ms_per_tick']:.2f} ms CPU per tick (in parallel), "
          f"{row['bag_payload_MB_per_tick']:.2f} MB payload per tick, backlog max {row['bag_backlog_max_MB']:.1f} MB, "
          f"dropped {row['bag_dropped_messages']}, close {row['bag_close_s']:.2f} s")


def run(quick: bool = False, warmup: int | None = None, ticks: int | None = None, scaling=None,
        profile_ticks: int | None = None, options: dict | None = None) -> dict:
    warmup = warmup if warmup is not None else (120 if quick else 180)
    ticks = ticks if ticks is not None else (120 if quick else 300)
    profile_ticks = profile_ticks if profile_ticks is not None else (40 if quick else 120)
    scaling = list(scaling) if scaling is not None else ([] if quick else list(SCALING_COUNTS))
    import rclpy

    out = Results("tick", options=options or {"quick": quick, "warmup": warmup, "ticks": ticks,
                                              "scaling": scaling, "profile_ticks": profile_ticks})
    out.data["ros_domain_id"] = int(os.environ["ROS_DOMAIN_ID"])
    out.data["scene"] = str(SCENE.relative_to(ROOT))
    root = Path(tempfile.mkdtemp(prefix="bench_tick_", dir=os.environ.get("BENCH_BAG_DIR")))
    rclpy.init(domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    try:
        print(f"full tick, {SCENE.name}: {warmup} warm-up ticks, {ticks} timed "
              f"(ROS_DOMAIN_ID {os.environ['ROS_DOMAIN_ID']}, bag in {root})", flush=True)
        main_row, profile_text = measure(SCENE, root / "bag_main", warmup, ticks, profile_ticks=profile_ticks)
        print_row(main_row)
        rows = []
        for count in scaling:
            if count == main_row["boids"]:
                rows.append(main_row)
                continue
            scene = scene_with_count(count, root)
            print(f"scaling: {count} boids ...", flush=True)
            row, _ = measure(scene, root / f"bag_{count}", warmup=max(60, warmup // 2), ticks=max(60, ticks // 2),
                             name=f"cgp_sim_bench_{count}")
            print_row(row)
            rows.append(row)
    finally:
        rclpy.try_shutdown()
        shutil.rmtree(root, ignore_errors=True)

    out.data["tick"] = main_row
    out.data["scaling"] = sorted(rows, key=lambda r: r["boids"]) if rows else [main_row]
    median = main_row["tick_ms_median"]
    out.figure("tick_15k_median", "full tick, 15k boids + 20 bodies: step + publish + bag (median)", median,
               "ms", f"<= {TARGET_MS:.1f}", median <= TARGET_MS, issue7=True, p90=main_row["tick_ms_p90"],
               max=main_row["tick_ms_max"], split_ms=main_row["split_ms_median"])
    out.figure("tick_15k_p90", "full tick, 15k boids + 20 bodies (p90)", main_row["tick_ms_p90"], "ms",
               f"<= {TARGET_MS:.1f} (reference)", main_row["tick_ms_p90"] <= TARGET_MS)
    out.figure("tick_15k_world_step", "  of which World.step (bodies + flock), median", 
               main_row["split_ms_median"]["world.step"], "ms", "(split)", None)
    if profile_text:
        (RESULTS / "tick_profile.txt").parent.mkdir(parents=True, exist_ok=True)
        (RESULTS / "tick_profile.txt").write_text(profile_text)
        out.data["profile_top"] = top_functions(profile_text, 25)
        out.data["profile_file"] = "benchmarks/results/tick_profile.txt"
    path = out.write()
    print()
    if len(out.data["scaling"]) > 1:
        print(f"{'boids':>7} {'bodies':>6} {'median ms':>10} {'p90':>7} {'max':>7} {'step':>7} {'flock':>7} "
              f"{'serialize':>9} {'publish':>8} {'record':>7} {'nbrs':>5}")
        for r in out.data["scaling"]:
            s = r["split_ms_median"]
            print(f"{r['boids']:>7} {r['bodies']:>6} {r['tick_ms_median']:10.2f} {r['tick_ms_p90']:7.2f} "
                  f"{r['tick_ms_max']:7.2f} {s['world.step']:7.2f} {s['  flock step']:7.2f} "
                  f"{s['serialize (messages.*)']:9.2f} {s['Publisher.publish']:8.2f} "
                  f"{s['recorder.write (caller)']:7.2f} {r['neighbors_per_boid']:5.1f}")
        print()
    print(format_figures([f for f in out.data["figures"] if f["pass"] is not None or f["issue7"]]))
    if profile_text:
        print("\nprofile, top functions by cumulative time (full report in benchmarks/results/tick_profile.txt):")
        for line in out.data.get("profile_top", [])[:15]:
            print("  " + line)
    print(f"\nwrote {path.relative_to(ROOT)}")
    return out.data


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer ticks, no scaling rows, shorter profile")
    parser.add_argument("--warmup", type=int, default=None, help="ticks before timing (default 180; quick 120)")
    parser.add_argument("--ticks", type=int, default=None, help="timed ticks (default 300; quick 120)")
    parser.add_argument("--scaling", type=int, nargs="*", default=None,
                        help=f"flock sizes for the scaling rows (default {' '.join(map(str, SCALING_COUNTS))}; "
                             "quick: none)")
    parser.add_argument("--profile-ticks", type=int, default=None, help="ticks profiled (0 = no profile)")
    args = parser.parse_args(argv)
    run(quick=args.quick, warmup=args.warmup, ticks=args.ticks, scaling=args.scaling,
        profile_ticks=args.profile_ticks, options=vars(args))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

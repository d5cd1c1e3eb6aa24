"""The node's full tick at 15,000 boids + 20 bodies (issue 7's first figure), in process, on this machine.

What is timed: ``SimNode.tick()`` — commands in, ``World.step()`` (20 rigid bodies × the scene's 4 sub-steps,
then the flock), every message serialized once as CDR (clock, body PoseArray, 20 Odometry, the flock's
PoseArray, the MarkerArray with the flock's 15k-point SPHERE_LIST), each published with
``Publisher.publish(bytes)`` and handed to the bag writer (``Recorder.write``; the writer thread compresses and
writes the MCAP file on the other core).  The node is built exactly as ``cgp-sim`` builds it —
``SimNode(parameter_overrides=[scene, bag, realtime=False])`` — in a process of its own ROS domain, and its
ticks are run back to back (no timer, no executor: no subscriber is connected, the publishers only serve
DDS's history).  Scene: ``benchmarks/scenes/tick_15k.yaml``.

Reported, over ``--ticks`` ticks after the warm-up (at least ``--warmup`` ticks, and on until the bodies have
settled and sleep: see ``cgp_core.world.SLEEP_SPEED``; at most 30 s of sim time):

- the tick's median, p90 and max (plain ticks: every other tick; target median <= 16.7 ms = 60 Hz), in the
  scene's steady state: the flock swimming, the bodies at rest;
- the median tick while the bodies still move (1 s to 6 s into the warm-up: landed, rolling, tumbling), where
  the 20 bodies' contact solve runs every sub-step;
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
#: warm-up ticks [first, last) timed as "bodies moving" (1 s to 6 s: landed, rolling, tumbling)
MOVING_TICKS = (60, 360)
#: the warm-up goes on until the bodies sleep, for at most this many ticks (30 s of sim time)
SETTLE_TICKS = 1800
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
        for k in self.buckets:
            self.buckets[k] = 0.0
        self._targets = [(node.world, "step", "step"), (node, "_out", "out")]
        self._targets += [(flock, "step", "flock") for flock in node.world.flocks]
        self._targets += [(node.messages, name, "serialize")
                          for name in ("clock", "body_poses", "body_odometry", "flock_poses", "markers")]
        if node.recorder is not None:
            self._targets.append((node.recorder, "write", "record"))
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


def make_node(scene: Path, bag_dir: Path | None, name: str):
    from rclpy.parameter import Parameter

    from cgp_sim_ros.node import SimNode

    return SimNode(node_name=name, parameter_overrides=[
        Parameter("scene", value=str(scene)), Parameter("bag", value=str(bag_dir) if bag_dir else ""),
        Parameter("realtime", value=False)])


class Phase:
    """Ticks of the node in one configuration (recording on / off): plain and instrumented tick times, the split,
    and the CPU the bag writer threads used."""

    def __init__(self, label: str, node, recording: bool):
        self.label, self.node, self.recording = label, node, recording
        self.timer = TickTimer(node)
        self.plain: list[float] = []
        self.instrumented: list[float] = []
        self.splits: list[dict] = []
        self.cpu_s = self.wall_s = self.writer_cpu_s = 0.0
        self.payload_bytes = 0
        self.backlog_max = 0
        self.dropped = 0
        self.errors: list[str] = []
        self.bags = 0

    def run(self, ticks: int, bag_dir: Path) -> None:
        """One untimed tick, then ``ticks`` ticks, every other one instrumented.  Recording phase: the node records into
        ``bag_dir`` (a new bag, unless the node is still recording the one it was started with); the bag is
        finished after the block, outside the timed ticks.  Other phase: the node's recorder is closed first,
        so no writer thread exists while it ticks."""
        node, timer = self.node, self.timer
        if self.recording and node.recorder is None:
            node._start_recording(Path(bag_dir))  # what the node does for its `bag` parameter
        elif not self.recording and node.recorder is not None:
            node.recorder.close()
            node.recorder = None
        node.tick()  # untimed: the first tick after a switch (a new bag's first messages, cold caches)
        writer = node.recorder.writer if node.recorder is not None else None
        writer_tid = writer._thread.native_id if writer is not None and writer._thread is not None else None
        deadline = time.monotonic() + 5.0
        while writer is not None and writer.queued_bytes > 0 and time.monotonic() < deadline:
            time.sleep(0.001)
        payload0 = writer._enqueued_bytes if writer is not None else 0
        writer_cpu0, cpu0, wall0 = thread_cpu_s(writer_tid), time.process_time(), time.perf_counter()
        for _ in range(ticks):
            instrument = len(self.plain) > len(self.instrumented)
            if instrument:
                timer.install()
            start = time.perf_counter()
            node.tick()
            elapsed = time.perf_counter() - start
            if instrument:
                timer.remove()
                self.instrumented.append(elapsed)
                self.splits.append(timer.split(elapsed))
            else:
                self.plain.append(elapsed)
        if writer is not None:  # the writer's CPU for these ticks includes catching up with them
            deadline = time.monotonic() + 5.0
            while writer.queued_bytes > 0 and time.monotonic() < deadline:
                time.sleep(0.001)
        self.wall_s += time.perf_counter() - wall0
        self.cpu_s += time.process_time() - cpu0
        if writer is not None:
            self.writer_cpu_s += thread_cpu_s(writer_tid) - writer_cpu0
            self.backlog_max = max(self.backlog_max, writer.max_queued_bytes)
            self.bags += 1
            self.payload_bytes += writer._enqueued_bytes - payload0
            node.recorder.close()  # finish this bag outside the timed ticks
            self.dropped += writer.dropped_messages
            if writer.error:
                self.errors.append(writer.error)
            node.recorder = None

    def row(self) -> dict:
        world = self.node.world
        plain_ms = np.array(self.plain) * 1e3
        ticks = len(self.plain) + len(self.instrumented)
        row = {
            "variant": self.label, "boids": sum(f.count for f in world.flocks), "bodies": world.body_model.count,
            "substeps": world.substeps, "integrator": world.scene.world.integrator, "ticks": ticks,
            "tick_ms_median": float(np.median(plain_ms)), "tick_ms_p90": float(np.percentile(plain_ms, 90)),
            "tick_ms_max": float(plain_ms.max()), "tick_ms_mean": float(plain_ms.mean()),
            "instrumented_tick_ms_median": float(np.median(self.instrumented) * 1e3),
            "split_ms_median": {stage: float(np.median([s[stage] for s in self.splits]) * 1e3) for stage in STAGES},
            "split_ms_mean": {stage: float(np.mean([s[stage] for s in self.splits]) * 1e3) for stage in STAGES},
            "neighbors_per_boid": float(np.mean([f.mean_neighbors for f in world.flocks])) if world.flocks else 0.0,
            "process_cpu_cores": self.cpu_s / self.wall_s,
            "sim_seconds_at_end": world.time,
        }
        if self.recording:
            row.update({
                "bag_writer_cpu_ms_per_tick": self.writer_cpu_s / ticks * 1e3,
                "bag_payload_MB_per_tick": self.payload_bytes / ticks / 1e6,
                "bag_backlog_max_MB": self.backlog_max / 1e6, "bag_dropped_messages": self.dropped,
                "bag_errors": self.errors, "bags": self.bags})
        return row


BLOCK_TICKS = 30


def measure(scene: Path, bag_root: Path, warmup: int, ticks: int, name: str = "cgp_sim_bench",
            compare_no_bag: bool = False, profile_ticks: int = 0) -> tuple[list[dict], str | None]:
    """Build the node recording into ``bag_root/bag_0`` (as ``cgp-sim --bag`` does), run ``warmup`` ticks,
    then ``ticks`` timed ticks.  With ``compare_no_bag``, as many ticks again with recording off, interleaved
    in blocks of ``BLOCK_TICKS`` (one node, so both phases step the same flock through the same states; each
    recording block writes a bag of its own, finished between blocks).  Returns one row per phase and the
    profile (``profile_ticks`` > 0, recording on)."""
    node = make_node(scene, bag_root / "bag_0", name)
    phases = [Phase("bag", node, recording=True)]
    if compare_no_bag:
        phases.append(Phase("no bag", node, recording=False))
    profile_text = None
    try:
        # Warm-up, in two parts.  The dropped bodies land and roll in the first seconds: the ticks from 1 s to
        # 6 s are timed as the "bodies moving" figure.  Then on until every body rests and they sleep (rolling
        # resistance stops the balls and capsules in ~16 s of sim time; at most SETTLE_TICKS), so that the
        # timed ticks measure the scene's steady state, as the headline figure says.
        moving = []
        for k in range(max(warmup, SETTLE_TICKS)):
            start = time.perf_counter()
            node.tick()
            if MOVING_TICKS[0] <= k < MOVING_TICKS[1]:
                moving.append(time.perf_counter() - start)
            if k >= warmup and node.world.bodies_asleep:
                break
        warmed = k + 1
        done = 0
        while done < ticks:
            block = min(BLOCK_TICKS, ticks - done)
            for phase in phases:
                phase.run(block, bag_root / f"bag_{done}")
            done += block
        rows = [phase.row() for phase in phases]
        for row in rows:
            row["warmup_ticks"] = warmed
            row["bodies_asleep"] = bool(node.world.bodies_asleep)
            row["bodies_moving_tick_ms_median"] = 1e3 * float(np.median(moving)) if moving else None
        if profile_ticks:
            if node.recorder is None:
                node._start_recording(bag_root / "bag_profile")
            profile_text = profile(node, profile_ticks)
        return rows, profile_text
    finally:
        node.close()
        node.destroy_node()


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


def top_functions(profile_text: str, ticks: int, count: int = 25) -> list[dict]:
    """The flat cumulative listing as records: function, where, ms per tick, % of the tick (the harness's own
    frame excluded)."""
    if not profile_text.startswith("pyinstrument"):
        return []  # cProfile's listing has other columns; its text is in the profile file
    listing = profile_text.split("== functions by cumulative (total) time ==", 1)[-1].split("== call tree ==")[0]
    rows = []
    for line in listing.splitlines():
        parts = line.split()
        if len(parts) < 3:
            continue
        try:
            seconds = float(parts[0])
        except ValueError:
            continue
        rows.append({"function": parts[1], "where": parts[2], "seconds": seconds})
    rows = [r for r in rows if not r["where"].startswith("bench_tick.py")]
    if not rows:
        return []
    total = max(r["seconds"] for r in rows)
    return [{"function": r["function"], "where": r["where"], "ms_per_tick": 1e3 * r["seconds"] / ticks,
             "percent_of_tick": 100.0 * r["seconds"] / total} for r in rows[:count]]


def print_row(row: dict) -> None:
    print(f"  [{row['variant']}] tick: median {row['tick_ms_median']:.2f} ms, p90 {row['tick_ms_p90']:.2f}, "
          f"max {row['tick_ms_max']:.2f} (instrumented ticks: median {row['instrumented_tick_ms_median']:.2f}); "
          f"{row['neighbors_per_boid']:.1f} neighbours/boid; {row['process_cpu_cores']:.2f} cores busy")
    for stage in STAGES:
        print(f"    {stage:42} {row['split_ms_median'][stage]:7.2f} ms median {row['split_ms_mean'][stage]:7.2f} mean")
    if "bag_writer_cpu_ms_per_tick" in row:
        print(f"    bag writer thread: {row['bag_writer_cpu_ms_per_tick']:.2f} ms CPU per tick (in parallel), "
              f"{row['bag_payload_MB_per_tick']:.2f} MB payload per tick, backlog max "
              f"{row['bag_backlog_max_MB']:.1f} MB, dropped {row['bag_dropped_messages']}")


def scaling_table(rows: list[dict]) -> str:
    lines = [f"{'boids':>7} {'bodies':>6} {'tick ms':>8} {'p90':>7} {'max':>7} {'step':>7} {'bodies':>7} "
             f"{'flock':>7} {'serialize':>9} {'publish':>8} {'record':>7} {'nbrs':>5}"]
    for r in rows:
        s = r["split_ms_median"]
        lines.append(f"{r['boids']:>7} {r['bodies']:>6} {r['tick_ms_median']:8.2f} {r['tick_ms_p90']:7.2f} "
                     f"{r['tick_ms_max']:7.2f} {s['world.step']:7.2f} "
                     f"{s['  rigid bodies (substeps) + obstacle set']:7.2f} {s['  flock step']:7.2f} "
                     f"{s['serialize (messages.*)']:9.2f} {s['Publisher.publish']:8.2f} "
                     f"{s['recorder.write (caller)']:7.2f} {r['neighbors_per_boid']:5.1f}")
    return "\n".join(lines)


def run(quick: bool = False, warmup: int | None = None, ticks: int | None = None, scaling=None,
        profile_ticks: int | None = None, compare_no_bag: bool = True, options: dict | None = None) -> dict:
    """Measure, print, write ``results/tick.json`` (and ``results/tick_profile.txt``); returns the results."""
    warmup = warmup if warmup is not None else (180 if quick else 300)
    ticks = ticks if ticks is not None else (120 if quick else 480)
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
        print(f"full tick, {SCENE.name}: {warmup} warm-up ticks, {ticks} timed"
              f"{', interleaved with a node that does not record' if compare_no_bag else ''} "
              f"(ROS_DOMAIN_ID {os.environ['ROS_DOMAIN_ID']}, bag in {root})", flush=True)
        main_rows, profile_text = measure(SCENE, root / "bag_main", warmup, ticks, compare_no_bag=compare_no_bag,
                                          profile_ticks=profile_ticks)
        for row in main_rows:
            print_row(row)
        main_row = main_rows[0]
        rows = []
        for count in scaling:
            if count == main_row["boids"]:
                rows.append(main_row)
                continue
            scene = scene_with_count(count, root)
            print(f"scaling: {count} boids ...", flush=True)
            (row,), _ = measure(scene, root / f"bag_{count}", warmup=max(60, warmup // 2),
                                ticks=max(60, ticks // 2), name=f"cgp_sim_bench_{count}")
            print_row(row)
            rows.append(row)
    finally:
        rclpy.try_shutdown()
        shutil.rmtree(root, ignore_errors=True)

    out.data["tick"] = main_row
    out.data["tick_no_bag"] = main_rows[1] if len(main_rows) > 1 else None
    out.data["scaling"] = sorted(rows, key=lambda r: r["boids"]) if rows else [main_row]
    median = main_row["tick_ms_median"]
    split = main_row["split_ms_median"]
    out.figure("tick_15k_median", "full tick, 15k boids + 20 settled bodies: step + publish + bag (median)", median,
               "ms", f"<= {TARGET_MS:.1f}", median <= TARGET_MS, issue7=True, p90=main_row["tick_ms_p90"],
               max=main_row["tick_ms_max"], split_ms=split)
    moving_ms = main_row.get("bodies_moving_tick_ms_median")
    if moving_ms is not None:
        out.figure("tick_15k_moving", "full tick 15k + 20 bodies while the bodies move (1-6 s), median", moving_ms,
                   "ms", f"<= {TARGET_MS:.1f} (reference)", moving_ms <= TARGET_MS)
    out.figure("tick_15k_p90", "full tick 15k + 20 bodies, p90", main_row["tick_ms_p90"], "ms",
               f"<= {TARGET_MS:.1f} (reference)", main_row["tick_ms_p90"] <= TARGET_MS)
    out.figure("tick_15k_world_step", "  of which World.step: 20 bodies (settled: asleep)", 
               split["  rigid bodies (substeps) + obstacle set"], "ms", "(split)", None)
    out.figure("tick_15k_flock_step", "  of which World.step: flock (15k, avoiding bodies)",
               split["  flock step"], "ms", "(split)", None)
    out.figure("tick_15k_serialize_publish", "  of which serialize + publish + recorder.write",
               split["serialize (messages.*)"] + split["Publisher.publish"] + split["recorder.write (caller)"],
               "ms", "(split)", None)
    if out.data["tick_no_bag"]:
        cost = median - out.data["tick_no_bag"]["tick_ms_median"]
        out.figure("tick_15k_bag_cost", "  recording's cost to the tick (vs the same node without bag)", cost,
                   "ms", "(split)", None)
    if profile_text:
        (RESULTS / "tick_profile.txt").parent.mkdir(parents=True, exist_ok=True)
        (RESULTS / "tick_profile.txt").write_text(profile_text)
        out.data["profile_top"] = top_functions(profile_text, profile_ticks, 30)
        out.data["profile_file"] = "benchmarks/results/tick_profile.txt"
    path = out.write()
    print()
    if len(out.data["scaling"]) > 1:
        print("scaling (with bag; median ms; split medians from the instrumented ticks):")
        print(scaling_table(out.data["scaling"]))
        print()
    print(format_figures(out.data["figures"]))
    if profile_text:
        print("\nprofile, top functions by cumulative time (full report in benchmarks/results/tick_profile.txt):")
        for r in out.data.get("profile_top", [])[:20]:
            print(f"  {r['ms_per_tick']:7.2f} ms/tick {r['percent_of_tick']:5.1f} %  {r['function']}  {r['where']}")
    print(f"\nwrote {path.relative_to(ROOT)}")
    return out.data


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer ticks, no scaling rows, shorter profile")
    parser.add_argument("--warmup", type=int, default=None, help="ticks before timing (default 180; quick 120)")
    parser.add_argument("--ticks", type=int, default=None, help="timed ticks per phase (default 480; quick 120)")
    parser.add_argument("--scaling", type=int, nargs="*", default=None,
                        help=f"flock sizes for the scaling rows (default {' '.join(map(str, SCALING_COUNTS))}; "
                             "quick: none)")
    parser.add_argument("--profile-ticks", type=int, default=None,
                        help="ticks profiled (default 120; quick 40; 0 = no profile)")
    parser.add_argument("--no-compare", action="store_true",
                        help="skip the interleaved node without bag (the recording's cost)")
    args = parser.parse_args(argv)
    run(quick=args.quick, warmup=args.warmup, ticks=args.ticks, scaling=args.scaling,
        profile_ticks=args.profile_ticks, compare_no_bag=not args.no_compare, options=vars(args))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

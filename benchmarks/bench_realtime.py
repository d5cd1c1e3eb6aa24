"""Issue 12's real-time figures: the node as ``make run`` runs it — timer-driven, real time, recording — and
its start-up.

**Real time** (target: achieved tick rate over 30 s >= 59.5 Hz, no "falling behind" warning).  A child process
runs ``cgp_sim_ros.ros.cli.main`` — exactly what the ``cgp-sim`` command runs, with ``--bag`` as ``make run``
passes it — on the default scene (60 Hz, real time), with two timing wrappers installed on the node class
before it is built: one on the timer callback (when each tick *starts*: the period between ticks) and one
around ``tick()`` (how long a tick *takes*).  30 s after the first tick the child sends itself SIGINT, which
``cgp-sim`` handles as a clean stop (the bag is finished).  Reported: the achieved rate (ticks in those 30 s /
30 s), the tick duration's and the tick period's median, p99 and max, the "falling behind" warnings the node
logged, and Python's garbage collections in the child.  A tick that sleeps between ticks can run slower than
back to back (cold caches after the sleep, timer wake-up latency): the period shows it where the duration
cannot.  The same run without the node's ``gc.freeze`` (the child makes it a no-op) is reported beside it, to
show what the garbage collector costs the period.

**Start-up** (targets: process start → first ``/clock`` message <= 5 s with warm caches, <= 30 s from a fresh
clone).  ``cgp-sim --scene default --bag <new dir>`` is started as its own process and this process listens on
``/clock``.  Discovery may take a second or more, so the first message received is not the first published:
in real time the node publishes ``/clock`` = t at t after its first tick, so the first tick happened at
``receive time − stamp``; the start-up is that minus the process start.  *Cold*: numba's compile caches of the
installed project are deleted first (``__pycache__/*.nbi, *.nbc`` under ``cgp_core`` and ``cgp_sim_ros``: an
install without ``make setup``'s warm-up, or the first start after an edit of every kernel: the node has the
default scene's kernels compiled by three worker processes, ``cgp_sim_ros.warmup.compile_missing_kernels``,
before its first tick).  Then ``make setup``'s warm-up (``python -P -m cgp_sim_ros.warmup``: every kernel,
what a fresh clone's ``make setup``/``make run`` compiles once) is timed; it also puts back the whole cache
(issue 14's flock rules, the parallel twins for big flocks), so that no kernel the cold node did not reach
compiles in the middle of the real-time runs.  *Warm*: the same command again — what
``make run`` starts on a fresh clone, after ``make setup``.

Writes ``benchmarks/results/realtime.json``.  Run alone: ``.venv/bin/python benchmarks/bench_realtime.py``
(``--quick``: 10 s instead of 30 s, no run without ``gc.freeze``).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from common import GcWatch, Results, format_figures, stop_node  # noqa: E402

TARGET_RATE_HZ = 59.5
TARGET_WARM_S = 5.0
TARGET_COLD_S = 30.0
WARNING = "falling behind real time"


# ---- the child: cgp-sim's main() with timing wrappers ----------------------------------------------------

def child(out_path: str, seconds: float, no_freeze: bool, argv: list[str]) -> int:
    """Run ``cgp_sim_ros.ros.cli.main(argv)`` with the node's timer callback and tick timed; stop ``seconds``
    after the first tick with SIGINT (cgp-sim's clean stop); write the times to ``out_path``."""
    import gc

    if no_freeze:
        gc.freeze = lambda: None  # the comparison run: the node's freeze does nothing
    from cgp_sim_ros.ros import cli
    from cgp_sim_ros.ros.node import SimNode

    callbacks, starts, ends = [], [], []
    gc_watch = GcWatch()  # installed at the first tick

    original_on_timer, original_tick = SimNode._on_timer, SimNode.tick

    def on_timer(self):
        callbacks.append(time.perf_counter())
        return original_on_timer(self)

    def tick(self):
        start = time.perf_counter()
        try:
            return original_tick(self)
        finally:
            starts.append(start)
            ends.append(time.perf_counter())
            if len(starts) == 1:
                gc.callbacks.append(gc_watch)
                threading.Timer(seconds, lambda: os.kill(os.getpid(), signal.SIGINT)).start()

    SimNode._on_timer, SimNode.tick = on_timer, tick
    status = cli.main(["cgp-sim", *argv])
    Path(out_path).write_text(json.dumps({
        "status": status, "callbacks": callbacks, "starts": starts, "ends": ends, "gc": gc_watch.as_dict(),
        "process_start_to_first_tick_s": (starts[0] - _PROCESS_START_PERF) if starts else None}))
    return 0


_PROCESS_START_PERF = time.perf_counter()  # this module is the child's first import: ~ the process start


# ---- the parent --------------------------------------------------------------------------------------------

def venv_python() -> str:
    return sys.executable


def run_realtime(label: str, seconds: float, no_freeze: bool, workdir: Path, scene: str = "default") -> dict:
    """One child run; returns its figures."""
    out = workdir / f"{label}.json"
    bag = workdir / f"bag_{label}"
    command = [venv_python(), str(Path(__file__).resolve()), "--child", str(out), "--seconds", str(seconds)]
    command += ["--no-freeze"] if no_freeze else []
    command += ["--", "--scene", scene, "--bag", str(bag)]
    env = dict(os.environ, PYTHONUNBUFFERED="1", RCUTILS_LOGGING_BUFFERED_STREAM="0")
    result = subprocess.run(command, cwd=workdir, env=env, capture_output=True, text=True, timeout=seconds + 300)
    log = result.stdout + result.stderr
    if result.returncode != 0 or not out.exists():
        raise RuntimeError(f"realtime child {label} failed ({result.returncode}):\n{log[-3000:]}")
    data = json.loads(out.read_text())
    starts, ends, callbacks = (np.array(data[k]) for k in ("starts", "ends", "callbacks"))
    first = starts[0]
    window = starts < first + seconds
    ticks = int(window.sum())
    duration_ms = (ends - starts)[window] * 1e3
    period_ms = np.diff(starts[window]) * 1e3
    warnings = len(re.findall(WARNING, log))
    return {
        "label": label, "seconds": seconds, "ticks": ticks, "achieved_hz": ticks / seconds,
        "tick_ms": {"median": float(np.median(duration_ms)), "p99": float(np.percentile(duration_ms, 99)),
                    "max": float(duration_ms.max())},
        "period_ms": {"median": float(np.median(period_ms)), "p99": float(np.percentile(period_ms, 99)),
                      "max": float(period_ms.max()), "p1": float(np.percentile(period_ms, 1))},
        "falling_behind_warnings": warnings, "gc": {k: v for k, v in data["gc"].items() if not k.startswith("_")},
        "process_start_to_first_tick_s": data["process_start_to_first_tick_s"],
        "timer_callbacks_without_tick": int(len(callbacks) - len(starts)),
    }


def numba_caches() -> list[Path]:
    """The numba cache files of the installed project (what a fresh install does not have yet)."""
    import importlib.util

    found = []
    for package in ("cgp_core", "cgp_sim_ros"):
        spec = importlib.util.find_spec(package)
        if spec is None or not spec.submodule_search_locations:
            continue
        for location in spec.submodule_search_locations:
            found += [p for p in Path(location).rglob("__pycache__/*") if p.suffix in (".nbi", ".nbc")]
    return found


def run_setup_warmup() -> float:
    """Seconds that ``make setup``'s warm-up takes to compile the kernels the cold start did not (and to load
    the others); afterwards the cache is complete, as ``make setup`` leaves it."""
    started = time.monotonic()
    subprocess.run([sys.executable, "-P", "-m", "cgp_sim_ros.warmup"], check=True, stdout=subprocess.DEVNULL)
    return time.monotonic() - started


def run_startup(label: str, workdir: Path, domain: int, cold: bool) -> dict:
    """``cgp-sim`` as its own process; seconds from its start to its first tick, seen through ``/clock``."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock

    removed = 0
    if cold:
        for path in numba_caches():
            path.unlink(missing_ok=True)
            removed += 1
    node = rclpy.create_node(f"startup_probe_{label}")
    received = []
    node.create_subscription(Clock, "/clock", lambda msg: received.append((time.monotonic(), msg)),
                             QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    executable = str(Path(sys.executable).parent / "cgp-sim")
    bag = workdir / f"bag_startup_{label}"
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
    started = time.monotonic()
    process = subprocess.Popen([executable, "--scene", "default", "--bag", str(bag)], env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = started + 180.0
        while not received and time.monotonic() < deadline and process.poll() is None:
            rclpy.spin_once(node, timeout_sec=0.05)
        if not received:
            raise RuntimeError(f"no /clock from cgp-sim within 180 s (exit {process.poll()})")
        arrival, msg = received[0]
        stamp = msg.clock.sec + 1e-9 * msg.clock.nanosec
        first_tick = arrival - stamp  # real time: /clock = t is published t after the first tick
    finally:
        stop_node(process)
        node.destroy_node()
    return {"label": label, "cold": cold, "numba_cache_files_removed": removed,
            "start_to_first_clock_s": first_tick - started, "first_clock_received_after_s": arrival - started,
            "first_stamp_received_s": stamp}


def run(quick: bool = False, seconds: float = 30.0, options: dict | None = None, scene: str = "default",
        startup: bool = True) -> dict:
    import rclpy

    if quick:
        seconds = 10.0
    out = Results("realtime", options=options or {"quick": quick, "seconds": seconds})
    domain = int(os.environ.get("CGP_SIM_BENCH_DOMAIN") or random.Random(os.getpid() ^ time.time_ns()).randint(1, 101))
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    workdir = Path(tempfile.mkdtemp(prefix="bench_realtime_", dir=os.environ.get("BENCH_BAG_DIR")))
    try:
        print(f"start-up: cgp-sim --scene default, cold (numba caches deleted) then warm (ROS_DOMAIN_ID {domain})",
              flush=True)
        cold = warm = None
        if startup:
            rclpy.init(domain_id=domain)
            try:
                cold = run_startup("cold", workdir, domain, cold=True)
                print(f"  cold: first /clock {cold['start_to_first_clock_s']:.2f} s after process start "
                      f"({cold['numba_cache_files_removed']} cache files removed)", flush=True)
                cold["setup_warmup_s"] = run_setup_warmup()
                print(f"  make setup's warm-up (every kernel, as on a fresh clone): {cold['setup_warmup_s']:.1f} s",
                      flush=True)
                warm = run_startup("warm", workdir, domain, cold=False)
                print(f"  warm: first /clock {warm['start_to_first_clock_s']:.2f} s after process start",
                      flush=True)
            finally:
                rclpy.try_shutdown()
        runs = [("realtime", False)] + ([] if quick else [("realtime_no_gc_freeze", True)])
        results = []
        for label, no_freeze in runs:
            print(f"{label}: scene {scene}, 60 Hz real time, recording, {seconds:g} s from the first tick ...",
                  flush=True)
            r = run_realtime(label, seconds, no_freeze, workdir, scene)
            print(f"  achieved {r['achieved_hz']:.2f} Hz; tick median {r['tick_ms']['median']:.2f} ms, p99 "
                  f"{r['tick_ms']['p99']:.2f}, max {r['tick_ms']['max']:.1f}; period median "
                  f"{r['period_ms']['median']:.2f} ms, p99 {r['period_ms']['p99']:.2f}, max "
                  f"{r['period_ms']['max']:.1f}; {r['falling_behind_warnings']} 'falling behind' warnings; "
                  f"gc {r['gc']['count']}, longest {r['gc']['longest_ms']:.1f} ms", flush=True)
            results.append(r)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)

    main = results[0]
    out.data.update({"startup": {"cold": cold, "warm": warm}, "runs": results})
    out.figure("realtime_default_hz", f"default scene, real time + recording: achieved rate over {seconds:g} s",
               main["achieved_hz"], "Hz", f">= {TARGET_RATE_HZ}", main["achieved_hz"] >= TARGET_RATE_HZ,
               issue12=True, falling_behind_warnings=main["falling_behind_warnings"])
    out.figure("realtime_default_warnings", "  'falling behind real time' warnings in that run",
               main["falling_behind_warnings"], "", "0", main["falling_behind_warnings"] == 0, issue12=True)
    out.figure("realtime_default_tick_p99", "  tick duration p99 (median in the JSON)", main["tick_ms"]["p99"], "ms",
               "<= 16.7", main["tick_ms"]["p99"] <= 1e3 / 60, issue12=True, median=main["tick_ms"]["median"])
    out.figure("realtime_default_period_p99", "  tick period p99 (timer-driven; median in the JSON)",
               main["period_ms"]["p99"], "ms", "(reference: 16.7)", None, median=main["period_ms"]["median"])
    if startup:
        out.figure("startup_warm_s", "start-up to first /clock, default scene, warm caches",
                   warm["start_to_first_clock_s"], "s", f"<= {TARGET_WARM_S:g}",
                   warm["start_to_first_clock_s"] <= TARGET_WARM_S, issue12=True)
        out.figure("startup_cold_s", "start-up to first /clock, default scene, no compile cache at all",
                   cold["start_to_first_clock_s"], "s", f"<= {TARGET_COLD_S:g}",
                   cold["start_to_first_clock_s"] <= TARGET_COLD_S, issue12=True)
        out.figure("setup_warmup_s", "  then make setup's warm-up (the rest of the kernels; once per clone)",
                   cold["setup_warmup_s"], "s", "(reference)", None)
    if len(results) > 1:
        other = results[1]
        out.figure("realtime_no_freeze_period_p99", "  same run without gc.freeze: tick period p99",
                   other["period_ms"]["p99"], "ms", "(comparison)", None, gc_longest_ms=other["gc"]["longest_ms"],
                   achieved_hz=other["achieved_hz"])
    path = out.write()
    print()
    print(format_figures(out.data["figures"]))
    print(f"\nwrote {path.relative_to(ROOT)}")
    return out.data


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "--child":
        rest = argv[argv.index("--") + 1:] if "--" in argv else []
        own = argv[:argv.index("--")] if "--" in argv else argv
        parser = argparse.ArgumentParser()
        parser.add_argument("--child", required=True)
        parser.add_argument("--seconds", type=float, required=True)
        parser.add_argument("--no-freeze", action="store_true")
        args = parser.parse_args(own)
        return child(args.child, args.seconds, args.no_freeze, rest)
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="10 s instead of 30 s, no run without gc.freeze")
    parser.add_argument("--seconds", type=float, default=30.0, help="real-time window after the first tick")
    parser.add_argument("--scene", default="default", help="scene of the real-time runs (diagnosis; the figures "
                        "are the default scene's)")
    parser.add_argument("--no-startup", action="store_true", help="skip the start-up measurements")
    args = parser.parse_args(argv)
    run(quick=args.quick, seconds=args.seconds, options=vars(args), scene=args.scene, startup=not args.no_startup)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

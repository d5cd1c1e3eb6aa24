"""Issue 34: the numba kernels' cold compile — every kernel (``make setup``'s warm-up) and the default scene's own
(what the node compiles at start-up when it finds no cache), wall and CPU time, and where the CPU time goes.

    .venv/bin/python benchmarks/bench_compile.py [--quick] [--before PATH] [--rounds N]

Each measurement is a fresh ``python -P -m cgp_sim_ros.warmup`` (``--default-scene`` for the default scene's
kernels) with ``NUMBA_CACHE_DIR`` set to a new temporary directory: numba then reads and writes its cache there
only (``cgp_core.jit``'s locators put a user-given cache directory first; the in-tree ``__pycache__`` beside the
sources is not read), so the compile is cold whatever the checkout's own cache holds.  The warm-up starts its
compile workers as it does in ``make setup``; the CPU time is the warm-up's and its workers' (``wait4``'s
rusage of the child: a process's waited-for children are counted in it).  Then the same command again on the
cache just written: the warm start, which should compile nothing.

Per function (every kernel's run only): a ``numba:compile`` listener (``numba.core.event``) in every process of
the run — loaded through a ``sitecustomize`` module on ``PYTHONPATH``, so the workers have it too — records each
dispatcher's compile with its *own* CPU time (``time.process_time``, its nested compiles of callees excluded);
the table lists the ten dearest functions, summed over their compiles (one per signature and per process) with
the parts (workers) that compiled them, and what the warm start still compiles (numba's own functions that have
no cache: they are compiled in every process).

``--before PATH`` runs another checkout's code (e.g. a worktree of the main branch before a change) interleaved
with this one — before, after, before, after — so that both see the same phases of the shared machine; the speed
probe (``common.speed_probe``) is taken before each run and printed beside its figures.  Not one of ``run.py``'s
default benchmarks (it takes minutes): an extra (``run.py --extras`` or ``--only compile``).

Writes ``benchmarks/results/compile.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from collections import defaultdict
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

from benchmarks.common import Results, format_speed_probe, speed_probe  # noqa: E402

#: issue 34's goals on 2 cores: every kernel within 60 s, the default scene's within 20 s (wall)
TARGETS = {"all": 60.0, "default_scene": 20.0, "warm": 3.0}

#: the listener every process of a run loads (``sitecustomize``): one JSON file of compile records per process
LISTENER = textwrap.dedent('''
    """bench_compile.py's numba:compile listener (loaded by site at start-up through PYTHONPATH)."""
    import atexit, json, os, sys, time

    _out = os.environ.get("CGP_SIM_COMPILE_EVENTS")
    if _out:
        from numba.core import event

        _stack, _records = [], []

        class _Own(event.Listener):
            def on_start(self, ev):
                _stack.append([time.process_time(), time.perf_counter(), 0.0, 0.0])

            def on_end(self, ev):
                cpu0, wall0, child_cpu, child_wall = _stack.pop()
                cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
                if _stack:
                    _stack[-1][2] += cpu
                    _stack[-1][3] += wall
                f = ev.data["dispatcher"].py_func
                _records.append({"function": f"{f.__module__}.{f.__qualname__}", "own_cpu": cpu - child_cpu,
                                 "own_wall": wall - child_wall, "args": str(ev.data["args"])[:300]})

        event.register("numba:compile", _Own())

        def _write():
            part = sys.argv[sys.argv.index("--part") + 1] if "--part" in sys.argv else "main"
            with open(os.path.join(_out, f"{os.getpid()}.json"), "w") as f:
                json.dump({"part": part, "records": _records}, f)

        atexit.register(_write)
''')


def run_warmup(tree: Path, cache: Path, default_scene: bool, events: Path | None) -> dict:
    """``python -P -m cgp_sim_ros.warmup`` of ``tree``'s code with the numba cache in ``cache``: wall and CPU
    seconds (the process and its workers), and the per-process compile records when ``events`` is given."""
    path = [str(tree)] + ([str(events / "site")] if events else []) + \
        [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=os.pathsep.join(path))
    env.pop("CGP_SIM_JIT_ONLY", None)
    env.pop("NUMBA_DISABLE_JIT", None)
    if events:
        env["CGP_SIM_COMPILE_EVENTS"] = str(events)
    command = [sys.executable, "-P", "-m", "cgp_sim_ros.warmup"] + (["--default-scene"] if default_scene else [])
    started = time.perf_counter()
    process = subprocess.Popen(command, cwd=tree, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    output = process.stdout.read().decode(errors="replace")
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - started
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode != 0:
        raise RuntimeError(f"the warm-up failed ({process.returncode}):\n{output[-3000:]}")
    result = {"wall_s": round(wall, 2), "cpu_s": round(usage.ru_utime + usage.ru_stime, 2),
              "output": output.strip().splitlines()[-3:]}
    if events:
        result["processes"] = [json.loads(p.read_text()) for p in sorted(events.glob("*.json"))]
    return result


def by_function(processes: list[dict]) -> list[dict]:
    """The compile records of a run summed per function, dearest first."""
    table = defaultdict(lambda: {"own_cpu_s": 0.0, "own_wall_s": 0.0, "compiles": 0, "parts": set()})
    for process in processes:
        for record in process["records"]:
            row = table[record["function"]]
            row["own_cpu_s"] += record["own_cpu"]
            row["own_wall_s"] += record["own_wall"]
            row["compiles"] += 1
            row["parts"].add(process["part"])
    rows = [{"function": name, **row, "parts": sorted(row["parts"])} for name, row in table.items()]
    return sorted(rows, key=lambda r: -r["own_cpu_s"])


def by_part(processes: list[dict]) -> dict[str, float]:
    """Compile CPU seconds per process (worker part, or "main": the warm-up's own process)."""
    parts = defaultdict(float)
    for process in processes:
        parts[process["part"]] += sum(r["own_cpu"] for r in process["records"])
    return {k: round(v, 1) for k, v in sorted(parts.items(), key=lambda kv: -kv[1])}


def measure(tree: Path, label: str, default_scene_only: bool, workdir: Path) -> dict:
    """One round for one checkout: every kernel cold (with the listener) and warm; the default scene's cold."""
    result = {"version": label, "tree": str(tree)}
    cache = Path(tempfile.mkdtemp(prefix="cache_", dir=workdir))
    events = Path(tempfile.mkdtemp(prefix="events_", dir=workdir))
    (events / "site").mkdir()
    (events / "site" / "sitecustomize.py").write_text(LISTENER)
    try:
        result["probe_default_scene"] = speed_probe()
        cold = run_warmup(tree, cache, True, events)
        processes = cold.pop("processes")
        cold["compile_cpu_s"] = round(sum(r["own_cpu"] for p in processes for r in p["records"]), 1)
        cold["by_part"] = by_part(processes)
        cold["top"] = [{**r, "own_cpu_s": round(r["own_cpu_s"], 2), "own_wall_s": round(r["own_wall_s"], 2)}
                       for r in by_function(processes)]
        result["default_scene"] = cold
        print(f"  {label:6s} default scene cold {cold['wall_s']:6.1f} s wall {cold['cpu_s']:6.1f} s CPU "
              f"(compiling {cold['compile_cpu_s']} s)   probe {result['probe_default_scene']}", flush=True)
    finally:
        shutil.rmtree(cache, ignore_errors=True)
        for f in events.glob("*.json"):
            f.unlink()
    if default_scene_only:
        shutil.rmtree(events, ignore_errors=True)
        return result
    cache = Path(tempfile.mkdtemp(prefix="cache_", dir=workdir))
    try:
        result["probe_all"] = speed_probe()
        cold = run_warmup(tree, cache, False, events)
        processes = cold.pop("processes")
        cold["compile_cpu_s"] = round(sum(r["own_cpu"] for p in processes for r in p["records"]), 1)
        cold["compiles"] = sum(len(p["records"]) for p in processes)
        cold["by_part"] = by_part(processes)
        functions = by_function(processes)
        cold["functions"] = len(functions)
        cold["top"] = [{**r, "own_cpu_s": round(r["own_cpu_s"], 2), "own_wall_s": round(r["own_wall_s"], 2)}
                       for r in functions]
        result["all"] = cold
        print(f"  {label:6s} every kernel cold  {cold['wall_s']:6.1f} s wall {cold['cpu_s']:6.1f} s CPU "
              f"(compiling {cold['compile_cpu_s']} s in {cold['compiles']} compiles)   probe {result['probe_all']}",
              flush=True)
        for f in events.glob("*.json"):
            f.unlink()
        result["probe_warm"] = speed_probe()
        warm = run_warmup(tree, cache, False, events)
        processes = warm.pop("processes")
        warm["compile_cpu_s"] = round(sum(r["own_cpu"] for p in processes for r in p["records"]), 1)
        warm["compiled"] = [{**r, "own_cpu_s": round(r["own_cpu_s"], 2), "own_wall_s": round(r["own_wall_s"], 2)}
                            for r in by_function(processes)[:20]]
        result["warm"] = warm
        print(f"  {label:6s} every kernel warm  {warm['wall_s']:6.1f} s wall {warm['cpu_s']:6.1f} s CPU "
              f"(still compiled: {warm['compile_cpu_s']} s)   probe {result['probe_warm']}", flush=True)
    finally:
        shutil.rmtree(cache, ignore_errors=True)
        shutil.rmtree(events, ignore_errors=True)
    return result


def _median(values: list[float]) -> float:
    values = sorted(values)
    middle = len(values) // 2
    return values[middle] if len(values) % 2 else (values[middle - 1] + values[middle]) / 2


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", type=Path, default=None,
                        help="another checkout whose code is run interleaved with this one (before a change)")
    parser.add_argument("--rounds", type=int, default=1, help="rounds of (before,) after (default 1)")
    parser.add_argument("--default-scene-only", action="store_true", help="only the default scene's kernels")
    parser.add_argument("--quick", action="store_true", help="(accepted for run.py; the same run)")
    args = parser.parse_args(argv)
    out = Results("compile", options={"before": str(args.before) if args.before else None, "rounds": args.rounds,
                                      "default_scene_only": args.default_scene_only})
    versions = ([("before", args.before.resolve())] if args.before else []) + [("after", ROOT)]
    workdir = Path(tempfile.mkdtemp(prefix="cgp_sim_bench_compile_"))
    runs = []
    try:
        for round_ in range(args.rounds):
            print(f"round {round_ + 1} of {args.rounds}", flush=True)
            for label, tree in versions:
                runs.append({"round": round_, **measure(tree, label, args.default_scene_only, workdir)})
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    out.data["runs"] = runs

    def figures_of(label: str) -> dict:
        mine = [r for r in runs if r["version"] == label]
        summary = {"default_scene_wall_s": _median([r["default_scene"]["wall_s"] for r in mine]),
                   "default_scene_cpu_s": _median([r["default_scene"]["cpu_s"] for r in mine])}
        if not args.default_scene_only:
            for key in ("wall_s", "cpu_s", "compile_cpu_s"):
                summary[f"all_{key}"] = _median([r["all"][key] for r in mine])
                summary[f"warm_{key}"] = _median([r["warm"][key] for r in mine])
        return summary

    summaries = {label: figures_of(label) for label, _ in versions}
    out.data["summary"] = summaries
    after = summaries["after"]
    if not args.default_scene_only:
        out.figure("compile_all_wall_s", "every kernel compiled, cold cache, 2 cores (wall)", after["all_wall_s"],
                   "s", f"<= {TARGETS['all']:g}", after["all_wall_s"] <= TARGETS["all"],
                   cpu_s=after["all_cpu_s"])
        out.figure("compile_all_cpu_s", "every kernel compiled, cold cache (CPU, all processes)",
                   after["all_cpu_s"], "s", "(reference)", None)
        out.figure("compile_warm_wall_s", "every kernel, warm cache (wall)", after["warm_wall_s"], "s",
                   f"<= {TARGETS['warm']:g}", after["warm_wall_s"] <= TARGETS["warm"])
    out.figure("compile_default_scene_wall_s", "the default scene's kernels compiled, cold cache, 2 cores (wall)",
               after["default_scene_wall_s"], "s", f"<= {TARGETS['default_scene']:g}",
               after["default_scene_wall_s"] <= TARGETS["default_scene"], cpu_s=after["default_scene_cpu_s"])
    path = out.write()

    print()
    print(f"{'':24s}" + "".join(f"{label:>22s}" for label, _ in versions))
    for key in summaries["after"]:
        print(f"{key:24s}" + "".join(f"{summaries[label][key]:22.1f}" for label, _ in versions))
    for label, _ in versions:
        last = [r for r in runs if r["version"] == label][-1]
        cold = last["default_scene"]
        print(f"\n{label}: the default scene's ten dearest functions (own compile CPU; probe "
              f"{last['probe_default_scene']}); by part: {cold['by_part']}")
        for row in cold["top"][:10]:
            print(f"  {row['function'][:68]:68s} {row['own_cpu_s']:6.2f} {row['compiles']:8d}  "
                  f"{','.join(row['parts'])}")
    if not args.default_scene_only:
        for label, _ in versions:
            last = [r for r in runs if r["version"] == label][-1]
            cold = last["all"]
            print(f"\n{label}: the ten dearest functions (own compile CPU, callees excluded; every kernel, cold; "
                  f"probe {last['probe_all']}); by part: {cold['by_part']}")
            print(f"  {'function':68s} {'CPU s':>6s} {'compiles':>8s}  parts")
            for row in cold["top"][:10]:
                print(f"  {row['function'][:68]:68s} {row['own_cpu_s']:6.2f} {row['compiles']:8d}  "
                      f"{','.join(row['parts'])}")
            warm = last["warm"]
            print(f"  warm start still compiles {warm['compile_cpu_s']} s: " + ", ".join(
                f"{r['function']} {r['own_cpu_s']:.2f} s ({r['compiles']})" for r in warm["compiled"][:6]))
    print(format_speed_probe(out.data["speed_probe"]))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

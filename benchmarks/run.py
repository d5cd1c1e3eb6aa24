"""``make bench``: run the benchmarks, then print ONE table of issue 12's figures (value, target, pass / SHORT),
side by side from one run, then issue 7's that still stand, and write them as ``benchmarks/results/summary.json``
(and ``summary.md``, the tables of ``benchmarks/README.md``).  Every figure a benchmark marks ``issue12`` goes
into the first table, whichever script wrote it (``common.Results.figure(..., issue12=True)``).

Each benchmark is a plain script that runs alone and writes ``benchmarks/results/<name>.json`` in the layout of
``benchmarks/common.py``; this script runs them one after the other in subprocesses (one at a time: the
machine has 2 cores and the tick uses both), keeps their output in ``results/<name>.log``, and aggregates
their figures.  A benchmark that fails or is skipped leaves its figures as ``n/a`` with the reason; the others
still run.

    .venv/bin/python benchmarks/run.py                 # everything (~10 min on the 2-core machine)
    .venv/bin/python benchmarks/run.py --quick         # fewer repetitions (~3-4 min)
    .venv/bin/python benchmarks/run.py --only tick cdr # some of them
    .venv/bin/python benchmarks/run.py --no-run        # only aggregate the JSON files already there
    .venv/bin/python benchmarks/run.py --update-readme # and put the tables into benchmarks/README.md
    .venv/bin/python benchmarks/run.py --extras        # also bench_bag.py, bench_integrators.py,
                                                       # bench_scenes.py, bench_render.py, bench_flock_stats.py,
                                                       # bench_recording.py, bench_fresh_clone.py,
                                                       # bench_load_world.py, bench_compile.py

Exit status: 0 when every benchmark ran (whether or not every target is met: a SHORT figure is a result,
not an error), 1 when one failed.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from common import RESULTS, format_figures, format_value, load_average, machine, speed_probe, verdict  # noqa: E402

#: name -> script; the order they run in (the tick first: it is the figure that matters most, and it
#: runs best on a machine that has not been busy for minutes)
BENCHMARKS = {"tick": "bench_tick.py", "realtime": "bench_realtime.py", "rigid": "bench_rigid.py",
              "boids": "bench_boids.py", "cdr": "bench_cdr.py", "contacts": "bench_contacts.py",
              "foxglove": "bench_foxglove.py", "spawn": "bench_spawn.py", "spawn_rows": "bench_spawn_rows.py",
              "sweep": "bench_sweep.py", "convex_pile": "bench_convex_pile.py", "gjk": "bench_gjk.py",
              "contact_report": "bench_contact_report.py", "work_bounds": "bench_work_bounds.py",
              "mesh": "bench_mesh.py", "robots": "bench_robots.py", "node_cost": "bench_node_cost.py",
              "robot_node": "bench_robot_node.py"}
EXTRAS = {"bag": "bench_bag.py", "integrators": "bench_integrators.py", "scenes": "bench_scenes.py",
          "render": "bench_render.py", "flock_stats": "bench_flock_stats.py", "recording": "bench_recording.py",
          "fresh_clone": "bench_fresh_clone.py", "load_world": "bench_load_world.py", "compile": "bench_compile.py"}

#: issue 12's figures measured by the scripts above, in the issue's order: (id, benchmark, the issue's wording).
#: Figures other scripts mark ``issue12`` (the rigid-body ones) follow them in the table.
ISSUE12 = [
    ("realtime_default_hz", "realtime", "default scene, make run (real time, recording): achieved rate over 30 s"),
    ("realtime_default_warnings", "realtime", "  ... with no 'falling behind' warning"),
    ("realtime_default_tick_p99", "realtime", "  ... tick duration p99"),
    ("tick_15k_fish_p99_first", "tick", "15,000 fish + 20 bodies dropped at t = 0, recorded: p99 tick, first 20 s"),
    ("tick_15k_fish_p99_next", "tick", "  ... p99 tick over the next 60 s"),
    ("bag_15k_fish_MB_per_s", "tick", "same run: bag growth per simulated second"),
    ("bag_15k_fish_drawn", "tick", "  ... and the fish still drawn by the recorded markers"),
    ("boids_100k", "boids", "boid step at 100k"),
    ("boids_scaling_100k_10k", "boids", "boid step cost(100k) / cost(10k)"),
    ("startup_warm_s", "realtime", "start-up: process start -> first /clock, default scene, warm caches"),
    ("startup_cold_s", "realtime", "start-up: the same from a fresh install (no compile cache)"),
]
ISSUE12_TARGETS = {
    "realtime_default_hz": ("Hz", ">= 59.5"), "realtime_default_warnings": ("", "0"),
    "realtime_default_tick_p99": ("ms", "<= 16.7"), "tick_15k_fish_p99_first": ("ms", "<= 16.7"),
    "tick_15k_fish_p99_next": ("ms", "<= 16.7"), "bag_15k_fish_MB_per_s": ("MB/s", "<= 60"),
    "bag_15k_fish_drawn": ("", "yes"), "boids_100k": ("ms", "<= 80"), "boids_scaling_100k_10k": ("x", "<= 14"),
    "startup_warm_s": ("s", "<= 5"), "startup_cold_s": ("s", "<= 30"),
}

#: issue 7's figures that still stand and are not issue 12's too (its full-tick figure is superseded by issue
#: 12's), in the issue's order
ISSUE7 = [
    ("boids_naive_ratio_4k", "boids", "vs a naive O(N²) numpy boids step at 4,000 boids"),
    ("cdr_publish_record_10k", "cdr", "publish + record a 10,000-pose PoseArray vs rclpy Pose objects"),
    ("contacts_1k_resting", "contacts", "1,000 spheres into a 5 x 5 m box: step once resting vs PyBullet"),
    ("contacts_1k_escaped", "contacts", "1,000 spheres into a box: no tunnelling (spheres out of the box)"),
    ("contacts_1k_penetration", "contacts", "1,000 spheres into a box: resting penetration"),
]
ISSUE7_TARGETS = {  # what the issue asks, for figures whose benchmark did not run
    "boids_naive_ratio_4k": ("x", ">= 100"), "cdr_publish_record_10k": ("x", ">= 20"),
    "contacts_1k_resting": ("ms", "< PyBullet"), "contacts_1k_escaped": ("", "0"),
    "contacts_1k_penetration": ("% of r", "<= 1"),
}


def run_benchmark(name: str, script: str, quick: bool, log_dir: Path) -> dict:
    """Run one script in a subprocess (its output shown live and kept in results/<name>.log)."""
    command = [sys.executable, str(HERE / script)] + (["--quick"] if quick and name != "integrators" else [])
    print(f"\n=== {name}: {' '.join(Path(c).name if i < 2 else c for i, c in enumerate(command))} ===", flush=True)
    log_path = log_dir / f"{name}.log"
    started = time.perf_counter()
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    with log_path.open("w") as log:
        process = subprocess.Popen(command, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                   text=True)
        for line in process.stdout:
            log.write(line)
            if "[INFO]" not in line:
                sys.stdout.write("  " + line)
                sys.stdout.flush()
        code = process.wait()
    elapsed = time.perf_counter() - started
    print(f"=== {name}: {'done' if code == 0 else f'FAILED (exit {code})'} in {elapsed:.0f} s ===", flush=True)
    return {"script": script, "returncode": code, "elapsed_s": round(elapsed, 1),
            "log": str(log_path.relative_to(ROOT))}


def load(name: str) -> dict | None:
    path = RESULTS / f"{name}.json"
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def collect(names: list[str], runs: dict[str, dict]) -> dict:
    """The summary: issue 12's figures in order (n/a with a reason when missing), then every other figure a
    benchmark marked issue12, then issue 7's that stand, then the supporting ones."""
    results = {name: load(name) for name in names}
    by_id = {}
    for name, data in results.items():
        for figure in (data or {}).get("figures", []):
            by_id[figure["id"]] = {**figure, "benchmark": name}

    def listed(table, targets):
        out = []
        for fid, bench, wording in table:
            if fid in by_id:
                out.append({**by_id[fid], "issue_wording": wording})
                continue
            run = runs.get(bench)
            reason = (f"{available_scripts().get(bench, bench)} failed (exit {run['returncode']}), see {run['log']}"
                      if run and run["returncode"] else f"{bench} was not run" if results.get(bench) is None
                      else f"not in results/{bench}.json")
            unit, target = targets[fid]
            out.append({"id": fid, "figure": wording, "value": None, "unit": unit, "target": target, "pass": None,
                        "benchmark": bench, "note": reason, "issue_wording": wording})
        return out

    issue12 = listed(ISSUE12, ISSUE12_TARGETS)
    known = {fid for fid, _, _ in ISSUE12}
    issue12 += [f for f in by_id.values() if f.get("issue12") and f["id"] not in known]
    issue7 = listed(ISSUE7, ISSUE7_TARGETS)
    shown = {f["id"] for f in issue12 + issue7}
    supporting = [f for f in by_id.values() if f["id"] not in shown]
    short = [f for f in issue12 if f["pass"] is False]
    missing = [f for f in issue12 if f["pass"] is None]
    return {
        "machine": machine(),
        "benchmarks": {name: {"ran_now": name in runs, **runs.get(name, {}),
                              "load_average": (data or {}).get("load_average"),
                              "speed_probe": (data or {}).get("speed_probe"),
                              "elapsed_s": (data or {}).get("elapsed_s", runs.get(name, {}).get("elapsed_s")),
                              "options": (data or {}).get("options")}
                       for name, data in results.items()},
        "figures": issue12, "issue7_figures": issue7, "supporting_figures": supporting,
        "all_met": not short and not missing, "short": [f["id"] for f in short],
        "not_measured": [f["id"] for f in missing],
    }


def available_scripts() -> dict[str, str]:
    return {**BENCHMARKS, **EXTRAS}


# ---- the tables (stdout and summary.md / README) ---------------------------------------------------------

def figures_markdown(figures: list[dict]) -> str:
    lines = ["| figure | value | target | result |", "|---|---:|---|---|"]
    for f in figures:
        value = f"{format_value(f['value'])} {f['unit']}".strip() if f["value"] is not None else "n/a"
        note = f" ({f['note']})" if f.get("note") else ""
        outcome = "**SHORT**" if f["pass"] is False else verdict(f)
        lines.append(f"| {f['figure']}{note} | {value} | {f['target']} | {outcome} |")
    return "\n".join(lines)


def scaling_markdown(names: list[str]) -> str:
    """How each figure grows: the tick with the flock size, boids 1k..100k, publish+record 1k..100k,
    spheres 100 / 1,000 and the broad phases."""
    out = []
    tick = load("tick") if "tick" in names else None
    if tick and tick.get("fish"):
        fish = tick["fish"]
        out += ["**The 15k-fish tick from the first tick** (`bench_tick.py`: 15,000 fish + 20 bodies, recorded; ms per "
                "tick; per stage: median / p99 / mean of the slowest 1 % of ticks)", "",
                "| window | ticks | bodies awake | median | p90 | p99 | max | tick-thread CPU median / p99 | "
                "rigid bodies | flock | flock stats | serialize | publish | record |",
                "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        runs = [("fish", fish)] + ([("sphere", tick["sphere"])] if tick.get("sphere") else [])
        for model, run in runs:
            for label, w in run["windows"].items():
                cells = []
                for stage in ("world.step: rigid bodies (+ obstacle set)", "world.step: flock",
                              "flock stats (order parameters + CDR)", "serialize (other messages.*)",
                              "Publisher.publish", "recorder.write (caller)"):
                    if stage not in w["split_median_ms"]:  # a result file from before the stage was split out
                        cells.append("–")
                        continue
                    cells.append(f"{w['split_median_ms'][stage]:.1f} / {w['split_p99_ms'][stage]:.1f} / "
                                 f"{w['split_of_slowest_1pct_ms'][stage]:.1f}")
                cpu = w.get("tick_thread_cpu_ms")
                cpu_cell = f"{cpu['median']:.1f} / {cpu['p99']:.1f}" if cpu else "–"
                out.append(f"| {model}, {label} | {w['ticks']:,} | {100 * w['bodies_awake_fraction']:.0f} % | "
                           f"{w['median']:.1f} | {w['p90']:.1f} | {w['p99']:.1f} | {w['max']:.1f} | {cpu_cell} | "
                           + " | ".join(cells) + " |")
        lod = fish["level_of_detail"]
        out += ["", f"Bag: {fish['bag_MB']:.0f} MB for {fish['sim_seconds']:.0f} s of simulated time = "
                f"{fish['bag_MB_per_sim_second']:.1f} MB/s (payload {fish['bag_payload_MB_per_sim_second']:.1f} MB/s "
                f"before lz4); the writer thread used {fish['bag_writer_cpu_ms_per_tick']:.1f} ms CPU per tick, "
                f"backlog max {fish['bag_backlog_max_MB']:.1f} MB, {fish['bag_dropped_messages']} dropped. Level of "
                f"detail: {' '.join(lod['lines'])} Garbage collections during the run (gen 0, 1, 2): "
                f"{fish['gc']['collections']}, the longest {fish['gc']['longest_ms']:.1f} ms.", ""]
    realtime = load("realtime") if "realtime" in names else None
    if realtime and realtime.get("runs"):
        out += ["**The default scene in real time** (`bench_realtime.py`: `cgp-sim --scene default --bag ...`, "
                "timer-driven, from the first tick; ms)", "",
                "| run | ticks | achieved | warnings | tick median | tick p99 | tick max | period median | "
                "period p99 | period max | longest gc |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for r in realtime["runs"]:
            out.append(f"| {r['label']} | {r['ticks']} | {r['achieved_hz']:.2f} Hz | {r['falling_behind_warnings']} | "
                       f"{r['tick_ms']['median']:.2f} | {r['tick_ms']['p99']:.2f} | {r['tick_ms']['max']:.1f} | "
                       f"{r['period_ms']['median']:.2f} | {r['period_ms']['p99']:.2f} | {r['period_ms']['max']:.1f} | "
                       f"{r['gc']['longest_ms']:.1f} |")
        st = realtime.get("startup", {})
        if st:
            out += ["", f"Start-up to the first `/clock` (default scene): cold (no compile cache) "
                    f"{st['cold']['start_to_first_clock_s']:.1f} s; then `make setup`'s warm-up, which compiles every "
                    f"kernel once per clone, {st['cold'].get('setup_warmup_s', float('nan')):.1f} s; "
                    f"warm (what `make run` starts, after `make setup`) {st['warm']['start_to_first_clock_s']:.1f} s.",
                    ""]
    if tick and tick.get("scaling"):
        out += ["**Full tick vs flock size** (20 bodies, bag on; median ms; the split is from the instrumented "
                "ticks, `bench_tick.py`)", "",
                "| boids | tick median | p90 | World.step: bodies | World.step: flock | serialize | publish | "
                "recorder.write | neighbours/boid |", "|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for r in tick["scaling"]:
            s = r["split_ms_median"]
            out.append(f"| {r['boids']:,} | {r['tick_ms_median']:.1f} | {r['tick_ms_p90']:.1f} | "
                       f"{s['  rigid bodies (substeps) + obstacle set']:.1f} | {s['  flock step']:.1f} | "
                       f"{s['serialize (messages.*)']:.2f} | {s['Publisher.publish']:.2f} | "
                       f"{s['recorder.write (caller)']:.2f} | {r['neighbors_per_boid']:.1f} |")
        nobag = tick.get("tick_no_bag")
        if nobag:
            out += ["", f"Same 15k scene without recording, interleaved in blocks with the recording node: median "
                    f"{nobag['tick_ms_median']:.1f} ms "
                    f"(bodies {nobag['split_ms_median']['  rigid bodies (substeps) + obstacle set']:.1f},"
                    f" flock {nobag['split_ms_median']['  flock step']:.1f}); the bag writer thread used "
                    f"{tick['tick'].get('bag_writer_cpu_ms_per_tick', float('nan')):.1f} ms CPU per tick for "
                    f"{tick['tick'].get('bag_payload_MB_per_tick', float('nan')):.2f} MB, backlog max "
                    f"{tick['tick'].get('bag_backlog_max_MB', float('nan')):.1f} MB, "
                    f"{tick['tick'].get('bag_dropped_messages', 0)} dropped."]
        out.append("")
    boids = load("boids") if "boids" in names else None
    if boids and boids.get("rows"):
        out += ["**Boid step vs flock size** (`bench_boids.py`; flocks at the default flock's steady-state density, "
                "median ms per `Flock.step`)", "",
                "| boids | backend | median | mean | max | neighbours/boid |", "|---:|---|---:|---:|---:|---:|"]
        for r in boids["rows"]:
            nb = r.get("neighbors_per_boid")
            out.append(f"| {r['boids']:,} | {r['backend']} | {r['ms_median']:.2f} | {r['ms_mean']:.2f} | "
                       f"{r['ms_max']:.2f} | {'' if nb is None else f'{nb:.1f}'} |")
        out.append("")
    cdr = load("cdr") if "cdr" in names else None
    if cdr and cdr.get("rows"):
        rows = {(r["message"], r["variant"]): r for r in cdr["rows"]}

        def cell(message, variant):
            r = rows.get((message, variant))
            return f"{r['ms']:.3f}" if r else "–"

        def ratio(message, slow, fast):
            a, b = rows.get((message, slow)), rows.get((message, fast))
            return f"{a['ms'] / b['ms']:.0f}x" if a and b else "–"

        out += ["**Serialization, publish and publish + record vs message size** (`bench_cdr.py`; ms per message, "
                "median of interleaved repetitions; rclpy = building the rclpy message objects from the arrays)", "",
                "| PoseArray poses | serialize: rclpy | numpy | ratio | publish: rclpy | numpy | ratio | "
                "publish + record: rclpy | numpy | ratio |", "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for n in (1_000, 10_000, 100_000):
            m = f"PoseArray {n}"
            if (m, "numpy") not in rows:
                continue
            out.append(f"| {n:,} | {cell(m, 'rclpy objects')} | {cell(m, 'numpy reuse')} | "
                       f"{ratio(m, 'rclpy objects', 'numpy reuse')} | {cell(m, 'rclpy publish')} | "
                       f"{cell(m, 'numpy publish')} | {ratio(m, 'rclpy publish', 'numpy publish')} | "
                       f"{cell(m, 'rclpy publish+record')} | {cell(m, 'numpy publish+record')} | "
                       f"{ratio(m, 'rclpy publish+record', 'numpy publish+record')} |")
        others = [m for m in dict.fromkeys(r["message"] for r in cdr["rows"]) if not m.startswith("PoseArray")]
        if others:
            out += ["", "| other message | serialize: rclpy | numpy | ratio |", "|---|---:|---:|---:|"]
            for m in others:
                fast = "numpy batch" if (m, "numpy batch") in rows else "numpy"
                out.append(f"| {m}{' (batch)' if fast == 'numpy batch' else ''} | {cell(m, 'rclpy objects')} | "
                           f"{cell(m, fast)} | {ratio(m, 'rclpy objects', fast)} |")
        out.append("")
    contacts = load("contacts") if "contacts" in names else None
    if contacts and contacts.get("piles"):
        out += ["**Spheres into a box vs sphere count** (`bench_contacts.py`; h = 1/240 s; ms per step, median; "
                f"PyBullet {contacts.get('pybullet') or 'not installed'} interleaved step by step)", "",
                "| engine | spheres | first second | resting | max penetration (% r) | out of the box |",
                "|---|---:|---:|---:|---:|---:|"]
        for r in contacts["piles"]:
            out.append(f"| {r['engine']} | {r['spheres']:,} | {r['first_second_ms']:.2f} | {r['resting_ms']:.2f} | "
                       f"{r['max_penetration_pct_radius']:.2f} | {r['escaped']} |")
        if contacts.get("broad_phase"):
            out += ["", "Broad phases on the settled pile (ms, median of 7):", "",
                    "| bodies | " + " | ".join(sorted({r['broad_phase'] for r in contacts['broad_phase']})) + " |",
                    "|---:|" + "---:|" * len({r['broad_phase'] for r in contacts['broad_phase']})]
            phases = sorted({r["broad_phase"] for r in contacts["broad_phase"]})
            for n in sorted({r["bodies"] for r in contacts["broad_phase"]}):
                cells = []
                for ph in phases:
                    hit = next((r for r in contacts["broad_phase"] if r["bodies"] == n and r["broad_phase"] == ph),
                               None)
                    cells.append(f"{hit['ms']:.2f}" if hit else "–")
                out.append(f"| {n:,} | " + " | ".join(cells) + " |")
        out.append("")
    return "\n".join(out)


def profile_markdown(names: list[str], rows: int = 18) -> str:
    tick = load("tick") if "tick" in names else None
    top = [r for r in (tick or {}).get("profile_top") or [] if isinstance(r, dict)]
    if not top:
        return ""
    ticks = (tick.get("options") or {}).get("profile_ticks")
    lines = [f"**Profile of the 15k tick** (pyinstrument, 1 ms sampling, {ticks or 'some'} ticks with recording on; "
             "functions by cumulative time; the profiler slows the many small calls of the rigid-body step more "
             "than the rest, so read the percentages, not the ms; full call tree in "
             "`benchmarks/results/tick_profile.txt`)", "",
             "| % of tick | ms/tick (profiled) | function | where |", "|---:|---:|---|---|"]
    for r in top[:rows]:
        lines.append(f"| {r['percent_of_tick']:.1f} | {r['ms_per_tick']:.2f} | `{r['function']}` | {r['where']} |")
    return "\n".join(lines) + "\n"


def conditions_markdown(summary: dict) -> str:
    m = summary["machine"]
    lines = [f"Measured on {m['processor']}, {m['cpus']} cores, Python {m['python']}, numpy {m['numpy']}"
             f"{', scipy ' + m['scipy'] if 'scipy' in m else ''}; {m['platform']}.", "",
             "| benchmark | when | took | load average before → after (1, 5, 15 min) | speed probe numpy / python ms "
             "before → after |", "|---|---|---:|---|---|"]
    for name, b in summary["benchmarks"].items():
        la, sp = b.get("load_average") or {}, b.get("speed_probe") or {}
        probe = " → ".join(f"{p['numpy_ms']:.0f} / {p['python_ms']:.0f}" for p in (sp.get("before"), sp.get("after"))
                           if p)
        took = b.get("elapsed_s")
        lines.append(f"| {name} | {'this run' if b.get('ran_now') else 'earlier run'}"
                     f"{' (quick)' if (b.get('options') or {}).get('quick') else ''} | "
                     f"{'' if took is None else f'{took:.0f} s'} | "
                     f"{la.get('before')} → {la.get('after')} | {probe} |")
    return "\n".join(lines)


def summary_markdown(summary: dict, names: list[str]) -> str:
    return "\n".join([
        "### Issue 12's figures", "", figures_markdown(summary["figures"]), "",
        "### Issue 7's figures that still stand", "", figures_markdown(summary["issue7_figures"]), "",
        "Supporting figures:", "", figures_markdown(summary["supporting_figures"]), "",
        "### How the figures scale", "", scaling_markdown(names), profile_markdown(names),
        "### Conditions", "", conditions_markdown(summary), ""])


def update_readme(markdown: str) -> bool:
    readme = HERE / "README.md"
    start, end = "<!-- results:start -->", "<!-- results:end -->"
    try:
        text = readme.read_text()
    except OSError:
        return False
    if start not in text or end not in text:
        return False
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    readme.write_text(f"{head}{start}\n{markdown}\n{end}{tail}")
    return True


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="each benchmark's --quick (fewer repetitions)")
    parser.add_argument("--only", nargs="+", choices=[*BENCHMARKS, *EXTRAS], help="run only these")
    parser.add_argument("--skip", nargs="+", choices=[*BENCHMARKS, *EXTRAS], default=[], help="do not run these")
    parser.add_argument("--extras", action="store_true", help="also run the extras: bench_bag.py, "
                        "bench_integrators.py, bench_scenes.py, bench_render.py, bench_flock_stats.py")
    parser.add_argument("--no-run", action="store_true", help="run nothing; aggregate the JSON already in results/")
    parser.add_argument("--update-readme", action="store_true",
                        help="replace the results section of benchmarks/README.md with this run's tables")
    args = parser.parse_args(argv)

    available = {**BENCHMARKS, **EXTRAS}
    selected = args.only or [*BENCHMARKS, *(EXTRAS if args.extras else [])]
    selected = [n for n in selected if n not in args.skip]
    RESULTS.mkdir(parents=True, exist_ok=True)
    runs: dict[str, dict] = {}
    started = time.perf_counter()
    load_before, probe_before = load_average(), speed_probe()
    if not args.no_run:
        print(f"benchmarks: {', '.join(selected)}{' (quick)' if args.quick else ''}; load average {load_before}, "
              f"speed probe {probe_before}", flush=True)
        for name in selected:
            runs[name] = run_benchmark(name, available[name], args.quick, RESULTS)
    names = [n for n in available if n in BENCHMARKS or n in selected]
    summary = collect([n for n in BENCHMARKS] + [n for n in EXTRAS if n in selected], runs)
    summary.update({"quick": args.quick, "elapsed_s": round(time.perf_counter() - started, 1),
                    "load_average": {"before": load_before, "after": load_average()},
                    "speed_probe": {"before": probe_before, "after": speed_probe()}})
    (RESULTS / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    markdown = summary_markdown(summary, names)
    (RESULTS / "summary.md").write_text(markdown)

    print("\n" + "=" * 118)
    print(f"issue 12 on this machine ({summary['machine']['cpus']} cores; load average {load_before} -> "
          f"{summary['load_average']['after']}; {'quick run' if args.quick else 'full run'}, "
          f"{summary['elapsed_s']:.0f} s)")
    print("=" * 118)
    print(format_figures(summary["figures"], width=70))
    for f in summary["figures"]:
        if f.get("note"):
            print(f"  n/a {f['id']}: {f['note']}")
    print(f"\nissue 7's figures that still stand:\n{format_figures(summary['issue7_figures'], width=70)}")
    print(f"\nsupporting figures:\n{format_figures(summary['supporting_figures'], width=70)}")
    verdict_line = ("every issue-12 target measured here met" if summary["all_met"] else
                    f"short: {', '.join(summary['short']) or '-'}; not measured: "
                    f"{', '.join(summary['not_measured']) or '-'}")
    print(f"\n{verdict_line}\nwrote {(RESULTS / 'summary.json').relative_to(ROOT)} and "
          f"{(RESULTS / 'summary.md').relative_to(ROOT)}")
    if args.update_readme:
        print("updated benchmarks/README.md" if update_readme(markdown) else
              "benchmarks/README.md has no <!-- results:start --> / <!-- results:end --> markers: not updated")
    failed = [n for n, r in runs.items() if r["returncode"]]
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())

#!/usr/bin/env python3
"""Couzin et al. 2002's phases and collective memory, reproduced with the simulator's own flocks — a thin
wrapper around ``cgp-sim-sweep`` (issue 26), which runs and draws it.

The experiment is the built-in sweep ``couzin_hysteresis`` (``msgs_config/sweeps/couzin_hysteresis.yaml``: the
paper's parameters, N = 100, r_r = 1, α = 270°, θ = 40°/s, s = 3, σ = 0.05, Δr_a = 14, τ = 0.1 s, open space,
a random start in a 10 m cube; Δr_o over 0-13, 12 seeds, three protocols: random starts of 200 s, Δr_o
increasing and decreasing with the group carried over, 100 s at each value; p and m averaged over each run's
last 40 s).  Each run is classified with Tunstrøm et al. 2013's thresholds, the polarized runs split at
HIGHLY_PARALLEL into dynamic and highly parallel, a group that ended in pieces is *fragmented*
(``cgp_sim_ros/sweep/plot.py``).  The same by hand::

    cgp-sim-sweep run couzin_hysteresis -o sweeps/couzin_hysteresis
    cgp-sim-sweep plot sweeps/couzin_hysteresis -o benchmarks/figures/couzin_hysteresis.png

This script runs that (resuming: a finished run is never run again), with ``--rate-check`` also the sweep
``couzin_rate_check`` (random starts at τ = 0.1 s and at 60 Hz), draws ``benchmarks/figures/couzin_hysteresis.png``,
writes ``benchmarks/results/couzin_sweep.json`` (every run's p, m and cohesion, in the layout the earlier
multiprocessing version wrote: the sweep tool reproduces its 432 runs bit for bit) and prints the table of
phase fractions.  ``--plot-only`` redraws from the sweep's tables without running anything.

Run: ``make figures`` (or ``.venv/bin/python benchmarks/figures/couzin_sweep.py [--seeds 4] [--rate-check]``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pyarrow.parquet as pq

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from cgp_sim_ros.sweep.engine import EngineError, run_sweep  # noqa: E402
from cgp_sim_ros.sweep.plot import phase_table, plot  # noqa: E402
from cgp_sim_ros.sweep.spec import load_sweep  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results" / "couzin_sweep.json"
FIGURE = ROOT / "benchmarks" / "figures" / "couzin_hysteresis.png"
SWEEPS = ROOT / "sweeps"
KEY = "flocks[school].couzin.orientation_width"
#: polarized groups above this p are "highly parallel", below "dynamic parallel" (chosen from the sweep: the
#: gap between the two clusters of polarized runs; see the printed table)
HIGHLY_PARALLEL = 0.97


def rows(out: Path) -> list[dict]:
    return [r for r in pq.read_table(out / "runs.parquet").to_pylist() if r["status"] == "done"]


def as_json(hysteresis: Path, rate_check: Path | None, seconds: float | None) -> dict:
    """The sweep's summary rows in couzin_sweep.json's layout."""
    info = json.loads((hysteresis / "sweep.json").read_text())
    random = next(e for e in info["experiments"] if e["name"] == "random")
    chained = next(e for e in info["experiments"] if e["name"] == "increasing")
    scene = json.loads(rows(hysteresis)[0]["scene"])["flocks"][0]
    couzin = {k: v for k, v in scene["couzin"].items() if k != "orientation_width"}
    results = {"parameters": {**couzin, "count": scene["count"], "dt": random["dt"],
                              "spawn_cube": scene["spawn"]["extent"][0], "steps": random["ticks"],
                              "hold": chained["ticks"], "window": round(random["window"] / random["dt"]),
                              "seeds": len(random["seeds"])},
               "orientation_widths": random["grid"][KEY], "random": [], "rate_check": [], "increasing": [],
               "decreasing": [], "seconds": seconds}

    def row(r):
        return {"width": r[KEY], "seed": r["seed"], "p": r["polarization"], "m": r["milling"],
                "cohesive": r["groups"] == 1}

    # the earlier script's order: random starts by width then seed, the chains by seed then link
    done = rows(hysteresis)
    for experiment in ("random", "increasing", "decreasing"):
        own = [r for r in done if r["experiment"] == experiment]
        own.sort(key=lambda r: (r[KEY], r["seed"]) if experiment == "random" else (r["seed"], r["link"]))
        results[experiment] = [row(r) for r in own]
    if rate_check is not None:  # 60 Hz first, then τ
        results["rate_check"] = sorted(({**row(r), "dt": r["dt"]} for r in rows(rate_check)),
                                       key=lambda r: (r["dt"], r["width"], r["seed"]))
    return results


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, help="seeds per point (default: the sweep file's 12)")
    parser.add_argument("--workers", type=int, help="LocalCluster workers (default: one per core)")
    parser.add_argument("--rate-check", action="store_true")
    parser.add_argument("--plot-only", action="store_true")
    args = parser.parse_args(argv)
    hysteresis = SWEEPS / "couzin_hysteresis"
    rate_check = SWEEPS / "couzin_rate_check" if args.rate_check else None
    seconds = None
    if not args.plot_only:
        try:
            for name, out in (("couzin_hysteresis", hysteresis), ("couzin_rate_check", rate_check)):
                if out is not None:
                    outcome = run_sweep(load_sweep(name, seeds=args.seeds if name == "couzin_hysteresis" else None),
                                        out, workers=args.workers)
                    if outcome.exit_code:
                        return outcome.exit_code
                    if name == "couzin_hysteresis" and outcome.ran:
                        seconds = round(outcome.wall_s, 1)
        except EngineError as exc:
            print(exc, file=sys.stderr)
            return 2
    if seconds is None and RESULTS.exists():
        seconds = json.loads(RESULTS.read_text()).get("seconds")
    results = as_json(hysteresis, rate_check if rate_check and rate_check.exists() else None, seconds)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=1) + "\n")
    _, table = plot(hysteresis, FIGURE, highly_parallel=HIGHLY_PARALLEL)
    print(table)
    if rate_check is not None and rate_check.exists():
        info = json.loads((rate_check / "sweep.json").read_text())
        print(phase_table(info, KEY, [r for r in rows(rate_check) if r["flock"]], HIGHLY_PARALLEL))
    print(f"\nwrote {FIGURE.relative_to(ROOT)} and {RESULTS.relative_to(ROOT)}"
          + (f" ({results['seconds']} s)" if results.get("seconds") else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())

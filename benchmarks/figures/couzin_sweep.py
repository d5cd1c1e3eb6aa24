#!/usr/bin/env python3
"""Couzin et al. 2002's phases and collective memory, reproduced with the simulator's own flocks.

Every run is a :class:`cgp_core.boids.Flock` with ``rules: couzin`` stepped exactly as the node steps it (no
other code path), with the paper's parameters: N = 100, r_r = 1, α = 270°, θ = 40°/s, s = 3, σ = 0.05,
Δr_a = 14, at the paper's time step τ = 0.1 s, in open space (``bounds: none``), started in a 10 m cube with
random headings.

Three experiments (``--seeds`` seeds each):

- **random starts**: for each Δr_o, a fresh random group runs ``--steps`` steps; p and m are averaged over
  the last ``--window`` steps;
- **increasing Δr_o**: one group starts at Δr_o = 0 and Δr_o is raised through the grid, the group carried
  over, ``--hold`` steps at each value (p, m averaged over the last ``--window``);
- **decreasing Δr_o**: the same from the largest Δr_o down (the group starts there as a random group).

Each run is classified with Tunstrøm et al. 2013's thresholds (``cgp_core.boids.order.classify``), the
polarized runs split into *dynamic parallel* (p <= HIGHLY_PARALLEL) and *highly parallel*; a run whose group
fragmented (not one connected group at the perception radius) is counted as *fragmented*.

Writes ``benchmarks/results/couzin_sweep.json`` (every run's p and m) and
``benchmarks/figures/couzin_hysteresis.png`` (p and m against Δr_o, increasing and decreasing: the
hysteresis loop; fractions of seeds per phase), and prints the table of phase fractions.  ``--plot-only``
redraws from the JSON.  With ``--rate-check`` it also compares random starts at dt = 0.1 s and 1/60 s.

Run: ``make figures`` (or ``.venv/bin/python benchmarks/figures/couzin_sweep.py [--seeds 12]``).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from cgp_core.boids import Flock, FlockParams  # noqa: E402
from cgp_core.boids.order import classify  # noqa: E402
from cgp_core.boids.params import CouzinParams  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results" / "couzin_sweep.json"
FIGURE = ROOT / "benchmarks" / "figures" / "couzin_hysteresis.png"

PAPER = dict(repulsion_radius=1.0, attraction_width=14.0, field_of_view_deg=270.0, turning_rate_deg=40.0,
             speed=3.0, noise=0.05)
COUNT = 100
DT = 0.1  # the paper's τ
ORIENTATION_WIDTHS = [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 7.0, 10.0, 13.0]
#: polarized groups above this p are "highly parallel", below "dynamic parallel" (chosen from the sweep: the
#: gap between the two clusters of polarized runs; see the printed table and the report)
HIGHLY_PARALLEL = 0.97
PHASES = ("swarm", "torus", "dynamic parallel", "highly parallel", "transitional", "fragmented")
COLORS = {"swarm": "#9e9e9e", "torus": "#d95f02", "dynamic parallel": "#7fb3d5", "highly parallel": "#1f4e79",
          "transitional": "#e6c229", "fragmented": "#000000"}


def flock_params(orientation_width: float, seed: int) -> FlockParams:
    return FlockParams(name="school", count=COUNT, seed=seed, rules="couzin",
                       couzin=CouzinParams(orientation_width=orientation_width, **PAPER),
                       spawn_center=[0.0, 0.0, 0.0], spawn_extent=[10.0, 10.0, 10.0], bounds_mode="none",
                       neighbor_search="brute")


def phase(p: float, m: float, cohesive: bool) -> str:
    """The phase of a run from its time-averaged p and m (Tunstrøm's thresholds, polarized split at
    HIGHLY_PARALLEL)."""
    if not cohesive:
        return "fragmented"
    kind = classify(p, m)
    if kind == "polarized":
        return "highly parallel" if p > HIGHLY_PARALLEL else "dynamic parallel"
    return {"milling": "torus"}.get(kind, kind)


def cohesive(flock: Flock) -> bool:
    """One connected group when animals within the perception radius are linked."""
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    x = flock.positions
    graph = cKDTree(x).sparse_distance_matrix(cKDTree(x), flock.params.radius, output_type="coo_matrix")
    return connected_components(graph, directed=False)[0] == 1


def measure(flock: Flock, steps: int, window: int, dt: float) -> tuple[float, float, bool]:
    """Step ``steps`` times; mean p and m over the last ``window`` steps, and whether the group is one."""
    ps, ms = [], []
    for step in range(steps):
        flock.step(dt)
        if step >= steps - window:
            order = flock.order()  # what the node publishes on ~/flocks/<flock>/stats
            ps.append(order.polarization)
            ms.append(order.milling)
    return float(np.mean(ps)), float(np.mean(ms)), bool(cohesive(flock))


def random_start(task):
    width, seed, steps, window, dt = task
    return ("random", width, seed, dt) + measure(Flock(flock_params(width, seed)), steps, window, dt)


def continuation(task):
    direction, seed, hold, window = task
    widths = ORIENTATION_WIDTHS if direction == "increasing" else ORIENTATION_WIDTHS[::-1]
    flock = Flock(flock_params(widths[0], seed))
    out = []
    for width in widths:
        flock.params = replace(flock.params, couzin=replace(flock.params.couzin, orientation_width=width))
        out.append((width,) + measure(flock, hold, window, DT))
    return direction, seed, out


def run(args) -> dict:
    seeds = range(args.seeds)
    random_tasks = [(w, s, args.steps, args.window, DT) for w in ORIENTATION_WIDTHS for s in seeds]
    if args.rate_check:
        random_tasks += [(w, 100 + s, int(args.steps * DT * 60), int(args.window * DT * 60), 1.0 / 60.0)
                         for w in (0.0, 1.5, 5.0, 13.0) for s in range(args.rate_seeds)]
        random_tasks += [(w, 100 + s, args.steps, args.window, DT) for w in (0.0, 1.5, 5.0, 13.0)
                         for s in range(args.rate_seeds)]
    continuation_tasks = [(d, s, args.hold, args.window) for d in ("increasing", "decreasing") for s in seeds]
    started = time.perf_counter()
    with multiprocessing.Pool(args.jobs) as pool:
        continued = pool.map_async(continuation, continuation_tasks, chunksize=1)
        randoms = pool.map(random_start, random_tasks, chunksize=4)
        continued = continued.get()
    results = {"parameters": {**PAPER, "count": COUNT, "dt": DT, "spawn_cube": 10.0, "steps": args.steps,
                              "hold": args.hold, "window": args.window, "seeds": args.seeds},
               "orientation_widths": ORIENTATION_WIDTHS, "random": [], "rate_check": [], "increasing": [],
               "decreasing": [], "seconds": None}
    for _, width, seed, dt, p, m, whole in randoms:
        row = {"width": width, "seed": seed, "p": p, "m": m, "cohesive": whole}
        if seed >= 100:
            results["rate_check"].append({**row, "dt": dt})
        else:
            results["random"].append(row)
    for direction, seed, rows in continued:
        results[direction] += [{"width": w, "seed": seed, "p": p, "m": m, "cohesive": c} for w, p, m, c in rows]
    results["seconds"] = round(time.perf_counter() - started, 1)
    return results


def fractions(rows: list[dict]) -> dict[float, dict[str, float]]:
    out = {}
    for width in ORIENTATION_WIDTHS:
        runs = [r for r in rows if r["width"] == width]
        if not runs:
            continue
        kinds = [phase(r["p"], r["m"], r["cohesive"]) for r in runs]
        out[width] = {k: kinds.count(k) / len(kinds) for k in PHASES}
    return out


def table(results: dict) -> str:
    lines = []
    for experiment in ("random", "increasing", "decreasing"):
        rows = results[experiment]
        seeds = len({r["seed"] for r in rows})
        lines.append(f"\n{experiment} ({seeds} seeds): fraction of seeds per phase, mean p and m")
        lines.append("| Δr_o | " + " | ".join(PHASES) + " | mean p | mean m |")
        lines.append("|---:|" + "---:|" * (len(PHASES) + 2))
        for width, share in fractions(rows).items():
            runs = [r for r in rows if r["width"] == width]
            lines.append(f"| {width:g} | " + " | ".join(f"{share[k]:.2f}" for k in PHASES)
                         + f" | {np.mean([r['p'] for r in runs]):.2f} | {np.mean([r['m'] for r in runs]):.2f} |")
    if results.get("rate_check"):
        lines.append("\nrate check (random starts, same seeds): mean p / mean m at dt = 0.1 s and 1/60 s")
        for width in sorted({r["width"] for r in results["rate_check"]}):
            cells = []
            for dt in (0.1, 1.0 / 60.0):
                runs = [r for r in results["rate_check"] if r["width"] == width and abs(r["dt"] - dt) < 1e-9]
                kinds = [phase(r["p"], r["m"], r["cohesive"]) for r in runs]
                cells.append(f"dt={dt:.3g}: p {np.mean([r['p'] for r in runs]):.2f} m "
                             f"{np.mean([r['m'] for r in runs]):.2f} ({', '.join(kinds)})")
            lines.append(f"  Δr_o {width:g}: " + "; ".join(cells))
    return "\n".join(lines)


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(11, 8.2), constrained_layout=True)
    grid = fig.add_gridspec(2, 3, height_ratios=[1.5, 1.0])
    top = fig.add_subplot(grid[0, :])
    widths = np.array(ORIENTATION_WIDTHS)
    for experiment, style, label in (("increasing", "-", "Δr_o increasing"), ("decreasing", "--", "Δr_o decreasing")):
        rows = results[experiment]
        for key, color, name in (("p", "#1f4e79", "polarization p"), ("m", "#d95f02", "milling m")):
            values = np.array([[r[key] for r in rows if r["width"] == w] for w in widths])
            top.plot(widths, values.mean(axis=1), style, color=color, marker="o" if experiment == "increasing"
                     else "s", markersize=4, label=f"{name}, {label}")
            jitter = 0.08 if experiment == "increasing" else -0.08
            top.scatter(np.repeat(widths + jitter, values.shape[1]), values.reshape(-1), s=6, color=color,
                        alpha=0.25, linewidths=0)
    top.axhline(0.65, color="0.6", lw=0.8, ls=":")
    top.axhline(0.35, color="0.6", lw=0.8, ls=":")
    params = results["parameters"]
    top.set_title(f"Couzin et al. 2002 with cgp_sim: N = {params['count']}, r_r = 1, Δr_a = 14, α = 270°, "
                  f"θ = 40°/s, s = 3, σ = 0.05, τ = 0.1 s\n{params['seeds']} seeds per point (dots: each run's "
                  f"time average), lines: mean over seeds", fontsize=10)
    top.set_xlabel("Δr_o (width of the zone of orientation)")
    top.set_ylabel("order parameter (time average)")
    top.set_ylim(-0.02, 1.02)
    top.legend(loc="center right", fontsize=8)
    for column, experiment in enumerate(("random", "increasing", "decreasing")):
        axis = fig.add_subplot(grid[1, column])
        share = fractions(results[experiment])
        bottom = np.zeros(len(share))
        xs = np.arange(len(share))
        for kind in PHASES:
            heights = np.array([share[w][kind] for w in share])
            if heights.any():
                axis.bar(xs, heights, bottom=bottom, color=COLORS[kind], label=kind, width=0.85)
            bottom += heights
        axis.set_xticks(xs, [f"{w:g}" for w in share], fontsize=7)
        axis.set_title({"random": "random starts", "increasing": "Δr_o increasing (carried over)",
                        "decreasing": "Δr_o decreasing (carried over)"}[experiment], fontsize=9)
        axis.set_xlabel("Δr_o")
        if column == 0:
            axis.set_ylabel("fraction of seeds")
        if column == 2:
            from matplotlib.patches import Patch

            present = [k for k in PHASES if any(phase(r["p"], r["m"], r["cohesive"]) == k
                                                for e in ("random", "increasing", "decreasing") for r in results[e])]
            axis.legend(handles=[Patch(color=COLORS[k], label=k) for k in present], fontsize=7, loc="lower left")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--steps", type=int, default=2000, help="steps of a random-start run (τ each)")
    parser.add_argument("--hold", type=int, default=1000, help="steps at each Δr_o when carried over")
    parser.add_argument("--window", type=int, default=400, help="steps averaged at the end of a run")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--rate-check", action="store_true")
    parser.add_argument("--rate-seeds", type=int, default=4)
    parser.add_argument("--plot-only", action="store_true")
    args = parser.parse_args(argv)
    if args.plot_only:
        results = json.loads(RESULTS.read_text())
    else:
        results = run(args)
        RESULTS.parent.mkdir(parents=True, exist_ok=True)
        RESULTS.write_text(json.dumps(results, indent=1) + "\n")
    print(table(results))
    plot(results, FIGURE)
    print(f"\nwrote {FIGURE.relative_to(ROOT)} and {RESULTS.relative_to(ROOT)}"
          + (f" ({results['seconds']} s)" if results.get("seconds") else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())

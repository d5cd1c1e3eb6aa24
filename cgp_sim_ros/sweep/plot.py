"""``cgp-sim-sweep plot``: the standard figure of a sweep, from its tables alone (``runs.parquet``, ``sweep.json``).

Top: each run's time-averaged order parameters (polarization p, milling m; the summary's window) against the
swept key — a dot per run (the seeds), a line through the means over the seeds, one line style per experiment.
Below: per experiment, the fraction of seeds in each phase at every value of the key.  Phases are
Tunstrøm et al. 2013's (:func:`cgp_core.boids.order.classify` on the time averages: polarized p > 0.65 and
m < 0.35, milling m > 0.65 and p < 0.35, swarm both < 0.35, else transitional), the polarized runs split at
``highly_parallel`` into *dynamic parallel* and *highly parallel* (Couzin et al. 2002's names; milling is
their *torus*), and a run whose flock ended in more than one group (``groups`` > 1) is *fragmented*.

matplotlib is an optional dependency (``pip install cgp_sim_ros[plot]`` or ``matplotlib``): running a sweep
never needs it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from cgp_core.boids.order import classify

PHASES = ("swarm", "torus", "dynamic parallel", "highly parallel", "transitional", "fragmented")
ABBREVIATIONS = {"swarm": "swarm", "torus": "torus", "dynamic parallel": "DP", "highly parallel": "HP",
                 "transitional": "tr", "fragmented": "frag"}
COLORS = {"swarm": "#9e9e9e", "torus": "#d95f02", "dynamic parallel": "#7fb3d5", "highly parallel": "#1f4e79",
          "transitional": "#e6c229", "fragmented": "#000000"}
LINE_STYLES = (("-", "o"), ("--", "s"), (":", "^"), ("-.", "D"))


class PlotError(ValueError):
    """Tables that cannot be drawn as asked (a missing directory, an ambiguous key, no matplotlib)."""


def phase(p: float, m: float, groups: int, highly_parallel: float = 0.97) -> str:
    """A run's phase from its time-averaged p and m and its final group count (see the module docstring)."""
    if groups is not None and groups > 1:
        return "fragmented"
    kind = classify(p, m)
    if kind == "polarized":
        return "highly parallel" if p > highly_parallel else "dynamic parallel"
    return {"milling": "torus"}.get(kind, kind)


def load(out: Path, x: str | None = None, flock: str | None = None) -> tuple[dict, str, list[dict]]:
    """(sweep.json, the x key, the finished runs' rows of one flock) of an output directory."""
    out = Path(out)
    if not (out / "runs.parquet").is_file() or not (out / "sweep.json").is_file():
        raise PlotError(f"{out}: no runs.parquet / sweep.json here (is it a sweep's output directory? run "
                        "cgp-sim-sweep run first)")
    info = json.loads((out / "sweep.json").read_text())
    rows = pq.read_table(out / "runs.parquet").to_pylist()
    keys = info["keys"]
    if x is None:
        chained = [e["chain"] for e in info["experiments"] if e["chain"]]
        if chained:
            x = chained[0]
        elif len(keys) == 1:
            x = keys[0]
        else:
            raise PlotError(f"{out}: several swept keys ({', '.join(keys) or 'none'}): choose one with --x")
    elif x not in keys:
        raise PlotError(f"--x {x}: not a swept key of this sweep (keys: {', '.join(keys)})")
    done = [r for r in rows if r["status"] == "done" and r["flock"] is not None]
    flocks = sorted({r["flock"] for r in done})
    if flock is None:
        if len(flocks) > 1:
            raise PlotError(f"{out}: several flocks ({', '.join(flocks)}): choose one with --flock")
        flock = flocks[0] if flocks else None
    elif flock not in flocks:
        raise PlotError(f"--flock {flock}: no finished run has it (flocks: {', '.join(flocks) or 'none'})")
    return info, x, [r for r in done if r["flock"] == flock and r[x] is not None]


def fractions(rows: list[dict], x: str, highly_parallel: float) -> dict[float, dict[str, float]]:
    """Per value of ``x`` (sorted): the fraction of runs in each phase."""
    out = {}
    for value in sorted({r[x] for r in rows}):
        kinds = [phase(r["polarization"], r["milling"], r["groups"], highly_parallel) for r in rows if r[x] == value]
        out[value] = {k: kinds.count(k) / len(kinds) for k in PHASES}
    return out


def phase_table(info: dict, x: str, rows: list[dict], highly_parallel: float) -> str:
    """Markdown: per experiment and value of ``x``, the fraction of seeds per phase, mean p and mean m."""
    lines = []
    for experiment in info["experiments"]:
        own = [r for r in rows if r["experiment"] == experiment["name"]]
        if not own:
            continue
        seeds = len({r["seed"] for r in own})
        lines.append(f"\n{experiment['name']} ({seeds} seeds): fraction of seeds per phase, mean p and m")
        lines.append(f"| {x} | " + " | ".join(PHASES) + " | mean p | mean m |")
        lines.append("|---:|" + "---:|" * (len(PHASES) + 2))
        for value, share in fractions(own, x, highly_parallel).items():
            at = [r for r in own if r[x] == value]
            lines.append(f"| {value:g} | " + " | ".join(f"{share[k]:.2f}" for k in PHASES)
                         + f" | {np.mean([r['polarization'] for r in at]):.2f}"
                         + f" | {np.mean([r['milling'] for r in at]):.2f} |")
    return "\n".join(lines)


def plot(out: Path, figure: Path | None = None, *, x: str | None = None, flock: str | None = None,
         highly_parallel: float = 0.97, title: str | None = None) -> tuple[Path, str]:
    """Draw the standard figure of the sweep in ``out``; returns (the figure's path, the phase table)."""
    try:
        import matplotlib
    except ImportError:
        raise PlotError("the figures need matplotlib, which is not installed: pip install matplotlib (or "
                        "cgp_sim_ros[plot])") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    info, x, rows = load(out, x, flock)
    if not rows:
        raise PlotError(f"{out}: no finished run to draw")
    experiments = [e for e in info["experiments"] if any(r["experiment"] == e["name"] for r in rows)]
    figure = Path(figure) if figure else Path(out) / f"{info['name']}.png"
    fig = plt.figure(figsize=(max(11, 3.7 * len(experiments)), 8.2), constrained_layout=True)
    grid = fig.add_gridspec(2, len(experiments), height_ratios=[1.5, 1.0])
    top = fig.add_subplot(grid[0, :])
    jitters = np.linspace(-0.08, 0.08, len(experiments)) if len(experiments) > 1 else [0.0]
    for index, experiment in enumerate(experiments):
        own = [r for r in rows if r["experiment"] == experiment["name"]]
        values = np.array(sorted({r[x] for r in own}), dtype=float)
        style, marker = LINE_STYLES[index % len(LINE_STYLES)]
        for key, color, name in (("polarization", "#1f4e79", "polarization p"), ("milling", "#d95f02", "milling m")):
            means = [np.mean([r[key] for r in own if r[x] == v]) for v in values]
            top.plot(values, means, style, color=color, marker=marker, markersize=4,
                     label=f"{name}, {experiment['name']}")
            dots = [(r[x] + jitters[index], r[key]) for r in own]
            top.scatter([d[0] for d in dots], [d[1] for d in dots], s=6, color=color, alpha=0.25, linewidths=0)
    top.axhline(0.65, color="0.6", lw=0.8, ls=":")
    top.axhline(0.35, color="0.6", lw=0.8, ls=":")
    seeds = max(len({r["seed"] for r in rows if r["experiment"] == e["name"]}) for e in experiments)
    window = experiments[0]["window"]
    heading = title or info.get("title") or info["name"]
    top.set_title(f"{heading}\n{seeds} seeds per point (dots: each run's average over its last {window:g} s), "
                  "lines: mean over seeds", fontsize=10)
    top.set_xlabel(x)
    top.set_ylabel("order parameter (time average)")
    top.set_ylim(-0.02, 1.02)
    top.legend(loc="center right", fontsize=8)
    present = [k for k in PHASES if any(phase(r["polarization"], r["milling"], r["groups"], highly_parallel) == k
                                        for r in rows)]
    for column, experiment in enumerate(experiments):
        axis = fig.add_subplot(grid[1, column])
        share = fractions([r for r in rows if r["experiment"] == experiment["name"]], x, highly_parallel)
        bottom = np.zeros(len(share))
        positions = np.arange(len(share))
        for kind in PHASES:
            heights = np.array([share[v][kind] for v in share])
            if heights.any():
                axis.bar(positions, heights, bottom=bottom, color=COLORS[kind], label=kind, width=0.85)
            bottom += heights
        axis.set_xticks(positions, [f"{v:g}" for v in share], fontsize=7)
        chain = " (carried over)" if experiment["chain"] == x else ""
        axis.set_title(f"{experiment['name']}{chain}", fontsize=9)
        axis.set_xlabel(x, fontsize=8)
        if column == 0:
            axis.set_ylabel("fraction of seeds")
        if column == len(experiments) - 1:
            axis.legend(handles=[Patch(color=COLORS[k], label=k) for k in present], fontsize=7, loc="lower left")
    figure.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(figure, dpi=110)
    plt.close(fig)
    return figure, phase_table(info, x, rows, highly_parallel)

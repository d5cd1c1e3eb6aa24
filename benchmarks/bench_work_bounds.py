"""Benchmark: the longest ticks the limits allow (issue 27: "one request must never stop the world").

Before the bound on a tick's rigid-body work (``cgp_core.limits.MAX_SHAPE_SUBSTEPS``, ``MAX_PARTICLE_SUBSTEPS``),
10,000 bodies × 1,000 sub-steps was inside every limit and ticked for minutes.  This steps, in-process, the
worlds at those bounds — what a user may still ask for — and reports each one's tick (median, p99, max over
``--ticks`` ticks from the first: the bodies are falling into a pile, not asleep):

- ``spheres_pile``: 10,000 spheres (r 0.1 m) in a 22³ lattice 1 cm apart, 4 sub-steps (40,000 shape sub-steps);
- ``spheres_substeps``: 40 spheres in a row, 1,000 sub-steps (40,000);
- ``compounds``: 625 compound bodies of 16 sphere parts in a lattice, 4 sub-steps (40,000);
- ``particle_body``: one body of 100,000 particles (r 5 cm) in a 2 m cube over the ground, 4 sub-steps (400,000
  particle sub-steps);
- ``particle_bodies``: 1,000 particle bodies of 100 particles in a lattice, 4 sub-steps (400,000).

The dense piles also run with the sweep alone for 3 ticks (``sweep_only``: the detector's switch to the grid
off, the broad phase before this work), for the figure of what the switch saves; not the particle bodies' pile,
where one call of the sweep alone took 16 s.  The target: every tick at the bounds under
a second (the node answers requests between ticks).

Plain script: prints a table and writes ``benchmarks/results/work_bounds.json`` (``benchmarks/common.py``'s
layout), with the speed probe before and after.

    .venv/bin/python benchmarks/bench_work_bounds.py [--ticks 30] [--quick]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from common import Results, format_figures, format_speed_probe  # noqa: E402

from cgp_core import limits  # noqa: E402
from cgp_core.scene import scene_from_dict  # noqa: E402
from cgp_core.warmup import warm_up  # noqa: E402
from cgp_core.world import World  # noqa: E402


def lattice(n: int, spacing: float = 0.21) -> np.ndarray:
    """``n`` points of a cubic lattice (jittered by 5 mm), centred over the ground, lowest layer at 0.15 m."""
    side = int(np.ceil(n ** (1 / 3)))
    grid = np.array([(x, y, z) for x in range(side) for y in range(side) for z in range(side)][:n], float)
    points = grid * spacing + np.random.default_rng(1).uniform(-0.005, 0.005, grid.shape) + [0, 0, 0.15]
    points[:, :2] -= points[:, :2].mean(0)
    return points


def spheres_pile(substeps: int = 4) -> dict:
    bodies = [{"name": f"s{k}", "shape": "sphere", "radius": 0.1, "position": p.tolist()}
              for k, p in enumerate(lattice(limits.MAX_SHAPE_SUBSTEPS // substeps))]
    return {"world": {"substeps": substeps, "sleep": False}, "bodies": bodies}


def spheres_substeps() -> dict:
    count = limits.MAX_SHAPE_SUBSTEPS // 1000
    bodies = [{"name": f"s{k}", "shape": "sphere", "radius": 0.1, "position": [0.25 * k, 0, 0.3]}
              for k in range(count)]
    return {"world": {"substeps": 1000, "sleep": False}, "bodies": bodies}


def compounds(count: int = limits.MAX_SHAPE_SUBSTEPS // (16 * 4)) -> dict:
    angles = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    parts = [{"shape": "sphere", "radius": 0.03, "position": [0.06 * np.cos(a), 0.06 * np.sin(a), 0.0]}
             for a in angles]
    bodies = [{"name": f"c{k}", "shape": "compound", "mass": 1.0, "parts": parts, "position": p.tolist()}
              for k, p in enumerate(lattice(count))]
    return {"world": {"substeps": 4, "sleep": False}, "bodies": bodies}


def particle_body() -> dict:
    count = limits.MAX_PARTICLE_SUBSTEPS // 4
    rng = np.random.default_rng(3)
    particles = np.column_stack([rng.uniform(-1, 1, (count, 3)), np.full(count, 0.01)]).tolist()
    return {"world": {"substeps": 4, "sleep": False},
            "bodies": [{"name": "cloud", "shape": "particles", "radius": 0.05, "particles": particles,
                        "position": [0, 0, 1.2]}]}


def particle_bodies() -> dict:
    rng = np.random.default_rng(2)
    bodies = []
    for k, p in enumerate(lattice(limits.MAX_PARTICLE_SUBSTEPS // (4 * 100))):
        grains = np.column_stack([rng.uniform(-0.07, 0.07, (100, 3)), np.full(100, 0.01)]).tolist()
        bodies.append({"name": f"p{k}", "shape": "particles", "radius": 0.02, "particles": grains,
                       "position": p.tolist()})
    return {"world": {"substeps": 4, "sleep": False}, "bodies": bodies}


CASES = {"spheres_pile": spheres_pile, "spheres_substeps": spheres_substeps, "compounds": compounds,
         "particle_body": particle_body, "particle_bodies": particle_bodies}
#: the piles the detector hands to the grid: also measured with the sweep alone, for 3 ticks (the particle bodies'
#: pile is not: one call of the sweep alone took 16 s there, a tick over a minute)
DENSE = ("spheres_pile", "compounds")
SWEEP_ONLY_TICKS = 3


def ticks_of(data: dict, ticks: int, *, sweep_only: bool = False) -> dict:
    world = World(scene_from_dict(data))
    detector = world.solver.detector
    if sweep_only:
        import cgp_core.collision.detector as det

        saved, det.SWEEP_TESTS_PER_BOX = det.SWEEP_TESTS_PER_BOX, 10 ** 12
    try:
        times = []
        for _ in range(ticks):
            start = time.perf_counter()
            world.step()
            times.append((time.perf_counter() - start) * 1e3)
    finally:
        if sweep_only:
            det.SWEEP_TESTS_PER_BOX = saved
    times = np.array(times)
    return {"median_ms": float(np.median(times)), "p99_ms": float(np.percentile(times, 99)),
            "max_ms": float(times.max()), "first_ms": float(times[0]), "ticks": ticks,
            "grid": bool(detector.dense), "finite": bool(np.isfinite(world.body_state.position).all())}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ticks", type=int, default=30)
    parser.add_argument("--quick", action="store_true", help="10 ticks each, no sweep-only runs")
    args = parser.parse_args(argv)
    ticks = 10 if args.quick else args.ticks
    out = Results("work_bounds", options=vars(args))
    warm_up()  # every kernel compiled or loaded (the convex stage's, the grid's) before anything is timed
    rows = []
    for name, make in CASES.items():
        data = make()
        runs = [("default", False)] + ([("sweep_only", True)] if name in DENSE and not args.quick else [])
        for mode, sweep_only in runs:
            row = {"case": name, "mode": mode,
                   **ticks_of(data, SWEEP_ONLY_TICKS if sweep_only else ticks, sweep_only=sweep_only)}
            rows.append(row)
            print(f"{name:18} {mode:11} median {row['median_ms']:8.1f}  p99 {row['p99_ms']:8.1f}  "
                  f"max {row['max_ms']:8.1f} ms  grid {row['grid']}", flush=True)
            if mode == "default":
                out.figure(f"{name}_max_tick", f"{name}: longest of {ticks} ticks from the first (default)",
                           round(row["max_ms"], 1), "ms", "< 1000", row["max_ms"] < 1000.0 and row["finite"])
    out.data["rows"] = rows
    path = out.write()
    print(format_figures(out.data["figures"]))
    print(format_speed_probe(out.data["speed_probe"]))
    print(f"wrote {path.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

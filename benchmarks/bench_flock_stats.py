"""Cost of a flock's per-tick statistics (issue 14: ``~/flocks/<flock>/stats`` on every tick) at 300, 2,000 and
15,000 boids — the node's way against the alternatives.

- ``Flock.order()`` after a step: what the node calls every tick.  Nearest-neighbour distances from the step's
  own neighbour list (each row's nearest, accepted where provably the nearest of all; the others searched
  again), the other order parameters in two compiled sequential passes (``cgp_core/boids/order.py``);
- its parts: the nearest-neighbour distances alone; the moments alone (p, m, centroid, R_g, speeds);
- ``flock_order(x, v)`` without a neighbour list: every boid searched from scratch (all pairs, or a KD-tree
  beyond ``order.BRUTE_FORCE_PAIRS``);
- scipy's ``cKDTree(x).query(x, k=2)``: the textbook way to the same distances;
- the FlockStats CDR serialization (``cgp_sim_ros.wire.cdr.FlockStatsSerializer``), when the ROS side is installed.

The flocks are the default flock (``FlockParams()``) at its steady-state density (0.52 boids/m³, as
``bench_boids.py`` and the 15k-fish tick scene), stepped 60 ticks from a random start (so the neighbour list is
a step's list and the flock has begun to form).  Each call is timed ``--repeats`` times, interleaved round by
round, median reported; both cores as the node has them (numba's threads for flocks of 2,000 and more).

    .venv/bin/python benchmarks/bench_flock_stats.py [--repeats 30]

Prints a table, writes benchmarks/results/flock_stats.json; asserts nothing.  (The stats' share of the real
15k-fish tick is in ``bench_tick.py``'s split.)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_boids import make_flock  # noqa: E402
from common import Results  # noqa: E402

from cgp_core.boids.order import _moments, flock_order, nearest_neighbor_distances  # noqa: E402
from cgp_core.jit import threads_for  # noqa: E402

SIZES = (300, 2000, 15000)
DENSITY = 0.52  # boids per m³: the default flock's steady state (bench_boids.py)
DT = 1.0 / 60.0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args(argv)
    out = Results("flock_stats", options=vars(args))
    try:
        from cgp_sim_ros.wire.cdr import FlockStatsSerializer
        serializer = FlockStatsSerializer("world")
    except ImportError:  # without the ROS side installed, the serialization is not timed
        serializer = None
    from scipy.spatial import cKDTree

    rows = []
    for n in SIZES:
        flock = make_flock(n, DENSITY, "grid")
        for _ in range(60):
            flock.step(DT)
        x, v = flock.positions, flock.velocities
        neighbors, searched, radius = flock._searched
        order = flock.order()
        moved = flock._moved_since_search
        nearest = nearest_neighbor_distances(x, None, neighbors, searched, radius, moved)

        def with_threads(function):
            def timed():
                with threads_for(n):
                    function()
            return timed

        cases = {
            "order_ms": flock.order,
            "nearest_from_list_ms": with_threads(lambda: nearest_neighbor_distances(x, None, neighbors, searched,
                                                                                   radius, moved)),
            "moments_ms": lambda: _moments(x, v, nearest),
            "from_scratch_ms": with_threads(lambda: flock_order(x, v)),
            "kdtree_ms": lambda: cKDTree(x).query(x, k=2),
        }
        if serializer is not None:
            values = (order.polarization, order.milling, *order.centroid, order.radius_of_gyration,
                      order.mean_nearest_neighbor_distance, order.mean_speed, order.min_speed, order.max_speed)
            cases["serialize_ms"] = lambda: serializer.serialize(0, n, values)
        times = {key: [] for key in cases}
        for function in cases.values():
            function()  # warm up (compiles on a cold cache)
        for _ in range(args.repeats):
            for key, function in cases.items():
                start = time.perf_counter()
                function()
                times[key].append(time.perf_counter() - start)
        row = {"boids": n, **{key: 1e3 * float(np.median(t)) for key, t in times.items()}}
        row["searched_again"] = int(np.count_nonzero(_searched_again(flock)))
        rows.append(row)
        out.figure(f"flock_stats_{n}", f"Flock.order (every stats figure, from the step's list), {n} boids",
                   row["order_ms"], "ms", "", None)
    out.data["rows"] = rows
    path = out.write()
    print(f"{'boids':>7} {'order ms':>9} {'NND list ms':>12} {'moments ms':>11} {'scratch ms':>11} "
          f"{'KD-tree ms':>11} {'CDR µs':>7} {'searched again':>15}")
    for row in rows:
        serialized = f"{1e3 * row['serialize_ms']:.1f}" if "serialize_ms" in row else "n/a"
        print(f"{row['boids']:>7} {row['order_ms']:>9.3f} {row['nearest_from_list_ms']:>12.3f} "
              f"{row['moments_ms']:>11.3f} {row['from_scratch_ms']:>11.3f} {row['kdtree_ms']:>11.3f} "
              f"{serialized:>7} {row['searched_again']:>15}")
    print(f"\nwrote {path.relative_to(Path(__file__).resolve().parents[1])}")
    return 0


def _searched_again(flock) -> np.ndarray:
    """(N,) bool: the boids whose nearest neighbour the step's list could not decide (searched again against
    every boid, inside the same kernel call while that is a small job)."""
    from cgp_core.boids import order as order_module

    neighbors, searched, radius = flock._searched
    found = np.empty(flock.count, np.bool_)
    order_module._nearest_in_rows(
        order_module.Searched(neighbors, searched, float(radius), flock._moved_since_search), flock.positions,
        flock.period, order_module.Budget(order_module.MAX_JUMPERS, 0), np.empty(flock.count), found)
    return ~found


if __name__ == "__main__":
    sys.exit(main())

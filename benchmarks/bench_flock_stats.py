"""Cost of a flock's per-tick statistics (issue 14): ``flock_order`` (polarization, milling, centroid, radius
of gyration, nearest-neighbour distances, speeds) and its FlockStats serialization, for 300, 2,000 and 15,000
boids, against scipy's KD-tree for the nearest-neighbour distances (what the grid kernel replaces).

    .venv/bin/python benchmarks/bench_flock_stats.py [--repeats 15]

Boids: uniform in a cube at one boid per m³ (the default flock's spacing, nearest neighbour ~0.55 m), random
velocities.  Median of ``--repeats`` calls after one warm-up call (which also compiles the numba kernel).
Prints a table, writes benchmarks/results/flock_stats.json; asserts nothing.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from cgp_core.boids.order import flock_order, nearest_neighbor_distances  # noqa: E402
from common import Results  # noqa: E402

SIZES = (300, 2000, 15000)


def median_ms(function, repeats: int) -> float:
    function()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args(argv)
    out = Results("flock_stats", options=vars(args))
    try:
        from cgp_sim_ros.flock_stats import serialize
    except ImportError:  # without the ROS side installed, the serialization is not timed
        serialize = None
    rows = []
    rng = np.random.default_rng(0)
    for n in SIZES:
        side = n ** (1.0 / 3.0)
        x = rng.random((n, 3)) * side
        v = rng.normal(size=(n, 3))
        order = flock_order(x, v)
        row = {"boids": n,
               "flock_order_ms": median_ms(lambda: flock_order(x, v), args.repeats),
               "nearest_grid_ms": median_ms(lambda: nearest_neighbor_distances(x.T), args.repeats),
               "nearest_kdtree_ms": median_ms(lambda: cKDTree(x).query(x, k=2), args.repeats),
               "serialize_us": (1e3 * median_ms(lambda: serialize(0, "world", order), args.repeats)
                                if serialize else None)}
        rows.append(row)
        out.figure(f"flock_order_{n}", f"flock_order (all stats), {n} boids", row["flock_order_ms"], "ms", "", None)
    out.data["rows"] = rows
    out.write()
    print(f"{'boids':>7} {'flock_order ms':>15} {'NND grid ms':>12} {'NND KD-tree ms':>15} {'serialize µs':>13}")
    for row in rows:
        serialized = f"{row['serialize_us']:.1f}" if row["serialize_us"] is not None else "n/a"
        print(f"{row['boids']:>7} {row['flock_order_ms']:>15.2f} {row['nearest_grid_ms']:>12.2f} "
              f"{row['nearest_kdtree_ms']:>15.2f} {serialized:>13}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

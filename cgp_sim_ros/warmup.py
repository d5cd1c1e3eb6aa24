"""Compile the simulation's numba kernels once, into their on-disk cache, so that no run pays for it.

``make setup`` runs ``python -P -m cgp_sim_ros.warmup`` right after installing the project (``-P``: the
installed package, whose ``__pycache__`` is where the node will look).  It steps the default scene with its
bodies placed so that every contact kernel runs (:func:`cgp_core.warmup.warm_up`; the flock kernels and its
obstacle query too), draws its markers (the fish kernel, the rounding of sphere lists) — in a few seconds when the cache is already there, about half a
minute on a fresh install.  Without it, the first ``make run`` would compile the same kernels before its first
tick; nothing else changes.
"""

from __future__ import annotations

import sys
import time


def main() -> int:
    started = time.perf_counter()
    import numpy as np

    from cgp_core.warmup import warm_up

    from .shapes import fish_triangles, quantized_points

    world = warm_up()  # the default scene, bodies placed so that every contact kernel runs; the flock's kernels
    flock = world.flocks[0]
    for detail in ("full", "low"):
        fish_triangles(flock.positions, flock.orientations, flock.params.boid_size, detail)
    quantized_points(np.zeros((1, 3)))
    print(f"cgp_sim: simulation kernels compiled and cached ({time.perf_counter() - started:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

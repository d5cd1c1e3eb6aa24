"""Compile the simulation's numba kernels once, into their on-disk cache, so that no run pays for it.

``make setup`` runs ``python -P -m cgp_sim_ros.warmup`` right after installing the project (``-P``: the
installed package, whose ``__pycache__`` is where the node will look).  It builds the default scene, steps it
(the flock kernels, its obstacle query, the rigid-body kernels the scene uses), draws its markers (the fish
kernel, the rounding of sphere lists) — in a few seconds when the cache is already there, about half a
minute on a fresh install.  Without it, the first ``make run`` would compile the same kernels before its first
tick; nothing else changes.
"""

from __future__ import annotations

import sys
import time


def main() -> int:
    started = time.perf_counter()
    import numpy as np

    from cgp_core.world import World

    from .shapes import fish_triangles, quantized_points

    world = World.from_scene("default")
    for _ in range(3):  # the first tick starts numba's thread pool; the next ones use the helper thread too
        world.step()
    flock = world.flocks[0]
    for detail in ("full", "low"):
        fish_triangles(flock.positions, flock.orientations, flock.params.boid_size, detail)
    quantized_points(np.zeros((1, 3)))
    print(f"cgp_sim: simulation kernels compiled and cached ({time.perf_counter() - started:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

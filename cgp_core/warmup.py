"""Compile cgp_core's numba kernels once, into their cache: ``python -m cgp_core.warmup`` (the core alone).

``make setup`` runs it (through ``cgp_sim_ros.warmup``, which adds the node's marker kernels) after installing
the project, so the node's first start (and every test) finds the compiled kernels in the cache next to the
installed sources (``__pycache__/*.nbi|*.nbc``) and starts in about a second instead of compiling for tens of
seconds.  It steps the default scene (bodies and flock) with the
bodies placed so that every contact kernel runs within a few ticks.  Safe to run any time: a warm cache makes it
a no-op of a second or two.
"""

from __future__ import annotations

import time


def warm_up(ticks: int = 24) -> "World":
    """Step the default scene ``ticks`` times with every contact kernel in use; returns the world."""
    from .world import World

    world = World.from_scene("default")
    state, names = world.body_state, world.body_model.names
    # ground under a sphere, a box, a capsule and a particle body; box–box against the pillar; box–capsule;
    # sphere against the particle body
    for name, xyz in {"ball": (1.6, 1.4, 0.32), "crate": (5.15, 0.0, 0.28), "capsule": (5.0, 0.0, 0.78),
                      "tetromino": (1.8, 2.0, 0.18)}.items():
        if name in names:
            state.position[names.index(name)] = xyz
    for _ in range(ticks):
        world.step()
    for flock in world.flocks:
        flock.order()  # the order parameters the node publishes every tick
    _warm_up_flock_rules()
    return world


def _warm_up_flock_rules() -> None:
    """Issue 14's kernels: a Couzin school fleeing a predator (the built-in ``predator`` scene), topological
    neighbours (with stragglers), the order parameters with and without a neighbour list."""
    from .boids import Flock, FlockParams
    from .world import World

    world = World.from_scene("predator")
    shark = world.body_model.names.index("shark")
    world.body_state.position[shark] = world.flocks[0].positions.mean(axis=0)
    for _ in range(3):
        world.step()
    world.flocks[0].order()
    flock = Flock(FlockParams(count=40, neighbor_mode="topological", spawn_extent=[30.0, 30.0, 18.0]))
    flock.step(1.0 / 60.0)
    flock.order()


if __name__ == "__main__":
    started = time.perf_counter()
    warm_up()
    print(f"cgp_core.warmup: compiled kernels ready in {time.perf_counter() - started:.1f} s")

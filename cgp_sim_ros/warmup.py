"""Compile the simulation's numba kernels once, into their on-disk cache, so that no run pays for it.

``make setup`` runs ``python -P -m cgp_sim_ros.warmup`` right after installing the project (``-P``: the
installed package, whose ``__pycache__`` is where the node will look).  It steps the default scene with its
bodies placed so that every contact kernel runs (:func:`cgp_core.warmup.warm_up`; the flock kernels and its
obstacle query too) and draws its markers (the fish kernel, the rounding of sphere lists), compiling in
parallel worker processes (:func:`cgp_core.warmup.compile_in_parallel`): measured on a 2-core machine when
nothing is cached (``benchmarks/bench_compile.py``, issue 34, on a shared machine), ~95-105 s of wall and
~180-200 s of CPU for every kernel (the default scene's own, ``--default-scene``: ~24-26 s and ~46-48 s), and ~2 s
when everything is.

The node does the same at start-up (:func:`compile_missing_kernels`, called by ``cgp-sim`` before it builds
the node) for the parts it finds uncompiled — a start right after an install or an edit of the kernels'
sources — so that it does not compile them one after the other, on one core, in its first tick.
"""

from __future__ import annotations

import dataclasses
import sys

from cgp_core import warmup as core
from cgp_core.bodies import Shape
from cgp_core.warmup import CompilePart

#: cgp_core's parts, the flock's with the node's marker kernels (fish triangles, sphere lists) added
PARTS: tuple[CompilePart, ...] = tuple(
    dataclasses.replace(p, modules=p.modules + ("cgp_sim_ros.drawing.shapes",),
                        sentinels=p.sentinels + ("cgp_sim_ros.drawing.shapes:_fish_vertices",))
    if p.name == "flock" else p for p in core.PARTS)


def scenario(complete: bool = True, flocks: bool = True) -> None:
    """What the node runs: the default scene's ticks (:func:`cgp_core.warmup.warm_up`) and its markers;
    ``complete``: also the kernels the default scene does not use (issue 14's flock rules; the parallel twins
    for big flocks, markers included); ``flocks=False``: the bodies alone."""
    import numpy as np

    from cgp_core.jit import parallel_from
    from cgp_core.warmup import warm_up

    from .drawing.shapes import fish_triangles, quantized_points

    world = warm_up(complete=complete, flocks=flocks)
    if not flocks:
        return
    flock = world.flocks[0]

    def draw():
        for detail in ("full", "low"):
            fish_triangles(flock.positions, flock.orientations, flock.params.boid_size, detail)
        quantized_points(np.zeros((1, 3)))

    draw()
    if complete:
        with parallel_from(0):
            draw()


def compile_missing_kernels(log, scene=None) -> None:
    """Compile, in parallel, the parts of the kernels ``scene`` runs (a :class:`~cgp_core.scene.Scene`; None: the
    default scene's) that are not cached yet; ``log(text)`` says what happens.

    A scene of the default scene's shapes (spheres, boxes, capsules, particle bodies, flocks) needs the default
    scene's parts only, and the kernels it does not use (issue 14's flock rules, the parallel twins for big
    flocks) are left to compile on first use: they would lengthen the flock worker's share.  A scene with hulls,
    compounds, meshes or robots needs the convex or robots part too, which would otherwise compile in its first
    tick, one kernel after another (the convex part alone is ~60 s of CPU): then every part is compiled, as
    ``make setup`` does.  So ``make run``, which leaves the compile to the node, starts the default scene after
    ~30 s of compiling on a fresh clone instead of every kernel's ~140 s."""
    beyond_default = scene is not None and (scene.robots or scene.articulations or any(
        b.shape in (Shape.CONVEX, Shape.COMPOUND, Shape.MESH) for b in scene.bodies))
    core.compile_missing(PARTS, "cgp_sim_ros.warmup", log, default_scene=not beyond_default)


def main(argv: list[str] | None = None) -> int:
    return core.main(sys.argv[1:] if argv is None else argv, name="cgp_sim", parts=PARTS,
                     worker_module="cgp_sim_ros.warmup", scenario=scenario)


if __name__ == "__main__":
    sys.exit(main())

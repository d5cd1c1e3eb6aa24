"""Compile cgp_core's numba kernels once, into their cache: ``python -m cgp_core.warmup`` (the core alone).

``make setup`` runs it (through ``cgp_sim_ros.warmup``, which adds the node's marker kernels) after installing
the project, so the node's first start (and every test) finds the compiled kernels in the cache next to the
installed sources (``__pycache__/*.nbi|*.nbc``) and starts in about a second instead of compiling for tens of
seconds.  It steps the default scene (bodies and flock) with the bodies placed so that every contact kernel
runs within a few ticks.  Safe to run any time: a warm cache makes it a no-op of a second or two.

**In parallel.**  numba compiles one kernel at a time on one core: the default scene's kernels take ~40 s of
CPU.  :func:`compile_in_parallel` shares that out among worker processes, one per :class:`CompilePart` (the
rigid-body solver; contact detection with the integrators; the flock), which compile side by side into the
same on-disk cache; the calling process then loads what they wrote.  Each worker runs the same warm-up scenario
as the serial path — so every kernel meets exactly the argument types of a real run — with only its own
modules compiled (``CGP_SIM_JIT_ONLY``, :mod:`cgp_core.jit`); the rest runs there as plain Python, which for a
few ticks of five bodies and one small flock costs about a second.
"""

from __future__ import annotations

import dataclasses
import importlib
import os
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .world import World


def warm_up(ticks: int = 24, *, complete: bool = True, flocks: bool = True) -> World:
    """Step the default scene ``ticks`` times with every contact kernel in use; returns the world.

    ``complete``: also the flock kernels the default scene does not use — issue 14's (Couzin's model,
    topological neighbours, predators) and the parallel twins that big flocks run (:mod:`cgp_core.jit`).
    ``flocks=False``: the default scene without its flock (the rigid-body compile workers, for which the flock
    would only be plain Python to wait for)."""
    from .jit import parallel_from
    from .scene import load_scene
    from .world import World

    scene = load_scene("default")
    world = World(scene if flocks else dataclasses.replace(scene, flocks=[]))
    state, names = world.body_state, world.body_model.names
    # ground under a sphere, a box, a capsule and a particle body; box–box against the pillar; box–capsule;
    # sphere against the particle body
    for name, xyz in {"ball": (1.6, 1.4, 0.32), "crate": (5.15, 0.0, 0.28), "capsule": (5.0, 0.0, 0.78),
                      "tetromino": (1.8, 2.0, 0.18)}.items():
        if name in names:
            state.position[names.index(name)] = xyz

    def run() -> None:
        for k in range(ticks):
            # every other tick with the contact report (the node's ~/contacts, on by default, summed only while
            # someone listens): the solver's one entry point, solve_step, with its `report` argument both ways
            world.report_contacts = k % 2 == 0
            world.step()
        for flock in world.flocks:
            flock.order()  # the order parameters the node publishes every tick
        if flocks and complete:
            _warm_up_flock_rules()

    run()
    if flocks and complete:
        with parallel_from(0):  # the same again, on the parallel twins
            run()
    if complete:
        # (in a compile worker, only the scenarios whose kernels it compiles: the robots' scene in another worker
        # only ran their kernels as plain Python and compiled numba's typed-list functions, which a robots' world
        # builds and which numba caches nowhere, ~2 s of CPU in each worker; issue 34)
        if _compiles_any("cgp_core.collision", "cgp_core.solver", "cgp_core.boids", "cgp_core.integrators"):
            warm_up_convex(flocks=flocks)
        _warm_up_grid()
        if _compiles_any("cgp_core.solver"):
            _warm_up_solver_by_regions()
        if _compiles_any("cgp_core.robots"):
            warm_up_robots()
    return world


def load_kernels_for(world: World) -> None:
    """Have the compiled kernels ``world`` comes to run loaded from numba's cache before its first tick, beyond
    those its first instant runs (the caller steps a throwaway copy of it for those: the node's
    :func:`cgp_sim_ros.ros.process.load_kernels`).  numba loads a kernel at its first call, and a tick that loads
    some takes that much longer: every rigid-body contact kernel (:func:`warm_up`'s scenario, two ticks: ~0.5 s);
    for a world of enough movable bodies to make :data:`~cgp_core.solver.sequential_impulse.SPLIT_MIN_CONTACTS`
    contacts (four a body), the solver's path for big worlds and numba's thread pool (~0.25 s: measured, the
    100-hull pile's first sub-step of 256 contacts took 115 ms when it loaded them itself); for a world with robots
    and free bodies, the loop that solves a robot and the bodies its links touch together (the ``arm`` scene's first
    such sub-step took 110–240 ms when it loaded it itself)."""
    import numpy as np

    from .solver.sequential_impulse import SPLIT_MIN_CONTACTS

    warm_up(ticks=2, complete=False, flocks=False)  # two: one with the contact report, one without
    if 4 * int(np.count_nonzero(world.body_model.inv_mass > 0.0)) >= SPLIT_MIN_CONTACTS:
        _warm_up_solver_by_regions()
    if runs_robot_and_body_loop(world):  # (the arm scene's tick 231: 110-240 ms loading it, measured through
        warm_up_robot_contacts(ticks=2)   # the node and in process)


def runs_robot_and_body_loop(world: World) -> bool:
    """Whether ``world`` has a robot and free bodies (movable, not links): the first sub-step a link touches one
    runs the loop that solves them together (``robots.coupled.step_coupled``), which :func:`load_kernels_for`
    loads beforehand (and the node's spawn path, :class:`cgp_sim_ros.ros.process.ConvexKernels`, before the
    first free body joins a robot world)."""
    import numpy as np

    robots = getattr(world, "robots", None)
    return robots is not None and bool(np.any((world.body_model.inv_mass > 0.0) & (robots.body_robot < 0)))


def _compiles_any(*modules: str) -> bool:
    """Whether this process compiles kernels of any of these modules or packages: every process but a compile
    worker (``CGP_SIM_JIT_ONLY``, :mod:`cgp_core.jit`), which compiles only its part's."""
    from .jit import JIT_ONLY

    return not JIT_ONLY or any(p == m or p.startswith(m + ".") or m.startswith(p + ".")
                               for p in JIT_ONLY for m in modules)


def warm_up_robots(ticks: int = 4) -> World:
    """Step the built-in ``arm`` scene: the robots' kernels (kinematics, Jacobians, CRBA, RNEA, the joint solver
    with position, velocity and effort drives, limits, a mimic coupling and link contacts), and the arm with a
    Gauss–Legendre joint integrator."""
    from .world import World

    world = World.from_scene("arm")
    world.robots.command("arm", ["shoulder_pan", "elbow", "wrist"], position=[0.3], velocity=[0.0, 0.5],
                         effort=[0.0, 0.0, 1.0])
    for _ in range(ticks):  # a robot that touches nothing: the robots' batched kernels (step_lone_robots, ...)
        world.step()
    # the joint-space mass matrix alone (the projection onto closed loops' constraints calls it; the arm has none):
    # the robots part's sentinel, which no tick compiled — every warm start of `make setup` found the part missing
    # and ran its compile worker again (~1.7 s; issue 34)
    from .robots import algorithms

    for r in world.robots.robots:
        algorithms.mass_matrix(r.kernel_arrays, world.robots.q[r.q_slice])
    warm_up_robot_contacts(ticks)
    from .scene import scene_from_dict

    # the Gauss–Legendre joint integrators (a scene's `joint_integrator`; both methods share one compile): ~21 s of
    # CPU that a scene choosing one waited for in its first tick, measured in a cold suite
    smooth = World(scene_from_dict({"world": {"joint_integrator": "gauss_legendre_4"},
                                    "robots": [{"name": "arm", "urdf": "arm.urdf"}]}, "<warm-up>"))
    for _ in range(2):
        smooth.step()
    return world


def warm_up_robot_contacts(ticks: int = 4) -> None:
    """A robot whose link touches a body (a crate resting on its level upper arm): its contact rows, its rows and
    the body rows in one loop (Robots.solve, robots.coupled.step_coupled); a fixed crate: the joint step alone,
    from Python."""
    from .scene import scene_from_dict
    from .world import World

    for fixed in (False, True):
        touching = World(scene_from_dict({
            "robots": [{"name": "arm", "urdf": "arm.urdf", "joints": {"shoulder_lift": 1.5708, "elbow": -1.5708}}],
            "bodies": [{"name": "crate", "shape": "box", "size": [0.06, 0.06, 0.04], "mass": 0.4, "fixed": fixed,
                        "position": [0.25, 0.0, 0.247]}]}, "<warm-up>"))
        for _ in range(ticks):
            touching.step()


def _warm_up_grid() -> None:
    """The broad phase's grid, which the collision detector runs for scenes too dense for the sweep (thousands of
    bodies in a pile: :data:`cgp_core.collision.detector.SWEEP_TESTS_PER_BOX`), with the detector's argument
    types: (p, 3) float64 bounds, (p,) intp bodies, the cell edge; and the sweep as the detector calls it from
    Python for more than :data:`~cgp_core.collision.detector.SMALL_SCENE` primitives ((p,) int64 groups, an int
    test budget).  The contacts worker compiles both: no scenario of its own has that many primitives, and the
    sweep was compiled by the warm-up's own process after every worker, ~2.3 s of CPU on the set-up's critical
    path (bench_compile: 'main')."""
    import numpy as np

    from .collision.broadphase import grid_kernel, sweep_and_prune_kernel

    lo = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [-4.0, -4.0, -1.0]])
    hi = lo + 1.0 + 7.0 * (lo < -1.0)
    grid_kernel(lo, hi, np.arange(3, dtype=np.intp), 0.0)
    sweep_and_prune_kernel(lo, hi, np.arange(3, dtype=np.int64), 64 * 3)


def _warm_up_solver_by_regions() -> None:
    """The solver's path for big worlds (:func:`cgp_core.solver.sequential_impulse.solve_sweeps_by_regions`: the
    sweeps by two regions on the thread pool), which a sub-step of :data:`~cgp_core.solver.sequential_impulse.
    SPLIT_MIN_CONTACTS` contacts or more takes: that many spheres resting on the ground, with and without the
    contact report."""
    from .scene import parse_scene
    from .solver.sequential_impulse import SPLIT_MIN_CONTACTS
    from .world import World

    side = int(SPLIT_MIN_CONTACTS ** 0.5) + 1
    bodies = "\n".join(f"  - {{name: s{i}_{j}, shape: sphere, radius: 0.1, position: [{0.25 * i}, {0.25 * j}, 0.1]}}"
                       for i in range(side) for j in range(side))
    world = World(parse_scene(f"world: {{sleep: false}}\nbodies:\n{bodies}\n"))
    for k in range(2):
        world.report_contacts = k % 2 == 0
        world.step()


#: issue 25's shapes placed so that every pair of the convex stage runs within a few ticks: hull–ground,
#: hull–hull, box–hull, hull–sphere, hull–capsule, the parts of a compound (sphere, box, capsule, hull) against
#: the ground and the others, a static mesh against a sphere, a capsule, a box and a hull, and a plank spinning
#: fast next to a fixed hull (the time of impact); with a small flock around them (the obstacle queries)
CONVEX_WARM_UP = """
world: {substeps: 2, sleep: false}
bodies:
  - {name: slab, shape: mesh, mesh: terrain.obj, fixed: true, position: [20, 0, -0.1]}
  - {name: post, shape: convex, fixed: true, points: [[0, 0, 0], [0.4, 0, 0], [0, 0.4, 0], [0.4, 0.4, 0],
     [0, 0, 2], [0.4, 0, 2], [0, 0.4, 2], [0.4, 0.4, 2]], position: [-0.2, -0.2, 0]}
  - {name: rock, shape: convex, mesh: rock.stl, density: 2600, position: [0.6, 0, 0.1]}
  - {name: rock_on_rock, shape: convex, mesh: rock.stl, scale: 0.5, density: 2600, position: [0.6, 0, 0.3]}
  - {name: box_on_rock, shape: box, size: [0.1, 0.1, 0.1], position: [0.7, 0.1, 0.3]}
  - {name: ball_by_rock, shape: sphere, radius: 0.05, position: [0.85, 0, 0.08]}
  - {name: stick_by_rock, shape: capsule, radius: 0.03, length: 0.2, position: [0.6, 0.2, 0.1],
     orientation: [0.7071068, 0, 0, 0.7071068]}
  - {name: table, shape: compound, mass: 3, position: [-0.8, 0, 0.05], parts: [
      {shape: box, size: [0.3, 0.3, 0.04], position: [0, 0, 0.2]},
      {shape: capsule, radius: 0.02, length: 0.12, position: [0.1, 0.1, 0.1]},
      {shape: sphere, radius: 0.03, position: [-0.1, -0.1, 0.03]},
      {shape: convex, points: [[0, 0, 0], [0.05, 0, 0], [0, 0.05, 0], [0, 0, 0.1]], position: [0.1, -0.1, 0]}]}
  - {name: mesh_ball, shape: sphere, radius: 0.1, position: [20, 0, 0.5]}
  - {name: mesh_stick, shape: capsule, radius: 0.05, length: 0.3, position: [21, 0, 0.5]}
  - {name: mesh_box, shape: box, size: [0.2, 0.2, 0.2], position: [20, 1, 0.5]}
  - {name: mesh_rock, shape: convex, mesh: rock.stl, position: [21, 1, 0.5]}
  - {name: spinner, shape: box, size: [1.0, 0.02, 0.05], position: [0, 0.75, 1.0], angular_velocity: [0, 0, 60]}
  - {name: spinning_rock, shape: convex, mesh: rock.stl, position: [20, -1, 0.6], angular_velocity: [0, 60, 0]}
flocks:
  - {name: minnows, count: 40, spawn: {center: [0.5, 0, 0.6], extent: [1.5, 1.5, 0.8]}, radius: 0.5,
     separation_radius: 0.2, min_speed: 0.5, max_speed: 1.0, boid_size: 0.05, obstacle_margin: 0.5, seed: 2,
     bounds: {mode: none}}
  - {name: tadpoles, count: 20, spawn: {center: [20, 0, 0.5], extent: [1.0, 1.0, 0.3]}, radius: 0.5,
     separation_radius: 0.2, min_speed: 0.5, max_speed: 1.0, boid_size: 0.05, obstacle_margin: 0.5, seed: 3,
     bounds: {mode: none}}
"""


def warm_up_convex(ticks: int = 6, *, flocks: bool = True) -> World:
    """Step :data:`CONVEX_WARM_UP`: the kernels of issue 25's shapes (the convex stage, GJK / EPA, the manifolds,
    the BVH queries, the time of impact; the flock's hull and mesh obstacle queries)."""
    import dataclasses

    from .scene import parse_scene
    from .world import World

    scene = parse_scene(CONVEX_WARM_UP, "<warm-up: convex shapes>")
    world = World(scene if flocks else dataclasses.replace(scene, flocks=[]))
    for _ in range(ticks):
        world.step()
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


# ---- compiling in parallel ------------------------------------------------------------------------------

@dataclass(frozen=True)
class CompilePart:
    """The kernels one compile worker compiles.

    Attributes:
        name:      shown in logs and in the worker's command line.
        modules:   modules or packages whose kernels the worker compiles (``CGP_SIM_JIT_ONLY``).  A kernel calls
                   other kernels only if they are compiled too, so a part lists the modules its kernels call.
        sentinels: ``"module:kernel"`` entry points whose on-disk cache tells whether this part is compiled
                   (a part's kernels are compiled together, so one entry point per stage of the run suffices).
    """

    name: str
    modules: tuple[str, ...]
    sentinels: tuple[str, ...]
    steps_flocks: bool = True  #: whether the worker's scenario needs the flocks (False: it leaves them out)
    #: whether the default scene runs these kernels: the node compiles such parts at start-up when they are not
    #: cached (``--default-scene``); the others only ``make setup`` does (a scene that needs them and finds no
    #: cache compiles them in its first tick)
    default_scene: bool = True
    #: parts whose workers must have finished before this one starts (when they compile too): the kernels this
    #: part shares with them (its kernels call theirs) are then loaded from the cache, not compiled a second time
    after: tuple[str, ...] = ()
    #: the part's compile CPU seconds as last measured (``benchmarks/bench_compile.py``'s compile CPU per part, every
    #: kernel), for the order in which :func:`compile_in_parallel` starts the workers when some wait for others; a
    #: guide only
    cpu_s: float = 0.0
    #: entry points only the complete scenario compiles (``make setup``'s, not ``--default-scene``'s, which a node
    #: runs for the default scene's parts): a part a node compiled is not taken for complete by ``make setup``,
    #: whose own process would otherwise compile the rest one kernel after another (:func:`missing_parts`)
    complete_sentinels: tuple[str, ...] = ()


#: the modules of the sphere / box / capsule contacts (the default scene's), and those of issue 25's shapes
_CONTACT_MODULES = ("cgp_core.collision.detector", "cgp_core.collision.primitives", "cgp_core.collision.broadphase",
                    "cgp_core.collision.narrowphase", "cgp_core.collision.box_box", "cgp_core.collision.materials")
_CONVEX_MODULES = ("cgp_core.collision.convex_phase", "cgp_core.collision.convex", "cgp_core.collision.gjk",
                   "cgp_core.collision.epa", "cgp_core.collision.manifold", "cgp_core.collision.bvh",
                   "cgp_core.collision.mesh_contacts", "cgp_core.collision.toi")

#: cgp_core's share-out, balanced on the compile times measured on an idle core (numba 0.68) for the default
#: scene: the solver ~16 s; contact detection and the integrators ~14 s; the flock ~9 s (``make setup`` also
#: compiles issue 14's rules and the parallel twins there: ~15 s more)
PARTS: tuple[CompilePart, ...] = (
    CompilePart("solver", ("cgp_core.solver", "cgp_core.rotation", "cgp_core.bodies"),
                ("cgp_core.solver.sequential_impulse:solve_step",
                 "cgp_core.solver.sequential_impulse:recover_penetration_kernel"), steps_flocks=False, cpu_s=15.0,
                complete_sentinels=("cgp_core.solver.sequential_impulse:solve_sweeps_by_regions",)),
    # (rotation's and bodies' few small kernels are compiled by both rigid-body parts: each part's kernels call them)
    CompilePart("contacts", _CONTACT_MODULES + ("cgp_core.integrators", "cgp_core.dynamics", "cgp_core.sleep",
                                                "cgp_core.rotation", "cgp_core.bodies"),
                ("cgp_core.collision.detector:narrow_phase", "cgp_core.integrators.implicit_midpoint:_step_kernel",
                 "cgp_core.dynamics:coming_velocities"), steps_flocks=False, cpu_s=26.0,
                complete_sentinels=("cgp_core.collision.broadphase:grid_kernel",)),
    # (the obstacle query of static meshes calls the BVH's closest point, which calls GJK's closest point on a
    # triangle; GJK calls the hulls' support mapping: with gjk compiled here, convex's kernels must be too, or the
    # convex shapes' contacts, plain Python in this worker, reach a compiled GJK calling a plain support_index)
    CompilePart("flock", ("cgp_core.boids", "cgp_core.collision.bvh", "cgp_core.collision.gjk",
                          "cgp_core.collision.convex"),
                ("cgp_core.boids.rules:_neighbor_sums", "cgp_core.boids.flock:_move"), cpu_s=30.0,
                complete_sentinels=("cgp_core.boids.predators:_flee", "cgp_core.boids.topological:_rank_candidates")),
    # issue 25's shapes: ~60 s of compiling on an idle core (GJK, EPA, the manifolds and the stage that calls them
    # all), more than any other part; it calls the sphere / box / capsule kernels too (compiled here as well)
    # (after "contacts": the sphere / box / capsule kernels it calls are that part's, ~25 s of CPU that both
    # workers compiled side by side on a cold cache, issue 34; so the workers run one more than the CPUs at a time,
    # the chains' heads first, and the other parts keep the CPUs busy meanwhile: compile_in_parallel)
    CompilePart("convex", _CONVEX_MODULES + _CONTACT_MODULES,
                ("cgp_core.collision.convex_phase:convex_phase", "cgp_core.collision.convex_phase:sweep_times"),
                steps_flocks=False, default_scene=False, after=("contacts",), cpu_s=54.0),
    # issue 35's robots: the recursive algorithms and the joint solver (~15 s on an idle core); rotation's small
    # kernels too, which the floating root's integration calls (without them the worker's kernels failed to type:
    # a compiled kernel cannot call rotation's plain-Python functions); and the contact solver's and bodies', which
    # the one loop of robot rows and body rows calls (robots.coupled.step_coupled) — after "solver", so that its
    # kernels not inlined into step_coupled load from the cache instead of being compiled twice
    CompilePart("robots", ("cgp_core.robots", "cgp_core.rotation", "cgp_core.solver", "cgp_core.bodies"),
                ("cgp_core.robots.algorithms:mass_matrix", "cgp_core.robots.joint_solver:step_joints",
                 "cgp_core.robots.joint_solver:step_lone_robots", "cgp_core.robots.coupled:step_coupled",
                 "cgp_core.robots.joint_integrators:smooth_steps"),
                steps_flocks=False, default_scene=False, after=("solver",), cpu_s=55.0),  # (+~12 s: robots.coupled)
)


def is_cached(kernel) -> bool:
    """Whether numba's on-disk cache holds a compiled version of ``kernel`` for its current source (of a
    :class:`~cgp_core.jit.ParallelKernel`: of its serial twin, which small flocks such as the default scene's
    run).  ``True`` for a plain function (the JIT is off: nothing to compile) and when numba's cache cannot be
    inspected (a numba whose internals differ: the kernels then compile on first use, as without this module)."""
    from .jit import ParallelKernel

    if isinstance(kernel, ParallelKernel):
        kernel = kernel.serial
    try:
        return bool(kernel._cache._cache_file._load_index())
    except AttributeError:
        return True


def missing_parts(parts: tuple[CompilePart, ...] = PARTS, *, complete: bool = True) -> list[CompilePart]:
    """The parts whose kernels are not in the cache (none when the JIT is disabled); ``complete``: those of the
    complete scenario (:attr:`CompilePart.complete_sentinels`), else the default scene's only."""
    from .jit import JIT_DISABLED

    if JIT_DISABLED:
        return []
    missing = []
    for part in parts:
        for sentinel in part.sentinels + (part.complete_sentinels if complete else ()):
            module, name = sentinel.split(":")
            if not is_cached(getattr(importlib.import_module(module), name)):
                missing.append(part)
                break
    return missing


@contextmanager
def _sigint_deferred():
    """A SIGINT (Ctrl-C) that arrives inside the block is held back and delivered, to the handler there was
    before, when the block ends.  Only the main thread can set a signal handler; elsewhere nothing is held back
    (and a process-directed signal could not be deferred by blocking it in one thread: any other thread of the
    process — numba's, DDS's — would take it)."""
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is None:
        yield  # (None: a handler not set from Python, which could not be put back)
        return
    arrived = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: arrived.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if arrived:
            signal.raise_signal(signal.SIGINT)


def worker_slots() -> int:
    """How many compile workers run at once when some wait for others: one more than the CPUs this process may use
    (a worker's imports and its plain-Python scenario steps leave its CPU part idle; and a third worker keeps both
    CPUs busy while the last one runs).  Measured on 2 CPUs, every kernel cold, three pairs alternated (2026-12-07
    19:56-20:10 UTC, probe python 10.7-11.7 ms): 3 slots 127.6 / 126.1 / 135.6 s against 2 slots 130.7 / 135.6 /
    144.3 s (issue 34; when one slot per CPU was chosen the parts were smaller and the convex part the longest)."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return cpus + 1


def _chain_s(part: CompilePart, parts: list[CompilePart]) -> float:
    """The compile CPU seconds from ``part``'s start to the end of the longest chain of parts that wait for it."""
    return part.cpu_s + max((_chain_s(p, parts) for p in parts if part.name in p.after), default=0.0)


def compile_in_parallel(parts: list[CompilePart], worker_module: str, *worker_args: str) -> dict[str, str]:
    """Run one worker process per part, ``python -P -m <worker_module> --part <name> <worker_args>`` with
    ``CGP_SIM_JIT_ONLY`` set to the part's modules; wait for them.  The workers import the same packages as this
    process (its package root first on ``PYTHONPATH``), so they write the cache this process reads.  Returns
    ``{part name: the worker's output}`` for each worker that failed (the kernels it should have compiled then
    compile on first use).

    Order: a part starts once the parts it comes :attr:`~CompilePart.after`, among those given, have finished.
    When none waits for another, every worker starts at once (they share the CPUs and end about together).  When
    some do, at most :func:`worker_slots` run at a time (one more than the CPUs), the longest chain of waiting
    parts first (by :attr:`~CompilePart.cpu_s`): every worker at once would slow the chains' heads — the contacts
    and solver parts, which the convex and robots parts wait for — and with them the end of the whole compile
    (issue 34)."""
    root = str(Path(__file__).resolve().parents[1])  # the directory cgp_core (and cgp_sim_ros) was imported from
    python_path = os.pathsep.join([root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])
    names = {part.name for part in parts}
    chains = any(a in names for part in parts for a in part.after)
    slots = worker_slots() if chains else len(parts)
    waiting = sorted(parts, key=lambda part: -_chain_s(part, parts))  # (stable: the given order on a tie)
    workers, readers, outputs, failed = {}, {}, {}, {}

    def start_ready() -> None:
        # A Ctrl-C between a worker's start and its entry in `workers` would leave that worker out of the
        # clean-up below, compiling on after the caller exits: SIGINT waits until every worker is entered.
        with _sigint_deferred():
            for part in [p for p in waiting if all(a not in names or a in outputs for a in p.after)]:
                if len(workers) - len(outputs) >= slots:
                    break
                waiting.remove(part)
                env = dict(os.environ, PYTHONPATH=python_path, CGP_SIM_JIT_ONLY=",".join(part.modules))
                worker = workers[part.name] = subprocess.Popen(
                    [sys.executable, "-P", "-m", worker_module, "--part", part.name, *worker_args], env=env,
                    stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
                # each worker's output read on a thread of its own: a worker must not block on a full pipe
                readers[part.name] = threading.Thread(
                    target=lambda name=part.name, worker=worker: outputs.__setitem__(name, worker.communicate()[0]),
                    daemon=True)
                readers[part.name].start()

    try:
        start_ready()
        while any(reader.is_alive() for reader in readers.values()):
            for reader in readers.values():
                reader.join(timeout=0.1)
            start_ready()
        if waiting:
            raise RuntimeError(f"compile parts wait for each other: {', '.join(p.name for p in waiting)}")
        for name, worker in workers.items():
            if worker.wait() != 0:
                failed[name] = outputs.get(name, "")
    finally:  # interrupted (Ctrl-C): no worker outlives the caller
        for worker in workers.values():
            if worker.poll() is None:
                worker.kill()
                worker.wait()
    return failed


def compile_missing(parts: tuple[CompilePart, ...], worker_module: str, log, *, default_scene: bool = False) -> None:
    """Compile, in parallel worker processes (:func:`compile_in_parallel`), the parts whose kernels are not
    cached yet; ``log(text)`` says what happens (nothing when every part is cached).  ``default_scene``: only the
    default scene's parts and kernels (the workers' ``--default-scene``; a part counts as cached by its
    :attr:`~CompilePart.sentinels` alone), else every kernel of ``parts`` (its
    :attr:`~CompilePart.complete_sentinels` too)."""
    if default_scene:
        parts = tuple(p for p in parts if p.default_scene)
    missing = missing_parts(parts, complete=not default_scene)
    if not missing:
        return
    started = time.perf_counter()
    log(f"compiling the simulation kernels ({', '.join(p.name for p in missing)}: no compile cache for them yet, "
        f"as at the first start after an install or an edit) in {len(missing)} processes …")
    # (the workers get --default-scene too: without it they compiled every kernel but the convex part's)
    failed = compile_in_parallel(missing, worker_module, *(["--default-scene"] if default_scene else []))
    for name, output in failed.items():
        tail = "\n".join(output.strip().splitlines()[-20:])
        log(f"the {name} compile worker failed (its kernels compile at first use instead):\n{tail}")
    log(f"kernels compiled in {time.perf_counter() - started:.1f} s")


def main(argv: list[str], *, name: str, parts: tuple[CompilePart, ...], worker_module: str, scenario) -> int:
    """The warm-up command, ``python -m <worker_module>``: compile the missing parts in parallel, then run
    ``scenario()`` (every kernel: it loads what the workers compiled and compiles anything they did not).
    With ``--part`` it is one of those workers: it runs ``scenario(complete=..., flocks=...)`` with only the
    part's modules compiled (``CGP_SIM_JIT_ONLY``, set by :func:`compile_in_parallel`)."""
    import argparse

    from .jit import JIT_ONLY, refuse_unparallelized_kernels

    refuse_unparallelized_kernels()
    parser = argparse.ArgumentParser(prog=f"python -m {worker_module}", description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=[p.name for p in parts],
                        help="run as the compile worker of this part (set by compile_in_parallel)")
    parser.add_argument("--default-scene", action="store_true",
                        help="only the kernels the default scene runs (not issue 14's flock rules, not the "
                             "parallel twins for big flocks)")
    args = parser.parse_args(argv)
    if args.part:
        if not JIT_ONLY:
            parser.error("CGP_SIM_JIT_ONLY is not set (workers are started by compile_in_parallel)")
        part = next(p for p in parts if p.name == args.part)
        scenario(complete=not args.default_scene, flocks=part.steps_flocks)
        return 0
    started = time.perf_counter()
    compile_missing(parts, worker_module, lambda text: print(f"{name}: {text}", file=sys.stderr, flush=True),
                    default_scene=args.default_scene)
    scenario(complete=not args.default_scene)
    print(f"{name}: simulation kernels compiled and cached ({time.perf_counter() - started:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:], name="cgp_core.warmup", parts=PARTS, worker_module="cgp_core.warmup",
                  scenario=warm_up))

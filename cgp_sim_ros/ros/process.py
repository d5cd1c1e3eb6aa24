"""What the node does to its process so that the tick keeps its budget — none of it changes a result.

Called by :class:`~cgp_sim_ros.ros.node.SimNode` once its world and endpoints exist (:func:`load_kernels`,
:func:`freeze_startup_objects`, :func:`share_the_gil_finely`), and while it runs (:class:`ThreadPinning`,
the parameter ``pin_threads``).  Why each, and what it measured, is in its docstring; ARCHITECTURE.md ("What
runs where") has the threads and cores.
"""

from __future__ import annotations

import copy
import gc
import sys
import threading
from collections.abc import Callable
from concurrent.futures import Future, InvalidStateError
from types import SimpleNamespace

import numpy as np

from cgp_core.bodies import Shape
from cgp_core.jit import JIT_DISABLED, ThreadPlacement, runs_on_pool

#: how long a thread that wants the GIL waits before the holder must let go [s] (Python's default: 5 ms)
GIL_SWITCH_INTERVAL_S = 0.001


def load_kernels(world, build_tick: Callable, log_debug: Callable[[str], None]) -> None:
    """Have the compiled kernels the first tick runs loaded before it.  numba loads a kernel from its
    on-disk cache at the kernel's first call, ~9 ms each: the default scene's first tick took ~170 ms
    (24 kernels), ten 60 Hz periods of a real-time run lost at its start.  A throwaway copy of ``world``
    takes one tick here and ``build_tick(copy)`` builds its messages (every marker part), which are dropped:
    nothing is published, the world itself is untouched.  Whatever fails here fails again, and is reported,
    in the real tick (here it goes to ``log_debug``).

    That tick runs the kernels of the scene's first instant only: the contact kernels of shapes that touch
    later were loaded when they first touched — the default scene's ball lands 0.7 s in, and that tick
    took ~16 ms (the penetration recovery's kernel loading).  So the core's warm-up scenario (its own
    world: bodies of every shape placed in contact, no flock) takes two ticks here too, one with the contact
    report and one without (the solver's two entry points): every rigid-body kernel is loaded before the first
    tick, also for bodies spawned later (~0.1 s more start-up); and for a world big enough to take the solver's
    path for big worlds, that path and numba's thread pool (:func:`cgp_core.warmup.load_kernels_for`).

    With the JIT off (``NUMBA_DISABLE_JIT=1``, the debugging mode) there is nothing to load, and the throwaway
    tick would be one more plain-Python tick before the first: skipped (a 40,000-particle world's start-up took
    that tick's seconds for nothing)."""
    if JIT_DISABLED:
        return
    from cgp_core.warmup import load_kernels_for

    from ..drawing.bodies import model_shapes

    # the hulls and meshes (static data) stay shared with the node's world: their drawings are made already
    world = copy.deepcopy(world, {id(shape): shape for _, shape in model_shapes(world.body_model)})
    try:
        load_kernels_for(world)
        world.step()
        build_tick(world)
    except Exception as exc:  # noqa: BLE001 - the real first tick reports it
        log_debug(f"loading the kernels before the first tick: {exc!r}")


def build_world(world, scene, build_tick: Callable) -> Future:
    """``load_world``'s new world, built on a helper thread while the node ticks (issue 36): a future of
    ``world.prepare_load(scene)`` (:meth:`cgp_core.world.World.prepare_load`; or the
    :class:`~cgp_core.scene.SceneError` it raised), after a throwaway copy of it took two ticks there — one with
    the contact report, one without, ``build_tick(copy)`` building its messages after each — so that the kernels
    its first ticks run (a flock's, where the old world had none: a 183 ms first tick when it loaded them
    itself) are loaded before it replaces the old one, as :func:`load_kernels` does at start-up.  The copy's
    Python takes turns with the tick's on the GIL (1 ms switch interval); the loading is mostly in llvmlite's C
    calls, which release it."""
    from ..drawing.bodies import model_shapes

    future: Future = Future()

    def run() -> None:
        from cgp_core.scene import SceneError

        try:
            new = world.prepare_load(scene)
        except SceneError as exc:
            future.set_result(exc)
            return
        except Exception as exc:  # noqa: BLE001 - answered as the load's failure, not a dead thread
            future.set_result(exc)
            return
        try:
            throwaway = copy.deepcopy(new, {id(shape): shape for _, shape in model_shapes(new.body_model)})
            for report in (True, False):
                throwaway.report_contacts = report
                throwaway.step()
                build_tick(throwaway)  # (with and without the contacts)
            for flock in throwaway.flocks:
                flock.order()
        except Exception:  # noqa: BLE001 - the real first tick loads (and reports) whatever failed here
            pass
        future.set_result(new)

    threading.Thread(target=run, name="cgp-sim-world", daemon=True).start()
    return future


def freeze_startup_objects() -> None:
    """Everything built so far — the imported modules (rclpy, numpy, scipy, numba and its compiled kernels),
    the scene, the world — lives as long as the node: move it out of the cyclic garbage collector's sight
    (``gc.freeze``).  Python's full collections, which it runs now and then between ticks, then scan only
    what the ticks create: about a millisecond instead of the ~200 ms pause measured at 15k fish, which
    alone would break the tick's 16.7 ms."""
    gc.collect()
    gc.freeze()


def share_the_gil_finely() -> None:
    """The tick releases the GIL in every compiled kernel (``nogil``), and the bag writer's thread takes it
    for its Python (MCAP framing, chunk buffers).  When a kernel returns while the writer is busy, the
    tick waits for the GIL until the writer blocks or the switch interval forces a hand-over — up to 5 ms
    by Python's default, a third of a 60 Hz tick, on any of the ~15 kernel calls of a flock step.  At 1 ms
    the wait is bounded by 1 ms; both threads still get their share (measured on the 15k-fish tick, three
    alternating runs each: p99 14.6-21.8 ms against 18.3-28.7 ms at 5 ms — an indication: this machine's
    speed varied between the runs almost as much)."""
    sys.setswitchinterval(min(sys.getswitchinterval(), GIL_SWITCH_INTERVAL_S))


class ThreadPinning:
    """The tick's thread on a CPU of its own, every other thread on the others (``cgp_core.jit.ThreadPlacement``:
    why, and what it measured), while ``pin_threads`` is on and a flock runs on numba's thread pool; else every
    thread on every CPU.  :meth:`update` is called by the node at start-up and every REPORT_PERIOD_S from the
    tick (threads started since are moved too; a flock spawned or deleted changes the answer); each change of
    the answer is logged (``log_info``).  Made on the thread that ticks: that is the one it pins."""

    def __init__(self, log_info: Callable[[str], None]):
        self.placement = ThreadPlacement()
        #: the last placement logged (None: nothing said yet)
        self.said: str | None = None
        self._log = log_info

    def update(self, flocks, pin_threads: bool) -> None:
        on_pool = any(runs_on_pool(f.count) for f in flocks)
        placement = self.placement
        if on_pool and pin_threads and placement.place():
            others = placement.others
            said = (f"threads: the tick on CPU {placement.cpu} alone; numba's pool workers, the bag writer and DDS "
                    f"on CPU{'s' if len(others) > 1 else ''} {', '.join(map(str, others))} (pin_threads; a flock runs "
                    "on numba's pool)")
        else:
            placement.release()
            if not on_pool:  # said only after a placement: a small flock's node has nothing to say about it
                said = "threads: not pinned (no flock runs on numba's pool now)" if self.said else None
            elif not pin_threads:
                said = "threads: not pinned (pin_threads false)"
            else:
                said = f"threads: not pinned ({placement.unavailable})"
        if said is not None and said != self.said:
            self._log(said)
            self.said = said

    def release(self) -> None:
        """Every thread on every CPU again (the node is going away)."""
        self.placement.release()


#: the shapes whose kernels (issue 25's convex stage, the BVH queries, the flock's hull and mesh obstacle queries)
#: the node does not load at start-up unless its scene has them
_CONVEX_SHAPES = (int(Shape.CONVEX), int(Shape.COMPOUND), int(Shape.MESH))


def _done() -> Future:
    future = Future()
    future.set_result(None)
    return future


def _all_of(futures: list) -> Future | None:
    """None for no future, the one future, or a future done when all of them are."""
    if not futures:
        return None
    if len(futures) == 1:
        return futures[0]
    joined = Future()

    def done(_):
        if all(f.done() for f in futures):
            try:
                joined.set_result(None)
            except InvalidStateError:  # the other helper thread's callback set it first
                pass
    for f in futures:
        f.add_done_callback(done)
    return joined


class ConvexKernels:
    """Issue 25's kernels (hulls, compound parts, static meshes), loaded from numba's cache *before* the first
    such body is added, off the tick's thread.  :func:`load_kernels` loads at start-up only what the scene's
    first ticks run, and a spawned hull or mesh then made the first tick with it load them: ~120 ms of that tick
    (issue 38, a 80k-triangle mesh: the slowest second at 51 Hz).  Now the spawn waits (its reply ~1 s later,
    once per node) while a helper thread steps :func:`cgp_core.warmup.warm_up_convex`'s own small world; the
    tick goes on (the loading is mostly in llvmlite's C calls, which release the GIL)."""

    def __init__(self, world):
        model = world.body_model
        self._future: Future | None = None
        if any(int(k) in _CONVEX_SHAPES for k in model.shape):  # the scene's first ticks load them
            self._future = _done()
        #: issue 36: the robots' kernels (kinematics, CRBA, RNEA, the joint solver) likewise before the first
        #: robot is spawned into a world that had none (a 0.36 s tick when its first tick loaded them)
        robots = getattr(world, "robots", None)
        self._robots_future: Future | None = _done() if robots is not None else None
        #: the loop that solves a robot and the bodies its links touch (robots.coupled.step_coupled): loaded at
        #: start-up for a world with a robot and free bodies (cgp_core.warmup.load_kernels_for), with the robots'
        #: kernels for a robot spawned, else before the first free body joins a robot world (the arm's first
        #: sub-step with a link on a box took 110-240 ms loading it)
        from cgp_core.warmup import runs_robot_and_body_loop

        self._coupled_future: Future | None = _done() if runs_robot_and_body_loop(world) else None

    def before_adding(self, prepared, world=None) -> Future | None:
        """A future to wait for before ``prepared`` (a :class:`cgp_core.world.PreparedSpawn`) is added to
        ``world`` (the node's current world), or None when nothing needs loading."""
        kind = getattr(prepared, "kind", None)
        model = getattr(prepared, "model", None)
        pending = []
        if kind == "robot":
            if self._robots_future is None:
                self._robots_future = self._start("warm_up_robots")
            if self._coupled_future is None:  # warm_up_robots steps a robot with a crate on its arm too
                self._coupled_future = self._robots_future
            pending.append(self._robots_future)
        if model is not None and any(int(k) in _CONVEX_SHAPES for k in model.shape):
            pending.append(self._convex())
        if (kind == "body" and world is not None and getattr(world, "robots", None) is not None
                and bool(np.any(np.asarray(model.inv_mass) > 0.0))):
            if self._coupled_future is None:
                self._coupled_future = self._start("warm_up_robot_contacts", ticks=2)
            pending.append(self._coupled_future)
        return _all_of([f for f in pending if not f.done()])

    def before_loading(self, loaded) -> Future | None:
        """:meth:`before_adding` for a whole scene about to be loaded (a :class:`cgp_sim_ros.worlds.LoadedScene`):
        its robots' and its hulls' and meshes' kernels."""
        scene = loaded.scene
        kind = "robot" if scene.robots or scene.articulations else "scene"
        return self.before_adding(SimpleNamespace(kind=kind, model=SimpleNamespace(shape=loaded.shapes)))

    def _convex(self) -> Future:
        if self._future is None:
            self._future = self._start("warm_up_convex")
        return self._future

    @staticmethod
    def _start(warm_up: str, **kwargs) -> Future:
        """``cgp_core.warmup.<warm_up>(**kwargs)`` on a helper thread: a future done when it has returned.  A
        failure there is dropped: the first tick that runs those kernels loads (and reports) whatever failed."""
        future = Future()

        def run() -> None:
            from cgp_core import warmup

            try:
                getattr(warmup, warm_up)(**kwargs)
            except Exception:  # noqa: BLE001 - see the docstring
                pass
            future.set_result(None)

        threading.Thread(target=run, name="cgp-sim-kernels", daemon=True).start()
        return future

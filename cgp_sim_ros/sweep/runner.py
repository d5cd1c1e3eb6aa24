"""What a worker runs: one task (a single run, or a chain of runs) → the measured tables.

:func:`run_task` takes the plain data of :meth:`cgp_sim_ros.sweep.spec.Task.payload` and steps, per run, a
:class:`cgp_core.world.World` built from the run's resolved scene — ``World.step()``, exactly what the node's
tick steps, headless.  Per run it measures:

- every ``record.every`` ticks (and once before the first tick): each flock's order parameters
  (:meth:`cgp_core.boids.Flock.order`, what the node publishes on ``~/flocks/<flock>/stats``) and each body's
  pose and twist — columns of the ``flocks`` / ``bodies`` tables;
- the summary (``runs`` table, a row per flock): p and m, R_g and the mean nearest-neighbour distance averaged
  over *every* tick of the last ``window_ticks`` (whatever the sampling), p and m at the end, and how many
  groups the flock is in at the end (boids closer than the flock's interaction radius linked: 1 = one
  cohesive group).

A chain's links run one after the other in this process: each link is a new ``World`` of its own scene, and
the previous link's final state is put into it (:func:`carry_state`).  A run fails — and is reported with its
error, the sweep going on — when its scene is refused, when anything raises, or when the world reports a
numerical blow-up (``World`` resets the body or flock and goes on, which would make the rest of the run
meaningless); a chain's later links then fail with "the chain stopped".  Failures of the machinery itself (a
worker lost, a version mismatch) are not caught here: they are the engine's to retry or report.
"""

from __future__ import annotations

import copy
import gc
import os
import socket
import time
import traceback
from pathlib import Path

import numpy as np
import pyarrow as pa

from cgp_core.boids.order import classify
from cgp_core.scene import scene_from_dict
from cgp_core.world import World

#: the columns of the flocks table a sample fills, in order (FlockOrder's fields; centroid split)
FLOCK_COLUMNS = ("count", "polarization", "milling", "centroid_x", "centroid_y", "centroid_z", "radius_of_gyration",
                 "mean_nearest_neighbor_distance", "mean_speed", "min_speed", "max_speed")
BODY_COLUMNS = ("x", "y", "z", "qx", "qy", "qz", "qw", "vx", "vy", "vz", "wx", "wy", "wz")


class VersionMismatch(RuntimeError):
    """This worker runs other code than the client planned the sweep with (its identities would lie)."""


class RunFailed(RuntimeError):
    """A run that cannot go on (a blow-up the world reported, a chain whose state cannot be carried)."""


def worker_version() -> dict:
    """What ``client.run`` asks every worker before a sweep: its code version, host and process."""
    from .spec import code_version

    return {"code_version": code_version(), "host": socket.gethostname(), "pid": os.getpid()}


def prepare_worker() -> None:
    """Before a sweep, on every worker (``client.run``): collect, then freeze what the worker holds (Dask's own
    objects, the imported modules) into the collector's permanent generation, so that the full collections the
    runs' allocations trigger do not traverse them again and again (part of the overhead ``engine.QUIET_WORKERS``
    describes).  What a run allocates later is collected as usual."""
    gc.collect()
    gc.freeze()


def run_task(payload: dict) -> dict:
    """Run every run of a task; returns ``{"task", "worker", "results": [per run: {"id", "status", "error",
    "wall_s", "summary": [rows], "flocks": pa.Table | None, "bodies": pa.Table | None}]}``.  With
    ``payload["write_to"]`` (a directory every worker sees) the fragments are written here and the tables left
    out of the result."""
    from .spec import code_version

    mine = code_version()
    if payload["code_version"] != mine:
        raise VersionMismatch(f"worker {socket.gethostname()} (pid {os.getpid()}) runs cgp_sim {mine}, the sweep "
                              f"was planned with {payload['code_version']}")
    worker = f"{socket.gethostname()}:{os.getpid()}"
    results = []
    world = None
    stopped = None
    for position, run in enumerate(payload["runs"]):
        started = time.perf_counter()
        if stopped is not None:
            results.append(_failed(run["id"], f"the chain stopped at link {stopped[0]}: {stopped[1]}", 0.0))
            continue
        try:
            world, result = _run(payload, run, world, position)
        except Exception as exc:  # noqa: BLE001 - every error of a run is its result (the sweep goes on)
            message = _message(exc)
            results.append(_failed(run["id"], message, time.perf_counter() - started))
            stopped = (position, message.splitlines()[0])
            continue
        result.update(id=run["id"], status="done", error=None, wall_s=time.perf_counter() - started)
        results.append(result)
    out = {"task": payload["task"], "worker": worker, "results": results}
    if payload.get("write_to"):
        from .store import write_fragments

        write_fragments(Path(payload["write_to"]), results, worker)
        for result in results:
            result["flocks"] = result["bodies"] = None
            result["written"] = True
    return out


def _message(exc: BaseException) -> str:
    """An error as a run's row shows it: the message (a scene error's ``file: key: reason`` lines) and, for
    anything not raised on purpose, where it came from."""
    from cgp_core.scene import SceneError

    if isinstance(exc, (SceneError, RunFailed)):
        return str(exc)
    where = traceback.extract_tb(exc.__traceback__)[-1]
    return f"{type(exc).__name__}: {exc} (at {Path(where.filename).name}:{where.lineno})"


def _failed(run_id: str, message: str, wall_s: float) -> dict:
    return {"id": run_id, "status": "failed", "error": message, "wall_s": wall_s, "summary": [], "flocks": None,
            "bodies": None}


def _run(payload: dict, run: dict, previous: World | None, link: int) -> tuple[World, dict]:
    """One run: build its world (carrying ``previous``'s state along a chain), step it, measure; returns the
    world at the end (the next link's start) and the run's result (summary rows, tables)."""
    scene = scene_from_dict(copy.deepcopy(run["scene"]), run["source"])
    world = World(scene, dt=payload["dt"], seed=payload["seed"])
    if previous is not None:
        carry_state(previous, world, link)
    ticks, window, every = payload["ticks"], payload["window_ticks"], payload["record"]["every"]
    record = payload["record"]
    flock_rows: list[list] = []  # per sample and flock: tick, time, flock, FLOCK_COLUMNS
    body_rows: list[np.ndarray] = []  # per sample: (n_bodies, 13)
    body_ticks: list[tuple[int, float]] = []
    averaged = {f.params.name: [] for f in world.flocks}  # per flock: (p, m, R_g, nnd) of every window tick
    bag = _Bag(payload, run, world) if record["bag"] else None
    start_tick = world.ticks

    def sample(tick: int, orders) -> None:
        if record["flocks"]:
            for flock, order in zip(world.flocks, orders):
                flock_rows.append([tick, world.time, flock.params.name, order.count, order.polarization,
                                   order.milling, *order.centroid, order.radius_of_gyration,
                                   order.mean_nearest_neighbor_distance, order.mean_speed, order.min_speed,
                                   order.max_speed])
        if record["bodies"] and world.body_model.count:
            state = world.body_state
            body_rows.append(np.hstack([state.position, state.orientation, state.linear_velocity(world.body_model),
                                        state.angular_velocity(world.body_model)]))
            body_ticks.append((tick, world.time))
        if bag is not None:
            bag.write(world, orders)

    sample(0, [f.order() for f in world.flocks] if (record["flocks"] or bag) else [])
    for step in range(ticks):
        world.step()
        errors = [e.text for e in world.take_events() if e.level == "error"]
        if errors:
            raise RunFailed(f"at t = {(world.ticks - start_tick) * world.dt:.6g} s of the run: {errors[0]}")
        tick = step + 1
        in_window = step >= ticks - window
        due = tick % every == 0 or tick == ticks
        orders = [f.order() for f in world.flocks] if in_window or (due and (record["flocks"] or bag)) else []
        if in_window:
            for flock, order in zip(world.flocks, orders):
                averaged[flock.params.name].append((order.polarization, order.milling, order.radius_of_gyration,
                                                    order.mean_nearest_neighbor_distance))
        if due:
            sample(tick, orders)
    if bag is not None:
        bag.close()
    summary = []
    for flock in world.flocks:
        values = averaged[flock.params.name]
        # means as the earlier figure script took them (np.mean of each column of the window's ticks)
        p, m, rg, nnd = (float(np.mean([v[i] for v in values])) for i in range(4))
        summary.append({"flock": flock.params.name, "count": flock.count, "polarization": p, "milling": m,
                        "radius_of_gyration": rg, "mean_nearest_neighbor_distance": nnd,
                        "polarization_end": values[-1][0], "milling_end": values[-1][1],
                        "groups": groups(flock), "order_class": classify(p, m)})
    return world, {"summary": summary, "flocks": _flock_table(flock_rows) if record["flocks"] else None,
                   "bodies": _body_table(world, body_ticks, body_rows) if record["bodies"] else None}


def carry_state(old: World, new: World, link: int) -> None:
    """Put ``old``'s final state into ``new`` (the next link of a chain, a world of the next scene): the clock,
    every body's pose and velocities (momenta recomputed with the new link's masses and inertias: a chain over a
    mass keeps the motion) and every flock's boids — positions, velocities, frames — and its noise generator,
    so a Couzin flock's random stream goes on as if the flock had never stopped.  The contact solver's
    warm-start impulses are not carried (they are a cache: the first sub-step of a link starts cold).
    :class:`RunFailed` when the entities differ (a chain along a key that adds, removes or resizes one)."""
    names = (list(old.body_model.names), [(f.params.name, f.count) for f in old.flocks])
    if names != (list(new.body_model.names), [(f.params.name, f.count) for f in new.flocks]):
        raise RunFailed(f"chain link {link}: its bodies and flocks {names_of(new)} differ from the previous "
                        f"link's {names_of(old)}: a chain carries the state of the same entities")
    new.time_ns, new.ticks = old.time_ns, old.ticks
    if old.body_model.count:
        model, state = new.body_model, new.body_state
        velocity = old.body_state.linear_velocity(old.body_model)
        spin = old.body_state.angular_velocity(old.body_model)
        for name in ("position", "orientation"):
            getattr(state, name)[:] = getattr(old.body_state, name)
        if state.rotation is not None:
            state.rotation[:] = state.rotation_matrices()
        movable = (~model.fixed)[:, None]
        state.linear_momentum[:] = model.mass[:, None] * velocity * movable
        from cgp_core.rotation import quat_to_matrix

        R = quat_to_matrix(state.orientation)
        inertia_world = R @ model.inertia_body @ np.swapaxes(R, -1, -2)
        state.angular_momentum[:] = np.einsum("nij,nj->ni", inertia_world, spin) * movable
        new.wake()
    for before, after in zip(old.flocks, new.flocks):
        for name in ("positions", "velocities", "headings", "dorsals", "orientations"):
            getattr(after, name)[:] = getattr(before, name)
        after.time, after.steps = before.time, before.steps
        after.noise_generator = copy.deepcopy(before.noise_generator)
    new.remember_tick_start()  # the last tick's accelerations start from the carried state


def names_of(world: World) -> str:
    return "[" + ", ".join([*world.body_model.names, *(f"{f.params.name} ({f.count})" for f in world.flocks)]) + "]"


def groups(flock) -> int:
    """How many groups the boids form when every two closer than the flock's interaction radius (``radius``; a
    Couzin flock's perception radius) are linked: 1 = one cohesive group."""
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    x = flock.positions
    tree = cKDTree(x)
    graph = tree.sparse_distance_matrix(tree, flock.params.radius, output_type="coo_matrix")
    return int(connected_components(graph, directed=False)[0])


def _flock_table(rows: list[list]) -> pa.Table:
    columns = list(zip(*rows)) if rows else [[] for _ in range(3 + len(FLOCK_COLUMNS))]
    arrays = [pa.array(columns[0], pa.int64()), pa.array(columns[1], pa.float64()), pa.array(columns[2], pa.string()),
              pa.array(columns[3], pa.int64())]
    arrays += [pa.array(np.asarray(c, dtype=np.float64)) for c in columns[4:]]
    return pa.Table.from_arrays(arrays, names=["tick", "time", "flock", *FLOCK_COLUMNS])


def _body_table(world: World, ticks: list[tuple[int, float]], rows: list[np.ndarray]) -> pa.Table:
    n = world.body_model.count
    values = np.concatenate(rows) if rows else np.zeros((0, len(BODY_COLUMNS)))
    arrays = [pa.array(np.repeat([t for t, _ in ticks], n).astype(np.int64)),
              pa.array(np.repeat([s for _, s in ticks], n).astype(np.float64)),
              pa.array(list(world.body_model.names) * len(ticks), pa.string())]
    arrays += [pa.array(values[:, i]) for i in range(len(BODY_COLUMNS))]
    return pa.Table.from_arrays(arrays, names=["tick", "time", "body", *BODY_COLUMNS])


class _Bag:
    """``record.bag``: the run's samples as a rosbag2 MCAP (``<out>/bags/<run id>/``), the node's topic names
    under ``/cgp_sim``: ``/clock``, ``~/bodies/poses``, ``~/flocks/<flock>/poses`` and ``~/flocks/<flock>/stats``,
    one message each per sample.  Written with the node's own bag writer and CDR serializers (no ROS needed)."""

    def __init__(self, payload: dict, run: dict, world: World):
        from cgp_sim_ros.wire import cdr
        from cgp_sim_ros.wire.bag import BagWriter

        if not payload.get("bag_dir"):
            raise RunFailed("record.bag needs an output directory for the bags (the engine sets it)")
        self.cdr = cdr
        self.writer = BagWriter(Path(payload["bag_dir"]) / run["id"])
        self.writer.add_topic("/clock", "rosgraph_msgs/msg/Clock")
        if world.body_model.count:
            self.writer.add_topic("/cgp_sim/bodies/poses", "geometry_msgs/msg/PoseArray")
        self.stats = {}
        for flock in world.flocks:
            name = flock.params.name
            self.writer.add_topic(f"/cgp_sim/flocks/{name}/poses", "geometry_msgs/msg/PoseArray")
            self.writer.add_topic(f"/cgp_sim/flocks/{name}/stats", "cgp_sim_msgs/msg/FlockStats")
            self.stats[name] = cdr.FlockStatsSerializer("world")

    def write(self, world: World, orders) -> None:
        stamp, cdr = world.time_ns, self.cdr
        self.writer.write("/clock", cdr.clock(stamp), stamp, stamp)
        if world.body_model.count:
            self.writer.write("/cgp_sim/bodies/poses", cdr.pose_array(stamp, "world", world.body_state.position,
                                                                      world.body_state.orientation), stamp, stamp)
        for flock, order in zip(world.flocks, orders):
            name = flock.params.name
            self.writer.write(f"/cgp_sim/flocks/{name}/poses",
                              cdr.pose_array(stamp, "world", flock.positions, flock.orientations), stamp, stamp)
            values = [order.polarization, order.milling, *order.centroid, order.radius_of_gyration,
                      order.mean_nearest_neighbor_distance, order.mean_speed, order.min_speed, order.max_speed]
            self.writer.write(f"/cgp_sim/flocks/{name}/stats", self.stats[name].serialize(stamp, order.count, values),
                              stamp, stamp)

    def close(self) -> None:
        self.writer.close()
        if self.writer.error:
            raise RunFailed(f"the run's bag: {self.writer.error}")

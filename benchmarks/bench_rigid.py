"""Rigid bodies alone (issue 12): the default scene's 5 bodies vs MuJoCo and PyBullet, a 200-body pile vs
PyBullet, and the compiled kernels' start-up cost.

1. **Default scene's bodies** (ball, crate, capsule, the 4-sphere particle body, the fixed pillar, the ground):
   ``World.step`` with the flock removed and ``sleep: false`` (so the bodies keep being solved after they come to
   rest, the worst case), one 1/60 s tick = 4 sub-steps of 1/240 s, from the drop through landing, rolling and
   settling (the first 18 s).  The same bodies built in MuJoCo (MJCF: sphere, box, capsule, a body of 4 sphere
   geoms, a fixed box, a plane; timestep 1/240, 4 steps per tick) and in PyBullet (the same shapes, the particle
   body a compound of 4 spheres; 1/240 s, 4 ``stepSimulation`` per tick), all three stepped tick by tick in
   turn in this process, so they see the same machine.  Median and p99 per tick over the 18 s, and the median
   in the first 2.5 s (falling, landing) and from 7.5 s to 17 s (rolling, settling).
2. **A 200-body pile**: 50 spheres, 50 boxes, 50 capsules and 50 four-sphere particle bodies on a jittered
   lattice, randomly turned, dropped into a 3 × 3 m bin (4 fixed walls) on the ground; ``sleep: false``; the
   same pile in PyBullet, interleaved tick by tick.  Median and p99 per tick over the first 4 s (they fall,
   land and pile up), and the ratio cgp_sim / PyBullet of the medians.
3. **Start-up of the compiled kernels** (``cgp_core.jit``, numba ``cache=True``): a fresh process with an
   empty numba cache directory (``NUMBA_CACHE_DIR``) imports cgp_core and runs :func:`cgp_core.warmup.warm_up`
   with ``complete=False`` (the default scene's kernels, bodies and flock, placed so every contact kernel runs
   in the first ticks; compiled one after the other in this one process: the CPU time the cold start's
   compile workers share out); then the same again with the cache just written (warm: import + first tick).

    .venv/bin/python benchmarks/bench_rigid.py [--quick]
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from common import Results, format_stage_times, reset_stage_times, stage_times  # noqa: E402

from cgp_core import Shape, World, parse_scene  # noqa: E402
from cgp_core.rotation import quat_to_matrix  # noqa: E402
from cgp_core.warmup import warm_up  # noqa: E402

H = 1.0 / 240.0
SUBSTEPS = 4


# ---- the same bodies in the peers ------------------------------------------------------------------------

def _world_angular_velocity(world: World) -> np.ndarray:
    return world.body_state.angular_velocity(world.body_model)


def mujoco_model(world: World):
    """An MJCF model of the world's bodies (and its ground plane), and a data object at the world's state."""
    import mujoco

    model, state = world.body_model, world.body_state
    geoms, bodies = [], []
    if world.ground is not None:
        geoms.append(f'<geom type="plane" size="100 100 0.1" friction="{world.ground.friction} 0.005 0.0001"/>')
    for i in range(model.count):
        x, q = state.position[i], state.orientation[i]
        pose = f'pos="{x[0]} {x[1]} {x[2]}" quat="{q[3]} {q[0]} {q[1]} {q[2]}"'
        mat = f'friction="{model.friction[i]} 0.005 0.0001"'
        shape = int(model.shape[i])
        if shape == Shape.SPHERE:
            g = [f'<geom type="sphere" size="{model.radius[i]}" mass="{model.mass[i]}" {mat}/>']
        elif shape == Shape.BOX:
            hx, hy, hz = model.half_extents[i]
            g = [f'<geom type="box" size="{hx} {hy} {hz}" mass="{model.mass[i]}" {mat}/>']
        elif shape == Shape.CAPSULE:
            g = [f'<geom type="capsule" size="{model.radius[i]} {model.half_extents[i, 2]}" mass="{model.mass[i]}" '
                 f'{mat}/>']
        else:
            g = [f'<geom type="sphere" size="{model.radius[i]}" pos="{p[0]} {p[1]} {p[2]}" mass="{p[3]}" {mat}/>'
                 for p in model.particles[i]]
        if model.fixed[i]:
            geoms += [s.replace("<geom ", f"<geom {pose} ").replace(f' mass="{model.mass[i]}"', "") for s in g]
        else:
            bodies.append(f'<body name="b{i}" {pose}><freejoint/>{"".join(g)}</body>')
    xml = (f'<mujoco><option timestep="{H}" gravity="{" ".join(map(str, world.gravity))}"/>'
           f'<worldbody>{"".join(geoms)}{"".join(bodies)}</worldbody></mujoco>')
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    movable = np.flatnonzero(~model.fixed)
    v, w = state.linear_velocity(model), _world_angular_velocity(world)
    R = quat_to_matrix(state.orientation)
    for k, i in enumerate(movable):
        d.qvel[6 * k:6 * k + 3] = v[i]
        d.qvel[6 * k + 3:6 * k + 6] = R[i].T @ w[i]  # a free joint's angular velocity is in the body frame
    return m, d


def pybullet_world(world: World):
    """A PyBullet DIRECT client holding the world's bodies at its state (compound spheres for particle bodies)."""
    import pybullet as pb

    client = pb.connect(pb.DIRECT)
    pb.setGravity(*world.gravity, physicsClientId=client)
    pb.setTimeStep(H, physicsClientId=client)
    if world.ground is not None:
        plane = pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=client),
                                   physicsClientId=client)
        pb.changeDynamics(plane, -1, lateralFriction=world.ground.friction, restitution=world.ground.restitution,
                          physicsClientId=client)
    model, state = world.body_model, world.body_state
    v, w = state.linear_velocity(model), _world_angular_velocity(world)
    for i in range(model.count):
        shape = int(model.shape[i])
        if shape == Shape.SPHERE:
            col = pb.createCollisionShape(pb.GEOM_SPHERE, radius=model.radius[i], physicsClientId=client)
        elif shape == Shape.BOX:
            col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=model.half_extents[i].tolist(),
                                          physicsClientId=client)
        elif shape == Shape.CAPSULE:
            col = pb.createCollisionShape(pb.GEOM_CAPSULE, radius=model.radius[i],
                                          height=2 * model.half_extents[i, 2], physicsClientId=client)
        else:
            p = model.particles[i]
            col = pb.createCollisionShapeArray([pb.GEOM_SPHERE] * len(p), radii=[model.radius[i]] * len(p),
                                               collisionFramePositions=p[:, :3].tolist(), physicsClientId=client)
        mass = 0.0 if model.fixed[i] else float(model.mass[i])
        body = pb.createMultiBody(mass, col, basePosition=state.position[i].tolist(),
                                  baseOrientation=state.orientation[i].tolist(), physicsClientId=client)
        pb.changeDynamics(body, -1, lateralFriction=model.friction[i], restitution=model.restitution[i],
                          physicsClientId=client)
        if mass:
            pb.resetBaseVelocity(body, v[i].tolist(), w[i].tolist(), physicsClientId=client)
    return pb, client


# ---- 1. the default scene's bodies -------------------------------------------------------------------------

def default_bodies_world() -> World:
    world = World.from_scene("default")
    world.flocks = []
    world.sleep_enabled = False
    return world


def bench_default(seconds: float) -> dict:
    import mujoco

    warm_up()  # every kernel compiled / loaded before timing
    world = default_bodies_world()
    m, d = mujoco_model(world)
    pb, client = pybullet_world(world)
    ticks = int(round(seconds * 60))
    times = {"cgp_sim": np.empty(ticks), "mujoco": np.empty(ticks), "pybullet": np.empty(ticks)}
    clock = time.perf_counter
    reset_stage_times(world.solver)
    for k in range(ticks):
        t0 = clock()
        world.step()
        t1 = clock()
        for _ in range(SUBSTEPS):
            mujoco.mj_step(m, d)
        t2 = clock()
        for _ in range(SUBSTEPS):
            pb.stepSimulation(physicsClientId=client)
        t3 = clock()
        times["cgp_sim"][k], times["mujoco"][k], times["pybullet"][k] = t1 - t0, t2 - t1, t3 - t2
    pb.disconnect(client)
    out = {}
    for name, t in times.items():
        t = t * 1e3
        out[name] = {"median": float(np.median(t)), "p99": float(np.percentile(t, 99)), "max": float(t.max()),
                     "median_0_2.5s": float(np.median(t[:150])), "median_7.5_17s": float(np.median(t[450:1020]))}
    out["final_positions"] = world.body_state.position.tolist()
    out["stages_ms"] = stage_times(world.solver, ticks)  # mean ms per tick, stage by stage
    return out


# ---- 2. the 200-body pile ---------------------------------------------------------------------------------

def pile_scene(count: int = 200, seed: int = 7) -> str:
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(count / 8)))
    lines = ["world: {sleep: false}", "bodies:"]
    for w, (x, y, sx, sy) in enumerate(((1.6, 0, 0.2, 3.4), (-1.6, 0, 0.2, 3.4), (0, 1.6, 3.4, 0.2),
                                         (0, -1.6, 3.4, 0.2))):
        lines.append(f"  - {{name: wall{w}, shape: box, size: [{sx}, {sy}, 1.5], position: [{x}, {y}, 0.75], "
                     "fixed: true}")
    for i in range(count):
        layer, cell = divmod(i, side * side)
        gx, gy = divmod(cell, side)
        x = -1.1 + 2.2 * gx / max(side - 1, 1) + rng.uniform(-0.05, 0.05)
        y = -1.1 + 2.2 * gy / max(side - 1, 1) + rng.uniform(-0.05, 0.05)
        z = 0.4 + 0.5 * layer
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        pose = f"position: [{x:.4f}, {y:.4f}, {z:.4f}], orientation: [{q[0]:.5f}, {q[1]:.5f}, {q[2]:.5f}, {q[3]:.5f}]"
        kind = i % 4
        if kind == 0:
            lines.append(f"  - {{name: s{i}, shape: sphere, radius: {rng.uniform(0.08, 0.14):.3f}, mass: 1.0, {pose}}}")
        elif kind == 1:
            size = ", ".join(f"{v:.3f}" for v in rng.uniform(0.14, 0.28, size=3))
            lines.append(f"  - {{name: b{i}, shape: box, size: [{size}], mass: 1.5, {pose}}}")
        elif kind == 2:
            lines.append(f"  - {{name: c{i}, shape: capsule, radius: 0.07, length: 0.24, mass: 1.0, {pose}}}")
        else:
            lines.append(f"  - {{name: p{i}, shape: particles, radius: 0.07, particles: [[0, 0, 0, 0.5], "
                         f"[0.14, 0, 0, 0.5], [0.28, 0, 0, 0.5], [0.28, 0.14, 0, 0.5]], {pose}}}")
    return "\n".join(lines) + "\n"


def bench_pile(seconds: float) -> dict:
    warm_up()  # every kernel compiled / loaded before timing
    world = World(parse_scene(pile_scene()), dt=1 / 60)
    pb, client = pybullet_world(world)
    ticks = int(round(seconds * 60))
    t_cgp, t_pb = np.empty(ticks), np.empty(ticks)
    contacts = []
    clock = time.perf_counter
    reset_stage_times(world.solver)
    for k in range(ticks):
        t0 = clock()
        world.step()
        t1 = clock()
        for _ in range(SUBSTEPS):
            pb.stepSimulation(physicsClientId=client)
        t2 = clock()
        t_cgp[k], t_pb[k] = t1 - t0, t2 - t1
        contacts.append(world.solver.stats.get("contacts", 0))
    pb.disconnect(client)
    movable = ~world.body_model.fixed
    z = world.body_state.position[movable, 2]
    return {"cgp_sim": {"median": float(np.median(t_cgp) * 1e3), "p99": float(np.percentile(t_cgp, 99) * 1e3),
                        "max": float(t_cgp.max() * 1e3)},
            "pybullet": {"median": float(np.median(t_pb) * 1e3), "p99": float(np.percentile(t_pb, 99) * 1e3)},
            "contacts_median": float(np.median(contacts)), "contacts_max": int(max(contacts)),
            "pile_height_max": float(z.max()), "escaped": int(np.count_nonzero(np.abs(
                world.body_state.position[movable, :2]).max(axis=1) > 1.6)),
            "lowest": float(z.min()), "stages_ms": stage_times(world.solver, ticks)}


# ---- 3. start-up of the compiled kernels -------------------------------------------------------------------

STARTUP = r"""
import time
t0 = time.perf_counter()
from cgp_core import World
t1 = time.perf_counter()
from cgp_core.warmup import warm_up
warm_up(ticks=1, complete=False)
first = time.perf_counter() - t1
warm_up(ticks=20, complete=False)
print(f"{t1 - t0:.3f} {first:.3f} {time.perf_counter() - t0:.3f}")
"""


def bench_startup() -> dict:
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        env.pop("NUMBA_DISABLE_JIT", None)
        out = {}
        for label in ("cold", "warm"):
            started, cpu = time.perf_counter(), resource.getrusage(resource.RUSAGE_CHILDREN)
            done = subprocess.run([sys.executable, "-c", STARTUP], env=env, cwd=HERE.parent, capture_output=True,
                                  text=True, check=True)
            total = time.perf_counter() - started
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            imp, first, ticks = map(float, done.stdout.split())
            # CPU time (user + system) of the child: what the compile costs on an idle core, whatever the load
            cpu_s = (after.ru_utime - cpu.ru_utime) + (after.ru_stime - cpu.ru_stime)
            out[label] = {"process_s": total, "cpu_s": cpu_s, "import_s": imp, "first_tick_s": first,
                          "to_21_ticks_s": ticks}
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs")
    args = parser.parse_args(argv)
    out = Results("rigid", options=vars(args))

    startup = bench_startup()
    print(f"start-up: cold (empty numba cache) {startup['cold']['process_s']:.1f} s to 21 ticks "
          f"({startup['cold']['cpu_s']:.1f} s CPU), "
          f"warm {startup['warm']['process_s']:.2f} s (import {startup['warm']['import_s']:.2f} s, "
          f"first tick {startup['warm']['first_tick_s'] * 1e3:.0f} ms)", flush=True)
    default = bench_default(6.0 if args.quick else 18.0)
    c, mj, pbt = default["cgp_sim"], default["mujoco"], default["pybullet"]
    print(f"default scene's 5 bodies, ms per tick (4 x 1/240 s), over {'6' if args.quick else '18'} s:")
    for name in ("cgp_sim", "mujoco", "pybullet"):
        r = default[name]
        print(f"  {name:9s} median {r['median']:7.3f}  p99 {r['p99']:7.3f}  max {r['max']:7.3f}  "
              f"0-2.5 s {r['median_0_2.5s']:7.3f}  7.5-17 s {r['median_7.5_17s']:7.3f}", flush=True)
    print("  cgp_sim's stages, mean ms per tick:\n" + format_stage_times(default["stages_ms"]), flush=True)
    pile = bench_pile(2.0 if args.quick else 4.0)
    print(f"200-body pile, ms per tick: cgp_sim median {pile['cgp_sim']['median']:.2f} p99 {pile['cgp_sim']['p99']:.2f}"
          f"; pybullet median {pile['pybullet']['median']:.2f} p99 {pile['pybullet']['p99']:.2f}; contacts median "
          f"{pile['contacts_median']:.0f}; escaped {pile['escaped']}", flush=True)
    print("  cgp_sim's stages, mean ms per tick:\n" + format_stage_times(pile["stages_ms"]), flush=True)

    ratio_mj = c["median"] / mj["median"]
    out.figure("rigid_default_tick_median", "default scene's 5 bodies, one tick while they move (core), median",
               c["median"], "ms", "<= 1.0", c["median"] <= 1.0)
    out.figure("rigid_default_tick_p99", "default scene's 5 bodies, one tick, p99 over the fall and settling",
               c["p99"], "ms", "(reference)", None)
    out.figure("rigid_default_vs_mujoco", "default scene's 5 bodies: cgp_sim / MuJoCo (median tick, side by side)",
               ratio_mj, "x", "<= 10", ratio_mj <= 10.0, mujoco_ms=mj["median"], pybullet_ms=pbt["median"])
    out.figure("rigid_default_vs_pybullet", "default scene's 5 bodies: cgp_sim / PyBullet (median tick)",
               c["median"] / pbt["median"], "x", "(reference)", None)
    out.figure("rigid_pile_200_median", "200 mixed bodies dropped into a pile, tick while they move, median",
               pile["cgp_sim"]["median"], "ms", "<= 16.7", pile["cgp_sim"]["median"] <= 16.7)
    out.figure("rigid_pile_200_vs_pybullet", "200-body pile: cgp_sim / PyBullet (median tick)",
               pile["cgp_sim"]["median"] / pile["pybullet"]["median"], "x", "(reference)", None)
    out.figure("rigid_compile_cold", "default scene's kernels compiled one by one in one process, empty numba "
               "cache, to 21 ticks (CPU time)", startup["cold"]["cpu_s"], "s",
               "(reference: the cold start shares it out among 3 processes)", None,
               wall_s=startup["cold"]["process_s"])
    out.figure("rigid_start_warm", "compiled kernels: fresh process, warm cache, to 21 ticks (wall)",
               startup["warm"]["process_s"], "s", "(well under 5)", None)
    out.data.update(default=default, pile=pile, startup=startup)
    print(f"wrote {out.write()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

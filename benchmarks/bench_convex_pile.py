"""Issue 25's convex pile: 100 random convex hulls dropped onto a plane, cgp_sim vs PyBullet vs MuJoCo, side by side
in one process.

The pile: 100 convex hulls, each the hull of 16–24 random points on an ellipsoid 0.3–0.5 m across (semi-axes 80–100 %
of half that), mass 1 kg, friction 0.6 (the ground's 0.6 too), no restitution, randomly turned, on a 5 × 5 × 4 grid
0.7 m apart whose lowest layer is at 0.4 m; gravity 9.81; one 1/60 s tick = 4 sub-steps of 1/240 s.  The same
pile built in PyBullet 3.2.7 (``GEOM_MESH`` from the points: its convex hull; 4 ``stepSimulation`` of 1/240 s per
tick) and MuJoCo 4.0.0 (a mesh geom per hull, which MuJoCo replaces by its convex hull; timestep 1/240 s, 4
``mj_step`` per tick), stepped tick by tick in turn so that all three see the same machine.

Figures: per-tick time while the hulls fall and pile up (the first 3 s) and over the next 5 s (median, p99); the
time until the whole pile sleeps (cgp_sim's default ``sleep: true``); resting creep — the mean displacement of the
bodies from 3 s to 8 s — of cgp_sim with sleeping off (solved every sub-step, as the peers are) against MuJoCo's and
PyBullet's; that run's per-tick time at rest too.  The same pile once more with ``world.contact_detection:
once_per_tick`` (cgp_core/collision/carry.py): a fourth world stepped in the same loop (the ``once/tick`` row), and
the sleeping-off rest run again in that mode, with the deepest penetration of each while piling.  The speed probe
(``common.speed_probe``) is printed beside them.  cgp_sim's kernels are loaded from numba's cache before the first
tick, as the node loads them (``cgp_core.warmup.load_kernels_for`` and a throwaway copy's tick): without it the
first ticks that run a kernel load it (tick 0 ~115 ms, the first contact ~50 ms, the first sub-step of 256 contacts
~115 ms), and those are the p99 of the 180 piling ticks.

    .venv/bin/python benchmarks/bench_convex_pile.py [--quick]
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from common import Results, speed_probe  # noqa: E402

from cgp_core import World, parse_scene  # noqa: E402
from cgp_core.warmup import load_kernels_for  # noqa: E402

H = 1.0 / 240.0
SUBSTEPS = 4
TICK = H * SUBSTEPS
FRICTION = 0.6
FALL_S, REST_S = 3.0, 5.0
#: the row of cgp_sim with contacts found once per tick (world.contact_detection: once_per_tick)
ONCE = "once/tick"


def pile_hulls(seed: int = 25) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """The 100 hulls' points (each (k, 3), 16 ≤ k ≤ 24, about their own origin), positions (100, 3) and
    orientations (100, 4) xyzw."""
    rng = np.random.default_rng(seed)
    points, positions, orientations = [], [], []
    for layer in range(4):
        for i in range(5):
            for j in range(5):
                k = int(rng.integers(16, 25))
                direction = rng.normal(size=(k, 3))
                direction /= np.linalg.norm(direction, axis=1)[:, None]
                across = rng.uniform(0.3, 0.5)
                points.append(direction * (across / 2) * rng.uniform(0.8, 1.0, size=3))
                positions.append(((i - 2) * 0.7, (j - 2) * 0.7, 0.4 + 0.7 * layer))
                q = rng.normal(size=4)
                orientations.append(q / np.linalg.norm(q))
    return points, np.array(positions), np.array(orientations)


def ours(sleep: bool, detection: str = "every_substep") -> World:
    """The pile in cgp_sim; ``detection``: the scene's ``world.contact_detection``."""
    points, positions, orientations = pile_hulls()
    lines = [f"world: {{substeps: {SUBSTEPS}, sleep: {str(sleep).lower()}, ground_friction: {FRICTION}, "
             f"ground_restitution: 0.0, contact_detection: {detection}}}", "bodies:"]
    for n, (p, x, q) in enumerate(zip(points, positions, orientations)):
        pts = ", ".join(f"[{a:.6f}, {b:.6f}, {c:.6f}]" for a, b, c in p)
        lines.append(f"  - {{name: h{n}, shape: convex, mass: 1.0, friction: {FRICTION}, restitution: 0.0, "
                     f"position: [{x[0]}, {x[1]}, {x[2]}], orientation: {q.tolist()}, points: [{pts}]}}")
    world = World(parse_scene("\n".join(lines) + "\n", "convex_pile_bench"), dt=TICK)
    load_kernels_for(world)  # as the node does before its first tick (cgp_sim_ros.ros.process.load_kernels)
    copy.deepcopy(world).step()
    return world


def pybullet_pile():
    import pybullet as pb

    points, positions, orientations = pile_hulls()
    client = pb.connect(pb.DIRECT)
    pb.setGravity(0, 0, -9.81, physicsClientId=client)
    pb.setTimeStep(H, physicsClientId=client)
    plane = pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=client),
                               physicsClientId=client)
    pb.changeDynamics(plane, -1, lateralFriction=FRICTION, restitution=0.0, physicsClientId=client)
    bodies = []
    for p, x, q in zip(points, positions, orientations):
        shape = pb.createCollisionShape(pb.GEOM_MESH, vertices=p.tolist(), physicsClientId=client)
        body = pb.createMultiBody(1.0, shape, basePosition=x.tolist(), baseOrientation=q.tolist(),
                                  physicsClientId=client)
        pb.changeDynamics(body, -1, lateralFriction=FRICTION, restitution=0.0, physicsClientId=client)
        bodies.append(body)

    def step():
        for _ in range(SUBSTEPS):
            pb.stepSimulation(physicsClientId=client)

    def where():
        return np.array([pb.getBasePositionAndOrientation(b, physicsClientId=client)[0] for b in bodies])

    return step, where, lambda: pb.disconnect(client)


def mujoco_pile():
    import mujoco

    points, positions, orientations = pile_hulls()
    assets = "".join(f'<mesh name="m{n}" vertex="{" ".join(f"{v:.6f}" for v in p.ravel())}"/>'
                     for n, p in enumerate(points))
    bodies = "".join(f'<body pos="{x[0]} {x[1]} {x[2]}" quat="{q[3]} {q[0]} {q[1]} {q[2]}"><freejoint/>'
                     f'<geom type="mesh" mesh="m{n}" mass="1" friction="{FRICTION} 0.005 0.0001"/></body>'
                     for n, (x, q) in enumerate(zip(positions, orientations)))
    xml = (f'<mujoco><option timestep="{H}" gravity="0 0 -9.81"/><asset>{assets}</asset><worldbody>'
           f'<geom type="plane" size="50 50 0.1" friction="{FRICTION} 0.005 0.0001"/>{bodies}</worldbody></mujoco>')
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)

    def step():
        for _ in range(SUBSTEPS):
            mujoco.mj_step(m, d)

    return step, lambda: d.qpos.reshape(-1, 7)[:, :3].copy(), lambda: None


def _stats(t: np.ndarray) -> dict:
    return {"median": float(np.median(t) * 1e3), "p99": float(np.percentile(t, 99) * 1e3)}


def side_by_side(seconds_fall: float, seconds_rest: float) -> dict:
    """All three stepped tick by tick in turn (cgp_sim with its default sleeping), and cgp_sim once more with
    contacts found once per tick (``contact_detection: once_per_tick``, cgp_core/collision/carry.py)."""
    world = ours(sleep=True)
    once = ours(sleep=True, detection="once_per_tick")
    pb_step, pb_where, pb_close = pybullet_pile()
    mj_step, mj_where, _ = mujoco_pile()
    ticks = round((seconds_fall + seconds_rest) / TICK)
    fall = round(seconds_fall / TICK)
    times = {name: np.empty(ticks) for name in ("cgp_sim", "pybullet", "mujoco", ONCE)}
    once_penetration = np.zeros(ticks)
    asleep_at = None
    contacts = []
    rest_start = {}
    clock = time.perf_counter
    for k in range(ticks):
        if k == fall:
            rest_start = {"pybullet": pb_where(), "mujoco": mj_where()}
        t0 = clock()
        world.step()
        t1 = clock()
        pb_step()
        t2 = clock()
        mj_step()
        t3 = clock()
        once.step()
        times[ONCE][k] = clock() - t3
        once_penetration[k] = once.solver.stats.get("max_penetration", 0.0) if not once.bodies_asleep else 0.0
        times["cgp_sim"][k], times["pybullet"][k], times["mujoco"][k] = t1 - t0, t2 - t1, t3 - t2
        contacts.append(world.solver.stats.get("contacts", 0) if not world.bodies_asleep else 0)
        if asleep_at is None and world.bodies_asleep:
            asleep_at = world.time
    creep = {"pybullet": float(np.linalg.norm(pb_where() - rest_start["pybullet"], axis=1).mean()),
             "mujoco": float(np.linalg.norm(mj_where() - rest_start["mujoco"], axis=1).mean())}
    out = {name: {"fall": _stats(t[:fall]), "rest": _stats(t[fall:])} for name, t in times.items()}
    heights = {"cgp_sim": float(world.body_state.position[:, 2].max()), "pybullet": float(pb_where()[:, 2].max()),
               "mujoco": float(mj_where()[:, 2].max())}
    pb_close()
    extra = 0
    while asleep_at is None and extra < round(10.0 / TICK):  # how long it takes, if not yet
        world.step()
        extra += 1
        if world.bodies_asleep:
            asleep_at = world.time
    return {"ticks": out, "asleep_at_s": asleep_at, "creep": creep, "once_max_penetration_m": {
        "fall_p99": float(np.percentile(once_penetration[:fall], 99)), "max": float(once_penetration.max())},
            "contacts_median_fall": float(np.median(
        contacts[:fall])), "contacts_max": int(max(contacts)), "pile_top_m": heights,
            "lowest_m": float(world.body_state.position[:, 2].min())}


def resting_creep(seconds_fall: float, seconds_rest: float, detection: str = "every_substep") -> dict:
    """cgp_sim with sleeping off: the mean displacement from ``seconds_fall`` over ``seconds_rest``, and the
    per-tick time while everything is solved every sub-step at rest; the deepest penetration while piling."""
    world = ours(sleep=False, detection=detection)
    fall = round(seconds_fall / TICK)
    penetration = np.empty(fall)
    for k in range(fall):
        world.step()
        penetration[k] = world.solver.stats.get("max_penetration", 0.0)
    start = world.body_state.position.copy()
    rest = np.empty(round(seconds_rest / TICK))
    for k in range(len(rest)):
        t0 = time.perf_counter()
        world.step()
        rest[k] = time.perf_counter() - t0
    return {"creep": float(np.linalg.norm(world.body_state.position - start, axis=1).mean()),
            "rest": _stats(rest), "max_penetration_m": float(world.solver.stats.get("max_penetration", 0.0)),
            "piling_penetration_m": {"p99": float(np.percentile(penetration, 99)), "max": float(penetration.max())}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="(the same run: the pile's 8 s are the point)")
    args = parser.parse_args(argv)
    out = Results("convex_pile", options=vars(args))
    probe_before = speed_probe()
    ours(sleep=True).step()  # compile / load every kernel before timing
    run = side_by_side(FALL_S, REST_S)
    still = resting_creep(FALL_S, REST_S)
    still_once = resting_creep(FALL_S, REST_S, "once_per_tick")
    probe_after = speed_probe()
    t = run["ticks"]
    print(f"speed probe (python loop): {probe_before['python_ms']:.1f} ms before, {probe_after['python_ms']:.1f} ms "
          "after", flush=True)
    print("100 convex hulls dropped onto a plane, ms per 1/60 s tick (4 x 1/240 s):")
    print(f"  {'':9s} {'0-3 s median':>13s} {'p99':>7s} {'3-8 s median':>13s} {'p99':>7s}")
    for name in ("cgp_sim", "pybullet", "mujoco", ONCE):
        f, r = t[name]["fall"], t[name]["rest"]
        print(f"  {name:9s} {f['median']:13.2f} {f['p99']:7.2f} {r['median']:13.2f} {r['p99']:7.2f}")
    print(f"  ({ONCE}: cgp_sim with contacts found once per tick, world.contact_detection: once_per_tick)")
    print(f"  cgp_sim, sleeping off, at rest (3-8 s): median {still['rest']['median']:.2f}, p99 "
          f"{still['rest']['p99']:.2f}; contacts once per tick {still_once['rest']['median']:.2f}, p99 "
          f"{still_once['rest']['p99']:.2f}")
    print("deepest penetration while piling, sleeping off (p99 of the ticks' / max), mm: every sub-step "
          f"{still['piling_penetration_m']['p99'] * 1e3:.1f} / {still['piling_penetration_m']['max'] * 1e3:.1f}, "
          f"once per tick {still_once['piling_penetration_m']['p99'] * 1e3:.1f} / "
          f"{still_once['piling_penetration_m']['max'] * 1e3:.1f}")
    asleep = run["asleep_at_s"]
    print(f"cgp_sim's pile asleep at {asleep if asleep is None else round(asleep, 2)} s; contacts while piling "
          f"(median) {run['contacts_median_fall']:.0f}, max {run['contacts_max']}; lowest body {run['lowest_m']:.3f} m")
    print(f"resting creep 3-8 s (mean displacement): cgp_sim (sleeping off) {still['creep'] * 1e3:.3f} mm, MuJoCo "
          f"{run['creep']['mujoco'] * 1e3:.3f} mm, PyBullet {run['creep']['pybullet'] * 1e3:.3f} mm; cgp_sim contacts "
          f"once per tick {still_once['creep'] * 1e3:.3f} mm")

    ours_fall, pb_fall, mj_fall = (t[n]["fall"]["median"] for n in ("cgp_sim", "pybullet", "mujoco"))
    out.figure("convex_pile_fall_tick", "100 convex hulls falling and piling (first 3 s): cgp_sim median tick",
               ours_fall, "ms", f"<= PyBullet's ({pb_fall:.2f} ms)", ours_fall <= pb_fall, pybullet_ms=pb_fall,
               mujoco_ms=mj_fall, p99_ms=t["cgp_sim"]["fall"]["p99"])
    out.figure("convex_pile_fall_vs_mujoco", "  ... cgp_sim / MuJoCo (median tick, first 3 s)", ours_fall / mj_fall,
               "x", "<= 2 (aim)", ours_fall / mj_fall <= 2.0)
    out.figure("convex_pile_rest_tick", "  ... the next 5 s (cgp_sim sleeping as by default), median tick",
               t["cgp_sim"]["rest"]["median"], "ms", "(reference)", None, pybullet_ms=t["pybullet"]["rest"]["median"],
               mujoco_ms=t["mujoco"]["rest"]["median"], awake_rest_ms=still["rest"]["median"])
    out.figure("convex_pile_asleep_s", "  ... the whole pile asleep after", asleep if asleep is not None else np.inf,
               "s", "<= 10", asleep is not None and asleep <= 10.0)
    out.figure("convex_pile_creep", "  ... resting creep 3-8 s, mean displacement (cgp_sim sleeping off)",
               still["creep"] * 1e3, "mm", f"< MuJoCo's ({run['creep']['mujoco'] * 1e3:.3f} mm)",
               still["creep"] < run["creep"]["mujoco"], mujoco_mm=run["creep"]["mujoco"] * 1e3,
               pybullet_mm=run["creep"]["pybullet"] * 1e3)
    once_fall = t[ONCE]["fall"]["median"]
    out.figure("convex_pile_fall_once_vs_mujoco", "  ... contacts found once per tick (world.contact_detection: "
               "once_per_tick): cgp_sim / MuJoCo (median tick, first 3 s)", once_fall / mj_fall, "x", "<= 2 (aim)",
               once_fall / mj_fall <= 2.0, ms=once_fall, p99_ms=t[ONCE]["fall"]["p99"],
               awake_rest_ms=still_once["rest"]["median"], creep_mm=still_once["creep"] * 1e3)
    out.data.update(side_by_side=run, sleeping_off=still, sleeping_off_once_per_tick=still_once,
                    probe_before=probe_before, probe_after=probe_after)
    print(f"wrote {out.write()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

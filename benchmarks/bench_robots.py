"""Issue 35's robots: a 7-DoF arm under position control holding a pose, and 64 such arms in one world, cgp_sim vs
PyBullet vs MuJoCo side by side in one process.

The arm: pybullet_data's ``kuka_iiwa/model.urdf`` (KUKA LBR iiwa, 7 revolute joints, URDF damping 0.5 N m s/rad,
STL collision meshes), fixed base, held at ``POSE`` against gravity.  One 1/60 s tick = 4 sub-steps of 1/240 s.
No ground and no other bodies: the figure is the articulated step itself (each engine still runs its collision
detection over the links, self-collision off as each loads URDF by default).

- **cgp_sim**: a ``World`` built from a scene dict with a ``robots:`` entry naming the URDF file, ``hold: true``
  (implicit position drives at the scene defaults kp = 1e5 N m/rad, kd = 1e3 N m s/rad, bounded by the URDF's
  effort limits); 64 arms: 64 entries on an 8 × 8 grid 1.5 m apart.
- **PyBullet**: ``loadURDF(useFixedBase=True)`` (its default btMultiBody), ``setJointMotorControlArray(
  POSITION_CONTROL, targetPositions=POSE, forces=<the URDF's effort limits>)``, 4 × ``stepSimulation`` of 1/240 s.
- **MuJoCo**: ``MjSpec.from_file`` on the same URDF (its mesh directory set to the URDF's: MuJoCo's URDF import
  strips mesh paths to file names), a ``position`` actuator per joint with the same kp and kv = 1e3 (MuJoCo's
  position actuator is implicit in kv only with the ``implicitfast`` integrator, used here), force-limited to the
  effort limits; timestep 1/240 s, 4 × ``mj_step`` per tick.

Every engine is stepped tick by tick in turn (interleaved) so that all see the same machine; the speed probe
(``common.speed_probe``) is printed beside the figures.  Also: the single arm's hold error (the largest |q − q*|
over the run, after the first second) in each engine.

``--joint-integrators``: instead, the cost of each scene ``joint_integrator`` (cgp_core.robots.joint_integrators:
the default semi-implicit Euler, the 2- and 3-stage Gauss–Legendre methods) per tick on tests/test_body_joints.py's
double pendulum, on the built-in ``arm`` scene (the 7-DoF arm following its trajectory through the boxes) and
on the ``chain`` scene (30 pinned links, 32 dofs), interleaved, with the fixed-point passes per sub-step, the
fallbacks and the speed probe beside.

    .venv/bin/python benchmarks/bench_robots.py [--quick] [--joint-integrators]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from common import Results, speed_probe  # noqa: E402

from cgp_core import World  # noqa: E402
from cgp_core.scene import scene_from_dict  # noqa: E402

H = 1.0 / 240.0
SUBSTEPS = 4
TICK = H * SUBSTEPS
POSE = [0.3, 0.6, -0.2, -1.2, 0.1, 0.8, 0.0]
KP, KD = 1.0e5, 1.0e3
SPACING = 1.5


def arm_urdf() -> Path:
    import pybullet_data

    return Path(pybullet_data.getDataPath()) / "kuka_iiwa" / "model.urdf"


def grid(count: int) -> list[tuple[float, float]]:
    side = int(round(np.sqrt(count)))
    return [((i % side) * SPACING, (i // side) * SPACING) for i in range(count)]


def ours(count: int) -> tuple[World, callable]:
    urdf = str(arm_urdf())
    joints = {f"lbr_iiwa_joint_{k + 1}": v for k, v in enumerate(POSE)}
    robots = [{"name": f"arm{i}", "urdf": urdf, "position": [x, y, 0.0], "joints": joints, "hold": True,
               "stiffness": KP, "damping": KD} for i, (x, y) in enumerate(grid(count))]
    # sleep off: the peers step every arm every tick; a holding arm would otherwise fall asleep (issue 35)
    world = World(scene_from_dict({"world": {"substeps": SUBSTEPS, "ground": False, "sleep": False}, "robots": robots},
                                  "<bench_robots>"), dt=TICK)
    names = [f"arm{i}" for i in range(count)]

    def q() -> np.ndarray:
        return np.array([world.robots.joint_state(n)[1] for n in names])

    return world, q


def pybullet_arms(count: int):
    import pybullet as pb

    client = pb.connect(pb.DIRECT)
    pb.setGravity(0, 0, -9.81, physicsClientId=client)
    pb.setTimeStep(H, physicsClientId=client)
    arms = []
    for x, y in grid(count):
        arm = pb.loadURDF(str(arm_urdf()), [x, y, 0.0], useFixedBase=True, physicsClientId=client)
        joints = list(range(pb.getNumJoints(arm, physicsClientId=client)))
        for j, v in zip(joints, POSE):
            pb.resetJointState(arm, j, v, physicsClientId=client)
        efforts = [pb.getJointInfo(arm, j, physicsClientId=client)[10] for j in joints]
        pb.setJointMotorControlArray(arm, joints, pb.POSITION_CONTROL, targetPositions=POSE, forces=efforts,
                                     physicsClientId=client)
        arms.append((arm, joints))

    def step():
        for _ in range(SUBSTEPS):
            pb.stepSimulation(physicsClientId=client)

    def q():
        return np.array([[s[0] for s in pb.getJointStates(a, j, physicsClientId=client)] for a, j in arms])

    return step, q, lambda: pb.disconnect(client)


def mujoco_arms(count: int):
    import mujoco

    urdf = arm_urdf()
    model_spec = mujoco.MjSpec.from_file(str(urdf))
    model_spec.meshdir = str(urdf.parent)
    top = mujoco.MjSpec()
    top.option.timestep = H
    top.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    top.meshdir = str(urdf.parent)
    efforts = {j.name: j.actfrcrange[1] for j in model_spec.joints}
    for i, (x, y) in enumerate(grid(count)):
        frame = top.worldbody.add_frame(pos=[x, y, 0.0])
        frame.attach_body(model_spec.copy().worldbody.first_body(), f"a{i}_", "")
    for j in top.joints:
        act = top.add_actuator(name=f"act_{j.name}", target=j.name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=KP, kv=KD)
        limit = efforts.get(j.name.split("_", 1)[1], 0.0)
        if limit > 0:
            act.forcelimited = True
            act.forcerange = [-limit, limit]
    m = top.compile()
    d = mujoco.MjData(m)
    d.qpos[:] = np.tile(POSE, count)
    d.ctrl[:] = np.tile(POSE, count)
    mujoco.mj_forward(m, d)

    def step():
        for _ in range(SUBSTEPS):
            mujoco.mj_step(m, d)

    return step, lambda: d.qpos.reshape(count, 7).copy(), lambda: None, m


def _stats(t: np.ndarray) -> dict:
    return {"median": float(np.median(t) * 1e3), "p99": float(np.percentile(t, 99) * 1e3)}


def side_by_side(count: int, seconds: float, engines=("cgp_sim", "pybullet", "mujoco")) -> dict:
    steps, readers, closers, notes = {}, {}, [], {}
    world, q = ours(count)
    world.step()  # compile / load every kernel before timing
    steps["cgp_sim"], readers["cgp_sim"] = world.step, q
    if "pybullet" in engines:
        try:
            s, r, c = pybullet_arms(count)
            steps["pybullet"], readers["pybullet"] = s, r
            closers.append(c)
        except Exception as exc:  # noqa: BLE001 - a missing peer is a result
            notes["pybullet"] = repr(exc)
    if "mujoco" in engines:
        try:
            s, r, c, m = mujoco_arms(count)
            steps["mujoco"], readers["mujoco"] = s, r
            notes["mujoco_model"] = f"{m.nbody} bodies, {m.ngeom} geoms, {m.nu} actuators"
        except Exception as exc:  # noqa: BLE001
            notes["mujoco"] = repr(exc)
    ticks = round(seconds / TICK)
    settle = round(1.0 / TICK)
    times = {name: np.empty(ticks) for name in steps}
    error = {name: 0.0 for name in steps}
    target = np.array(POSE)
    clock = time.perf_counter
    for k in range(ticks):
        for name, step in steps.items():
            t0 = clock()
            step()
            times[name][k] = clock() - t0
        if k >= settle and (k % 6 == 0 or k == ticks - 1):
            for name, read in readers.items():
                error[name] = max(error[name], float(np.abs(read() - target).max()))
    for close in closers:
        close()
    return {"ticks": {name: _stats(t) for name, t in times.items()}, "hold_error_rad": error, "notes": notes,
            "count": count, "seconds": seconds}


#: the scene's joint_integrator values timed by joint_integrator_ticks (cgp_core.robots.joint_integrators)
JOINT_INTEGRATORS = ("semi_implicit_euler", "gauss_legendre_4", "gauss_legendre_6")


def double_pendulum_scene(joint_integrator: str) -> dict:
    """tests/test_body_joints.py's chaotic double pendulum (two boxes on two pins, no ground)."""
    top = np.array([0.0, 0.0, 3.0])
    return {"world": {"ground": False, "sleep": False, "joint_integrator": joint_integrator},
            "bodies": [{"name": "upper", "shape": "box", "size": [0.6, 0.05, 0.05], "mass": 1.0,
                        "position": (top + [0.3, 0, 0]).tolist()},
                       {"name": "lower", "shape": "box", "size": [0.05, 0.05, 0.5], "mass": 0.7,
                        "position": (top + [0.6, 0, 0.25]).tolist()}],
            "joints": [{"name": "shoulder", "type": "revolute", "parent": "world", "child": "upper",
                        "anchor": top.tolist(), "axis": [0, 1, 0]},
                       {"name": "elbow", "type": "revolute", "parent": "upper", "child": "lower",
                        "anchor": (top + [0.6, 0, 0]).tolist(), "axis": [0, 1, 0]}]}


def scene_world(name: str, joint_integrator: str) -> World:
    """A built-in scene with every robot's and articulation's joint integrator set: ``arm`` (the 7-DoF arm7.urdf
    following its looping trajectory across the table's boxes: drives, contacts), ``chain`` (a 5 kg ball on 30
    pinned 0.1 kg links knocking a wall over: 32 dofs)."""
    from cgp_core.scene import load_scene

    scene = load_scene(name)
    scene.world.joint_integrator = joint_integrator
    for spec in list(scene.robots) + list(scene.articulations):
        spec.joint_integrator = joint_integrator
    return World(scene)


def joint_integrator_ticks(seconds: float) -> dict:
    """Median / p99 tick [ms] of the double pendulum and of the ``arm`` scene with each joint integrator, the
    worlds stepped tick by tick in turn (all see the same machine), and the Gauss–Legendre fixed-point passes per
    sub-step."""
    worlds = {}
    for name in JOINT_INTEGRATORS:
        worlds[("double_pendulum", name)] = World(scene_from_dict(double_pendulum_scene(name)))
        worlds[("arm", name)] = scene_world("arm", name)
        worlds[("chain", name)] = scene_world("chain", name)
    for world in worlds.values():
        world.step()  # compile / load every kernel before timing
    ticks = round(seconds / TICK)
    times = {key: np.empty(ticks) for key in worlds}
    clock = time.perf_counter
    for k in range(ticks):
        for key, world in worlds.items():
            t0 = clock()
            world.step()
            times[key][k] = clock() - t0
    out = {}
    for (scene, name), world in worlds.items():
        robots = world.robots
        passes = float(robots.integrator_iterations.sum()) / ((ticks + 1) * world.substeps * len(robots.robots))
        out.setdefault(scene, {})[name] = {**_stats(times[(scene, name)]), "passes_per_substep": round(passes, 2),
                                           "subdivided": int(robots.integrator_subdivided.sum()),
                                           "fallbacks": int(robots.integrator_fallbacks.sum())}
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs")
    parser.add_argument("--joint-integrators", action="store_true",
                        help="only the cost of each joint_integrator (double pendulum, the arm scene)")
    args = parser.parse_args(argv)
    out = Results("robots" if not args.joint_integrators else "robots_joint_integrators", options=vars(args))
    if args.joint_integrators:
        return joint_integrator_figures(out, 5.0 if args.quick else 20.0)
    probe_before = speed_probe()
    one = side_by_side(1, 5.0 if args.quick else 10.0)
    many = side_by_side(64, 2.0 if args.quick else 5.0)
    probe_after = speed_probe()
    print(f"speed probe (numpy / python ms): before {probe_before['numpy_ms']:.1f} / {probe_before['python_ms']:.1f},"
          f" after {probe_after['numpy_ms']:.1f} / {probe_after['python_ms']:.1f}", flush=True)
    print("KUKA iiwa (7 dof, kuka_iiwa/model.urdf) holding a pose, ms per 1/60 s tick (4 x 1/240 s):")
    print(f"  {'':9s} {'1 arm median':>13s} {'p99':>7s} {'64 arms median':>15s} {'p99':>7s} "
          f"{'hold error (1 arm)':>19s}")
    for name in one["ticks"]:
        a, b = one["ticks"][name], many["ticks"].get(name, {"median": float("nan"), "p99": float("nan")})
        print(f"  {name:9s} {a['median']:13.3f} {a['p99']:7.3f} {b['median']:15.2f} {b['p99']:7.2f} "
              f"{one['hold_error_rad'][name]:17.2e} rad")
    for note in (one["notes"], many["notes"]):
        for k, v in note.items():
            print(f"  note {k}: {v}")
    t1, t64 = one["ticks"], many["ticks"]
    ours1, ours64 = t1["cgp_sim"]["median"], t64["cgp_sim"]["median"]
    pb64 = t64.get("pybullet", {}).get("median")
    mj64 = t64.get("mujoco", {}).get("median")
    out.figure("robots_one_arm_tick", "a 7-DoF arm holding a pose: cgp_sim median tick", ours1, "ms", "<= 0.5",
               ours1 <= 0.5, p99_ms=t1["cgp_sim"]["p99"], pybullet_ms=t1.get("pybullet", {}).get("median"),
               mujoco_ms=t1.get("mujoco", {}).get("median"))
    out.figure("robots_one_arm_hold", "  ... its largest hold error after 1 s", one["hold_error_rad"]["cgp_sim"],
               "rad", "<= 1e-3", one["hold_error_rad"]["cgp_sim"] <= 1e-3,
               pybullet_rad=one["hold_error_rad"].get("pybullet"), mujoco_rad=one["hold_error_rad"].get("mujoco"))
    out.figure("robots_64_arms_tick", "64 such arms in one world: cgp_sim median tick", ours64, "ms",
               "<= PyBullet's" + (f" ({pb64:.2f} ms)" if pb64 else ""), None if pb64 is None else ours64 <= pb64,
               p99_ms=t64["cgp_sim"]["p99"], pybullet_ms=pb64, mujoco_ms=mj64)
    out.figure("robots_64_arms_vs_mujoco", "  ... cgp_sim / MuJoCo (median tick)",
               None if mj64 is None else ours64 / mj64, "x", "<= 3", None if mj64 is None else ours64 / mj64 <= 3.0)
    out.data.update(one_arm=one, arms_64=many, probe_before=probe_before, probe_after=probe_after)
    print(f"wrote {out.write()}")
    return 0


def joint_integrator_figures(out, seconds: float) -> int:
    probe_before = speed_probe()
    ticks = joint_integrator_ticks(seconds)
    probe_after = speed_probe()
    print(f"speed probe (numpy / python ms): before {probe_before['numpy_ms']:.1f} / {probe_before['python_ms']:.1f},"
          f" after {probe_after['numpy_ms']:.1f} / {probe_after['python_ms']:.1f}", flush=True)
    print("joint integrators, ms per 1/60 s tick (4 x 1/240 s), interleaved:")
    print(f"  {'scene':16s} {'joint_integrator':20s} {'median':>8s} {'p99':>8s} {'x default':>10s} "
          f"{'passes/sub-step':>16s} {'split':>6s} {'fallbacks':>9s}")
    for scene, by_name in ticks.items():
        base = by_name["semi_implicit_euler"]["median"]
        for name, t in by_name.items():
            print(f"  {scene:16s} {name:20s} {t['median']:8.3f} {t['p99']:8.3f} {t['median'] / base:10.2f} "
                  f"{t['passes_per_substep']:16.2f} {t['subdivided']:6d} {t['fallbacks']:9d}")
            out.figure(f"joint_integrator_{scene}_{name}", f"{scene}: {name} median tick", t["median"], "ms",
                       "(measured)", None, p99_ms=t["p99"], vs_default=round(t["median"] / base, 3),
                       passes_per_substep=t["passes_per_substep"], subdivided=t["subdivided"],
                       fallbacks=t["fallbacks"])
    out.data.update(joint_integrators=ticks, probe_before=probe_before, probe_after=probe_after)
    print(f"wrote {out.write()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

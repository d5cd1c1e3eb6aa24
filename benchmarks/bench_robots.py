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

``--pushing``: instead, robots whose links push free bodies — the built-in ``arm`` scene (the 7-DoF arm sweeping
the boxes off its table: in the sweep's sub-steps its links touch boxes, and its rows and theirs are solved in one
loop, :mod:`cgp_core.robots.coupled`) tiled 1, 4 and 16 times 3 m apart, all arms on the same trajectory, so
that in those sub-steps every arm is in the one coupled system.  Per 1/60 s tick, median, p99 and max over one
trajectory cycle (9 s: the sweep and the return), and the ticks with a coupled sub-step apart; cgp_sim only (no
peer has this scene).  Each world runs in a child process of its own; ``--before TREE`` runs another checkout's
code (e.g. ``git worktree add /tmp/before <commit>``) the same way, interleaved with this one's, round by round.

    .venv/bin/python benchmarks/bench_robots.py [--quick] [--joint-integrators | --pushing [--before TREE]]
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


#: the child process of ``--pushing``: the arm scene tiled ``count`` times, stepped for ``ticks`` ticks; prints the
#: tick times [s] and which ticks had a coupled sub-step, as JSON (the tree under test is on PYTHONPATH)
PUSHING_CHILD = r"""
import copy, json, sys, time
import numpy as np, yaml
from cgp_core import World
from cgp_core.scene import parse_scene
from cgp_core.warmup import load_kernels_for
import cgp_core.robots.world as robots_world

count, ticks, arm_yaml = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
base = yaml.safe_load(open(arm_yaml))
side = int(np.ceil(np.sqrt(count)))
scene = {"world": base["world"], "robots": [], "bodies": []}
for k in range(count):
    dx, dy = 3.0 * (k % side), 3.0 * (k // side)
    robot = copy.deepcopy(base["robots"][0])
    robot["name"] = f"arm{k}"
    robot["position"] = [robot["position"][0] + dx, robot["position"][1] + dy, robot["position"][2]]
    scene["robots"].append(robot)
    for body in base["bodies"]:
        body = copy.deepcopy(body)
        body["name"] = f"{body['name']}_{k}"
        body["position"] = [body["position"][0] + dx, body["position"][1] + dy, body["position"][2]]
        scene["bodies"].append(body)
world = World(parse_scene(yaml.safe_dump(scene), f"arms_{count}"))
load_kernels_for(world)  # as the node does before its first tick
copy.deepcopy(world).step()
coupled = [0]
island = robots_world.Robots._island
def counted(self, *args, **kwargs):
    coupled[0] += 1
    return island(self, *args, **kwargs)
robots_world.Robots._island = counted
times, flags = [], []
for _ in range(ticks):
    coupled[0] = 0
    t0 = time.perf_counter()
    world.step()
    times.append(time.perf_counter() - t0)
    flags.append(coupled[0] > 0)
print(json.dumps({"times": times, "coupled": flags}))
"""

#: ``--pushing``: the tilings
PUSHING_COUNTS = (1, 4, 16)


def pushing_run(tree: Path, count: int, ticks: int) -> dict:
    """One child process (:data:`PUSHING_CHILD`) on ``tree``'s code: its tick statistics [ms]."""
    import json
    import os
    import subprocess

    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run([sys.executable, "-c", PUSHING_CHILD, str(count), str(ticks),
                           str(tree / "msgs_config" / "scenes" / "arm.yaml")], env=env, capture_output=True,
                          text=True, timeout=1800, cwd=str(tree))
    if done.returncode != 0:
        raise RuntimeError(f"the pushing child on {tree} failed:\n{done.stderr[-3000:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    t, coupled = np.array(result["times"]), np.array(result["coupled"], bool)
    return {**_stats(t), "max": float(t.max() * 1e3), "coupled_ticks": int(coupled.sum()),
            "coupled_median": float(np.median(t[coupled]) * 1e3) if coupled.any() else None,
            "free_median": float(np.median(t[~coupled]) * 1e3) if (~coupled).any() else None}


def pushing_figures(out, before: Path | None, rounds: int, seconds: float) -> int:
    ticks = round(seconds / TICK)
    versions = {"after": HERE.parent} if before is None else {"before": before.resolve(), "after": HERE.parent}
    runs = {label: {count: [] for count in PUSHING_COUNTS} for label in versions}
    probes = []
    for r in range(rounds):
        for count in PUSHING_COUNTS:
            for label, tree in versions.items():
                probes.append(speed_probe())
                runs[label][count].append(pushing_run(tree, count, ticks))
                row = runs[label][count][-1]
                print(f"  round {r + 1} {label:6s} {count:2d} arm(s): median {row['median']:6.2f}  "
                      f"p99 {row['p99']:6.2f}  max {row['max']:6.2f} ms  (coupled ticks {row['coupled_ticks']}: median "
                      f"{row['coupled_median']:.2f} ms)  probe python {probes[-1]['python_ms']:.1f} ms", flush=True)
    print(f"arms sweeping boxes off their tables (the arm scene tiled), ms per 1/60 s tick over {seconds:.0f} s, "
          f"median of {rounds} round(s):")
    print(f"  {'':7s} {'arms':>4s} {'median':>7s} {'p99':>7s} {'max':>7s} {'coupled tick median':>20s} "
          f"{'per arm':>8s}")
    summary = {}
    for label in versions:
        for count in PUSHING_COUNTS:
            rows = runs[label][count]
            m = {key: float(np.median([row[key] for row in rows])) for key in ("median", "p99", "max")}
            m["coupled_median"] = float(np.median([row["coupled_median"] for row in rows]))
            summary.setdefault(label, {})[count] = m
            print(f"  {label:7s} {count:4d} {m['median']:7.2f} {m['p99']:7.2f} {m['max']:7.2f} "
                  f"{m['coupled_median']:20.2f} {m['coupled_median'] / count:8.2f}")
    after = summary["after"]
    for count in PUSHING_COUNTS:
        extra = {f"before_{key}_ms": summary["before"][count][key] for key in ("median", "p99")} \
            if "before" in summary else {}
        out.figure(f"robots_pushing_{count}_p99", f"{count} arm(s) sweeping boxes: cgp_sim p99 tick",
                   after[count]["p99"], "ms", "<= 16.7 (60 Hz)", after[count]["p99"] <= 1000.0 / 60.0,
                   median_ms=after[count]["median"], coupled_median_ms=after[count]["coupled_median"], **extra)
    out.data.update(pushing=runs, pushing_summary=summary, probes=probes)
    print(f"speed probe (python ms) over the runs: {min(p['python_ms'] for p in probes):.1f} - "
          f"{max(p['python_ms'] for p in probes):.1f}")
    print(f"wrote {out.write()}")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs")
    parser.add_argument("--joint-integrators", action="store_true",
                        help="only the cost of each joint_integrator (double pendulum, the arm scene)")
    parser.add_argument("--pushing", action="store_true",
                        help="only arms sweeping boxes (the arm scene tiled 1, 4, 16 times)")
    parser.add_argument("--before", type=Path, help="--pushing: another checkout run interleaved with this one")
    parser.add_argument("--rounds", type=int, default=1, help="--pushing: rounds (default 1)")
    args = parser.parse_args(argv)
    name = "robots_joint_integrators" if args.joint_integrators else "robots_pushing" if args.pushing else "robots"
    out = Results(name, options={k: str(v) for k, v in vars(args).items()})
    if args.joint_integrators:
        return joint_integrator_figures(out, 5.0 if args.quick else 20.0)
    if args.pushing:
        return pushing_figures(out, args.before, args.rounds, 9.0)
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

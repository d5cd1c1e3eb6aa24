"""Compare two source trees of cgp_sim: the same runs, bit for bit, and side by side in speed.

A refactoring that promises "behaviour stays exactly as it is" (issue 24) proves it here: every case below is
stepped in separate processes, one importing ``cgp_core`` from each tree, and the recorded states are compared
with ``np.array_equal`` tick by tick.

    .venv/bin/python tools/compare_trees.py bits  [--old ee7b2f6] [--ticks 300]
    .venv/bin/python tools/compare_trees.py speed [--old ee7b2f6] [--rounds 5] [--paired]
    .venv/bin/python tools/compare_trees.py compile [--old ee7b2f6]

``--old`` is a git revision (exported with ``git archive`` into a temporary directory) or the path of a tree;
``--new`` defaults to this checkout.  Each child runs ``python -P`` with only the tree on ``PYTHONPATH``, so it
imports that tree's ``cgp_core`` (never the installed one); numba caches into the tree (``__pycache__``).

``bits`` — the cases: every built-in scene as a whole ``World`` (bodies and flocks; ``--ticks`` ticks), the
default scene's bodies placed so that every contact kernel runs (test_jit_parity's placement), a pile of particle
bodies, capsules on capsules, boxes and spheres, a 200-body pile (bench_rigid's; sweep and prune), the default
bodies under each integrator, wrench commands (world and body frame, at points, timed) and a teleport with a twist
plus the entity-state queries.  Recorded every tick: every body's x, q, P, L (and the explicit integrator's matrix),
every flock's positions, velocities and orientations, and the contact count.

``speed`` — per round and tree, one child process per case, the rounds interleaved old / new / new / old ...:
the default scene's bodies (5 bodies, sleep off; the dispatch overhead of the compiled calls matters most there),
the default scene as ``make run`` steps it (its fish too), bench_rigid's 200-body pile, the built-in sphere_pile,
and a 15k-boid flock step (bench_boids' scene); the median tick of each, with ``benchmarks/common.py: speed_probe``
before each child; ``--paired``: one long-lived child per tree and case instead, the two timing the same steps in
turn, ``--rounds`` pairs.  ``compile`` — the cold
compile (``python -m cgp_core.warmup`` with an empty ``NUMBA_CACHE_DIR``), old and new alternately.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]

# ---- the cases (run in the child; public API only, so that both trees run them) --------------------------------

BUILTIN = ("default", "box_stack", "pyramid", "sphere_pile", "ramp", "tennis_racket", "zero_g", "predator",
           "couzin_torus", "fish_school")

PARTICLES = """
world: {sleep: false}
bodies:
  - {name: table, shape: box, size: [1.2, 1.2, 0.3], position: [0, 0, 0.15], fixed: true}
""" + "".join(
    f"  - {{name: L{i}, shape: particles, radius: 0.08, particles: [[0, 0, 0, 1], [0.16, 0, 0, 1], [0.32, 0, 0, 1],"
    f" [0.32, 0.16, 0, 2]], position: [{0.15 * (i % 3) - 0.2}, {0.1 * (i % 2)}, {0.6 + 0.3 * i}],"
    f" orientation: [{0.1 * i}, 0.2, {0.05 * i}, 0.97], angular_velocity: [0.3, {-0.2 * i}, 0.5]}}\n"
    for i in range(6))

CAPSULES = """
world: {sleep: false}
bodies:
  - {name: log, shape: capsule, radius: 0.2, length: 1.6, position: [0, 0, 0.2],
     orientation: [0, 0.7071068, 0, 0.7071068], fixed: true}
  - {name: crate, shape: box, size: [0.8, 0.8, 0.4], position: [2.0, 0, 0.2], fixed: true}
  - {name: c1, shape: capsule, radius: 0.15, length: 0.8, mass: 2.0, position: [0.1, 0.05, 1.0],
     orientation: [0.05, 0.7, 0.02, 0.71], angular_velocity: [0.2, 0.1, -0.3]}
  - {name: c2, shape: capsule, radius: 0.1, length: 0.6, mass: 1.0, position: [2.05, 0.1, 1.2],
     orientation: [0.3, 0.1, 0.0, 0.95]}
  - {name: c3, shape: capsule, radius: 0.1, length: 0.6, mass: 1.0, position: [0.0, 0.0, 2.0],
     orientation: [0.0, 0.0, 0.0, 1.0], linear_velocity: [0.0, 0.0, -1.0]}
  - {name: ball, shape: sphere, radius: 0.15, mass: 1.0, position: [-0.5, 0.02, 1.5], restitution: 0.5}
  - {name: c4, shape: capsule, radius: 0.12, length: 0.5, mass: 1.0, position: [2.3, -0.2, 0.9],
     orientation: [0.0, 0.7071068, 0.0, 0.7071068], restitution: 0.3}
"""

JIT_PARITY_PLACES = {"ball": (1.6, 1.4, 0.32), "crate": (5.15, 0.0, 0.28), "capsule": (5.0, 0.0, 0.78),
                     "tetromino": (1.8, 2.0, 0.18)}


def pile_scene(count: int = 200, seed: int = 7) -> str:
    """bench_rigid's pile: spheres, boxes, capsules and particle bodies dropped into a bin."""
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


CASES = (*BUILTIN, "contact_kernels", "particles", "capsules", "pile", "explicit_euler", "symplectic_euler", "rk4",
         "wrenches", "teleport")


def _world(case: str):
    """The World of a case, and what to do before each tick (``before(world, tick)``) or None."""
    import yaml

    from cgp_core import World
    from cgp_core.scene import load_scene, parse_scene, resolve_scene

    if case in BUILTIN:
        return World(load_scene(case)), None
    if case == "particles":
        return World(parse_scene(PARTICLES)), None
    if case == "capsules":
        return World(parse_scene(CAPSULES)), None
    if case == "pile":
        return World(parse_scene(pile_scene())), None
    if case in ("explicit_euler", "symplectic_euler", "rk4"):
        data = yaml.safe_load(resolve_scene("default").read_text())
        data["world"]["integrator"] = case
        data["flocks"] = []
        return World(parse_scene(yaml.safe_dump(data))), None
    world = World(load_scene("default"))
    world.flocks = []
    if case == "contact_kernels":
        world.sleep_enabled = False
        names, state = world.body_model.names, world.body_state
        for name, xyz in JIT_PARITY_PLACES.items():
            state.position[names.index(name)] = xyz
        state.linear_momentum[names.index("ball")] = (0.6, 1.0, -2.0)
        return world, None
    if case == "wrenches":
        def before(w, tick):
            if tick % 7 == 0:
                w.apply_wrench("crate", (30.0, -10.0, 50.0), point=(-2.1, 1.2, 2.9), torque=(1.0, 2.0, -1.0))
            if tick % 11 == 0:
                w.apply_wrench("capsule", (0.0, 20.0, 5.0), point=(0.0, 0.0, 0.4), frame="capsule", duration=0.05)
            if tick == 3:
                w.apply_wrench("tetromino", (2.0, 0.0, 0.0), torque=(0.0, 0.0, 0.5), frame="body", duration=-1.0)
            if tick == 200:
                w.clear_wrenches()
        return world, before
    if case == "teleport":
        def before(w, tick):
            if tick in (40, 160):
                w.set_body_state("crate", (0.5, -1.0, 2.0 + tick / 100), (0.1, 0.3, 0.2, 0.927362),
                                 linear_velocity=(1.0, 0.5, 0.0), angular_velocity=(3.0, -2.0, 1.5))
                w.set_body_state("tetromino", (-1.0, 1.0, 1.5), (0.0, 0.0, 0.38268343, 0.92387953),
                                 angular_velocity=(0.5, 0.5, 4.0))
        return world, before
    raise ValueError(f"unknown case {case!r}; cases: {', '.join(CASES)}")


def run_case(case: str, ticks: int, out: str) -> None:
    """Step a case and save what it recorded (the child side of ``bits``)."""
    world, before = _world(case)
    record: dict[str, list] = {}

    def keep(name, value):
        record.setdefault(name, []).append(np.array(value, copy=True))

    for tick in range(ticks):
        if before is not None:
            before(world, tick)
        world.step()
        s = world.body_state
        for name in ("position", "orientation", "linear_momentum", "angular_momentum"):
            keep(f"body.{name}", getattr(s, name))
        if s.rotation is not None:
            keep("body.rotation", s.rotation)
        keep("contacts", [world.solver.stats.get("contacts", 0)])
        for k, flock in enumerate(world.flocks):
            keep(f"flock{k}.positions", flock.positions)
            keep(f"flock{k}.velocities", flock.velocities)
            keep(f"flock{k}.orientations", flock.orientations)
        if case == "teleport":
            for name in ("crate", "tetromino"):
                e = world.entity_state(name)
                keep(f"entity.{name}", np.concatenate([e.position, e.orientation, e.linear_velocity,
                                                       e.angular_velocity, e.linear_acceleration,
                                                       e.angular_acceleration]))
            keep("energy", world.body_state.kinetic_energy(world.body_model))
    np.savez(out, **{k: np.array(v) for k, v in record.items()})


# ---- the parent --------------------------------------------------------------------------------------------

def tree_of(spec: str, scratch: Path) -> Path:
    """A source tree: a directory as given, or a git revision of this checkout exported into ``scratch``."""
    path = Path(spec)
    if path.is_dir() and (path / "cgp_core").is_dir():
        return path.resolve()
    target = scratch / spec.replace("/", "_")
    if not (target / "cgp_core").is_dir():
        target.mkdir(parents=True, exist_ok=True)
        archive = subprocess.run(["git", "-C", str(HERE), "archive", spec], check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(target)], input=archive, check=True)
    return target


def tree_environment(tree: Path, **extra: str) -> dict:
    """This process's environment for a child that imports ``tree`` only (``PYTHONPATH``), plus ``extra``."""
    environment = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "CGP_SIM_JIT_ONLY")}
    environment.update(extra, PYTHONPATH=str(tree))
    return environment


def child_command(args: list[str]) -> list[str]:
    """This script run as a child with ``args`` (``-P``: the tree on ``PYTHONPATH``, not the checkout, is imported)."""
    return [sys.executable, "-P", str(Path(__file__).resolve()), *args]


def child(tree: Path, args: list[str], env: dict | None = None, timeout: float = 3600) -> subprocess.CompletedProcess:
    done = subprocess.run(child_command(args), env=tree_environment(tree, **(env or {})), capture_output=True,
                          text=True, timeout=timeout, cwd=str(tree))
    if done.returncode != 0:
        raise RuntimeError(f"child {args} in {tree} failed:\n{done.stderr[-4000:]}")
    return done


def compare_bits(old: Path, new: Path, cases: list[str], ticks: int, scratch: Path) -> bool:
    identical = True
    for case in cases:
        n = ticks if case != "fish_school" else min(ticks, 120)
        results = {}
        for label, tree in (("old", old), ("new", new)):
            out = scratch / f"{case}.{label}.npz"
            child(tree, ["_run", case, str(n), str(out)])
            results[label] = dict(np.load(out))
        a, b = results["old"], results["new"]
        problems = []
        if sorted(a) != sorted(b):
            problems.append(f"recorded different arrays: {sorted(set(a) ^ set(b))}")
        for key in sorted(set(a) & set(b)):
            if a[key].shape != b[key].shape:
                problems.append(f"{key}: shapes {a[key].shape} / {b[key].shape}")
            elif not np.array_equal(a[key], b[key]):
                differs = np.flatnonzero([not np.array_equal(x, y) for x, y in zip(a[key], b[key])])
                problems.append(f"{key}: differs from tick {differs[0] + 1} on (largest |Δ| "
                                f"{np.nanmax(np.abs(a[key] - b[key])):.3g})")
        size = sum(v.size for v in a.values())
        print(f"{case:17s} {n:4d} ticks  {size:>10,d} numbers  "
              f"{'bit-identical' if not problems else 'DIFFERENT: ' + '; '.join(problems)}", flush=True)
        identical &= not problems
    return identical


# the speed cases (child side): a world and its name; timed tick by tick after a warm-up
SPEED_CASES = ("default_bodies", "default", "pile", "sphere_pile", "boids_15k", "hull_pile")


def speed_stepper(case: str):
    """What one timed step of a speed case is, with how many steps to warm up and to time."""
    from cgp_core import World
    from cgp_core.boids import Flock, FlockParams
    from cgp_core.scene import load_scene, parse_scene

    if case == "default_bodies":
        world = World(load_scene("default"))
        world.flocks = []
        world.sleep_enabled = False
        return world.step, 60, 600
    if case == "default":  # what `make run` steps: the default scene as it is, its 300 fish and sleeping on
        return World(load_scene("default")).step, 0, 300
    if case == "pile":
        return World(parse_scene(pile_scene())).step, 0, 240
    if case == "sphere_pile":  # the built-in scene (~2,500 contacts, one-point manifolds: the regions' case)
        return World(load_scene("sphere_pile")).step, 0, 240
    if case == "boids_15k":
        # bench_boids' flock: 15,000 default boids spawned in a cube, a soft-walled box three times its size
        side = (15_000 / 0.08) ** (1.0 / 3.0)
        flock = Flock(FlockParams(count=15_000, seed=0, spawn_center=[0.0, 0.0, 1.5 * side + 1],
                                  spawn_extent=[side, side, side], bounds_min=[-1.5 * side, -1.5 * side, 0.5],
                                  bounds_max=[1.5 * side, 1.5 * side, 3.0 * side + 1]))
        return (lambda: flock.step(1.0 / 60.0)), 20, 100
    if case == "hull_pile":  # bench_convex_pile's 100 hulls while they fall and pile (its 0-3 s window)
        from benchmarks.bench_convex_pile import ours

        return ours(sleep=True).step, 10, 150
    raise ValueError(case)


def warmed_stepper(case: str):
    """:func:`speed_stepper`'s step, already taken its warm-up steps (at least 3), and how many steps to time."""
    step, warm, steps = speed_stepper(case)
    for _ in range(max(warm, 3)):
        step()
    return step, steps


def run_speed(case: str) -> None:
    sys.path.insert(0, str(HERE / "benchmarks"))
    from common import speed_probe

    step, steps = warmed_stepper(case)
    probe = speed_probe()
    times = np.empty(steps)
    for k in range(steps):
        t0 = time.perf_counter()
        step()
        times[k] = time.perf_counter() - t0
    print(json.dumps({"median_ms": float(np.median(times) * 1e3), "p90_ms": float(np.percentile(times, 90) * 1e3),
                      "probe": probe}))


def run_chunks(case: str) -> None:
    """``speed --paired``'s child: for each line ``go`` on stdin, the case built afresh, warmed up and timed over its
    steps; prints the mean ms a step."""
    print("ready", flush=True)
    for line in sys.stdin:
        if line.strip() != "go":
            break
        step, steps = warmed_stepper(case)
        t0 = time.perf_counter()
        for _ in range(steps):
            step()
        print((time.perf_counter() - t0) / steps * 1e3, flush=True)


def _probe(probes: list[dict]) -> str:
    return (f"{np.median([p['numpy_ms'] for p in probes]):.1f}/"
            f"{np.median([p['python_ms'] for p in probes]):.1f}")


def compare_speed(old: Path, new: Path, rounds: int, cases: list[str]) -> dict:
    table: dict = {case: {"old": [], "new": [], "probe_old": [], "probe_new": []} for case in cases}
    for r in range(rounds):
        order = (("old", old), ("new", new)) if r % 2 == 0 else (("new", new), ("old", old))
        for case in cases:
            for label, tree in order:
                result = json.loads(child(tree, ["_speed", case]).stdout.strip().splitlines()[-1])
                table[case][label].append(result["median_ms"])
                table[case][f"probe_{label}"].append(result["probe"])
        print(f"round {r + 1}/{rounds} done", flush=True)
    for case, row in table.items():
        old_ms, new_ms = np.median(row["old"]), np.median(row["new"])
        ratios = np.array(row["new"]) / np.array(row["old"])
        print(f"{case:15s} old {old_ms:8.3f} ms  new {new_ms:8.3f} ms  new/old {new_ms / old_ms:5.3f} "
              f"(per round {' '.join(f'{x:.3f}' for x in ratios)}); speed probe numpy/python ms: old "
              f"{_probe(row['probe_old'])}, new {_probe(row['probe_new'])}")
    return table


def compare_paired(old: Path, new: Path, rounds: int, cases: list[str]) -> dict:
    """``speed --paired``: per case, one long-lived child per tree, the two timing the same steps in turn (old, new,
    new, old ...; ``rounds`` pairs), so that a slow phase of the machine falls on both sides of a pair.  Per-round
    child processes (the plain ``speed``) saw per-round ratios of 0.72-1.33 for one unchanged case on this machine;
    pairs of chunks taken seconds apart resolve a few per cent."""
    sys.path.insert(0, str(HERE / "benchmarks"))
    from common import speed_probe

    table: dict = {}
    for case in cases:
        probe = speed_probe()
        kids = {}
        for label, tree in (("old", old), ("new", new)):
            kids[label] = subprocess.Popen(child_command(["_chunks", case]), cwd=str(tree), env=tree_environment(tree),
                                           stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        try:
            for kid in kids.values():
                if kid.stdout.readline().strip() != "ready":
                    raise RuntimeError(f"{case}: a child did not start")
            times: dict = {"old": [], "new": []}
            for r in range(rounds):
                for label in (("old", "new") if r % 2 == 0 else ("new", "old")):
                    kids[label].stdin.write("go\n")
                    kids[label].stdin.flush()
                    times[label].append(float(kids[label].stdout.readline()))
        finally:
            for kid in kids.values():
                kid.kill()
                kid.wait()
        o, n = np.array(times["old"]), np.array(times["new"])
        ratios = n / o
        table[case] = {"old_ms": o.tolist(), "new_ms": n.tolist(), "probe": probe}
        print(f"{case:15s} old {np.median(o):8.4f} ms  new {np.median(n):8.4f} ms a step (medians of {rounds}); "
              f"new/old: median of the pairs {np.median(ratios):.3f}, of the best {n.min() / o.min():.3f}, "
              f"pairs where new is faster {np.mean(ratios < 1):.0%}; speed probe numpy/python ms before "
              f"{probe['numpy_ms']:.1f}/{probe['python_ms']:.1f}", flush=True)
    return table


def compare_compile(old: Path, new: Path, rounds: int) -> dict:
    sys.path.insert(0, str(HERE / "benchmarks"))
    from common import speed_probe

    table: dict = {"old": [], "new": []}
    for r in range(rounds):
        order = (("old", old), ("new", new)) if r % 2 == 0 else (("new", new), ("old", old))
        for label, tree in order:
            with tempfile.TemporaryDirectory() as cache:
                probe = speed_probe()
                t0 = time.perf_counter()
                done = subprocess.run([sys.executable, "-P", "-m", "cgp_core.warmup"],
                                      env=tree_environment(tree, NUMBA_CACHE_DIR=cache), cwd=str(tree),
                                      capture_output=True, text=True, timeout=3600)
                elapsed = time.perf_counter() - t0
                if done.returncode != 0:
                    raise RuntimeError(done.stderr[-3000:])
                table[label].append(elapsed)
                print(f"{label}: cold warm-up {elapsed:.1f} s (speed probe numpy/python ms: {_probe([probe])})",
                      flush=True)
    print(f"cold compile: old {np.median(table['old']):.1f} s, new {np.median(table['new']):.1f} s, "
          f"new/old {np.median(table['new']) / np.median(table['old']):.3f}")
    return table


def main(argv: list[str]) -> int:
    if argv and argv[0] == "_run":
        run_case(argv[1], int(argv[2]), argv[3])
        return 0
    if argv and argv[0] == "_speed":
        run_speed(argv[1])
        return 0
    if argv and argv[0] == "_chunks":
        run_chunks(argv[1])
        return 0
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=("bits", "speed", "compile"))
    parser.add_argument("--old", default="ee7b2f6", help="git revision or tree directory (default ee7b2f6)")
    parser.add_argument("--new", default=str(HERE), help="tree directory (default: this checkout)")
    parser.add_argument("--ticks", type=int, default=300)
    parser.add_argument("--cases", nargs="*", default=None,
                        help=f"bits: a subset of {', '.join(CASES)}; speed: of {', '.join(SPEED_CASES)}")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--paired", action="store_true",
                        help="speed: one long-lived child per tree and case, timing the same steps in turn "
                             "(--rounds pairs; 20-30 resolve a few per cent on this machine)")
    parser.add_argument("--scratch", default=None, help="where the exported tree and the results go (default: a "
                                                        "temporary directory, removed afterwards)")
    args = parser.parse_args(argv)
    scratch = Path(args.scratch or tempfile.mkdtemp(prefix="cgp_compare_"))
    scratch.mkdir(parents=True, exist_ok=True)
    try:
        old, new = tree_of(args.old, scratch), tree_of(args.new, scratch)
        print(f"old: {old}\nnew: {new}", flush=True)
        if args.what == "bits":
            return 0 if compare_bits(old, new, args.cases or list(CASES), args.ticks, scratch) else 1
        if args.what == "speed" and args.paired:
            compare_paired(old, new, args.rounds, args.cases or list(SPEED_CASES))
        elif args.what == "speed":
            compare_speed(old, new, args.rounds, args.cases or list(SPEED_CASES))
        else:
            compare_compile(old, new, args.rounds)
        return 0
    finally:
        if args.scratch is None:
            shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

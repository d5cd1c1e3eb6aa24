"""Benchmark: spheres falling into a box (issue 7's rigid-body figure), and the broad phases' scaling.

Scene: ``n`` spheres (r = 0.1 m, 1 kg, μ = 0.5, e = 0.3 — the scene defaults) dropped from a jittered lattice
into a 5 × 5 m box: the ground plane z = 0 plus four fixed wall boxes (0.2 m thick, 1 m high), sub-step
h = 1/240 s, gravity −9.81 m/s².  Measured per step of :func:`cgp_core.dynamics.step_bodies` (symplectic
Euler): median wall time in the first second (t < 1 s: falling, first impacts) and once resting
(the last ``--rest-steps`` steps of ``--seconds`` simulated seconds), the deepest and the mean penetration
in the resting steps, and whether any sphere left the box (tunnelled through the ground or a wall).

If PyBullet is installed (``pip install pybullet``, a benchmark-only extra; ``--no-pybullet`` skips it) the
same scene is run in PyBullet with its default settings (only the time step 1/240 s — its default too —,
gravity, shapes, masses and materials are set), interleaved step by step in the same process, and its
timings are reported next to ours.

Also measured: the broad phases (grid, sweep and prune, brute force) on the resting pile, for the scaling
figure (cost vs body count).

Plain script: prints a table and writes ``benchmarks/results/contacts.json`` (layout and ``figures``:
``benchmarks/common.py``).  The targets (issue 7, 1,000 spheres): a resting step faster than PyBullet's
(measured in the same run, or the 24 ms measured on this machine when PyBullet is absent), no sphere out of
the box, resting penetration ≤ 1 % of r.

    .venv/bin/python benchmarks/bench_contacts.py [--quick] [--counts 100 1000] [--seconds 6] [--no-pybullet]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from common import Results, format_figures, format_stage_times, reset_stage_times, stage_times  # noqa: E402

from cgp_core.bodies import BodyModel, BodyState, Shape  # noqa: E402
from cgp_core.collision import BROAD_PHASES, CollisionDetector, Ground  # noqa: E402
from cgp_core.collision.primitives import build_collision_model, primitive_aabbs  # noqa: E402
from cgp_core.dynamics import step_bodies  # noqa: E402
from cgp_core.integrators import make_integrator  # noqa: E402
from cgp_core.solver import make_solver  # noqa: E402

RADIUS = 0.1
BOX = 5.0
WALL_THICKNESS = 0.2
WALL_HEIGHT = 1.0
H = 1.0 / 240.0
GRAVITY = np.array([0.0, 0.0, -9.81])
FRICTION = 0.5
RESTITUTION = 0.3
PYBULLET_RESTING_MS = 24.0  # issue 7, measured on this machine with PyBullet 3.2.7
PYBULLET_FIRST_SECOND_MS = 9.6


def sphere_start_positions(n: int, seed: int = 0) -> np.ndarray:
    """A jittered lattice with 0.3 m spacing filling the box from z = 0.5 m up."""
    rng = np.random.default_rng(seed)
    per_side = int((BOX - 2 * RADIUS - 0.2) / 0.3)
    layer = per_side * per_side
    idx = np.arange(n)
    ix, iy, iz = idx % per_side, (idx // per_side) % per_side, idx // layer
    span = (per_side - 1) * 0.3
    pos = np.column_stack((ix * 0.3 - span / 2, iy * 0.3 - span / 2, 0.5 + iz * 0.3)).astype(float)
    pos[:, :2] += rng.uniform(-0.04, 0.04, size=(n, 2))
    return pos


def walls():
    """Four fixed wall boxes around the 5 × 5 m floor: (centre, half extents)."""
    half = BOX / 2 + WALL_THICKNESS / 2
    t, hh, l = WALL_THICKNESS / 2, WALL_HEIGHT / 2, BOX / 2 + WALL_THICKNESS
    return [((half, 0, hh), (t, l, hh)), ((-half, 0, hh), (t, l, hh)),
            ((0, half, hh), (l, t, hh)), ((0, -half, hh), (l, t, hh))]


def build_scene(n: int, seed: int = 0) -> tuple[BodyModel, BodyState]:
    wall = walls()
    count = n + len(wall)
    shape = np.array([Shape.SPHERE] * n + [Shape.BOX] * len(wall), dtype=np.int8)
    radius = np.array([RADIUS] * n + [0.0] * len(wall))
    half = np.zeros((count, 3))
    half[n:] = [w[1] for w in wall]
    mass = np.ones(count)
    fixed = np.array([False] * n + [True] * len(wall))
    inertia = np.zeros((count, 3, 3))
    inertia[:] = np.eye(3) * 0.4 * RADIUS ** 2
    inv_inertia = np.linalg.inv(inertia)
    inv_inertia[fixed] = 0.0
    model = BodyModel(names=[f"s{i}" for i in range(n)] + [f"wall{i}" for i in range(len(wall))], shape=shape,
                      radius=radius, half_extents=half, mass=mass, inv_mass=np.where(fixed, 0.0, 1.0),
                      inertia_body=inertia, inv_inertia_body=inv_inertia,
                      restitution=np.full(count, RESTITUTION), friction=np.full(count, FRICTION), fixed=fixed,
                      particles=[None] * count, color=np.ones((count, 4)))
    position = np.zeros((count, 3))
    position[:n] = sphere_start_positions(n, seed)
    position[n:] = [w[0] for w in wall]
    orientation = np.tile([0.0, 0.0, 0.0, 1.0], (count, 1))
    state = BodyState(position=position, orientation=orientation, linear_momentum=np.zeros((count, 3)),
                      angular_momentum=np.zeros((count, 3)))
    return model, state


def escaped(position: np.ndarray, n: int) -> int:
    """Spheres outside the box: below the ground or beyond a wall's inner face."""
    p = position[:n]
    inner = BOX / 2 + 1e-3
    return int(np.count_nonzero((p[:, 2] < -1e-3) | (np.abs(p[:, 0]) > inner) | (np.abs(p[:, 1]) > inner)))


class Ours:
    name = "cgp_sim"

    def __init__(self, n, **solver_settings):
        self.n = n
        self.model, self.state = build_scene(n)
        self.integrator = make_integrator("symplectic_euler")
        self.solver = make_solver(**solver_settings)
        self.ground = Ground(friction=FRICTION, restitution=0.0)

    def step(self):
        step_bodies(self.model, self.state, self.integrator, self.solver, H, gravity=GRAVITY, ground=self.ground)

    def penetrations(self):
        """Penetration depth of every contact at the current poses (fresh detection, no margins)."""
        det = CollisionDetector(speculative_distance=0.0)
        c = det.detect(self.model, self.state, 1e-9, ground=self.ground,
                       velocity=np.zeros((self.model.count, 3)), angular_velocity=np.zeros((self.model.count, 3)))
        return np.maximum(-c.separation, 0.0)

    def positions(self):
        return self.state.position

    def max_speed(self):
        return float(np.linalg.norm(self.state.linear_velocity(self.model)[: self.n], axis=1).max())


class Bullet:
    name = "pybullet"

    def __init__(self, n):
        import pybullet as pb

        self.pb = pb
        self.n = n
        self.client = pb.connect(pb.DIRECT)
        c = self.client
        pb.setGravity(*GRAVITY, physicsClientId=c)
        pb.setTimeStep(H, physicsClientId=c)
        plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=c)
        ground = pb.createMultiBody(0, plane, physicsClientId=c)
        pb.changeDynamics(ground, -1, lateralFriction=FRICTION, restitution=0.0, physicsClientId=c)
        for centre, half in walls():
            shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=c)
            w = pb.createMultiBody(0, shape, basePosition=centre, physicsClientId=c)
            pb.changeDynamics(w, -1, lateralFriction=FRICTION, restitution=RESTITUTION, physicsClientId=c)
        sphere = pb.createCollisionShape(pb.GEOM_SPHERE, radius=RADIUS, physicsClientId=c)
        self.ids = []
        for p in sphere_start_positions(n):
            b = pb.createMultiBody(1.0, sphere, basePosition=p.tolist(), physicsClientId=c)
            pb.changeDynamics(b, -1, lateralFriction=FRICTION, restitution=RESTITUTION, physicsClientId=c)
            self.ids.append(b)

    def step(self):
        self.pb.stepSimulation(physicsClientId=self.client)

    def positions(self):
        return np.array([self.pb.getBasePositionAndOrientation(b, physicsClientId=self.client)[0]
                         for b in self.ids])

    def penetrations(self):
        pts = self.pb.getContactPoints(physicsClientId=self.client)
        return np.maximum(-np.array([p[8] for p in pts] or [0.0]), 0.0)

    def max_speed(self):
        return float(max(np.linalg.norm(self.pb.getBaseVelocity(b, physicsClientId=self.client)[0])
                         for b in self.ids))


def run_pile(n: int, seconds: float, rest_steps: int, with_bullet: bool) -> list[dict]:
    sims = [Ours(n)]
    if with_bullet:
        sims.append(Bullet(n))
    steps = int(round(seconds / H))
    first = int(round(1.0 / H))
    times = {s.name: np.zeros(steps) for s in sims}
    extra = {s.name: {"contacts": [], "manifolds": []} for s in sims}
    ours = sims[0]
    stages = {}
    reset_stage_times(ours.solver)
    for k in range(steps):
        if k == first:
            stages["first_second"] = stage_times(ours.solver, first)
        if k == steps - rest_steps:
            reset_stage_times(ours.solver)
        for s in sims:  # interleaved, so both see the same machine load
            t0 = time.perf_counter()
            s.step()
            times[s.name][k] = time.perf_counter() - t0
            if isinstance(s, Ours) and k >= steps - rest_steps:
                extra[s.name]["contacts"].append(s.solver.stats["contacts"])
                extra[s.name]["manifolds"].append(s.solver.stats["manifolds"])
    rows = []
    for s in sims:
        pen = s.penetrations()
        t = times[s.name] * 1e3
        row = {
            "engine": s.name, "spheres": n, "steps": steps,
            "first_second_ms": float(np.median(t[:first])),
            "resting_ms": float(np.median(t[-rest_steps:])),
            "max_penetration_mm": float(pen.max() * 1e3) if pen.size else 0.0,
            "mean_penetration_mm": float(pen[pen > 0].mean() * 1e3) if (pen > 0).any() else 0.0,
            "max_penetration_pct_radius": float(pen.max() / RADIUS * 100) if pen.size else 0.0,
            "escaped": escaped(s.positions(), n),
            "max_speed_end": s.max_speed(),
        }
        if extra[s.name]["contacts"]:
            row["contacts_resting"] = int(np.median(extra[s.name]["contacts"]))
            row["manifolds_resting"] = int(np.median(extra[s.name]["manifolds"]))
        if s is ours:  # where the step's time goes (mean ms per step, stage by stage; cgp_core.jit.StageProfile)
            row["stages_first_second_ms"] = stages.get("first_second", {})
            row["stages_resting_ms"] = stage_times(ours.solver, rest_steps)
        rows.append(row)
    return rows


def broadphase_scaling(counts) -> list[dict]:
    rows = []
    for n in counts:
        sim = Ours(n)
        for _ in range(int(2.0 / H)):  # let it settle into a pile
            sim.step()
        cm = build_collision_model(sim.model)
        lo, hi = primitive_aabbs(cm, sim.state.position, sim.state.rotation_matrices())
        lo -= 0.002
        hi += 0.002
        ref = None
        for name, fn in BROAD_PHASES.items():
            if name == "brute_force" and n > 2000:
                continue
            reps = []
            for _ in range(7):
                t0 = time.perf_counter()
                pairs = fn(lo, hi)
                reps.append(time.perf_counter() - t0)
            ref = pairs if ref is None else ref
            rows.append({"broad_phase": name, "bodies": n + 4, "pairs": int(len(pairs[0])),
                         "ms": float(np.median(reps) * 1e3)})
    return rows


def figures(out: Results, piles: list[dict]) -> None:
    """The issue-7 figures for 1,000 spheres, added to ``out`` (layout: ``benchmarks/common.py``)."""
    ours = next((r for r in piles if r["engine"] == "cgp_sim" and r["spheres"] == 1000), None)
    if ours is None:
        return
    bullet = next((r for r in piles if r["engine"] == "pybullet" and r["spheres"] == 1000), None)
    ref_rest = bullet["resting_ms"] if bullet else PYBULLET_RESTING_MS
    ref_first = bullet["first_second_ms"] if bullet else PYBULLET_FIRST_SECOND_MS
    source = "PyBullet, this run" if bullet else "PyBullet, issue 7's figure: not installed"
    out.figure("contacts_1k_resting", "1k spheres into a box: step once resting (median)", ours["resting_ms"], "ms",
               f"< {ref_rest:.1f} ({source})", ours["resting_ms"] < ref_rest, issue7=True,
               pybullet_ms=ref_rest, pybullet_source=source, ratio_pybullet_over_ours=ref_rest / ours["resting_ms"])
    out.figure("contacts_1k_escaped", "1k spheres into a box: spheres out of the box (tunnelled)", ours["escaped"],
               "", "0", ours["escaped"] == 0, issue7=True)
    out.figure("contacts_1k_penetration", "1k spheres into a box: resting penetration, max",
               ours["max_penetration_pct_radius"], "% of r", "<= 1", ours["max_penetration_pct_radius"] <= 1.0,
               issue7=True)
    out.figure("contacts_1k_first_second", "1k spheres into a box: step in the first second (median)",
               ours["first_second_ms"], "ms", f"< {ref_first:.1f} (reference)", ours["first_second_ms"] < ref_first,
               pybullet_ms=ref_first)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--counts", type=int, nargs="+", default=[100, 1000])
    ap.add_argument("--seconds", type=float, default=6.0, help="simulated time per run [s]")
    ap.add_argument("--rest-steps", type=int, default=240, help="steps at the end counted as 'resting'")
    ap.add_argument("--no-pybullet", action="store_true", help="skip PyBullet even if it is installed")
    ap.add_argument("--scaling", type=int, nargs="*", default=None,
                    help="sphere counts for the broad-phase scaling table (default 250 500 1000 2000 4000; "
                         "quick: 250 1000)")
    ap.add_argument("--quick", action="store_true", help="4 s simulated, 120 resting steps, a smaller scaling table")
    args = ap.parse_args(argv)
    if args.quick:
        args.seconds, args.rest_steps = min(args.seconds, 4.0), min(args.rest_steps, 120)
    if args.scaling is None:
        args.scaling = [250, 1000] if args.quick else [250, 500, 1000, 2000, 4000]
    out = Results("contacts", options=vars(args))

    with_bullet = False
    if not args.no_pybullet:
        try:
            import pybullet  # noqa: F401
            with_bullet = True
        except ImportError:
            print("PyBullet not installed (pip install pybullet): comparing with the issue's 24 ms instead")
    results = out.data
    results.update({"h": H, "piles": [], "broad_phase": [], "pybullet": None})
    if with_bullet:
        import pybullet

        results["pybullet"] = getattr(pybullet, "__version__", None) or _pybullet_version()
    for n in args.counts:
        results["piles"].extend(run_pile(n, args.seconds, args.rest_steps, with_bullet))
    results["broad_phase"] = broadphase_scaling(args.scaling) if args.scaling else []
    figures(out, results["piles"])

    print(f"\nSpheres (r = {RADIUS} m) into a {BOX:g} x {BOX:g} m box, h = 1/240 s, {args.seconds:g} s simulated")
    print(f"{'engine':10} {'spheres':>7} {'1st s ms':>9} {'rest ms':>8} {'max pen mm':>10} {'% r':>6} "
          f"{'mean pen mm':>11} {'escaped':>7} {'contacts':>8} {'manifolds':>9}")
    for r in results["piles"]:
        print(f"{r['engine']:10} {r['spheres']:7d} {r['first_second_ms']:9.2f} {r['resting_ms']:8.2f} "
              f"{r['max_penetration_mm']:10.3f} {r['max_penetration_pct_radius']:6.2f} "
              f"{r['mean_penetration_mm']:11.3f} {r['escaped']:7d} {r.get('contacts_resting', ''):>8} "
              f"{r.get('manifolds_resting', ''):>9}")
    for r in results["piles"]:
        for window in ("first_second", "resting"):
            if r.get(f"stages_{window}_ms"):
                print(f"  {r['spheres']} spheres, {window.replace('_', ' ')}: stages, mean ms per step")
                print(format_stage_times(r[f"stages_{window}_ms"]))
    if results["figures"]:
        print("\nIssue 7 figures")
        print(format_figures(results["figures"]))
    if results["broad_phase"]:
        print("\nBroad phase on the settled pile (AABBs + 2 mm), median of 7")
        print(f"{'method':16} {'bodies':>7} {'pairs':>7} {'ms':>8}")
        for r in results["broad_phase"]:
            print(f"{r['broad_phase']:16} {r['bodies']:7d} {r['pairs']:7d} {r['ms']:8.3f}")
    path = out.write()
    print(f"\nwrote {path.relative_to(ROOT)}")
    return 0


def _pybullet_version() -> str | None:
    try:
        from importlib.metadata import version

        return version("pybullet")
    except Exception:  # noqa: BLE001 - the version is informative only
        return None


if __name__ == "__main__":
    raise SystemExit(main())

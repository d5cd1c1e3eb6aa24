"""Boid flock step cost on this machine (issue 4, and the boid figures of issues 7 and 12).

Figures (targets from issues 7 and 12 and the budget split):
- step at 100k boids <= 80 ms, and cost(100k) / cost(10k) <= 14 (near-linear) — issue 12 keeps them;
- step at 10k and 15k boids: 15k <= 7 ms (the whole 60 Hz tick at 15k, publishing included, is 16.7 ms);
- at 4k boids, >= 100x faster than a naive O(N²) numpy step with the same rules (vectorized over all pairs,
  written below, checked against the flock on a small case before it is timed);
- the parallel kernels' gain: the 15k step on numba's two threads vs one (side by side).

Realistic density: the benchmark flocks are spawned at the density of the *default* flock's steady state
(300 default boids run for 20 s; the mean number of neighbours within d gives the density), warmed up for
``--warmup`` seconds of sim time, then timed.  Every timing reports the neighbours per boid measured while it
ran, and the backend.  Each row is a whole ``Flock.step`` (neighbours, rules, walls, integration, frames and
the orientation quaternions), median over the timed steps, on numba's default threads (both cores; flocks of
fewer than 2,000 boids run on one, see ``cgp_core/jit.py``).  Grid and KD-tree / naive runs are interleaved
round by round (the machine is shared).

The scaling figure cost(100k) / cost(10k) is measured with the 10k and 100k flocks interleaved round by round.
Writes a table to stdout and ``benchmarks/results/boids.json`` (layout: ``benchmarks/common.py``).
Run: ``.venv/bin/python benchmarks/bench_boids.py`` (``--quick``: fewer steps, no 100k KD-tree).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numba  # noqa: E402

from cgp_core.bodies import BodyModel, BodyState, Shape  # noqa: E402
from cgp_core.boids import Flock, FlockParams, Obstacles, make_search  # noqa: E402
from cgp_core.boids.frames import frames_to_quaternions, update_frames  # noqa: E402
from cgp_core.boids.rules import COHESION_GATE  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import Results, format_figures  # noqa: E402

DT = 1.0 / 60.0
TARGET_15K_MS = 7.0
TARGET_100K_MS = 80.0
TARGET_SCALING = 14.0
TARGET_NAIVE_RATIO = 100.0


# ---- the naive baseline -------------------------------------------------------------------------------

def naive_step(flock: Flock, dt: float) -> None:
    """One step of ``flock`` with the same rules as ``Flock.step`` (no obstacles), but every pair of boids
    handled as a dense N × N matrix: what a vectorized numpy implementation without a spatial structure
    looks like.  O(N²) time and memory."""
    p = flock.params
    x, v = flock._x, flock._v  # (N, 3): the state itself
    offset = x[None, :, :] - x[:, None, :]  # (N, N, 3): x_j − x_i
    dist2 = np.einsum("ijk,ijk->ij", offset, offset)
    within = dist2 < p.radius**2
    np.fill_diagonal(within, False)
    distance = np.sqrt(dist2)
    heading = flock._heading
    if p.fov_deg < 360.0:
        visible = within & (np.einsum("ik,ijk->ij", heading, offset) > p.cos_half_fov * distance)
    else:
        visible = within
    count = visible.sum(axis=1)
    has = count > 0
    safe = np.maximum(count, 1)[:, None]
    crowded = (within & (dist2 < (COHESION_GATE * p.separation_radius) ** 2)).any(axis=1)
    pulls = has & ~crowded if p.separation_weight > 0 else has
    cohesion = (visible @ x / safe - x) * pulls[:, None]
    close = within & (dist2 < p.separation_radius**2)
    weight = np.where(close, (p.separation_radius - distance) / np.where(close, distance, 1.0), 0.0)
    separation = -np.einsum("ij,ijk->ik", weight, offset)
    alignment = (visible @ v / safe - v) * has[:, None]
    wanted = p.cohesion_weight * cohesion + p.separation_weight * separation + p.alignment_weight * alignment
    margin = max(p.bounds_margin, 1e-9)
    needed = (np.maximum(p.bounds_min + margin - x, 0.0) - np.maximum(x - (p.bounds_max - margin), 0.0)) * (
        p.bounds_strength / margin) if p.bounds_mode == "soft" else np.zeros_like(x)
    needed_norm = np.linalg.norm(needed, axis=1, keepdims=True)
    needed *= np.minimum(1.0, p.max_acceleration / np.maximum(needed_norm, 1e-300))
    budget = np.maximum(p.max_acceleration - np.linalg.norm(needed, axis=1, keepdims=True), 0.0)
    wanted_norm = np.linalg.norm(wanted, axis=1, keepdims=True)
    wanted *= np.minimum(1.0, budget / np.maximum(wanted_norm, 1e-300))
    v += (needed + wanted) * dt
    speed = np.linalg.norm(v, axis=1, keepdims=True)
    v *= np.clip(speed, p.min_speed, p.max_speed) / speed
    x += v * dt
    if p.bounds_mode == "soft":
        low, high = x < p.bounds_min, x > p.bounds_max
        np.clip(x, p.bounds_min, p.bounds_max, out=x)
        v[low] = np.maximum(v[low], 0.0)
        v[high] = np.minimum(v[high], 0.0)
    heading, dorsal = update_frames(flock._heading.T, flock._dorsal.T, v.T, dt, p.bank_gain,
                                    p.orientation_time_constant)
    flock._heading[:], flock._dorsal[:] = heading.T, dorsal.T
    flock._q[:] = frames_to_quaternions(heading, dorsal).T


def check_naive_matches(params: FlockParams) -> float:
    """Largest position difference after 30 steps, naive vs Flock.step, from the same state (must be tiny:
    same rules, different summation order)."""
    a, b = Flock(params), Flock(params)
    for _ in range(30):
        a.step(DT)
        naive_step(b, DT)
    return float(np.abs(a.positions - b.positions).max())


# ---- flocks at the steady-state density ---------------------------------------------------------------

def steady_state_neighbors(seconds: float = 20.0) -> float:
    """Mean neighbours within d per boid of the default flock, averaged over the last quarter of the run."""
    flock = Flock(FlockParams())
    samples = []
    steps = int(seconds / DT)
    for k in range(steps):
        flock.step(DT)
        if k >= 0.75 * steps:
            samples.append(flock.mean_neighbors)
    return float(np.mean(samples))


def make_flock(count: int, density: float, backend: str, seed: int = 0) -> Flock:
    """``count`` default boids spawned in a cube at ``density`` [1/m³], in a soft-walled box 3x its size."""
    side = (count / density) ** (1.0 / 3.0)
    params = FlockParams(count=count, seed=seed, neighbor_search=backend, spawn_center=[0.0, 0.0, 1.5 * side + 1],
                         spawn_extent=[side, side, side], bounds_min=[-1.5 * side, -1.5 * side, 0.5],
                         bounds_max=[1.5 * side, 1.5 * side, 3.0 * side + 1])
    return Flock(params)


def random_bodies(count: int, flock: Flock, seed: int = 0) -> Obstacles:
    """``count`` fixed bodies (spheres, boxes, capsules in turn, 0.5–1.5 m) scattered through the flock's
    spawn box: the '+ 20 bodies' of issue 7's tick, as the flock sees them."""
    rng = np.random.default_rng(seed)
    p = flock.params
    low = p.spawn_center - 0.5 * p.spawn_extent
    high = p.spawn_center + 0.5 * p.spawn_extent
    shape = np.array([(Shape.SPHERE, Shape.BOX, Shape.CAPSULE)[k % 3] for k in range(count)], dtype=np.int8)
    size = rng.uniform(0.5, 1.5, count)
    half_extents = np.zeros((count, 3))
    half_extents[shape == Shape.BOX] = size[shape == Shape.BOX, None] * [1.0, 0.6, 0.4]
    half_extents[shape == Shape.CAPSULE, 2] = size[shape == Shape.CAPSULE]
    radius = np.where(shape == Shape.BOX, 0.0, 0.5 * size)
    model = BodyModel(names=[f"b{k}" for k in range(count)], shape=shape, radius=radius, half_extents=half_extents,
                      mass=np.ones(count), inv_mass=np.zeros(count), inertia_body=np.tile(np.eye(3), (count, 1, 1)),
                      inv_inertia_body=np.zeros((count, 3, 3)), restitution=np.zeros(count),
                      friction=np.zeros(count), fixed=np.ones(count, bool), particles=[None] * count,
                      color=np.ones((count, 4)))
    q = rng.normal(size=(count, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    state = BodyState(position=rng.uniform(low, high, (count, 3)), orientation=q,
                      linear_momentum=np.zeros((count, 3)), angular_momentum=np.zeros((count, 3)))
    return Obstacles.from_bodies(model, state, ground=True)


class Runner:
    """A flock (or the naive baseline on one) warmed up and timed a few steps at a time, so variants can
    be interleaved."""

    def __init__(self, count: int, density: float, backend: str, warmup_s: float, bodies: int = 0,
                 threads: int | None = None):
        self.backend = backend
        self.threads = threads
        self.flock = make_flock(count, density, "grid")
        self.obstacles = random_bodies(bodies, self.flock) if bodies else None
        self.label = backend if not bodies else f"{backend}+{bodies} bodies"
        if threads is not None:
            self.label += f", {threads} thread{'s' if threads > 1 else ''}"
        for _ in range(int(warmup_s / DT)):
            self.flock.step(DT, self.obstacles)  # the warm-up uses the grid (same seed: same start for every backend)
        if backend not in ("grid", "naive"):
            self.flock._search = make_search(backend)
        self.times: list[float] = []
        self.neighbors: list[float] = []
        self.steps_run = 0

    def _step(self) -> None:
        if self.backend == "naive":
            naive_step(self.flock, DT)
        elif self.threads is not None:
            # the flock picks its threads per step (jit.threads_for); pin them for this comparison
            import cgp_core.boids.flock as flock_module

            original = flock_module.threads_for
            flock_module.threads_for = lambda items: _fixed_threads(self.threads)
            try:
                self.flock.step(DT, self.obstacles)
            finally:
                flock_module.threads_for = original
        else:
            self.flock.step(DT, self.obstacles)

    def run(self, steps: int) -> None:
        """One untimed step (caches and the allocator settle after the other variant ran: the naive step
        allocates gigabytes), then ``steps`` timed ones."""
        flock = self.flock
        self._step()
        self.steps_run += steps + 1
        for _ in range(steps):
            start = time.perf_counter()
            self._step()
            _ = flock.orientations  # part of the step's output (computed in step)
            self.times.append(time.perf_counter() - start)
            if self.backend != "naive":
                self.neighbors.append(flock.mean_neighbors)

    def row(self) -> dict:
        t = np.array(self.times) * 1e3
        row = {"boids": self.flock.count, "backend": self.label, "ms_median": float(np.median(t)),
               "ms_mean": float(np.mean(t)), "ms_max": float(np.max(t)), "ms_p99": float(np.percentile(t, 99)),
               "steps": len(t)}
        if self.neighbors:
            row["neighbors_per_boid"] = float(np.mean(self.neighbors))
        return row


class _fixed_threads:
    """Context manager: numba's threads pinned (the benchmark's one-thread vs two-thread comparison)."""

    def __init__(self, count: int):
        self.count = count

    def __enter__(self):
        self.previous = numba.get_num_threads()
        numba.set_num_threads(self.count)

    def __exit__(self, *exc):
        numba.set_num_threads(self.previous)


def interleaved(runners: list[Runner], rounds: int, steps: int | list[int]) -> None:
    steps = steps if isinstance(steps, list) else [steps] * len(runners)
    for _ in range(rounds):
        for runner, n in zip(runners, steps):
            runner.run(n)


def breakdown(flock: Flock, obstacles: Obstacles | None = None, repeats: int = 15) -> dict:
    """Where a step's time goes (medians of the stages called one by one on the current state)."""
    from cgp_core.boids import rules
    from cgp_core.boids.frames import low_pass_weight, quaternions_rows, update_frames_rows

    def median_ms(fn):
        fn()
        t = []
        for _ in range(repeats):
            s = time.perf_counter()
            fn()
            t.append(time.perf_counter() - s)
        return float(np.median(t) * 1e3)

    p = flock.params
    out = {"neighbour search (grid, half shell)": median_ms(flock.neighbors)}
    neighbors = flock.neighbors()
    out["neighbour sums (Reynolds' rules)"] = median_ms(lambda: rules.neighbor_sums(
        neighbors, flock._x, flock._v, flock._heading, p.separation_radius, p.cos_half_fov, flock.period))
    if obstacles is not None:
        out["obstacle query"] = median_ms(lambda: obstacles.query(flock._x.T, 2.5))
    heading, dorsal, q = flock._heading.copy(), flock._dorsal.copy(), flock._q.copy()
    out["frames + quaternions"] = median_ms(lambda: (
        update_frames_rows(heading, dorsal, flock._v, DT, p.bank_gain,
                           low_pass_weight(DT, p.orientation_time_constant)),
        quaternions_rows(heading, dorsal, q)))
    out["whole step"] = median_ms(lambda: flock.step(DT, obstacles))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps, skip the 100k KD-tree run")
    parser.add_argument("--warmup", type=float, default=3.0, help="sim seconds before timing (default 3)")
    args = parser.parse_args(argv)
    rounds, steps = (3, 10) if args.quick else (5, 20)
    out = Results("boids", options=vars(args))

    print("steady state of the default flock (300 boids, 20 s) ...", flush=True)
    k_steady = steady_state_neighbors()
    radius = FlockParams().radius
    density = k_steady / (4.0 / 3.0 * math.pi * radius**3)
    print(f"  {k_steady:.1f} neighbours within d = {radius} m  ->  density {density:.3f} boids/m³", flush=True)

    naive_error = check_naive_matches(FlockParams(count=300, seed=1))
    print(f"  naive baseline vs Flock.step after 30 steps: max position difference {naive_error:.2e} m")

    rows = []

    def measure(specs, rounds_, steps_):
        """``specs``: (count, backend, bodies[, threads]) runners interleaved round by round (so ratios between
        them are measured under the same machine load)."""
        print(", ".join(f"{spec[0]} {spec[1]}{f'+{spec[2]} bodies' if spec[2] else ''}"
                        + (f" on {spec[3]} thread(s)" if len(spec) > 3 else "") for spec in specs) + " ...",
              flush=True)
        runners = [Runner(spec[0], density, spec[1], args.warmup, spec[2], *spec[3:]) for spec in specs]
        interleaved(runners, rounds_, steps_)
        for r in runners:
            rows.append(r.row())
        return runners

    measure([(1_000, "grid", 0), (1_000, "kdtree", 0), (1_000, "brute", 0)], rounds, steps)
    naive_runners = measure([(4_000, "grid", 0), (4_000, "naive", 0)], rounds, [steps, 1])
    runners_15k = measure([(15_000, "grid", 0), (15_000, "kdtree", 0), (15_000, "grid", 20)], rounds, steps)
    threads = numba.config.NUMBA_NUM_THREADS
    runners_threads = measure([(15_000, "grid", 0, 1), (15_000, "grid", 0, threads)], rounds, steps)
    # 10k and 100k interleaved: their ratio is the scaling figure
    big = [(10_000, "grid", 0), (100_000, "grid", 0)] + ([] if args.quick else [(10_000, "kdtree", 0),
                                                                                (100_000, "kdtree", 0)])
    runners_big = measure(big, max(2, rounds - 2) if args.quick else rounds - 1,
                          [steps, steps] + ([] if args.quick else [max(2, steps // 4), 2]))

    def find(count, backend):
        return next(r for r in rows if r["boids"] == count and r["backend"] == backend)

    grid_4k = naive_runners[0]
    naive_ratio = float(find(4_000, "naive")["ms_median"] / np.median(np.array(grid_4k.times) * 1e3))
    t10k, t100k, t15k = (find(n, "grid")["ms_median"] for n in (10_000, 100_000, 15_000))
    t15k_bodies = find(15_000, "grid+20 bodies")["ms_median"]
    out.figure("boids_100k", "boid step at 100k boids (grid, median)", t100k, "ms", f"<= {TARGET_100K_MS:g}",
               t100k <= TARGET_100K_MS, issue7=True, issue12=True,
               neighbors_per_boid=find(100_000, "grid")["neighbors_per_boid"])
    out.figure("boids_scaling_100k_10k", "boid step cost(100k) / cost(10k)", t100k / t10k, "x",
               f"<= {TARGET_SCALING:g}", t100k / t10k <= TARGET_SCALING, issue7=True, issue12=True)
    out.figure("boids_naive_ratio_4k", "naive O(N²) numpy step / our step, 4k boids", naive_ratio, "x",
               f">= {TARGET_NAIVE_RATIO:g}", naive_ratio >= TARGET_NAIVE_RATIO, issue7=True)
    out.figure("boids_15k", "boid step at 15k boids (grid, median; budget split)", t15k, "ms",
               f"<= {TARGET_15K_MS:g}", t15k <= TARGET_15K_MS)
    out.figure("boids_15k_bodies", "boid step at 15k boids + 20 fixed bodies (median)", t15k_bodies, "ms",
               f"<= {TARGET_15K_MS:g}", t15k_bodies <= TARGET_15K_MS)
    out.figure("boids_10k", "boid step at 10k boids (grid, median)", t10k, "ms", "(reference)", None)
    one, both = (float(np.median(r.times) * 1e3) for r in runners_threads)
    out.figure("boids_15k_threads", f"boid step at 15k: 1 thread / {threads} threads (parallel kernels' gain)",
               one / both, "x", "(reference)", None, one_thread_ms=one, all_threads_ms=both)
    figures = out.data["figures"]

    print()
    print(f"{'boids':>7}  {'backend':24} {'ms/step':>9} {'mean':>8} {'p99':>8} {'max':>8} {'nbrs/boid':>10}")
    for r in sorted(rows, key=lambda r: (r["boids"], r["backend"])):
        print(f"{r['boids']:>7}  {r['backend']:24} {r['ms_median']:9.2f} {r['ms_mean']:8.2f} {r['ms_p99']:8.2f} "
              f"{r['ms_max']:8.2f} {r.get('neighbors_per_boid', float('nan')):10.1f}")
    print()
    print(format_figures(figures))

    parts = {"15k": breakdown(runners_15k[0].flock), "15k + 20 bodies": breakdown(runners_15k[2].flock,
                                                                                  runners_15k[2].obstacles),
             "100k": breakdown(runners_big[1].flock, repeats=5)}
    print()
    for size, stages in parts.items():
        print(f"breakdown at {size} (ms, medians of the stages run one by one):")
        for name, ms in stages.items():
            print(f"  {name:55} {ms:8.2f}")

    out.data.update({"steady_state": {"neighbors_per_boid": k_steady, "density_per_m3": density, "radius_m": radius},
                     "naive_check_max_position_difference_m": naive_error,
                     "rows": sorted(rows, key=lambda r: (r["boids"], r["backend"])),
                     "breakdown_ms": parts, "warmup_s": args.warmup})
    path = out.write()
    print(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Cost of one integrator step for 1, 100 and 1000 bodies (µs per step), all integrators.

    .venv/bin/python benchmarks/bench_integrators.py [--repeats 5]

Bodies: boxes of random size and mass (diagonal tensors) and particle-set-like bodies (full tensors), random
orientations, spin ~3 rad/s per axis, gravity on — a scene's typical load.  Each measurement times a batch
of steps from a fresh copy of the state and keeps the fastest of ``--repeats`` batches (the least disturbed
by other processes).  Prints a table; asserts nothing.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cgp_core.bodies import BodyModel, BodyState  # noqa: E402
from cgp_core.forces import apply_gravity  # noqa: E402
from cgp_core.inertia import box_inertia  # noqa: E402
from cgp_core.integrators import INTEGRATORS, make_integrator  # noqa: E402
from cgp_core.rotation import quat_to_matrix  # noqa: E402

H = 1.0 / 240.0
SIZES = (1, 100, 1000)


def make_scene(n: int, seed: int = 0) -> tuple[BodyModel, BodyState]:
    rng = np.random.default_rng(seed)
    mass = rng.uniform(0.5, 5.0, n)
    inertia = np.stack([box_inertia(m, rng.uniform(0.1, 1.0, 3)) for m in mass])
    # every other body gets its tensor in non-principal axes, as a particle-set body has
    q_axes = rng.normal(size=(n, 4))
    A = quat_to_matrix(q_axes / np.linalg.norm(q_axes, axis=1, keepdims=True))
    inertia[1::2] = A[1::2] @ inertia[1::2] @ np.swapaxes(A[1::2], 1, 2)
    model = BodyModel.empty()
    model.names = [f"b{i}" for i in range(n)]
    model.mass, model.inv_mass = mass, 1.0 / mass
    model.inertia_body, model.inv_inertia_body = inertia, np.linalg.inv(inertia)
    model.fixed = np.zeros(n, bool)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    omega_body = rng.normal(scale=3.0, size=(n, 3))
    L = np.einsum("nij,nj->ni", quat_to_matrix(q), np.einsum("nij,nj->ni", inertia, omega_body))
    state = BodyState(position=rng.normal(size=(n, 3)), orientation=q,
                      linear_momentum=mass[:, None] * rng.normal(size=(n, 3)), angular_momentum=L)
    apply_gravity(model, state, np.array([0.0, 0.0, -9.81]))  # constant over the batch
    return model, state


def time_per_step(name: str, n: int, repeats: int) -> float:
    model, initial = make_scene(n)
    integrator = make_integrator(name)
    steps = max(20, 2000 // max(1, n // 10)) if n > 1 else 2000
    best = np.inf
    for _ in range(repeats):
        state = initial.copy()
        start = time.perf_counter()
        for _ in range(steps):
            integrator.step(model, state, H)
        best = min(best, (time.perf_counter() - start) / steps)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(f"integrator step cost, h = 1/240 s, µs per step (fastest of {args.repeats} batches)")
    print(f"{'integrator':18s}" + "".join(f"{f'n = {n}':>12s}" for n in SIZES) + f"{'µs/body @1000':>15s}")
    for name in INTEGRATORS:
        costs = [time_per_step(name, n, args.repeats) * 1e6 for n in SIZES]
        print(f"{name:18s}" + "".join(f"{c:12.1f}" for c in costs) + f"{costs[-1] / SIZES[-1]:15.2f}")


if __name__ == "__main__":
    main()

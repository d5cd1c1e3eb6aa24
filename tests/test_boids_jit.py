"""The compiled boid kernels are the plain-Python functions they are written as: a small flock stepped with the
numba JIT (this process) and with ``NUMBA_DISABLE_JIT=1`` (a child process, where every kernel runs as
ordinary Python) ends in the same state, bit for bit — soft walls, a periodic box, a field of view, bodies to
avoid and the ground; and issue 14's kernels: a Couzin school (its noise included) fleeing a moving predator,
a topological flock with stragglers (the KD-tree path), and every flock's order parameters."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

# Run identically here and in the child: build the flocks, step them, return their final state.
SCENARIO = textwrap.dedent("""
    import numpy as np
    from cgp_core.bodies import BodyModel, BodyState, Shape
    from cgp_core.boids import Flock, FlockParams, Obstacles
    from cgp_core.boids.params import CouzinParams
    from cgp_core.boids.predators import Predators
    from cgp_core.rotation import quat_from_euler

    def run():
        n = 3
        model = BodyModel(
            names=["ball", "crate", "rod"], shape=np.array([Shape.SPHERE, Shape.BOX, Shape.CAPSULE], np.int8),
            radius=np.array([0.8, 0.0, 0.3]), half_extents=np.array([[0, 0, 0], [0.6, 0.4, 0.5], [0, 0, 0.8]]),
            mass=np.ones(n), inv_mass=np.zeros(n), inertia_body=np.tile(np.eye(3), (n, 1, 1)),
            inv_inertia_body=np.zeros((n, 3, 3)), restitution=np.zeros(n), friction=np.zeros(n),
            fixed=np.ones(n, bool), particles=[None] * n, color=np.ones((n, 4)))
        state = BodyState(position=np.array([[1.5, 0.0, 3.0], [-1.5, 1.0, 2.5], [0.0, -1.5, 3.5]]),
                          orientation=np.array([quat_from_euler(0.1 * k, 0.2, 0.3 * k) for k in range(n)]),
                          linear_momentum=np.zeros((n, 3)), angular_momentum=np.zeros((n, 3)))
        obstacles = Obstacles.from_bodies(model, state, ground=True)
        soft = Flock(FlockParams(count=90, seed=3, spawn_center=[0, 0, 3], spawn_extent=[5, 5, 3],
                                 bounds_min=[-5, -5, 0.5], bounds_max=[5, 5, 7], model="fish", goal=[3, 0, 3]))
        wrap = Flock(FlockParams(count=70, seed=4, bounds_mode="wrap", fov_deg=360.0, bounds_min=[0, 0, 0],
                                 bounds_max=[6, 5, 5], spawn_center=[3, 2.5, 2.5], spawn_extent=[6, 5, 5]))
        shark = Predators(position=np.array([[-1.0, 0.5, 3.0]]), velocity=np.array([[1.5, 0.2, 0.0]]),
                          radius=np.array([0.6]))
        school = Flock(FlockParams(count=50, seed=5, rules="couzin", spawn_center=[0, 0, 3], spawn_extent=[5, 5, 3],
                                   couzin=CouzinParams(orientation_width=1.5, attraction_width=5.0),
                                   bounds_min=[-5, -5, 0.5], bounds_max=[5, 5, 7], fright_radius=3.0))
        topo = Flock(FlockParams(count=60, seed=6, neighbor_mode="topological", neighbor_k=6, bounds_mode="none",
                                 spawn_center=[0, 0, 3], spawn_extent=[9, 9, 5]))
        for _ in range(12):
            soft.step(1.0 / 60.0, obstacles)
            wrap.step(1.0 / 60.0)
            school.step(1.0 / 60.0, obstacles, shark)
            topo.step(1.0 / 60.0, None, shark)
        flocks = (("soft", soft), ("wrap", wrap), ("school", school), ("topo", topo))
        out = {f"{name}_{what}": np.array(getattr(flock, what))
               for name, flock in flocks for what in ("positions", "velocities", "orientations", "dorsals")}
        for name, flock in flocks:
            o = flock.order()
            out[f"{name}_order"] = np.array([o.polarization, o.milling, *o.centroid, o.radius_of_gyration,
                                             o.mean_nearest_neighbor_distance, o.mean_speed, o.min_speed,
                                             o.max_speed])
        return out
""")


def test_jit_and_plain_python_give_the_same_flock(tmp_path):
    out = tmp_path / "plain.npz"
    child = SCENARIO + ("\nfrom cgp_core.jit import JIT_DISABLED"
                        "\nassert JIT_DISABLED, 'the child must run plain Python'"
                        f"\nnp.savez({str(out)!r}, **run())\n")
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    result = subprocess.run([sys.executable, "-c", child], cwd=REPO, env=env, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stderr
    plain = np.load(out)

    namespace: dict = {}
    exec(SCENARIO, namespace)  # noqa: S102 - the fixed scenario above
    from cgp_core.jit import JIT_DISABLED

    assert not JIT_DISABLED, "this process must run the compiled kernels"
    compiled = namespace["run"]()
    assert set(compiled) == set(plain.files)
    for key, value in compiled.items():
        np.testing.assert_array_equal(value, plain[key], err_msg=key)
    start = np.array(namespace["Flock"](namespace["FlockParams"](count=90, seed=3, spawn_center=[0, 0, 3],
                                                                 spawn_extent=[5, 5, 3])).positions)
    assert np.abs(compiled["soft_positions"] - start).max() > 0.1, "the flocks must have moved"

"""Couzin et al. 2002's zonal model (cgp_core/boids/couzin.py): each rule of the paper on hand-built
neighbourhoods, the turning-rate limit and the noise, constant speed, the same results compiled and as plain
Python, determinism per seed, and the paper's phases and collective memory on one seed each (regression runs;
thresholds from the sweep in benchmarks/figures/couzin_sweep.py)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from cgp_core.boids import BruteForceSearch, Flock, FlockParams
from cgp_core.boids.couzin import NOISE_TIME_STEP, blend_avoidance, noise_angles, social_directions, turn_headings
from cgp_core.boids.order import classify, milling, polarization
from cgp_core.boids.params import CouzinParams

REPO = Path(__file__).resolve().parents[1]
X = np.array([1.0, 0.0, 0.0])
Y = np.array([0.0, 1.0, 0.0])


def desired_of_first(others, other_headings, *, couzin=None, heading=X):
    """The desired direction of a focal boid at the origin with ``heading``, among ``others`` (k, 3) with
    ``other_headings`` (k, 3), through the flock's own path (brute-force pairs → zone sums → decision)."""
    couzin = couzin or CouzinParams()
    params = FlockParams(count=1 + len(others), rules="couzin", couzin=couzin, bounds_mode="none")
    positions = np.vstack([np.zeros(3), others]).T.astype(np.float32) + np.float32(50.0)
    pairs = BruteForceSearch().pairs(positions, params.radius)
    headings = np.vstack([heading, other_headings]).T.astype(float)
    headings /= np.linalg.norm(headings, axis=0)
    desired, perceived = social_directions(pairs, np.arange(positions.shape[1]), headings, positions.shape[1], params)
    return desired[:, 0], perceived[0]


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def test_repulsion_has_absolute_priority():
    # one neighbour inside r_r ahead-left, many aligned and attracting ones: the boid only moves away
    others = [[0.5, 0.3, 0.0], [2.0, 0.0, 0.0], [0.0, 2.5, 0.0], [8.0, 1.0, 0.0], [0.0, 9.0, 2.0]]
    desired, _ = desired_of_first(others, [Y] * len(others))
    np.testing.assert_allclose(desired, unit([-0.5, -0.3, 0.0]), atol=1e-5)  # float32 work coordinates


def test_repulsion_sums_unit_vectors_away_from_every_close_neighbour():
    desired, _ = desired_of_first([[0.5, 0, 0], [0, 0.8, 0]], [X, X])
    np.testing.assert_allclose(desired, unit([-1.0, -1.0, 0.0]), atol=1e-5)  # float32 work coordinates  # −Σ r̂_ij, not weighted by distance


def test_orientation_alone_aligns_with_the_neighbours_headings():
    others = [[2.0, 0.0, 0.0], [0.0, -2.5, 0.0]]  # both in r_r <= d < r_r + Δr_o = 3
    desired, _ = desired_of_first(others, [Y, unit([0, 1, 1])])
    np.testing.assert_allclose(desired, unit(Y + unit([0, 1, 1])), atol=1e-5)  # float32 work coordinates


def test_attraction_alone_heads_for_the_neighbours():
    others = [[6.0, 3.0, 0.0], [4.0, -4.0, 0.0]]  # beyond r_r + Δr_o = 3, within 17
    desired, _ = desired_of_first(others, [Y, Y])
    np.testing.assert_allclose(desired, unit(unit([6, 3, 0]) + unit([4, -4, 0])), atol=1e-5)  # float32 work coordinates


def test_orientation_and_attraction_are_averaged_as_directions():
    # three aligned neighbours (d_o = 3 ŷ) and one attracting one (d_a = x̂): ½(d̂_o + d̂_a), not ½(3ŷ + x̂)
    others = [[2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, -2.0, 0.5], [10.0, 0.0, 0.0]]
    desired, perceived = desired_of_first(others, [Y, Y, Y, unit([0, 0, 1])])
    np.testing.assert_allclose(desired, unit(X + Y), atol=1e-5)  # float32 work coordinates
    assert perceived == 4


def test_blind_volume_hides_neighbours_behind_in_every_zone():
    # straight behind (angle 180° > α/2 = 135°): repulsion, orientation and attraction neighbours all ignored
    behind = [[-0.5, 0.0, 0.0], [-2.0, 0.1, 0.0], [-9.0, -0.5, 0.0]]
    desired, perceived = desired_of_first(behind, [Y, Y, Y])
    np.testing.assert_allclose(desired, X)  # nothing perceived: carry on
    assert perceived == 0
    # at 130° off the heading (inside α/2) the repulsion neighbour is seen
    seen = 0.5 * np.array([math.cos(math.radians(130)), math.sin(math.radians(130)), 0.0])
    desired, perceived = desired_of_first([seen], [Y])
    np.testing.assert_allclose(desired, -unit(seen), atol=1e-5)  # float32 work coordinates
    # with α = 360° nothing is hidden
    desired, perceived = desired_of_first(behind, [Y, Y, Y], couzin=CouzinParams(field_of_view_deg=360.0))
    assert perceived == 3
    np.testing.assert_allclose(desired, [1.0, 0.0, 0.0], atol=1e-5)  # float32 work coordinates  # −r̂ of the one at −0.5 x̂


def test_neighbours_beyond_the_attraction_zone_are_not_perceived():
    desired, perceived = desired_of_first([[17.5, 0.0, 0.0]], [Y])  # r_r + Δr_o + Δr_a = 17
    assert perceived == 0
    np.testing.assert_allclose(desired, X)


def test_turning_is_limited_to_theta_dt_in_the_plane_of_heading_and_goal():
    headings = np.array([[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    desired = np.array([[0.0, math.cos(0.05), -1.0], [1.0, math.sin(0.05), 0.0], [0.0, 0.0, 0.0]])
    zero = np.zeros(3)
    out = turn_headings(headings, desired, zero, zero, 0.1)
    np.testing.assert_allclose(out[:, 0], [math.cos(0.1), math.sin(0.1), 0.0], atol=1e-12)  # 90° away: turns 0.1
    np.testing.assert_allclose(out[:, 1], desired[:, 1], atol=1e-12)  # 0.05 < 0.1: takes the desired direction
    assert math.acos(np.clip(out[:, 2] @ headings[:, 2], -1, 1)) == pytest.approx(0.1)  # straight behind: 0.1
    np.testing.assert_allclose(np.linalg.norm(out, axis=0), 1.0)


def test_noise_rotates_the_desired_direction_by_the_gaussian_angle():
    n = 20000
    rng = np.random.default_rng(5)
    sigma, dt = 0.2, 0.1
    angle, azimuth = noise_angles(rng, n, sigma, dt)
    assert np.std(angle) == pytest.approx(sigma, rel=0.03)
    desired = np.tile(unit([1, 2, 3])[:, None], (1, n))
    out = turn_headings(desired.copy(), desired, angle, azimuth, math.pi)  # no turning limit
    deviation = np.arccos(np.clip(np.einsum("ij,ij->j", out, desired), -1, 1))
    np.testing.assert_allclose(deviation, np.abs(angle), atol=1e-7)
    # the axis is uniform around d: the sideways deviations average out (along d: −(1 − cos ψ) on average)
    sideways = out - np.einsum("ij,ij->j", out, desired) * desired
    assert np.linalg.norm(sideways.mean(axis=1)) < 0.005
    # the noise per tick scales as sqrt(dt / τ): the same diffusion per second at any rate
    small, _ = noise_angles(np.random.default_rng(6), n, sigma, NOISE_TIME_STEP / 6)
    assert np.std(small) == pytest.approx(sigma / math.sqrt(6), rel=0.03)


def test_avoidance_takes_over_in_proportion_to_its_strength():
    desired = np.array([[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    needed = np.array([[0.0, 0.0, 0.0], [0.0, 10.0, 40.0], [0.0, 0.0, 0.0]])
    out = blend_avoidance(desired, needed, 20.0)
    np.testing.assert_allclose(out[:, 0], X)
    np.testing.assert_allclose(out[:, 1], unit([0.5, 0.5, 0]))
    np.testing.assert_allclose(out[:, 2], Y)  # at full strength: absolute priority


def couzin_params(**overrides) -> FlockParams:
    base = dict(count=60, seed=4, rules="couzin", couzin=CouzinParams(orientation_width=5.0),
                spawn_center=[0, 0, 0], spawn_extent=[8, 8, 8], bounds_mode="none")
    return FlockParams(**{**base, **overrides})


def test_speed_is_constant_and_headings_follow_velocities():
    flock = Flock(couzin_params(couzin=CouzinParams(speed=2.5)))
    for _ in range(100):
        flock.step(1 / 60)
        np.testing.assert_allclose(np.linalg.norm(flock.velocities, axis=1), 2.5)
    np.testing.assert_allclose(flock.headings, flock.velocities / 2.5, atol=1e-12)


def test_turning_rate_bounds_every_heading_change_per_tick():
    flock = Flock(couzin_params(couzin=CouzinParams(turning_rate_deg=40.0, orientation_width=1.0)))
    dt = 0.05
    for _ in range(60):
        before = flock.headings.copy()
        flock.step(dt)
        turned = np.arccos(np.clip(np.einsum("ij,ij->i", before, flock.headings), -1, 1))
        assert turned.max() <= math.radians(40.0) * dt + 1e-9


_RUN_SNIPPET = """
import sys, numpy as np
sys.path.insert(0, {repo!r})
from cgp_core.boids import Flock, FlockParams
from cgp_core.boids.params import CouzinParams
flock = Flock(FlockParams(count=40, seed=2, rules="couzin", couzin=CouzinParams(orientation_width=2.0),
                          spawn_center=[0, 0, 0], spawn_extent=[6, 6, 6], bounds_mode="none"))
for _ in range(40):
    flock.step(0.1)
sys.stdout.write(np.ascontiguousarray(flock.positions).tobytes().hex())
"""


def test_compiled_and_plain_python_kernels_give_the_same_flock():
    code = _RUN_SNIPPET.format(repo=str(REPO))
    runs = {}
    for disabled in ("0", "1"):
        env = dict(os.environ, NUMBA_DISABLE_JIT=disabled)
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        runs[disabled] = np.frombuffer(bytes.fromhex(out.stdout), dtype=np.float64)
    np.testing.assert_array_equal(runs["0"], runs["1"])


# ---- the paper's phases, one seed each (N = 100, r_r = 1, α = 270°, θ = 40°/s, s = 3, σ = 0.05, Δr_a = 14,
# τ = 0.1 s, random start in a 10 m cube).  Thresholds and seeds from benchmarks/figures/couzin_sweep.py (see
# benchmarks/results/couzin_sweep.json): each run's time-averaged p and m over its last 400 steps.

PAPER = dict(repulsion_radius=1.0, attraction_width=14.0, field_of_view_deg=270.0, turning_rate_deg=40.0,
             speed=3.0, noise=0.05)


def paper_flock(orientation_width: float, seed: int) -> Flock:
    return Flock(FlockParams(count=100, seed=seed, rules="couzin",
                             couzin=CouzinParams(orientation_width=orientation_width, **PAPER),
                             spawn_center=[0, 0, 0], spawn_extent=[10, 10, 10], bounds_mode="none",
                             neighbor_search="brute"))


def averaged_order(flock: Flock, steps: int, window: int, dt: float = 0.1) -> tuple[float, float]:
    ps, ms = [], []
    for step in range(steps):
        flock.step(dt)
        if step >= steps - window:
            ps.append(polarization(flock.headings.T))
            ms.append(milling(flock.positions.T, flock.headings.T))
    return float(np.mean(ps)), float(np.mean(ms))


@pytest.mark.parametrize("phase, width, seed", [
    ("swarm", 0.0, 0), ("torus", 1.5, 0), ("dynamic parallel", 5.0, 0), ("highly parallel", 13.0, 0)])
def test_couzin_phases_one_seed_each(phase, width, seed):
    p, m = averaged_order(paper_flock(width, seed), 2000, 400)
    kind = classify(p, m)
    if phase == "swarm":
        assert kind == "swarm", (p, m)
    elif phase == "torus":
        assert kind == "milling" and m > 0.8, (p, m)
    elif phase == "dynamic parallel":
        assert kind == "polarized" and p < 0.97, (p, m)
    else:
        assert kind == "polarized" and p > 0.97, (p, m)


def test_collective_memory_a_parallel_group_stays_parallel_where_a_random_one_mills():
    width = 1.5
    flock = paper_flock(13.0, 0)
    averaged_order(flock, 600, 1)  # a highly parallel group ...
    flock.params = replace(flock.params, couzin=replace(flock.params.couzin, orientation_width=width))
    p, m = averaged_order(flock, 1500, 400)  # ... brought down to the torus' Δr_o
    assert classify(p, m) == "polarized", (p, m)


DETERMINISM_SCENE = """
world: {{gravity: [0, 0, 0], ground: false}}
bodies: [{{name: shark, shape: sphere, radius: 0.8, mass: 5.0, position: [-9, 0, 0], predator: true}}]
flocks:
  - name: f
    count: 80
    spawn: {{center: [0, 0, 0], extent: [6, 6, 6]}}
    bounds: {{mode: none}}
    fright_radius: 4.0
    neighbors: {{mode: {mode}, k: 7}}
    seed: 3
{rules}
"""


@pytest.mark.parametrize("mode", ["metric", "topological"])
@pytest.mark.parametrize("rules", ["reynolds", "couzin"])
def test_every_rule_set_is_deterministic_per_seed(rules, mode):
    """Same seed, same trajectory to the bit (noise included), through a predator's attack; a reset replays it;
    another seed gives another flock."""
    from cgp_core import World
    from cgp_core.scene import parse_scene

    block = "    rules: couzin\n    couzin: {orientation_width: 3.0, attraction_width: 6.0}" if rules == "couzin" else ""
    scene = parse_scene(DETERMINISM_SCENE.format(mode=mode, rules=block))

    def run(world):
        world.apply_wrench("shark", force=[30.0, 0.0, 0.0], duration=0.5)
        for _ in range(120):
            world.step()
        return world.flocks[0].positions.copy(), world.flocks[0].orientations.copy()

    first, second = World(scene), World(scene)
    a, b = run(first), run(second)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    first.reset()
    np.testing.assert_array_equal(run(first)[0], a[0])
    other = run(World(scene, seed=4))
    assert not np.allclose(other[0], a[0])

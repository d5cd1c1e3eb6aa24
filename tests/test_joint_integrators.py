"""The joint-space Gauss–Legendre integrators (cgp_core.robots.joint_integrators, issue 35): a scene's
``joint_integrator`` (``world:`` for every robot and articulation, or a robot entry's own) steps the smooth flow
q̇ = qd, M(q) q̈ = τ − b(q, qd) by the s-stage Gauss–Legendre method before the joint solver's rows and drives.

Energy is measured on the scenes of tests/test_body_joints.py from the world's body states (as there), at the
world's 60 Hz × 4 sub-steps (h = 1/240 s) unless a test says otherwise."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.special import ellipk
from test_body_joints import (
    G,
    double_pendulum_scene,
    energy,
    four_bar_scene,
    pendulum_scene,
    spherical_pendulum_scene,
)

from cgp_core import World
from cgp_core.robots import joint_integrators
from cgp_core.scene import SceneError, scene_from_dict

#: the double pendulum's energy scale (m₁ + m₂) g ℓ₁ (the one test_double_pendulum_energy_drift_over_10_s uses:
#: 10.0 J; its total energy is E₀ = 1.72 J, its kinetic energy reaches ~8 J)
DOUBLE_PENDULUM_SCALE = (1.0 + 0.7) * G * 0.6


def with_integrator(scene: dict, name: str, substeps: int | None = None) -> dict:
    scene["world"]["joint_integrator"] = name
    if substeps is not None:
        scene["world"]["substeps"] = substeps
    return scene


def double_pendulum_errors(name: str, seconds: float) -> tuple[np.ndarray, World]:
    """(E(t) − E₀) / scale at every tick of ``seconds`` of the double pendulum's release, and the world."""
    world = World(scene_from_dict(with_integrator(double_pendulum_scene(), name)))
    names = ["upper", "lower"]
    e0, errors = energy(world, names), []
    for _ in range(int(round(seconds * 60))):
        world.step()
        errors.append((energy(world, names) - e0) / DOUBLE_PENDULUM_SCALE)
    return np.array(errors), world


def test_double_pendulum_energy_over_60_s_with_gauss_legendre_6():
    """Issue 35: max |E(t) − E₀| / ((m₁ + m₂) g ℓ₁) over 60 s of the chaotic release ≤ 1e-6 with the 3-stage
    Gauss–Legendre method (measured 3.5e-9; the default semi-implicit Euler reaches 0.31 in 10 s, see
    test_body_joints).  Every sub-step's stage iteration converged (no fallback), in ~6 fixed-point passes."""
    errors, world = double_pendulum_errors("gauss_legendre_6", 60.0)
    assert np.abs(errors).max() <= 1e-6, np.abs(errors).max()
    assert world.robots.integrator_fallbacks.tolist() == [0]
    assert world.robots.integrator_iterations[0] <= 7 * 60 * 60 * 4
    assert not [e for e in world.events if e.level != "info"]


def test_double_pendulum_energy_with_gauss_legendre_4_is_bounded_at_its_h4_level():
    """The 2-stage (4th-order) method's energy error is an h⁴ oscillation, not a drift: over 60 s its largest is
    1.0–1.2e-6 of the scale (just above issue 35's 1e-6, hence gauss_legendre_6; measured per 10 s window: 4.5e-7
    … 1.2e-6 as the chaotic motion visits faster states, and the same over 120 s), while its mean over each 10 s
    window stays ≤ 6e-8: ≤ 1e-7 in the first and in the last window."""
    errors, _ = double_pendulum_errors("gauss_legendre_4", 60.0)
    assert np.abs(errors).max() <= 2e-6, np.abs(errors).max()
    windows = errors.reshape(6, 600).mean(axis=1)
    assert abs(windows[0]) <= 1e-7 and abs(windows[-1]) <= 1e-7, windows


def final_state(name: str, substeps: int) -> np.ndarray:
    world = World(scene_from_dict(with_integrator(double_pendulum_scene(), name, substeps)))
    for _ in range(60):
        world.step()
    return np.concatenate([world.robots.q, world.robots.qd])


@pytest.mark.parametrize("name, order, substeps", [("gauss_legendre_4", 4, (2, 4, 8)),
                                                    ("gauss_legendre_6", 6, (2, 4))])
def test_convergence_order(name, order, substeps):
    """The double pendulum's state (q, qd) after 1 s against a reference (the 6th-order method at 48 sub-steps):
    halving h (2 → 4 → 8 sub-steps of the 60 Hz tick) divides the error by ~2^order, within a factor 1.35 either
    way.  Measured: 16.2 and 16.1 (errors 1.5e-6, 9.0e-8, 5.6e-9); 63.1 (2.9e-9, 4.7e-11; at 8 sub-steps the
    6th-order error, 8e-13, nears the round-off of 480 steps: 59 there, not asserted)."""
    reference = final_state("gauss_legendre_6", 48)
    errors = [float(np.abs(final_state(name, s) - reference).max()) for s in substeps]
    ratios = [errors[i] / errors[i + 1] for i in range(len(errors) - 1)]
    for ratio in ratios:
        assert 2 ** order / 1.35 <= ratio <= 2 ** order * 1.35, (errors, ratios)


def hermite_crossings(t, x, v) -> np.ndarray:
    """The zero crossings of x(t) from samples of x and ẋ: the cubic Hermite interpolant's root in each sign
    change (Newton from the linear estimate): O(Δt⁴), where linear interpolation is O(Δt³)."""
    out = []
    for k in np.flatnonzero(np.sign(x[:-1]) * np.sign(x[1:]) < 0):
        dt = t[k + 1] - t[k]
        s = x[k] / (x[k] - x[k + 1])
        for _ in range(20):
            h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
            d00, d10, d01, d11 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s, 3 * s**2 - 2 * s
            f = h00 * x[k] + h10 * dt * v[k] + h01 * x[k + 1] + h11 * dt * v[k + 1]
            df = d00 * x[k] + d10 * dt * v[k] + d01 * x[k + 1] + d11 * dt * v[k + 1]
            s -= f / df
        out.append(t[k] + s * dt)
    return np.array(out)


@pytest.mark.parametrize("name", ["gauss_legendre_4", "gauss_legendre_6"])
def test_pendulum_at_170_degrees_has_the_elliptic_period(name):
    """T = 4 √(I / (m g d)) K(sin²(θ₀/2)) (scipy's ellipk takes the parameter m = k²), two full periods from the
    zero crossings of the angle — found by cubic Hermite interpolation with the joint's velocity, since linear
    interpolation's own error at 60 Hz (~1e-6 of the period) is above what these methods leave: ≤ 1e-8 relative
    (measured 8e-11 and 1e-11; the default step, test_body_joints' ≤ 1e-4, measures 1.04e-5 this way too)."""
    theta0, length, width, mass = np.radians(170.0), 1.0, 0.1, 2.0
    world = World(scene_from_dict(with_integrator(pendulum_scene(theta0, length, width, mass), name)))
    d = 0.5 * length
    inertia = mass * (width ** 2 + length ** 2) / 12.0 + mass * d * d
    period = 4.0 * np.sqrt(inertia / (mass * G * d)) * ellipk(np.sin(theta0 / 2) ** 2)
    t, angle, rate = [], [], []
    for _ in range(int(2.3 * period * 60)):
        world.step()
        t.append(world.time)
        angle.append(theta0 - world.robots.q[0])  # the pin's coordinate: 0 at the release, about +y (θ about −y)
        rate.append(-world.robots.qd[0])
    assert abs(angle[0] - theta0) < 0.1 and min(angle) < -np.radians(160.0)  # it swings from 170° to about −170°
    crossings = hermite_crossings(np.array(t), np.array(angle), np.array(rate))
    measured = crossings[4] - crossings[0]
    assert abs(measured / (2 * period) - 1.0) <= 1e-8, (measured / 2, period)


def test_spherical_pendulum_on_a_ball_joint_keeps_its_energy():
    """A ball joint's quaternion moves by the exponential map (the stages in local coordinates, dexp⁻¹): the
    spherical pendulum of test_body_joints keeps its energy to ≤ 1e-9 of m g ℓ over 10 s with gauss_legendre_6
    (measured 7e-15; gauss_legendre_4 2.6e-10; the default step 0.026)."""
    scene = with_integrator(spherical_pendulum_scene(), "gauss_legendre_6")
    world = World(scene_from_dict(scene))
    e0, worst = energy(world, ["bob"]), 0.0
    for _ in range(600):
        world.step()
        worst = max(worst, abs(energy(world, ["bob"]) - e0))
    assert worst / (2.0 * G * 1.0) <= 1e-9, worst
    assert world.robots.integrator_fallbacks.tolist() == [0]


def test_a_free_flying_pair_on_a_ball_joint_keeps_its_energy():
    """A floating tree (its root's orientation a quaternion moved by the exponential map, world-frame ω) with a
    ball joint, thrown tumbling under gravity: the energy after the first tick (the scene's body velocities are
    fitted to the joint there) is kept to ≤ 1e-9 of it over 5 s with gauss_legendre_6 (measured 3.4e-12;
    gauss_legendre_4 3.5e-10; the default step drifts by 3 %)."""
    drift = {}
    for name in ("semi_implicit_euler", "gauss_legendre_6"):
        world = World(scene_from_dict(
            {"world": {"ground": False, "joint_integrator": name, "sleep": False},
             "bodies": [{"name": "a", "shape": "box", "size": [0.6, 0.1, 0.2], "mass": 1.0, "position": [0, 0, 5],
                         "angular_velocity": [1.0, 2.0, 3.0], "linear_velocity": [0.5, 0, 1]},
                        {"name": "b", "shape": "box", "size": [0.1, 0.5, 0.3], "mass": 0.5,
                         "position": [0.35, 0.25, 5]}],
             "joints": [{"name": "j", "type": "ball", "parent": "a", "child": "b", "anchor": [0.3, 0, 5]}]}))
        world.step()
        e0, worst = energy(world, ["a", "b"]), 0.0
        for _ in range(300):
            world.step()
            worst = max(worst, abs(energy(world, ["a", "b"]) - e0))
        drift[name] = worst / e0
        assert world.robots.integrator_fallbacks.tolist() == [0]
    assert drift["gauss_legendre_6"] <= 1e-9 and drift["semi_implicit_euler"] >= 1e-2, drift


def test_the_chain_scene_runs_with_gauss_legendre_without_a_fallback():
    """The built-in ``chain`` scene (a 5 kg ball on 30 pinned 0.1 kg links knocking a wall over: 32 dofs, M's
    condition ~3.5e7, contacts) with gauss_legendre_6 for 5 s: every sub-step's stages converge (to the round-off
    floor of its ill-conditioned M where 1e-13 cannot be resolved; ~11 passes per sub-step, a few sub-steps split
    into smaller Gauss–Legendre steps where the links whip at ~100 rad/s — measured over 20 s: 48 of 4,800, none
    falling back, where the first design blew up), no warning, nothing non-finite."""
    from cgp_core.scene import load_scene

    scene = load_scene("chain")
    for spec in scene.articulations:
        spec.joint_integrator = "gauss_legendre_6"
    world = World(scene)
    for _ in range(300):
        world.step()
    assert world.robots.integrator_fallbacks.tolist() == [0] * len(world.robots.robots)
    assert not [e.text for e in world.events if e.level != "info"]
    assert np.all(np.isfinite(world.robots.q))


def test_a_four_bar_keeps_its_loop_closed_with_gauss_legendre():
    """The loop-closing pin keeps its equality rows and the Newton projection after the integration: the loop
    error stays ≤ 1e-12 m over 2 s with gauss_legendre_6, and the linkage moves."""
    world = World(scene_from_dict(with_integrator(four_bar_scene(), "gauss_legendre_6")))
    q0 = world.robots.q.copy()
    worst = 0.0
    for _ in range(120):
        world.step()
        worst = max(worst, max(world.robots.loop_errors().values()))
    assert worst <= 1e-12, worst
    assert np.abs(world.robots.q - q0).max() > 0.1


def test_a_held_arm_stays_held():
    """The 7-DoF arm of the ``arm`` scene (arm7.urdf) held at a bent pose by its position drives (implicit, in the
    joint solver as before) against gravity for 2 s (sleep off: stepped throughout): with gauss_legendre_6 it sags
    (2.6e-4 rad) into the equilibrium the default step holds, to ≤ 1e-6 rad (1.3e-7 measured: the smooth flow's
    stages see the arm fall within the sub-step, an O(h²) change of the drive's equilibrium), at rest to
    ≤ 1e-4 rad/s (9e-6 measured: the same residual, as a steady qd that the position update's ½ h Δqd of the
    drive cancels; the default: 0), ≤ 1e-4 rad from the default during the first ticks' transient, without a
    fallback."""
    worlds = [World(scene_from_dict({"world": {"joint_integrator": name, "sleep": False},
                                     "robots": [{"name": "arm", "urdf": "arm7.urdf", "position": [0, 0, 0.2],
                                                 "joints": {"shoulder_lift": 0.3, "elbow": 0.6, "wrist": 0.6}}]}))
              for name in ("semi_implicit_euler", "gauss_legendre_6")]
    q0 = worlds[0].robots.q.copy()
    worst = 0.0
    for _ in range(120):
        for world in worlds:
            world.step()
        worst = max(worst, float(np.abs(worlds[1].robots.q - worlds[0].robots.q).max()))
    assert worst <= 1e-4, worst
    assert np.abs(worlds[1].robots.q - worlds[0].robots.q).max() <= 1e-6
    assert 1e-5 <= np.abs(worlds[1].robots.q - q0).max() <= 1e-3  # it sags under gravity, a little
    assert np.abs(worlds[1].robots.qd).max() <= 1e-4
    assert worlds[1].robots.integrator_fallbacks.sum() == 0 and worlds[1].robots.integrator_iterations.sum() > 0


@pytest.mark.parametrize("name", ["gauss_legendre_4", "gauss_legendre_6"])
def test_a_door_slammed_onto_its_limit_stops_there_without_gaining_energy(name):
    """test_body_joints' door thrown at 6 rad/s onto its hinge's limit, with a Gauss–Legendre joint integrator:
    the limit row acts on the flow's velocity, so the door stops at the stop; sampled at the ticks it is past it
    by ≤ 1e-6 rad (measured 1.2e-8: a sub-step's overshoot, ≤ h v / 2, is gone by the tick's end — the position
    stage) and its energy never exceeds the initial one."""
    limit = 1.2
    scene = {"world": {"ground": False, "joint_integrator": name},
             "bodies": [{"name": "frame", "shape": "box", "size": [0.1, 0.1, 2.0], "fixed": True,
                         "position": [-0.1, 0.0, 1.0], "mass": 1.0},
                        {"name": "door", "shape": "box", "size": [0.9, 0.04, 2.0], "mass": 20.0,
                         "position": [0.5, 0.0, 1.0], "angular_velocity": [0, 0, 6.0],
                         "linear_velocity": [0.0, 2.7, 0.0]}],
             "joints": [{"name": "hinge", "type": "revolute", "parent": "frame", "child": "door",
                         "anchor": [0.05, 0.0, 1.0], "axis": [0, 0, 1], "limits": [-0.5, limit]}]}
    world = World(scene_from_dict(scene))
    e0 = energy(world, ["door"])
    most, energies = -np.inf, []
    for _ in range(120):
        world.step()
        _, q, _, _ = world.robots.joint_state("hinge")
        most = max(most, float(q[0]))
        energies.append(energy(world, ["door"]))
    assert most <= limit + 1e-6, most
    assert max(energies) <= e0 * (1 + 1e-9)
    assert abs(q[0] - limit) <= 1e-3


def test_two_robots_whose_links_touch_are_solved_together_with_gauss_legendre():
    """Two free (not held) 3-link arms 0.25 m apart fall onto each other: their links touch, so the robot stage
    solves them as one island (one joint-space system), each robot's smooth flow stepped first.  With
    gauss_legendre_6 the island forms, nothing falls back, and after 2 s the arms rest within 0.05 rad of where the
    default step puts them (the contacts make both first order; measured 0.011)."""
    finals = {}
    for name in ("semi_implicit_euler", "gauss_legendre_6"):
        world = World(scene_from_dict({"world": {"joint_integrator": name, "sleep": False},
                                       "robots": [{"name": "a", "urdf": "arm3.urdf", "hold": False},
                                                  {"name": "b", "urdf": "arm3.urdf", "position": [0.25, 0, 0],
                                                   "hold": False}]}))
        island = 0
        for _ in range(120):
            world.step()
            island = max(island, max(len(group) for group in world.robots.islands))
        assert island == 2 and np.all(np.isfinite(world.robots.q))
        assert world.robots.integrator_fallbacks.tolist() == [0, 0]
        finals[name] = world.robots.q.copy()
    assert np.abs(finals["gauss_legendre_6"] - finals["semi_implicit_euler"]).max() <= 0.05, finals


def test_a_step_that_does_not_converge_falls_back_to_the_default_step_and_says_so(monkeypatch):
    """With one fixed-point pass allowed the stages never converge: every sub-step falls back to the default
    semi-implicit Euler step — the same trajectory, bit for bit — counted per robot and reported as a warning
    event each tick."""
    default = World(scene_from_dict(double_pendulum_scene()))
    monkeypatch.setattr(joint_integrators, "MAX_ITERATIONS", 1)
    world = World(scene_from_dict(with_integrator(double_pendulum_scene(), "gauss_legendre_4")))
    for _ in range(5):
        default.step()
        world.step()
    assert np.array_equal(world.robots.q, default.robots.q) and np.array_equal(world.robots.qd, default.robots.qd)
    assert world.robots.integrator_fallbacks.tolist() == [20]
    warnings = [e.text for e in world.events if e.level == "warn"]
    assert len(warnings) == 5 and "did not converge in 4 sub-step(s)" in warnings[0], warnings


def test_the_default_is_the_semi_implicit_euler_step_unchanged():
    """A scene that names the default gets exactly the trajectory of one that names nothing."""
    a = World(scene_from_dict(double_pendulum_scene()))
    b = World(scene_from_dict(with_integrator(double_pendulum_scene(), "semi_implicit_euler")))
    for _ in range(10):
        a.step()
        b.step()
    assert np.array_equal(a.robots.q, b.robots.q) and np.array_equal(a.robots.qd, b.robots.qd)
    assert b.robots.integrator_iterations.tolist() == [0]


def test_a_robot_entry_overrides_the_world():
    scene = scene_from_dict({"world": {"joint_integrator": "gauss_legendre_4"},
                             "robots": [{"name": "a", "urdf": "arm3.urdf"},
                                        {"name": "b", "urdf": "arm3.urdf", "position": [1, 0, 0],
                                         "joint_integrator": "semi_implicit_euler"}]})
    assert [r.joint_integrator for r in scene.robots] == ["gauss_legendre_4", "semi_implicit_euler"]
    world = World(scene)
    assert [r.joint_integrator for r in world.robots.robots] == ["gauss_legendre_4", "semi_implicit_euler"]


def test_a_spawned_robot_takes_the_worlds_joint_integrator_unless_its_entry_names_one():
    world = World(scene_from_dict({"world": {"joint_integrator": "gauss_legendre_6"}}))
    world.spawn({"robot": {"urdf": "arm3.urdf"}}, name="a")
    world.spawn({"robot": {"urdf": "arm3.urdf", "joint_integrator": "semi_implicit_euler"}}, name="b",
                position=(1.0, 0.0, 0.0))
    assert [r.joint_integrator for r in world.robots.robots] == ["gauss_legendre_6", "semi_implicit_euler"]
    for _ in range(3):
        world.step()
    assert world.robots.integrator_iterations[0] > 0 and world.robots.integrator_iterations[1] == 0


@pytest.mark.parametrize("data, key", [
    ({"world": {"joint_integrator": "rk4"}}, "world.joint_integrator"),
    ({"robots": [{"name": "a", "urdf": "arm3.urdf", "joint_integrator": "gauss_legendre"}]},
     "robots[0].joint_integrator"),
    ({"world": {"joint_integrator": 4}}, "world.joint_integrator"),
])
def test_an_unknown_joint_integrator_is_refused_naming_the_key(data, key):
    with pytest.raises(SceneError) as info:
        scene_from_dict(data, "scene.yaml")
    text = str(info.value)
    assert f"scene.yaml: {key}: " in text and "gauss_legendre_4, gauss_legendre_6, semi_implicit_euler" in text \
        or f"scene.yaml: {key}: must be a string" in text, text


PARITY = r"""
import sys
import numpy as np
sys.path.insert(0, sys.argv[3])
from test_body_joints import double_pendulum_scene, spherical_pendulum_scene
from cgp_core import World
from cgp_core.jit import JIT_DISABLED
from cgp_core.scene import scene_from_dict

assert JIT_DISABLED == (sys.argv[2] == "plain")
# the double pendulum thrown whipping: the upper box at spin rad/s about the shoulder, the lower at twice that
def thrown(spin):
    scene = double_pendulum_scene()
    w = np.array([0.0, spin, 0.0])
    scene["bodies"][0].update(angular_velocity=w.tolist(), linear_velocity=np.cross(w, [0.3, 0, 0]).tolist())
    scene["bodies"][1].update(angular_velocity=(2 * w).tolist(),
                              linear_velocity=(np.cross(w, [0.6, 0, 0]) + np.cross(2 * w, [0, 0, 0.25])).tolist())
    return scene

out = []
for scene in (double_pendulum_scene(), spherical_pendulum_scene(), thrown(200.0)):
    scene["world"]["joint_integrator"] = "gauss_legendre_6"
    w = World(scene_from_dict(scene))
    for _ in range(3):
        w.step()
    out.append(np.concatenate([w.robots.q, w.robots.qd, w.robots.integrator_iterations,
                               w.robots.integrator_subdivided]))
np.save(sys.argv[1], np.concatenate(out))
"""


def test_compiled_and_plain_python_give_the_same_bits(tmp_path):
    """The Gauss–Legendre kernels compiled and as plain Python (NUMBA_DISABLE_JIT=1): the same bits (positions,
    velocities, passes and split sub-steps) after 3 ticks of the double pendulum, of the spherical pendulum (a ball
    joint's dexp⁻¹) and of the double pendulum thrown at 200 rad/s (~34 passes a sub-step: simplified Newton, and
    sub-steps split into smaller steps — 4 of 12, measured)."""
    results = {}
    for mode in ("compiled", "plain"):
        env = os.environ.copy()
        env.pop("NUMBA_DISABLE_JIT", None)
        if mode == "plain":
            env["NUMBA_DISABLE_JIT"] = "1"
        path = tmp_path / f"{mode}.npy"
        done = subprocess.run([sys.executable, "-c", PARITY, str(path), mode, os.path.dirname(__file__)], env=env,
                              capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, done.stderr[-3000:]
        results[mode] = np.load(path)
    assert np.array_equal(results["compiled"], results["plain"]), np.abs(results["compiled"] - results["plain"]).max()
    assert results["compiled"][-1] > 0  # the thrown pendulum's sub-steps were split: that path ran

"""Forces and torques (cgp_core.forces): the split of a force at a point into F on the COM and τ = (p − x̄) × F,
checked on hand-made configurations, against the particle picture of the lecture (a rigid set of point masses
receiving an impulse at one particle), and through an integrator step."""

from __future__ import annotations

import numpy as np
import pytest

from cgp_core.bodies import BodyModel, BodyState
from cgp_core.forces import apply_damping, apply_force_at_point, apply_gravity, apply_torque
from cgp_core.inertia import box_inertia, particle_mass_properties
from cgp_core.integrators import INTEGRATORS, make_integrator
from cgp_core.rotation import quat_from_rotvec, quat_to_matrix


def make_bodies(inertia, mass, fixed=None, position=None, orientation=None) -> tuple[BodyModel, BodyState]:
    inertia = np.array(inertia, dtype=float).reshape(-1, 3, 3)
    n = len(inertia)
    mass = np.broadcast_to(np.asarray(mass, dtype=float), (n,)).copy()
    fixed = np.zeros(n, bool) if fixed is None else np.asarray(fixed, bool)
    model = BodyModel.empty()
    model.names = [f"body{i}" for i in range(n)]
    model.mass = mass
    model.inv_mass = np.where(fixed, 0.0, 1.0 / mass)
    model.inertia_body = inertia
    model.inv_inertia_body = np.where(fixed[:, None, None], 0.0, np.linalg.inv(inertia))
    model.fixed = fixed
    position = np.zeros((n, 3)) if position is None else np.array(position, dtype=float).reshape(n, 3)
    orientation = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)) if orientation is None else \
        np.array(orientation, dtype=float).reshape(n, 4)
    state = BodyState(position=position, orientation=orientation, linear_momentum=np.zeros((n, 3)),
                      angular_momentum=np.zeros((n, 3)))
    return model, state


# ---- force at a point ------------------------------------------------------------------------------------


def test_push_at_the_end_of_a_lever_turns_counterclockwise_about_z():
    """p − x̄ = +x, F = +y: τ = x × y = +z (right-hand rule: a counterclockwise turn seen from above).
    The slide's F × (p − x̄) would give −z, and its F (F · (p − x̄)) would give zero force here."""
    model, state = make_bodies(np.eye(3), 1.0, position=[[1.0, 2.0, 3.0]])
    apply_force_at_point(state, 0, [0.0, 5.0, 0.0], [3.0, 2.0, 3.0])  # lever 2 m along x
    np.testing.assert_array_equal(state.force[0], [0.0, 5.0, 0.0])
    np.testing.assert_array_equal(state.torque[0], [0.0, 0.0, 10.0])


def test_force_through_the_centre_of_mass_gives_no_torque():
    model, state = make_bodies(np.eye(3), 1.0, position=[[1.0, -2.0, 0.5]])
    F = np.array([1.0, 2.0, -3.0])
    for s in (0.0, 1.0, -2.5):  # any point on the line of action through x̄
        apply_force_at_point(state, 0, F, state.position[0] + s * F)
    np.testing.assert_allclose(state.force[0], 3 * F)
    np.testing.assert_allclose(state.torque[0], 0.0, atol=1e-15)


def test_couple_gives_pure_torque_independent_of_where_the_body_is():
    """Equal and opposite forces at p₁ and p₂: no net force, torque (p₁ − p₂) × F wherever the COM is."""
    F = np.array([0.0, 0.0, 4.0])
    p1, p2 = np.array([0.5, 0.0, 0.0]), np.array([-0.5, 0.0, 0.0])
    for com in ([0.0, 0.0, 0.0], [3.0, -1.0, 7.0]):
        model, state = make_bodies(np.eye(3), 1.0, position=[com])
        apply_force_at_point(state, [0, 0], [F, -F], [p1, p2])
        np.testing.assert_allclose(state.force[0], 0.0, atol=1e-15)
        np.testing.assert_allclose(state.torque[0], np.cross(p1 - p2, F), atol=1e-14)  # (0, −4, 0)


def test_several_forces_on_one_body_add_up_and_other_bodies_are_untouched():
    rng = np.random.default_rng(1)
    model, state = make_bodies(np.repeat(np.eye(3)[None], 3, 0), 1.0, position=rng.normal(size=(3, 3)))
    bodies = np.array([2, 0, 2, 2])
    forces = rng.normal(size=(4, 3))
    points = rng.normal(size=(4, 3))
    apply_force_at_point(state, bodies, forces, points)
    for b in range(3):
        mine = bodies == b
        expected_torque = sum((np.cross(p - state.position[b], f) for p, f in zip(points[mine], forces[mine])),
                              np.zeros(3))
        np.testing.assert_allclose(state.force[b], forces[mine].sum(axis=0), atol=1e-14)
        np.testing.assert_allclose(state.torque[b], expected_torque, atol=1e-14)


def test_impulse_at_one_particle_equals_the_rigid_response_of_the_whole_particle_set():
    """The lecture's picture: a rigid body is a set of particles.  An impulse J at particle k gives the
    body ΔP = J and ΔL = (x_k − x̄) × J; the resulting particle velocities vᵢ = v + ω × rᵢ (ω = J_body⁻¹ ΔL)
    must carry exactly that momentum Σ mᵢvᵢ and angular momentum Σ mᵢ rᵢ × vᵢ about the COM."""
    rng = np.random.default_rng(2)
    points = rng.normal(size=(15, 3))
    masses = rng.uniform(0.2, 1.0, size=15)
    total, com, J = particle_mass_properties(points, masses)
    model, state = make_bodies(J, total, position=[com])
    impulse, dt = np.array([0.3, -1.0, 2.0]), 1e-3
    apply_force_at_point(state, 0, impulse / dt, points[4])
    integrator = make_integrator("implicit_midpoint")
    integrator.step(model, state, dt)  # the kick applies F dt and τ dt before anything moves
    v = state.linear_momentum[0] / total
    omega = np.linalg.solve(J, state.angular_momentum[0])  # the velocities right after the kick (R = 1)
    r = points - com
    particle_velocities = v + np.cross(omega, r)
    np.testing.assert_allclose((masses[:, None] * particle_velocities).sum(axis=0), impulse, rtol=1e-12)
    np.testing.assert_allclose((masses[:, None] * np.cross(r, particle_velocities)).sum(axis=0),
                               np.cross(points[4] - com, impulse), rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_off_centre_push_on_a_box_at_rest(name):
    """One step of a force F at a corner of a box at rest: Δv = F h / m and Δω = I_world⁻¹ ((p − x̄) × F) h,
    with the box turned so that I_world is not diagonal."""
    inertia = box_inertia(2.0, [0.1, 0.4, 0.8])
    q = quat_from_rotvec(np.array([0.2, -0.7, 0.4]))
    model, state = make_bodies(inertia, 2.0, position=[[0.0, 0.0, 1.0]], orientation=[q])
    R = quat_to_matrix(q)
    corner = state.position[0] + R @ np.array([0.05, 0.2, 0.4])
    F, h = np.array([0.0, 3.0, 0.0]), 1.0 / 240.0
    apply_force_at_point(state, 0, F, corner)
    make_integrator(name).step(model, state, h)
    tau = np.cross(corner - np.array([0.0, 0.0, 1.0]), F)
    np.testing.assert_allclose(state.linear_momentum[0] / 2.0, F * h / 2.0, rtol=1e-14)
    np.testing.assert_allclose(state.angular_momentum[0], tau * h, rtol=1e-14)
    omega = np.linalg.solve(R @ inertia @ R.T, state.angular_momentum[0])
    np.testing.assert_allclose(omega, np.linalg.solve(R @ inertia @ R.T, tau) * h, rtol=1e-12)


# ---- pure torques, gravity, damping ----------------------------------------------------------------------


def test_pure_torque_adds_no_force():
    model, state = make_bodies(np.repeat(np.eye(3)[None], 2, 0), 1.0)
    apply_torque(state, [1, 1], [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    np.testing.assert_array_equal(state.torque, [[0.0, 0.0, 0.0], [1.0, 2.0, 0.0]])
    np.testing.assert_array_equal(state.force, 0.0)


def test_gravity_is_m_g_on_movable_bodies_only():
    model, state = make_bodies(np.repeat(np.eye(3)[None], 3, 0), [1.0, 2.5, 4.0], fixed=[False, False, True])
    apply_gravity(model, state, [0.0, 0.0, -9.81])
    np.testing.assert_allclose(state.force, [[0, 0, -9.81], [0, 0, -2.5 * 9.81], [0, 0, 0]])
    np.testing.assert_array_equal(state.torque, 0.0)


def test_damping_decays_momenta_with_time_constant_one_over_c_for_every_body_size():
    """F = −c m v, τ = −c L: momenta decay like e^(−c t) whatever the mass (symplectic Euler gives
    (1 − c h)^n exactly)."""
    inertia = np.stack([np.eye(3) * 0.1, np.eye(3) * 10.0])
    model, state = make_bodies(inertia, [0.5, 50.0])
    P0 = np.array([[1.0, 0.0, 0.0], [0.0, 100.0, 0.0]])
    L0 = np.array([[0.0, 0.0, 0.2], [0.0, 20.0, 0.0]])  # about principal axes: no gyroscopic exchange
    state.linear_momentum[:] = P0
    state.angular_momentum[:] = L0
    c_lin, c_ang, h, n = 0.5, 2.0, 1e-3, 1000
    integrator = make_integrator("symplectic_euler")
    for _ in range(n):
        apply_damping(model, state, c_lin, c_ang)
        integrator.step(model, state, h)
        state.clear_accumulators()
    np.testing.assert_allclose(state.linear_momentum, P0 * (1 - c_lin * h) ** n, rtol=1e-12)
    np.testing.assert_allclose(state.angular_momentum, L0 * (1 - c_ang * h) ** n, rtol=1e-12)
    np.testing.assert_allclose(state.linear_momentum, P0 * np.exp(-c_lin * n * h), rtol=1e-3)


def test_damping_leaves_fixed_bodies_alone():
    model, state = make_bodies(np.eye(3), 1.0, fixed=[True])
    state.linear_momentum[:] = 1.0
    state.angular_momentum[:] = 1.0
    apply_damping(model, state, 1.0, 1.0)
    np.testing.assert_array_equal(state.force, 0.0)
    np.testing.assert_array_equal(state.torque, 0.0)

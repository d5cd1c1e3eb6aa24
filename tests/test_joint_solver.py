"""The joint-space sub-step (cgp_core.robots.joint_solver) against closed forms: systems whose M and bias are
written here by hand (a pendulum, a slider, planar chains of point masses), so the solver is tested apart from
the robot model.

The planar chain: point masses m_k at the end of link k (length l_k), relative joint angles q, absolute angles
φ_k = q_0 + … + q_k measured from +x, gravity −y.  Point k is at Σ_{i≤k} l_i (cos φ_i, sin φ_i); its Jacobian
column j (j ≤ k) is Σ_{i=j..k} l_i (−sin φ_i, cos φ_i); its velocity-product acceleration is
−Σ_{i≤k} l_i φ̇_i² (cos φ_i, sin φ_i).  M = Σ m_k J_kᵀ J_k, b = Σ m_k J_kᵀ (a_k + g ŷ) — checked against the
textbook two-link M(q), C(q, qd) below.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.special import ellipk

from cgp_core.robots.joint_solver import (
    DRIVE_EFFORT,
    DRIVE_POSITION,
    DRIVE_VELOCITY,
    ContactRows,
    FreeBodies,
    JointDrives,
    JointProperties,
    JointSolver,
    JointSystem,
    integrate_dofs,
    position_gains,
)

G = 9.81
H = 1.0 / 240.0


# ---- closed-form systems ----------------------------------------------------------------------------------------

def chain_point_jacobian(q, lengths, k):
    """(2, n) Jacobian of point k of the planar chain."""
    phi = np.cumsum(q)
    J = np.zeros((2, len(q)))
    for j in range(k + 1):
        J[0, j] = -np.sum(lengths[j:k + 1] * np.sin(phi[j:k + 1]))
        J[1, j] = np.sum(lengths[j:k + 1] * np.cos(phi[j:k + 1]))
    return J


def chain_points(q, lengths):
    phi = np.cumsum(q)
    return np.cumsum(np.stack((lengths * np.cos(phi), lengths * np.sin(phi)), axis=1), axis=0)


def chain(q, qd, masses, lengths, g=G):
    """(M, bias) of the planar chain (module docstring)."""
    n = len(q)
    phi, w = np.cumsum(q), np.cumsum(qd)
    M, bias = np.zeros((n, n)), np.zeros(n)
    for k in range(n):
        J = chain_point_jacobian(q, lengths, k)
        acc = -np.sum(lengths[:k + 1, None] * (w[:k + 1, None] ** 2)
                      * np.stack((np.cos(phi[:k + 1]), np.sin(phi[:k + 1])), axis=1), axis=0)
        M += masses[k] * J.T @ J
        bias += masses[k] * J.T @ (acc + np.array([0.0, g]))
    return M, bias


def chain_energy(q, qd, masses, lengths, g=G):
    M, _ = chain(q, qd, masses, lengths, g)
    return 0.5 * qd @ M @ qd + g * np.sum(masses * chain_points(q, lengths)[:, 1])


def pendulum(q, qd, m=1.0, length=1.0, g=G):
    """(M, bias) of a point-mass pendulum, q from the downward vertical."""
    return np.array([[m * length * length]]), np.array([m * g * length * np.sin(q[0])])


def run(solver, model, q, qd, joints, drives, steps, contacts=None, record=None):
    """Step ``steps`` sub-steps; ``model(q, qd) -> (M, bias)``; ``drives`` a JointDrives or a function of the step
    index; ``contacts(q, qd) -> (ContactRows, FreeBodies)`` or None.  Returns q, qd and the lists of each step's
    (q, qd, JointStep)."""
    qs, qds, steps_out = [], [], []
    for k in range(steps):
        M, bias = model(q, qd)
        system = JointSystem(M, bias, np.zeros(len(qd)), q, qd)
        d = drives(k) if callable(drives) else drives
        rows, bodies = contacts(q, qd) if contacts else (None, None)
        step = solver.step(system, joints, d, rows, bodies)
        q, qd = integrate_dofs(q, step, solver.settings.h), step.velocity
        qs.append(q)
        qds.append(qd)
        steps_out.append(step)
        if record:
            record(k, q, qd, step)
    return np.array(qs), np.array(qds), steps_out


def position_drives(target, kp, kd):
    n = len(target)
    return JointDrives(np.full(n, DRIVE_POSITION, np.int64), np.asarray(target, float), np.zeros(n), np.zeros(n),
                       np.asarray(kp, float), np.asarray(kd, float))


def crossing_times(t, x):
    """Times where x crosses 0 upward, linearly interpolated."""
    i = np.nonzero((x[:-1] < 0.0) & (x[1:] >= 0.0))[0]
    return t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])


# ---- the closed forms themselves -----------------------------------------------------------------------------

def test_the_chain_helper_is_the_textbook_two_link_arm():
    m1, m2, l1, l2 = 1.3, 0.7, 0.5, 0.4
    rng = np.random.default_rng(1)
    for _ in range(5):
        q, qd = rng.uniform(-2, 2, 2), rng.uniform(-3, 3, 2)
        M, bias = chain(q, qd, np.array([m1, m2]), np.array([l1, l2]))
        c2, s2 = np.cos(q[1]), np.sin(q[1])
        M_ref = np.array([[m1 * l1 ** 2 + m2 * (l1 ** 2 + l2 ** 2 + 2 * l1 * l2 * c2), m2 * (l2 ** 2 + l1 * l2 * c2)],
                          [m2 * (l2 ** 2 + l1 * l2 * c2), m2 * l2 ** 2]])
        hh = -m2 * l1 * l2 * s2
        coriolis = np.array([hh * (2 * qd[0] * qd[1] + qd[1] ** 2), -hh * qd[0] ** 2])
        gravity = np.array([(m1 + m2) * G * l1 * np.cos(q[0]) + m2 * G * l2 * np.cos(q[0] + q[1]),
                            m2 * G * l2 * np.cos(q[0] + q[1])])
        np.testing.assert_allclose(M, M_ref, atol=1e-12)
        np.testing.assert_allclose(bias, coriolis + gravity, atol=1e-12)


# ---- no rows: the plain dynamics ---------------------------------------------------------------------------

@pytest.mark.parametrize("amplitude", [0.05, 2.0])
def test_pendulum_period_small_and_large_amplitude(amplitude):
    length = 1.0
    solver = JointSolver(H)
    qs, _, steps = run(solver, pendulum, np.array([amplitude]), np.zeros(1), JointProperties.free(1),
                       JointDrives.none(1), 1400)
    assert all(s.sweeps == 1 and s.contact_impulse.shape == (0, 3) for s in steps)  # no row was there
    t = H * np.arange(1, len(qs) + 1)
    ups = crossing_times(t, qs[:, 0])
    period = np.mean(np.diff(ups))
    exact = 4.0 * np.sqrt(length / G) * ellipk(np.sin(amplitude / 2) ** 2)
    assert abs(period - exact) < 1e-3 * exact
    small = 2.0 * np.pi * np.sqrt(length / G)
    if amplitude > 1.0:
        assert period > 1.25 * small  # the large swing is slower: the ellipk term is what is being checked


def test_free_three_link_chain_conserves_energy():
    masses, lengths = np.array([1.5, 1.0, 0.5]), np.array([0.4, 0.35, 0.3])
    solver = JointSolver(H)
    q0, qd0 = np.array([-np.pi / 2 + 0.3, 0.2, -0.2]), np.zeros(3)   # swinging about the hanging pose
    e0 = chain_energy(q0, qd0, masses, lengths)
    energies = []
    run(solver, lambda q, qd: chain(q, qd, masses, lengths), q0, qd0, JointProperties.free(3), JointDrives.none(3),
        480, record=lambda k, q, qd, s: energies.append(chain_energy(q, qd, masses, lengths)))
    # symplectic Euler: the energy oscillates by O(h), no drift (the bias's Coriolis terms are consistent with M)
    swing = e0 - chain_energy(np.array([-np.pi / 2, 0, 0]), qd0, masses, lengths)
    assert np.max(np.abs(np.array(energies) - e0)) < 0.02 * swing


# ---- limits ----------------------------------------------------------------------------------------------------

def test_limit_stops_a_pendulum_without_overshoot_or_energy_gain():
    length, upper = 1.0, 0.3
    joints = JointProperties.free(1)._replace(lower=np.array([-np.inf]), upper=np.array([upper]))
    solver = JointSolver(H)
    qs, qds, steps = run(solver, pendulum, np.array([-np.pi / 2]), np.zeros(1), joints, JointDrives.none(1), 720)
    q = qs[:, 0]
    assert q.max() > upper - 1e-6                   # it reached the stop ...
    assert (q.max() - upper) * length < 1e-3        # ... and went past it by less than 1 mm at the bob
    # speculatively: the velocity row itself closes the gap exactly, the position stage had nothing to do
    assert max(abs(s.pseudo_velocity[0]) for s in steps) < 1e-9
    hit = int(np.argmax(q > upper - 1e-3))
    energy = 0.5 * length ** 2 * qds[:, 0] ** 2 + G * length * (1 - np.cos(q))
    at_stop = G * length * (1 - np.cos(upper))
    # inelastic stop: afterwards it swings between −0.3 and the stop, never with more energy than resting there
    assert energy[hit + 1:].max() < 1.02 * at_stop
    assert abs(q[hit + 1:].min() + upper) < 0.01
    # the limit row reports its torque: while pressing at the stop the effort is negative (pushes back)
    assert min(s.effort[0] for s in steps[hit:hit + 3]) < -1.0


def test_penetrated_limit_is_corrected_by_position_not_velocity():
    joints = JointProperties.free(1)._replace(lower=np.array([0.0]))
    solver = JointSolver(H)
    system = JointSystem(np.array([[1.0]]), np.zeros(1), np.zeros(1), np.array([-0.05]), np.zeros(1))
    step = solver.step(system, joints, JointDrives.none(1))
    assert step.velocity[0] == 0.0                               # no velocity (no energy) from the correction
    q = integrate_dofs(system.position, step, H)
    assert abs(q[0]) < 1e-12                                     # β = 1: out in one sub-step


# ---- mimic --------------------------------------------------------------------------------------------------

def test_mimic_holds_exactly_while_the_leader_is_driven():
    masses, lengths = np.array([1.0, 0.6]), np.array([0.5, 0.4])
    mult, offset = -0.5, 0.1
    joints = JointProperties.free(2)._replace(mimic_follower=np.array([1]), mimic_leader=np.array([0]),
                                              mimic_multiplier=np.array([mult]), mimic_offset=np.array([offset]))
    kp, kd = position_gains(chain(np.zeros(2), np.zeros(2), masses, lengths)[0], H)

    def drives(k):
        d = position_drives([0.5 * np.sin(2.0 * k * H), 0.0], kp, kd)
        return d._replace(mode=np.array([DRIVE_POSITION, 0], np.int64))   # the follower is not driven

    solver = JointSolver(H)
    q0 = np.array([0.0, 0.3])  # starts off the coupling by 0.2 rad: the first sub-step's position stage fixes it
    qs, _, _ = run(solver, lambda q, qd: chain(q, qd, masses, lengths), q0, np.zeros(2), joints, drives, 1200)
    error = qs[:, 1] - (mult * qs[:, 0] + offset)
    assert np.max(np.abs(error)) < 1e-6
    assert np.ptp(qs[:, 0]) > 0.8  # the leader did move (and gravity pulled at both)


# ---- friction and damping -----------------------------------------------------------------------------------

@pytest.mark.parametrize("friction", [8.0, 3.0])
def test_coulomb_friction_holds_below_and_slides_above(friction):
    m, slope = 2.0, 0.3
    load = m * G * np.sin(slope)   # 5.77 N down the slope (bias: +load, pulling q negative)
    joints = JointProperties.free(1)._replace(friction=np.array([friction]))
    solver = JointSolver(H)
    qs, qds, steps = run(solver, lambda q, qd: (np.array([[m]]), np.array([load])), np.array([0.2]), np.zeros(1),
                         joints, JointDrives.none(1), 240)
    t = H * np.arange(1, 241)
    if friction > load:
        assert np.max(np.abs(qs[:, 0] - 0.2)) < 1e-12 and np.max(np.abs(qds)) < 1e-12
        assert abs(steps[-1].effort[0] - load) < 1e-9        # static friction balances the load
    else:
        np.testing.assert_allclose(qds[:, 0], -(load - friction) / m * t, rtol=1e-9)
        assert abs(steps[-1].effort[0] - friction) < 1e-9    # sliding: the full friction force


def test_viscous_damping_decays_as_the_exponential():
    inertia, c = 2.0, 3.0
    joints = JointProperties.free(1)._replace(damping=np.array([c]))
    solver = JointSolver(H)
    _, qds, steps = run(solver, lambda q, qd: (np.array([[inertia]]), np.zeros(1)), np.zeros(1), np.ones(1), joints,
                        JointDrives.none(1), 240)
    k = np.arange(1, 241)
    np.testing.assert_allclose(qds[:, 0], (1.0 + c * H / inertia) ** -k, rtol=1e-12)   # backward Euler exactly
    exact = np.exp(-c * H * k / inertia)
    # and the exponential within the scheme's known error, n (c h / I)² / 2 to first order
    assert np.max(np.abs(qds[:, 0] / exact - 1)) < 240 * (c * H / inertia) ** 2
    assert abs(steps[-1].effort[0] + c * qds[-1, 0]) < 1e-12    # the damping torque is in the effort


def test_velocity_limit_caps_the_speed_exactly():
    m, push, vmax = 1.0, 10.0, 2.0
    joints = JointProperties.free(1)._replace(velocity_limit=np.array([vmax]), effort_limit=np.array([100.0]))
    drives = JointDrives.none(1)._replace(mode=np.array([DRIVE_EFFORT], np.int64), target_effort=np.array([push]))
    _, qds, steps = run(JointSolver(H), lambda q, qd: (np.array([[m]]), np.zeros(1)), np.zeros(1), np.zeros(1),
                        joints, drives, 120)
    t = H * np.arange(1, 121)
    np.testing.assert_allclose(qds[:, 0], np.minimum(push / m * t, vmax), rtol=0, atol=1e-12)
    free, capped = t < vmax * m / push - H, t > vmax * m / push + H
    assert all(abs(s.effort[0] - push) < 1e-12 for s, f in zip(steps, free) if f)   # the drive alone
    assert all(abs(s.effort[0]) < 1e-9 for s, c in zip(steps, capped) if c)         # the cap takes it all back


# ---- drives -------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("links", [3, 7])
def test_position_drives_hold_a_chain_against_gravity(links):
    rng = np.random.default_rng(links)
    masses, lengths = rng.uniform(0.5, 2.0, links), rng.uniform(0.2, 0.4, links)
    target = rng.uniform(-0.5, 0.5, links)
    M0, _ = chain(target, np.zeros(links), masses, lengths)
    kp, kd = position_gains(M0, H)
    joints = JointProperties.free(links)._replace(effort_limit=np.full(links, 300.0))
    solver = JointSolver(H)
    qs, _, steps = run(solver, lambda q, qd: chain(q, qd, masses, lengths), target.copy(), np.zeros(links), joints,
                       position_drives(target, kp, kd), 480)
    assert np.max(np.abs(qs - target)) <= 1e-3
    gravity = chain(qs[-1], np.zeros(links), masses, lengths)[1]
    np.testing.assert_allclose(steps[-1].effort, gravity, rtol=1e-6, atol=1e-9)   # the drives carry the weight
    assert np.max(np.abs(steps[-1].effort)) < 300.0


def test_saturated_drive_reports_its_limit_and_sags_as_a_constant_torque_would():
    masses, lengths = np.array([1.5, 1.0, 0.5]), np.array([0.4, 0.35, 0.3])
    target = np.zeros(3)   # straight out, horizontal: the base carries ~18 N m of gravity
    kp, kd = position_gains(chain(target, np.zeros(3), masses, lengths)[0], H)
    limit = np.array([5.0, 100.0, 100.0])
    joints = JointProperties.free(3)._replace(effort_limit=limit)
    model = lambda q, qd: chain(q, qd, masses, lengths)  # noqa: E731
    held = position_drives(target, kp, kd)
    qs, _, steps = run(JointSolver(H), model, target.copy(), np.zeros(3), joints, held, 120)
    assert all(abs(s.effort[0] - 5.0) < 1e-12 for s in steps)        # the reported effort is the limit
    assert qs[-1, 0] < -0.05                                          # and the arm sags
    # physics says: a drive at its limit is a constant torque — the same arm with an effort drive of +5 N m
    pushed = held._replace(mode=np.array([DRIVE_EFFORT, DRIVE_POSITION, DRIVE_POSITION], np.int64),
                           target_effort=np.array([5.0, 0.0, 0.0]))
    qs_ref, _, _ = run(JointSolver(H), model, target.copy(), np.zeros(3), joints, pushed, 120)
    np.testing.assert_allclose(qs, qs_ref, atol=1e-9)


def test_velocity_drive_is_backward_euler_in_its_damping():
    m, kd, target = 2.0, 50.0, 1.5
    drives = JointDrives.none(1)._replace(mode=np.array([DRIVE_VELOCITY], np.int64), target_velocity=np.array([target]),
                                          damping=np.array([kd]))
    _, qds, steps = run(JointSolver(H), lambda q, qd: (np.array([[m]]), np.zeros(1)), np.zeros(1), np.zeros(1),
                        JointProperties.free(1), drives, 240)
    k = np.arange(1, 241)
    np.testing.assert_allclose(qds[:, 0], target * (1 - (1 + H * kd / m) ** -k), rtol=1e-12)
    assert abs(steps[0].effort[0] - kd * (target - qds[0, 0])) < 1e-12


def test_a_sub_step_at_rest_against_its_rows_is_what_the_stages_give():
    """A sub-step whose rows all stay at zero is answered without building them (joint_solver.rows_at_rest,
    rest_step): the same bits as the stages.  Each random 3-link chain (joint and velocity limits, position drives
    of random effort limits, sometimes friction; some near a limit, some fast, some saturated) is stepped twice
    from the same state: once as it is, and once with a warm-start memory holding an impulse for a row no
    sub-step has — which the stages ignore but rows_at_rest refuses, so that run always takes the stages."""
    from cgp_core.robots.joint_solver import KEY_SLOTS, ROW_MIMIC, SOLVE, JointSolverMemory

    rng = np.random.default_rng(35)
    masses, lengths = np.array([1.5, 1.0, 0.5]), np.array([0.4, 0.35, 0.3])
    rested = 0
    for trial in range(60):
        lower, upper = -rng.uniform(0.3, 1.5, 3), rng.uniform(0.3, 1.5, 3)
        q = rng.uniform(lower - 0.02, upper + 0.02)  # some past a limit, some near one
        qd = rng.normal(0.0, 0.3 if trial % 2 else 4.0, 3)
        joints = JointProperties.free(3)._replace(
            lower=lower, upper=upper, velocity_limit=np.full(3, 3.0),
            effort_limit=np.where(rng.random(3) < 0.1, 5.0, 1e4), friction=np.where(rng.random(3) < 0.1, 0.2, 0.0))
        target = q + rng.normal(0.0, 1e-3, 3)  # held near where it is
        kp, kd = position_gains(chain(target, np.zeros(3), masses, lengths)[0], H)
        M, bias = chain(q, qd, masses, lengths)
        system = JointSystem(M, bias, np.zeros(3), q, qd)
        solvers = JointSolver(H), JointSolver(H)
        solvers[1].memory = JointSolverMemory(np.array([ROW_MIMIC * KEY_SLOTS + 99]), np.array([1.0]))
        shortcut, stages = (s.step(system, joints, position_drives(target, kp, kd)) for s in solvers)
        assert solvers[1].profile.seconds[SOLVE] > 0.0  # the stages ran
        rested += solvers[0].profile.seconds[SOLVE] == 0.0
        for a, b in zip(shortcut, stages):
            assert np.array_equal(np.asarray(a), np.asarray(b)) and np.shape(a) == np.shape(b), trial
        for a, b in zip(solvers[0].memory, solvers[1].memory):
            assert np.array_equal(a, b) and a.dtype == b.dtype, trial
    assert 15 <= rested <= 45  # both kinds of sub-step were compared


def test_stiff_drive_is_stable():
    kp, inertia = 1e6, 1.0
    drives = position_drives([0.0], [kp], [0.0])
    solver = JointSolver(H)
    energies = []
    qs, qds, _ = run(solver, lambda q, qd: (np.array([[inertia]]), np.zeros(1)), np.array([0.5]), np.zeros(1),
                     JointProperties.free(1), drives, 480,
                     record=lambda k, q, qd, s: energies.append(0.5 * inertia * qd[0] ** 2 + 0.5 * kp * q[0] ** 2))
    assert np.all(np.isfinite(qs)) and np.max(np.abs(qs)) <= 0.5
    assert np.all(np.diff(energies) <= 1e-9)      # backward Euler in the drive only dissipates
    assert abs(qs[-1, 0]) < 1e-9


# ---- contacts -----------------------------------------------------------------------------------------------

def test_arm_resting_on_a_plane_gets_the_gravity_torques_share():
    """A rod on a pivot at the origin, horizontal (q = 0), its tip (at l) on the plane y = 0."""
    m, length, mu = 2.0, 1.0, 0.5
    d = length / 2
    inertia = m * length ** 2 / 3

    def model(q, qd):
        return np.array([[inertia]]), np.array([m * G * d * np.cos(q[0])])

    def contacts(q, qd):
        jac = np.array([[length * np.cos(q[0])], [-length * np.sin(q[0])], [0.0]])   # n = y, t₁ = x, t₂ = z
        return (ContactRows(jac[None], np.array([-1]), np.zeros((1, 3, 6)), np.array([length * np.sin(q[0])]),
                            np.array([mu]), np.array([7])), FreeBodies.empty())

    solver = JointSolver(H)
    qs, _, steps = run(solver, model, np.zeros(1), np.zeros(1), JointProperties.free(1), JointDrives.none(1), 240,
                       contacts=contacts)
    assert np.max(np.abs(qs)) < 1e-12
    for s in steps:
        assert abs(s.contact_impulse[0, 0] - H * m * G * d / length) < 1e-12   # N l = m g d
        assert s.effort[0] == 0.0


def test_penetration_into_the_ground_is_removed_without_velocity():
    """No gravity.  The rod's tip starts 1 cm inside the plane: the position stage lifts it by β (s + slop) per
    sub-step and never gives it a velocity."""
    length = 1.0

    def contacts(q, qd):
        jac = np.array([[length * np.cos(q[0])], [-length * np.sin(q[0])], [0.0]])
        return (ContactRows(jac[None], np.array([-1]), np.zeros((1, 3, 6)), np.array([length * np.sin(q[0])]),
                            np.array([0.5]), np.array([7])), FreeBodies.empty())

    solver = JointSolver(H)
    s = solver.settings
    q0 = -np.arcsin(0.01 / length)
    qs, qds, _ = run(solver, lambda q, qd: (np.array([[1.0]]), np.zeros(1)), np.array([q0]), np.zeros(1),
                     JointProperties.free(1), JointDrives.none(1), 60, contacts=contacts)
    assert np.all(qds == 0.0)
    gap = length * np.sin(qs[:, 0])
    assert abs(gap[0] - (-0.01 + s.contact_correction * (0.01 - s.penetration_slop))) < 1e-5   # linearized
    assert np.all(np.diff(gap) >= 0) and abs(gap[-1] + s.penetration_slop) < 1e-6


def test_drive_pressing_on_a_contact_is_held_to_its_effort_limit():
    """No gravity.  The rod of the test above, its drive's target 5e-4 rad below the plane: unconstrained, the
    stiff drive's torque at its end velocity stays under the limit; held by the contact, it would be kp · 5e-4 =
    50 N m.  The drive saturates at its limit, and the plane carries exactly that torque's share."""
    m, length, limit = 2.0, 1.0, 10.0
    inertia = m * length ** 2 / 3
    kp, kd = position_gains(np.array([[inertia]]), H)
    kp = np.array([1e5])
    drives = position_drives([-5e-4], kp, kd)
    joints = JointProperties.free(1)._replace(effort_limit=np.array([limit]))

    def contacts(q, qd):
        jac = np.array([[length * np.cos(q[0])], [-length * np.sin(q[0])], [0.0]])
        return (ContactRows(jac[None], np.array([-1]), np.zeros((1, 3, 6)), np.array([length * np.sin(q[0])]),
                            np.array([0.5]), np.array([7])), FreeBodies.empty())

    solver = JointSolver(H)
    qs, _, steps = run(solver, lambda q, qd: (np.array([[inertia]]), np.zeros(1)), np.zeros(1), np.zeros(1), joints,
                       drives, 60, contacts=contacts)
    assert np.max(np.abs(qs)) < 1e-12
    for s in steps:
        assert abs(s.effort[0] + limit) < 1e-9                               # the drive pushes down at its limit
        assert abs(s.contact_impulse[0, 0] - H * limit / length) < 1e-12     # and the plane pushes back that much


def test_pendulum_hitting_a_free_box_conserves_momentum_and_loses_energy():
    """No gravity.  A point bob (m, l) on a pivot at the origin, q from the downward vertical, swings into a free
    cube (mass mb, half-size a) whose left face it meets at the bottom."""
    m, length, mb, a, mu = 1.0, 1.0, 2.0, 0.1, 0.3
    inertia_b = mb * (2 * a) ** 2 / 6
    box = {"x": np.array([length * np.sin(0.0) + a + 0.01, -length, 0.0]), "P": np.zeros(3), "L": np.zeros(3)}
    pushed = []

    def bob(q):
        return np.array([length * np.sin(q[0]), -length * np.cos(q[0]), 0.0])

    def contacts(q, qd):
        p, x = bob(q), box["x"]
        n, t1, t2 = np.array([-1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0])
        separation = (x[0] - a) - p[0]
        if separation > 0.05 or abs(p[1] - x[1]) > a:
            return ContactRows.empty(1), FreeBodies.empty()
        dp = np.array([length * np.cos(q[0]), length * np.sin(q[0]), 0.0])    # ∂p/∂q
        r = p - x          # COM → the contact point, the same point on both sides (the bob)
        jac = np.array([[n @ dp], [t1 @ dp], [t2 @ dp]])
        body_jac = np.array([np.concatenate((-e, -np.cross(r, e))) for e in (n, t1, t2)])
        velocity = np.concatenate((box["P"] / mb, box["L"] / inertia_b))[None]
        bodies = FreeBodies(np.array([1 / mb]), np.eye(3)[None] / inertia_b, velocity, box["P"][None],
                            box["L"][None])
        box["bodies"] = bodies
        return ContactRows(jac[None], np.array([0]), body_jac[None], np.array([separation]), np.array([mu]),
                           np.array([3])), bodies

    def momentum(q, qd):
        return m * length ** 2 * qd[0] + np.cross(box["x"], box["P"])[2] + box["L"][2]

    def energy(q, qd):
        box_energy = 0.5 * box["P"] @ box["P"] / mb + 0.5 * box["L"] @ box["L"] / inertia_b
        return 0.5 * m * length ** 2 * qd[0] ** 2 + box_energy

    q, qd = np.array([-0.3]), np.array([2.0])
    solver = JointSolver(H)
    l0, e0 = momentum(q, qd), energy(q, qd)
    for _ in range(120):
        rows, bodies = contacts(q, qd)
        system = JointSystem(np.array([[m * length ** 2]]), np.zeros(1), np.zeros(1), q, qd)
        before = box["P"].copy()
        step = solver.step(system, JointProperties.free(1), JointDrives.none(1), rows, bodies)
        if len(rows.key):
            box["P"], box["L"] = bodies.linear_momentum[0].copy(), bodies.angular_momentum[0].copy()
            # the box's momentum changes by exactly the contact impulse (the normal pushes it along +x)
            assert abs(box["P"][0] - before[0] - step.contact_impulse[0, 0]) < 1e-12
            pushed.append(step.contact_impulse[0, 0])
        q, qd = integrate_dofs(q, step, H), step.velocity
        box["x"] = box["x"] + H * box["P"] / mb
        assert abs(momentum(q, qd) - l0) < 1e-12   # about the pivot: the contact impulse is internal
        assert energy(q, qd) <= e0 + 1e-12
    assert sum(pushed) > 0.5 and box["P"][0] > 0.5
    # an inelastic hit at the bottom: bob and box leave together, ω = m l² ω₀ / (m l² + mb l²) nearly
    assert energy(q, qd) < 0.9 * e0


def test_warm_start_converges_a_resting_contact_in_fewer_sweeps():
    """A 3-link arm, joints 1 and 2 position-driven, joint 0 free, its tip resting on the ground with friction."""
    masses, lengths = np.array([1.0, 1.0, 1.0]), np.array([0.4, 0.4, 0.4])
    q0 = np.array([-0.5, 0.5, 0.5])
    tip_height = chain_points(q0, lengths)[-1, 1]
    kp, kd = position_gains(chain(q0, np.zeros(3), masses, lengths)[0], H)
    drives = position_drives(q0, kp, kd)._replace(mode=np.array([0, DRIVE_POSITION, DRIVE_POSITION], np.int64))

    def contacts(q, qd):
        J = chain_point_jacobian(q, lengths, 2)
        jac = np.stack((J[1], J[0], np.zeros(3)))
        gap = chain_points(q, lengths)[-1, 1] - tip_height
        return (ContactRows(jac[None], np.array([-1]), np.zeros((1, 3, 6)), np.array([gap]), np.array([1.0]),
                            np.array([0])), FreeBodies.empty())

    sweeps = {}
    for warm in (True, False):
        solver = JointSolver(H, warm_start=warm, velocity_iterations=200, velocity_tolerance=1e-10)
        qs, _, steps = run(solver, lambda q, qd: chain(q, qd, masses, lengths), q0.copy(), np.zeros(3),
                           JointProperties.free(3), drives, 240, contacts=contacts)
        assert np.max(np.abs(qs - q0)) < 1e-3          # it rests
        sweeps[warm] = sum(s.sweeps for s in steps[120:])
    assert sweeps[True] < 0.5 * sweeps[False]


def test_bad_bundles_are_refused_before_the_kernels():
    solver = JointSolver(H)
    system = JointSystem(np.eye(2), np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2))
    bad_mimic = JointProperties.free(2)._replace(mimic_follower=np.array([1]), mimic_leader=np.array([2]),
                                                 mimic_multiplier=np.ones(1), mimic_offset=np.zeros(1))
    with pytest.raises(ValueError, match="mimic dofs"):
        solver.step(system, bad_mimic, JointDrives.none(2))
    contacts = ContactRows(np.zeros((1, 3, 2)), np.array([0]), np.zeros((1, 3, 6)), np.zeros(1), np.zeros(1),
                           np.array([0]))
    with pytest.raises(ValueError, match="contact bodies"):
        solver.step(system, JointProperties.free(2), JointDrives.none(2), contacts, FreeBodies.empty())
    with pytest.raises(ValueError, match="mass_matrix"):
        solver.step(system._replace(mass_matrix=np.eye(3)), JointProperties.free(2), JointDrives.none(2))
    with pytest.raises(ValueError, match="sub-step"):
        JointSolver(0.0)


# ---- compiled and plain Python agree -------------------------------------------------------------------------

def scenario() -> np.ndarray:
    """A 3-link arm with every row kind: drives (one saturating), friction, a velocity limit, a mimic, a limit,
    and its tip touching a free box; the trajectory and efforts (steps, 9)."""
    masses, lengths = np.array([1.5, 1.0, 0.5]), np.array([0.4, 0.35, 0.3])
    target = np.array([0.2, -0.3, 0.0])
    kp, kd = position_gains(chain(target, np.zeros(3), masses, lengths)[0], H)
    drives = position_drives(target, kp, kd)._replace(mode=np.array([DRIVE_POSITION, DRIVE_POSITION, 0], np.int64))
    joints = JointProperties(np.array([-1.0, -0.25, -1.0]), np.full(3, 1.0), np.array([300.0, 2.0, 10.0]),
                             np.array([np.inf, 1.0, np.inf]), np.array([0.1, 0.0, 0.05]), np.array([0.0, 0.3, 0.0]),
                             np.array([2]), np.array([1]), np.array([0.5]), np.array([0.0]))
    box = {"P": np.array([0.0, 0.5, 0.0]), "L": np.zeros(3)}

    def contacts(q, qd):
        J = chain_point_jacobian(q, lengths, 2)
        jac = np.stack((J[1], J[0], np.zeros(3)))
        r = np.array([0.1, 0.1, 0.0])
        body_jac = np.array([np.concatenate((-e, -np.cross(r, e))) for e in np.eye(3)[[1, 0, 2]]])
        bodies = FreeBodies(np.array([1.0]), np.eye(3)[None] * 6.0, np.concatenate((box["P"], box["L"] * 6))[None],
                            box["P"][None].copy(), box["L"][None].copy())
        box["bodies"] = bodies
        return (ContactRows(jac[None], np.array([0]), body_jac[None], np.array([0.01]), np.array([0.4]),
                            np.array([0])), bodies)

    out = []

    def record(k, q, qd, step):
        box["P"], box["L"] = box["bodies"].linear_momentum[0], box["bodies"].angular_momentum[0]
        out.append(np.concatenate((q, qd, step.effort)))

    run(JointSolver(H), lambda q, qd: chain(q, qd, masses, lengths), np.array([0.0, 0.0, 0.0]), np.zeros(3),
        joints, drives, 60, contacts=contacts, record=record)
    return np.array(out)


PARITY = r"""
import importlib.util, sys
import numpy as np
from cgp_core.jit import JIT_DISABLED
assert JIT_DISABLED == (sys.argv[2] == "plain")
spec = importlib.util.spec_from_file_location("tjs", sys.argv[3])
module = importlib.util.module_from_spec(spec)
spec.loader.exec_module(module)
np.save(sys.argv[1], module.scenario())
"""


def test_compiled_and_plain_python_agree(tmp_path):
    results = {}
    for mode in ("compiled", "plain"):
        env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
        env.pop("NUMBA_DISABLE_JIT", None)
        if mode == "plain":
            env["NUMBA_DISABLE_JIT"] = "1"
        path = tmp_path / f"{mode}.npy"
        done = subprocess.run([sys.executable, "-c", PARITY, str(path), mode, __file__], env=env,
                              capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-3000:]
        results[mode] = np.load(path)
    assert results["compiled"].shape == (60, 9)
    np.testing.assert_allclose(results["compiled"], results["plain"], rtol=0, atol=1e-12)


def test_the_factorization_of_a_block_diagonal_a_is_the_dense_one_and_its_solves_stay_in_their_blocks():
    """An island of robots has a block-diagonal A (one block per robot): the envelope Cholesky (which skips what
    lies outside the envelope) gives the dense loops' factor, the blocks are found from it, and a right-hand side
    inside some blocks is solved there alone — the dense solve's numbers, zeros elsewhere."""
    from cgp_core.robots.joint_solver import (
        cholesky,
        cholesky_solve,
        cholesky_solve_into,
        diagonal_blocks,
        envelope,
    )

    rng = np.random.default_rng(11)
    sizes = [3, 1, 4, 2]
    n = sum(sizes)
    A = np.zeros((n, n))
    at = 0
    for size in sizes:
        B = rng.normal(size=(size, size))
        A[at:at + size, at:at + size] = B @ B.T + size * np.eye(size)
        at += size
    A[5, 3] = A[3, 5] = 0.0  # a zero inside the third block, under its envelope: still one block
    A[6, 3] = A[3, 6] = 0.0
    first = envelope(A)
    assert first.tolist() == [0, 0, 0, 3, 4, 4, 4, 4, 8, 8]
    block_start, block_end = diagonal_blocks(first)
    assert block_start.tolist() == [0, 0, 0, 3, 4, 4, 4, 4, 8, 8]
    assert block_end.tolist() == [3, 3, 3, 4, 8, 8, 8, 8, 10, 10]
    L = cholesky(A, first)
    # the dense loops: the same function with an envelope of zeros, every column of every row (nothing skipped)
    assert np.array_equal(L, cholesky(A, np.zeros(n, np.int64)))
    np.testing.assert_allclose(L @ L.T, A, atol=1e-12)
    b = np.zeros(n)
    b[4:8] = rng.normal(size=4)  # the third block only
    x = np.full(n, 7.0)  # outside the range: left as it is
    cholesky_solve_into(L, b, 4, 8, x)
    assert np.array_equal(x[4:8], cholesky_solve(L, b)[4:8])
    assert np.all(x[:4] == 7.0) and np.all(x[8:] == 7.0)
    assert np.all(cholesky_solve(L, b)[np.r_[0:4, 8:10]] == 0.0)

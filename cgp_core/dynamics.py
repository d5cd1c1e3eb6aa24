"""The rigid-body sub-step: the pipeline :class:`~cgp_core.world.World` runs ``substeps`` times per tick.

:func:`step_bodies` runs the stages of ARCHITECTURE.md ("The step pipeline") in order, each named where it
runs.  Everything about contacts — detection settings, solver settings, warm-start memory — lives in the
``solver`` object (and its ``solver.detector``), so this function is the whole order of events and nothing
else.

Usage (no World needed)::

    from cgp_core.dynamics import Ground, step_bodies
    from cgp_core.integrators import make_integrator
    from cgp_core.solver import make_solver
    integrator, solver = make_integrator("symplectic_euler"), make_solver()
    for _ in range(240):
        step_bodies(model, state, integrator, solver, 1 / 240, gravity=(0, 0, -9.81), ground=Ground())
"""

from __future__ import annotations

import numpy as np

from .bodies import BodyModel, BodyState, tensor_times, world_tensor
from .checks import positive
from .collision.contacts import ContactSet
from .collision.materials import Ground
from .forces import apply_damping, apply_gravity
from .integrators.base import Integrator
from .jit import njit
from .rotation import quat_to_matrices
from .sleep import Islands
from .solver.base import ContactSolver

__all__ = ["Ground", "step_bodies"]


def step_bodies(model: BodyModel, state: BodyState, integrator: Integrator, solver: ContactSolver, h: float, *,
                gravity, ground: Ground | None, damping: tuple[float, float] = (0.0, 0.0),
                islands: Islands | None = None, robots=None) -> ContactSet:
    """Advance all bodies (the awake ones, with ``islands``) by one sub-step of ``h`` seconds, in place.

    Args:
        gravity:          (3,) m/s².
        ground:           the static plane z = 0 (:class:`Ground`), or ``None`` for a scene without one.
        damping:          ``(linear, angular)`` viscous rates [1/s] (:func:`cgp_core.forces.apply_damping`).
        robots:           the world's robots (:class:`cgp_core.robots.world.Robots`) or ``None``: their links
                          are bodies of ``model`` whose motion the robot stage computes in joint space.
        islands:          per-island sleep state (:class:`cgp_core.sleep.Islands`): sleeping bodies are left
                          out (no forces, no integration; static to the awake ones) and an island an awake body
                          touches is woken here.  ``None``: every body is stepped.

    Forces and torques already in ``state.force`` / ``state.torque`` (wrench commands) are kept and act with
    gravity over this sub-step; the accumulators are cleared at the end.  Returns the contacts of the sub-step.
    """
    h = positive(h, "sub-step h [s]")
    try:
        gravity = np.asarray(gravity, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"gravity must be 3 finite numbers [m/s²], got {gravity!r}") from None
    if gravity.shape != (3,) or not np.isfinite(gravity).all():
        raise ValueError(f"gravity must be 3 finite numbers [m/s²], got {gravity.tolist()}")

    active = None if islands is None else islands.awake

    # 1. accumulate forces (on top of any wrench forces already accumulated by the caller); wrenches on robot
    #    links become joint efforts (the robot stage adds gravity in joint space itself)
    if robots is not None:
        robots.take_wrenches(model, state)
    apply_gravity(model, state, gravity)
    apply_damping(model, state, *damping)
    if active is not None:
        state.force[~active] = 0.0  # sleeping bodies are held where they rest
        state.torque[~active] = 0.0

    # 2. detect contacts, with speculative margins sized by the velocities the bodies are about to move with.
    #    The poses do not change before stage 4, so R and I_world⁻¹ (n, 3, 3) are computed once here and handed
    #    to detection and the solver (each would otherwise rebuild them from the quaternions)
    R = quat_to_matrices(state.orientation) if state.rotation is None else np.ascontiguousarray(state.rotation)
    inv_inertia, velocity, angular_velocity = coming_velocities(R, model.inv_inertia_body, model.inv_mass,
                                                                state.linear_momentum, state.angular_momentum,
                                                                state.force, state.torque, h)
    contacts = solver.detector.detect(model, state, h, ground=ground, velocity=velocity,
                                      angular_velocity=angular_velocity, rotation=R, active=active)
    if islands is not None and solver.detector.touched_sleeping.size:
        # an awake body reached a sleeping island: it wakes (at rest, as it slept) and takes part from now on
        islands.wake(solver.detector.touched_sleeping)
        active = islands.awake
        contacts = solver.detector.detect(model, state, h, ground=ground, velocity=velocity,
                                          angular_velocity=angular_velocity, rotation=R, active=active)

    # 3a. robot stage: the contacts that touch a link are rows in the robots' joint space, with limits, drives,
    #     mimic couplings and joint friction (cgp_core.robots.world); the robots whose links touch no free body
    #     are solved here, those that do are handed to 3b (``coupled``), with the remaining contacts
    coupled = None
    if robots is not None and robots.n_dofs:
        robots.active = active  # sleeping robots (their links asleep) are not stepped
        contacts = robots.solve(contacts, model, state, h, gravity)
        coupled = robots.coupled

    # 3b. solve contacts: impulses added to P and L as momentum changes at the start of the sub-step, so that
    #    momentum + h·force + impulse satisfies non-penetration, restitution and friction; the robots whose links
    #    touch a free body (``coupled``) have their rows solved in the same loop (cgp_core.robots.coupled)
    solver.solve_velocities(model, state, contacts, h, inv_inertia=inv_inertia, active=active, coupled=coupled)

    # 4. integrate; then continuous collision for bodies turning fast next to fixed hulls and meshes (put back at
    #    their time of impact: cgp_core.collision.convex_phase)
    if robots is not None and robots.n_dofs:
        # bodies moved by joints are not the integrator's (their momenta are the joints', their poses written
        # from q below): an implicit integrator would iterate on them for nothing, or fail to converge
        free = robots.body_robot < 0
        integrator.step(model, state, h, active=free if active is None else active & free)
    else:
        integrator.step(model, state, h, active=active)
    if robots is not None and robots.n_dofs:
        robots.integrate(h)
        robots.write_bodies(model, state)  # the links where the joints put them, whatever the integrator did
        robots.displace_free_bodies(model, state)  # the position stage of a sub-step with coupled robots (3b)
    solver.detector.sweep_fast_rotation(model, state, h)

    # 5. recover penetration (moves bodies apart; momenta untouched: adds no kinetic energy); nothing to do after a
    #    sub-step with coupled robots, whose one position loop corrected the contacts between free bodies too
    solver.recover_penetration(model, state, h)

    # 6. clear accumulators
    state.clear_accumulators()
    return contacts


@njit
def coming_velocities(R, inv_inertia_body, inv_mass, linear_momentum, angular_momentum, force, torque, h):
    """World-frame I⁻¹ = R I_body⁻¹ Rᵀ ``(n, 3, 3)`` (:func:`~cgp_core.bodies.world_tensor`), and the velocities
    the bodies will move with over the sub-step without contacts, v = (P + h F) / m and ω = I⁻¹ (L + h τ)
    (:func:`~cgp_core.bodies.tensor_times`) ``(n, 3)`` each."""
    n = len(R)
    inv_inertia = np.empty((n, 3, 3))
    velocity = np.empty((n, 3))
    angular_velocity = np.empty((n, 3))
    L, T = angular_momentum, torque
    for i in range(n):
        world_tensor(R[i], inv_inertia_body[i], inv_inertia[i])
        for k in range(3):
            velocity[i, k] = (linear_momentum[i, k] + h * force[i, k]) * inv_mass[i]
        angular_velocity[i, 0], angular_velocity[i, 1], angular_velocity[i, 2] = tensor_times(
            inv_inertia[i], L[i, 0] + h * T[i, 0], L[i, 1] + h * T[i, 1], L[i, 2] + h * T[i, 2])
    return inv_inertia, velocity, angular_velocity

"""The robots' joint-space rows and the free bodies' contact rows in ONE solve loop (issue 35), for the sub-steps
in which a link touches a free body.

**Why.**  A link pressing a free body against something else — a crate pushed across the ground, a box squeezed
between a gripper and a wall — is one constraint problem: the link's row and the crate's ground rows act on the
same crate velocity.  Solved as two Gauss–Seidel blocks one after the other (first every robot row, then every
body row), the robot sees the crate move freely and gives it the link's speed; the ground's friction then takes
some of it back, and the link runs on into the crate every sub-step (at a median 5 cm/s, 2.8 cm deep after 1.5 s
in tests/test_robot_world.py's push).  Here every sweep visits both kinds of rows on one shared velocity state of the
free bodies (the body solver's V, n + 1 rows), as Bullet's btMultiBodyConstraintSolver does, so the crate's
velocity at the end of the sub-step satisfies the link row and the ground rows together.

**The sub-step** (:func:`step_coupled`, one compiled call; the robots are those whose links touch a free body, as
one joint-space system, :meth:`cgp_core.robots.world.Robots.solve`):

1. the body solver's :func:`~cgp_core.solver.sequential_impulse.prepare_bodies`: V = M⁻¹ (momentum + h·force);
2. the joint solver's prepare and warm start (:func:`~.joint_solver.prepare_joints`,
   :func:`~.joint_solver.warm_start_joints`): the robot's rows, their free body's share of the warm impulses on V;
3. the body solver's prepare and warm start (:func:`~cgp_core.solver.sequential_impulse.prepare_contacts`,
   :func:`~cgp_core.solver.sequential_impulse.warm_start_contacts`) on that V;
4. the sweeps (:func:`solve_together`): a joint-row sweep (:func:`~.joint_solver.sweep_joints`) then a body-row
   sweep (the body solver's manifolds, :func:`~cgp_core.solver.sequential_impulse._solve_manifold`), until a
   round changed no row of either kind by more than its tolerance, or the larger of the two iteration caps; then
   the body solver's impact sweeps (with a joint sweep each, so the bounce reaches the robot too);
5. a drive the rows held beyond its effort limit: taken out of A and 2.–4. again (as :func:`~.joint_solver.
   step_joints` does);
6. the body solver's bounce time shift, impulses to momenta and warm-start memory;
7. the position stage, ONE loop too (:func:`relax_together`): the robot rows with a position error (limits,
   mimics, loop closures, the links' contacts with the world and with free bodies; :func:`~.joint_solver.
   relax_sweep`) and the normal rows of the contacts between free bodies (as the body solver's penetration
   recovery solves them) in the same Gauss–Seidel sweeps, on one displacement state: the robot's Δq (a
   pseudo-velocity Δq / h, integrated with q̇⁺ but never added to it) and the free bodies' D (applied to their
   poses after the integrator, :meth:`~cgp_core.robots.world.Robots.displace_free_bodies`; no momentum changes);
8. the joint solver's store stage (the robot rows' impulses to the free bodies' momenta, the effort, the memory).

**Why the position stage is one loop.**  Before, it was two: the joint solver's
(:func:`~.joint_solver.relax_positions`) before the integrator, the body solver's penetration recovery of the
body–body contacts after it.  A crate squeezed between a link and something else was corrected by one and undone
by the other: the link's stage pushed the crate out of the link into the shelf above it, the body solver's pushed
it back out of the shelf into the link, and the arm (heavy, held by its drives) took almost none of it — a crate
started 1 cm deep in a held arm under a shelf stayed 5.4 mm deep in the arm and 4.4 mm in the shelf for ever
(tests/test_robot_world.py's squeeze).  In one loop the shelf's row holds the crate while the link's row moves
the arm.  Both kinds of rows use the error predicted from the solved velocities (start value + h J (q̇⁺, V)), the
joint solver's measure; the body solver's recovery measures the motion the integrator actually made, which for
the kick-then-drift integrators (``implicit_midpoint``, the default, and ``symplectic_euler``) is the same
translation h V and the same rotation to second order in h (the loop runs before the integrator, inside this
kernel, so that the robot's correction is integrated with q̇⁺, and the free bodies' is applied after the
integrator as the link contacts' was; ``explicit_euler`` and ``rk4`` move the bodies otherwise, and in these
sub-steps their body–body contacts are corrected by the prediction).  The body solver's recovery then has nothing
to do in such a sub-step (:meth:`~cgp_core.solver.sequential_impulse.SequentialImpulseSolver.solve_velocities`
with ``coupled``); the loop's time is its ``recover_penetration`` stage, as the shared sweeps are its ``solve``.

A sub-step in which no link touches a free body has nothing to couple: the robots' rows and the bodies' rows share
no velocity, and the two solvers run on their own (:func:`~.joint_solver.step_joints`,
:func:`~cgp_core.solver.sequential_impulse.solve_step`; a scene without robots never comes here).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..collision.contacts import ContactSet
from ..jit import clock, lap, njit
from ..solver.arrays import BodyArrays, Scratch, SolverBodies, StepSettings, WarmStart
from ..solver.manifold import MAX_BLOCK
from ..solver.sequential_impulse import (
    NORMAL,
    RECOVER,
    _solve_region,
    contacts_head,
    impact_manifolds,
    position_target,
    prepare_bodies,
    relax_normal_rows,
    solve_tail,
)
from ..solver.sequential_impulse import SOLVE as BODY_SOLVE
from ..solver.sequential_impulse import _row_velocity as body_row_velocity
from .joint_solver import (
    POSITION_TOLERANCE,
    PREPARE,
    STORE,
    WARM_START,
    ContactRows,
    FreeBodies,
    JointDrives,
    JointProperties,
    JointSettings,
    JointSolverMemory,
    JointStep,
    JointSystem,
    drive_terms,
    position_goals,
    prepare_joints,
    relax_sweep,
    saturated_by_rows,
    store_joints,
    sweep_joints,
    warm_start_joints,
)


class JointProblem(NamedTuple):
    """The coupled robots' side of :func:`step_coupled` (each a plain tuple of its bundle from Python)."""

    system: tuple    # JointSystem
    joints: tuple    # JointProperties (with equality arrays)
    drives: tuple    # JointDrives
    contacts: tuple  # ContactRows: body = the world body row of a free body (rows of the body solver's V)
    memory: tuple    # JointSolverMemory
    settings: tuple  # JointSettings


class BodyProblem(NamedTuple):
    """The body solver's side of :func:`step_coupled`: the first six arguments of
    :func:`~cgp_core.solver.sequential_impulse.solve_step`, as it takes them."""

    contacts: tuple  # ContactSet of the contacts between free bodies (and with the static world)
    bodies: tuple    # BodyArrays (the momenta get every impulse, in place)
    memory: tuple    # WarmStart
    settings: tuple  # StepSettings
    tally: tuple     # ContactTally (read only with ``report``)
    report: bool     # whether the contact report is summed this tick


@njit
def solve_together(joint_rows, joint_lam, v, manifolds, rows, targets, lam, bodies, joint_settings, settings):
    """The one loop: each round a sweep over the robot rows (:func:`~.joint_solver.sweep_joints`, on v and the
    shared V) and one over the body solver's manifolds (as :func:`~cgp_core.solver.sequential_impulse.
    solve_contacts` does, on the same V), in place on both λ, v and V = ``bodies.velocity``; the rounds stop
    once neither kind changed a row velocity by more than its own tolerance, or after the larger of the two
    iteration caps.  Then the body solver's impact sweeps over the manifolds holding a bouncing point, each with a
    robot sweep.  Returns the rounds run (impact sweeps not counted, as in ``solve_contacts``)."""
    m = len(manifolds.a)
    G = len(manifolds.group_start) - 1
    V = bodies.velocity
    lam_n = np.empty(m)
    big = np.empty((m, 2))
    every = np.ones(G, np.bool_)
    run = np.arange(G)
    impact, any_impact = impact_manifolds(manifolds, targets)
    cap = max(joint_settings.velocity_iterations, settings.velocity_iterations)
    rounds = 0
    impact_done = 0
    regular = True
    while True:
        joint_change = sweep_joints(joint_rows, joint_lam, v, V)
        # (the body solver's sweep, not inlined: compiled once, for the body solver's sweeps and these)
        change = _solve_region(run, every if regular else impact, manifolds, rows, targets, lam, lam_n, V, big)
        converged = change <= settings.velocity_tolerance and joint_change <= joint_settings.velocity_tolerance
        if regular:
            rounds += 1
            if converged or rounds >= cap:
                regular = False
                if not any_impact or settings.impact_sweeps == 0:
                    break
        else:
            impact_done += 1
            if converged or impact_done >= settings.impact_sweeps:
                break
    return rounds


@njit
def relax_together(joint_rows, v, manifolds, rows, targets, bodies, joint_settings, settings):
    """The one position loop (the module docstring's 6.): the robot rows with a position error (limits, mimics,
    loop closures, the links' contact normals: :func:`~.joint_solver.relax_sweep`) and the normal rows of the
    contacts between free bodies (as :func:`~cgp_core.solver.sequential_impulse.recover_penetration_kernel`
    solves them, a manifold's ≤ 4 points as a block) in the same Gauss–Seidel sweeps, on one displacement state:
    the robot's d (n,) and the free bodies' D (n + 1, 6).  Every row's error is the one predicted after the
    velocity stage (its start value + h J (v, V), V = ``bodies.velocity`` solved), each kind with its own β, slop
    and cap (``joint_settings``, the body solver's ``settings``); a bounce placed at its time of impact is a
    two-sided row, as in the body solver.  The sweeps stop once one moved no row by more than
    :data:`~.joint_solver.POSITION_TOLERANCE` (at once where nothing penetrates beyond the slop), or after as many
    as the velocity loop may run (:func:`solve_together`'s cap; more if a position stage asks for more): the rows
    and their mass ratios are the velocity loop's, and a light crate squeezed between a heavy arm and a second
    crate under a shelf needs them (with the joint solver's 10 sweeps the two contacts were left ~1.2 mm deep,
    the velocity loop's small residual approach each sub-step balanced by a position loop not converged; with 20
    or more, within the slop).  The body rows take part only if the body solver's ``position_iterations`` is not
    0.  Returns the robot's pseudo-velocity
    d / h and D, which the caller applies to the free bodies' poses after the integrator (never to the momenta)."""
    V, h = bodies.velocity, joint_settings.h
    a, b, separation = manifolds.a, manifolds.b, manifolds.separation
    m = len(a)
    relax_bodies = settings.position_iterations > 0
    goal = position_goals(joint_rows, v, V, joint_settings)
    target = np.empty(m)
    lower = np.zeros(m)
    for c in range(m):
        predicted = separation[c] + h * body_row_velocity(rows.J, c, NORMAL, V, a[c], b[c])
        target[c], lower[c] = position_target(predicted, targets.toi_shift[c], settings)
    d = np.zeros(len(v))
    D = np.zeros((len(V), 6))
    joint_lam = np.zeros(len(joint_rows.kind))
    lam = np.zeros(m)
    scratch = Scratch(np.empty((2, MAX_BLOCK)), np.zeros(MAX_BLOCK, np.bool_), np.empty((m, 2)))
    sweeps = max(joint_settings.velocity_iterations, settings.velocity_iterations, joint_settings.position_iterations,
                 settings.position_iterations)
    for _ in range(sweeps):
        change = relax_sweep(joint_rows, goal, joint_lam, d, D)
        if relax_bodies:
            change = max(change, relax_normal_rows(manifolds, rows, lam, target, lower, D, scratch))
        if change <= POSITION_TOLERANCE:
            break
    for i in range(len(d)):
        d[i] /= h
    return d, D


@njit
def step_coupled(joint_problem, body_problem, joint_profile, body_profile):
    """One sub-step's velocity solve of the robots whose links touch free bodies together with every contact
    between free bodies (the module docstring's stages), and the position stage of both.  ``joint_problem``:
    :class:`JointProblem`; ``body_problem``: :class:`BodyProblem` (plain tuples); the stages are timed into
    ``joint_profile`` (:data:`~.joint_solver.STAGES`) and ``body_profile`` (the body solver's; the shared sweeps
    are its ``solve``, the shared position loop its ``recover_penetration``).

    Returns ``(joint, body)``: ``joint`` = (:class:`~.joint_solver.JointStep` — its ``body_displacement`` the free
    bodies', from the one position loop (n + 1 rows, the last the ground's) —, the new :class:`~.joint_solver.
    JointSolverMemory`); ``body`` = what :func:`~cgp_core.solver.sequential_impulse.solve_step` returns (the
    :class:`~cgp_core.solver.arrays.Handover`, the new warm start, the tally or None)."""
    system, joints, drives, contacts, memory, settings = joint_problem
    system, joints, drives = JointSystem(*system), JointProperties(*joints), JointDrives(*drives)
    contacts, memory, settings = ContactRows(*contacts), JointSolverMemory(*memory), JointSettings(*settings)
    body_contacts, body_arrays, body_memory, body_settings, tally, report = body_problem
    body_contacts, body_arrays = ContactSet(*body_contacts), BodyArrays(*body_arrays)
    body_memory, body_settings = WarmStart(*body_memory), StepSettings(*body_settings)
    h, n = settings.h, len(system.velocity)
    start = clock()
    prepared = prepare_bodies(body_arrays, body_settings.h)
    # the robot rows see the free bodies as the body solver does (a sleeping body: static), and their impulses go
    # to the same momenta
    free = FreeBodies(prepared.inv_mass, prepared.inv_inertia, prepared.velocity, body_arrays.linear_momentum,
                      body_arrays.angular_momentum)
    allowed = np.ones(n, np.bool_)
    terms = drive_terms(system, joints, drives)
    rounds = 0
    while True:  # at most n + 1 passes: each but the last takes a drive out of A (as step_joints)
        implicit, joint_rows = prepare_joints(system, joints, terms, contacts, free, h, allowed)
        v = implicit.velocity.copy()
        V = prepared.velocity.copy()  # every pass starts from the contact-free velocities
        start = lap(joint_profile, PREPARE, start)
        joint_lam = warm_start_joints(joint_rows, memory, v, V, settings.warm_start)
        start = lap(joint_profile, WARM_START, start)
        bodies = SolverBodies(prepared.inv_mass, prepared.inv_inertia, prepared.position, prepared.dynamic, V,
                              prepared.velocity_before)
        # (the body solver's stages 2-3 as its own kernel, not inlined: compiled once, for it and this loop)
        solving, start = contacts_head(body_contacts, bodies, body_memory, body_settings, body_profile, start)
        manifolds, rows, targets, lam = solving.manifolds, solving.rows, solving.targets, solving.lam
        rounds += solve_together(joint_rows, joint_lam, v, manifolds, rows, targets, lam, bodies, settings,
                                 body_settings)
        start = lap(body_profile, BODY_SOLVE, start)
        if not saturated_by_rows(joints, terms, implicit, v, h, allowed):
            break
    # the body solver's stages 5-7 and its report (bounce time shift, impulses to the momenta, warm-start memory):
    # its own third call, not inlined — compiled once, for the body solver and this loop
    # (its arrays and settings as the plain tuples given: solve_tail's one signature)
    body = solve_tail(solving, body_problem[1], body_problem[3], rounds, tally, report, body_profile)
    start = clock()
    pseudo, displacement = relax_together(joint_rows, v, manifolds, rows, targets, bodies, settings, body_settings)
    start = lap(body_profile, RECOVER, start)
    effort, contact_impulse, new_memory = store_joints(joints, terms, implicit, joint_rows, joint_lam, v, free, h)
    lap(joint_profile, STORE, start)
    step = JointStep(v, pseudo, effort, contact_impulse, rounds, displacement)
    return (step, new_memory), body

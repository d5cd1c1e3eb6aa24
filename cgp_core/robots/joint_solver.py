"""One sub-step of an articulation in joint space: implicit drives and damping, then constraint rows solved by
projected Gauss–Seidel with warm starting — the joint-space sibling of :mod:`cgp_core.solver.sequential_impulse`
(the same vocabulary: rows, effective masses, accumulated and clamped impulses, speculative targets, a position
stage that never touches the velocities).

**The system.**  A robot in reduced coordinates has ``n`` joint velocities qd; the caller (the robot model)
gives, at the sub-step's start, the joint-space mass matrix M (n, n) (symmetric positive definite), the bias
b(q, qd) (n,) (Coriolis, centrifugal and gravity: ``inverse_dynamics(q, qd, qdd=0)``) and the applied joint
efforts τ (n,) (external forces mapped by Jᵀ, anything not a drive).  Per dof it also gives a *coordinate*
``position`` (n,): the joint angle / displacement of a revolute or prismatic joint, which the limits, the
position drives and the mimic couplings read (a dof without one — a floating base's — carries any number and
must have infinite limits, no position drive and no mimic).

**Drives and damping, implicitly.**  Per dof a drive mode (:data:`DRIVE_NONE`, :data:`DRIVE_EFFORT`,
:data:`DRIVE_VELOCITY`, :data:`DRIVE_POSITION`).  A position drive's torque kp (q* − q) + kd (qd* − qd), a
velocity drive's kd (qd* − qd) and URDF viscous damping −c qd are taken at the *end* of the sub-step (backward
Euler in the drive), which is the linear solve

    A qd⁺ = M qd + h (τ − b + τ_effort + Kp (q* − q) + Kd qd*),    A = M + h (C + Kd) + h² Kp

(Kp, Kd, C diagonal), unconditionally stable: kp = 1e6 N m/rad on a 1 kg m² link at h = 1/240 s simply
converges.  A drive whose torque there, kp (q* − q − h qd⁺) + kd (qd* − qd⁺), would exceed ±effort_limit is
*saturated*: it is taken out of A (the others are solved again without it, until no new one saturates — at most
n solves of a small dense system) and becomes a soft row (below) with the drive's own softness, whose impulse is
clamped to ±h·effort_limit (Box2D's motor, Bullet's multibody motor).  The rows can hold a drive back (a gripper
pressing on an object, a target behind a joint limit): a drive whose torque at the solved qd⁺ exceeds its limit is
taken out of A too and the sub-step solved again (prepare, warm start, sweeps; rare, and at most n times), so no
drive's reported torque ever exceeds its effort limit.

Why this mix and not soft rows throughout: a soft row is the same equation (its softness γ = 1/(h kd + h² kp) is
exactly the drive's term of A), but Gauss–Seidel converges slowly on stiff drives coupled through a dense M⁻¹ (an
arm's links): a holding error of 1e-3 rad against gravity would need many sweeps per sub-step.  In A the
unsaturated drives are solved exactly (one Cholesky factorization of an n × n matrix), every row's effective
mass 1/(J A⁻¹ Jᵀ) sees the drives' stiffness (a limit row on a driven joint knows what the drive will do), and
only the saturated drives — whose impulse is a constant ±h·effort_limit once clamped — are left to the sweeps.

**Rows** (one sub-step's, in the order a sweep visits them: the soft and bounded ones first, the hard ones
last, as Box2D does; every row asks J qd⁺ + γ λ = target within lower ≤ λ ≤ upper, λ the accumulated impulse):

- saturated drives: J = e_i, γ = 1/(h kd + h² kp), target γ h (kp (q* − q) + kd qd*), |λ| ≤ h·effort_limit;
- Coulomb joint friction: J = e_i, target 0, |λ| ≤ h·friction;
- velocity limits: two one-sided rows ±e_i, J qd ≥ −velocity_limit, λ ≥ 0;
- mimic couplings: J = e_follower − multiplier·e_leader, target 0, λ free (an equality); their position error
  is the position stage's;
- equality rows given by the caller (``JointProperties.equality_jacobian`` (k, n), ``equality_error`` (k,)): J qd
  = 0, λ free; the position stage drives their error C to 0 (J Δq = −β C).  A loop-closing joint between two
  bodies of a tree is three of them (point coincidence: J = J_point(a) − J_point(b), C = p_a − p_b); the caller
  re-linearises them every sub-step, so the nonlinear constraint converges quadratically over the sub-steps;
- joint limits: one-sided rows (J = e_i at the lower limit, −e_i at the upper), *speculative*: J qd ≥ −s/h for
  a gap s > 0 (the joint may close the gap in this sub-step, no more), ≥ 0 when at or past the limit; no bias
  term (penetration is the position stage's, so it never becomes velocity: no energy gain), no restitution (a
  joint stop is inelastic);
- contacts with the world: per contact point three rows [normal, t₁, t₂] given by the caller as joint-space
  Jacobian rows d·J_point (n,), optionally coupled to ONE free rigid body (the caller's 6-vector [−d, −r × d] of
  it, r from its centre of mass to the point; d points from the body (or the world) to the robot), whose
  velocity (v, ω) the row moves too (ΔV = M_b⁻¹ J_bᵀ Δλ) and whose momenta get the impulses in place.  Normal:
  λ ≥ 0, speculative J v ≥ −max(s, 0)/h; friction: the two tangent rows of a point solved together and clamped
  to the cone |λ_t| ≤ μ λₙ (tangents before their normal, as the contact solver does).

Each row's effective mass is 1 / (J A⁻¹ Jᵀ + J_b M_b⁻¹ J_bᵀ + γ); A⁻¹ Jᵀ is precomputed for every row from the
Cholesky factor of A (our own loop: no LAPACK, so compiled and plain-Python runs agree bit for bit).  A sweep
stops the iterations once no row's velocity changed by more than ``velocity_tolerance``.

**Warm starting.**  Rows are keyed by identity (kind, dof / mimic index / contact key and direction), the
previous sub-step's accumulated impulse of the same key is applied before the first sweep (clamped to this
sub-step's bounds).  A resting contact or a holding saturated drive starts at its answer.

**Position stage** ("relax"): the hard rows with a position error — joint limits (gap s) and mimic couplings
(error C = q_f − m q_l − offset) — predicted after the velocity step (s + h J qd⁺), are corrected by a
displacement Δq found by the same projected Gauss–Seidel on the same A⁻¹ (limits: J Δq ≥ −β s⁺, λ ≥ 0; mimic:
J Δq = −β C⁺); it is returned as a *pseudo-velocity* Δq / h that the caller integrates with qd⁺ but never adds
to qd (split impulses): the correction adds no kinetic energy.  The constraints are linear in joint space, so
β = 1 (the default) removes the error in one sub-step: a mimic follower tracks its leader to round-off.
The contacts take part too, as in the contact solver's position stage (J Δq + J_b D ≥ β (−s⁺ − slop), at most
``max_correction``, β = ``contact_correction``, s⁺ predicted with the free body's solved velocity): against the
static world only the robot moves (a robot started in the ground rises out of it without velocity); against a free
body the correction is shared by the two sides' effective masses — the robot's part in the pseudo-velocity, the
body's a displacement D = M_b⁻¹ J_bᵀ λ (:attr:`JointStep.body_displacement`) that the caller applies to the body's
pose after the integrator, never to its momenta (:meth:`cgp_core.robots.world.Robots.displace_free_bodies`): a
link pushing a crate does not sink into it, and the crate gains no energy.

**Integration** is the caller's: q⁺ = integrate(q, qd⁺ + pseudo, h) with the robot's own integrator (a floating
base's quaternion, continuous joints); for 1-dof joints it is q + h (qd⁺ + pseudo) (:func:`integrate_dofs`).

**Effort** (what a joint torque sensor reads, per dof [N m or N]): the drive's torque (implicit drive at qd⁺,
or a saturated drive's row impulse / h), an effort drive's clamped command, the viscous damping −c qd⁺, and the
impulses / h of the joint's own rows (friction, velocity limits, limits, mimic: Jᵀ λ / h, the mimic's reaction
on the leader included).  Not in it: gravity and Coriolis (b), the caller's τ, contacts.  The caller averages
it over a tick's sub-steps.

**What the World calls, each sub-step, per robot** (a sketch: the model's functions are
``cgp_core.robots.algorithms``; ``solver`` a :class:`JointSolver` kept per robot):

1. ``M = mass_matrix(arrays, q)``; ``bias = inverse_dynamics(arrays, q, qd, 0, gravity)``; ``applied`` = Σ
   J_pointᵀ F of the sub-step's wrenches on the robot's links; ``position`` = the 1-dof joints' coordinates;
2. the robot's contacts from the detector, each point as a :class:`ContactRows` entry: ``joint_jacobian[c, k] =
   d_k · point_jacobian(...)`` for d = (n, t₁, t₂) with n pointing *to the robot*, ``body``/``body_jacobian`` for a
   free body on the other side (``[−d, −r × d]``, r from its COM), ``separation``, ``friction``, a stable ``key``;
   :class:`FreeBodies` with the bodies' velocity M_b⁻¹ (P + h F) and the World's own momentum arrays (written in
   place: pass the arrays themselves, not a fancy-indexed copy);
3. ``step = solver.step(JointSystem(M, bias, applied, position, qd), joints, drives, contacts, bodies)``;
4. ``qd = step.velocity``; ``q = integrate_positions(arrays, q, step.velocity + step.pseudo_velocity, h)``;
5. add ``step.effort`` into the tick's sum (the joint_states effort is the mean over the sub-steps);
6. move each free body by ``step.body_displacement`` after the integrator (poses only).

:func:`step_joints` sees a free body only through the robot's rows, not the body's own contacts.  In a World, a
robot whose links touch a free body is therefore not stepped by it: its rows and the body solver's contact rows
are solved in ONE loop, each sweep visiting both on the free bodies' shared velocities
(:func:`cgp_core.robots.coupled.step_coupled`, built from this module's stages, :func:`sweep_joints` and, for the
position stage, :func:`position_goals` and :func:`relax_sweep`), so a body pressed between a link and the ground
converges within the sub-step, and a body squeezed between a link and a shelf is pushed out of both.

**The stages** (:data:`STAGES`, timed into a :class:`~cgp_core.jit.StageProfile`), run by :func:`step_joints`:

1. :func:`prepare_joints` — the implicit matrix A with its saturated drives found, its factor, qd_free, and
   the rows (:class:`JointRows`) with A⁻¹ Jᵀ and effective masses;
2. :func:`warm_start_joints` — the previous sub-step's impulses of the same keys applied;
3. :func:`solve_joints` — the sweeps (:func:`sweep_joints` each);
4. :func:`relax_positions` — the position stage (pseudo-velocity; the free bodies' displacement);
5. :func:`store_joints` — the free bodies' impulses added to their momenta, the effort, the warm-start memory.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..checks import positive
from ..jit import StageProfile, clock, lap, njit
from ..solver.sequential_impulse import tangent_basis_scalar
from .algorithms import joint_space_terms, point_jacobian, robot_view
from .model import RobotStarts, row_starts

#: drive modes (:attr:`JointDrives.mode`)
DRIVE_NONE, DRIVE_EFFORT, DRIVE_VELOCITY, DRIVE_POSITION = 0, 1, 2, 3

#: row kinds (:attr:`JointRows.kind`), in the order a sweep visits them; kinds up to ROW_LIMIT are the joint's
#: own (they count in the effort)
#: ROW_EQUALITY (the caller's equality rows: loop closures, :mod:`cgp_core.robots.articulations`) is not the
#: joint's own: its impulse is a reaction like a contact's, not in the effort
ROW_DRIVE, ROW_FRICTION, ROW_VELOCITY_LIMIT, ROW_MIMIC, ROW_LIMIT, ROW_EQUALITY, ROW_TANGENT, ROW_NORMAL = range(8)

#: a row's warm-start key is kind · KEY_SLOTS + its index within the kind (contacts: key · 3 + direction)
KEY_SLOTS = 1 << 40

#: a position-stage sweep moving no row by more than this [rad / m] ends the sweeps
POSITION_TOLERANCE = 1e-14

#: the stages of :attr:`JointSolver.profile`, in order
STAGES = ("prepare", "warm_start", "solve", "relax", "store")
PREPARE, WARM_START, SOLVE, RELAX, STORE = range(len(STAGES))


# ---- the bundles ----------------------------------------------------------------------------------------------

class JointSystem(NamedTuple):
    """The robot at the start of the sub-step, as its model computes it (``n`` dofs)."""

    mass_matrix: np.ndarray  # (n, n) joint-space M(q), SPD [kg m² / kg]
    bias: np.ndarray         # (n,) b(q, qd): Coriolis + centrifugal + gravity, inverse_dynamics at qdd = 0 [N m / N]
    applied: np.ndarray      # (n,) other applied joint efforts τ (external forces as Jᵀ F) [N m / N]
    position: np.ndarray     # (n,) each dof's coordinate (revolute angle [rad], prismatic [m]; any value for dofs
    #                          without one: they must have infinite limits, no position drive, no mimic)
    velocity: np.ndarray     # (n,) qd [rad/s / m/s]


class JointProperties(NamedTuple):
    """The URDF's per-dof numbers and mimic couplings (``n`` dofs, ``k`` mimic joints)."""

    lower: np.ndarray             # (n,) lower position limit (−inf: none)
    upper: np.ndarray             # (n,) upper position limit (+inf: none)
    effort_limit: np.ndarray      # (n,) |drive effort| ≤ this [N m / N] (inf: unlimited; 0: cannot be driven)
    velocity_limit: np.ndarray    # (n,) |qd| ≤ this (inf or ≤ 0: none)
    damping: np.ndarray           # (n,) viscous c: torque −c qd [N m s/rad / N s/m]
    friction: np.ndarray          # (n,) Coulomb friction: |torque| ≤ this [N m / N]
    mimic_follower: np.ndarray    # (k,) int64 dof of the follower
    mimic_leader: np.ndarray      # (k,) int64 dof of the leader
    mimic_multiplier: np.ndarray  # (k,) q_f = multiplier · q_l + offset
    mimic_offset: np.ndarray      # (k,)
    #: e equality rows given by the caller (loop closures): J qd = 0 and the position error C → 0; None: none
    #: (:meth:`JointSolver.step` makes them (0, n) / (0,) arrays)
    equality_jacobian: np.ndarray | None = None  # (e, n) each row's J; a zero row is inert
    equality_error: np.ndarray | None = None     # (e,) its position error C at the sub-step's start [m or rad]

    @staticmethod
    def free(n: int) -> JointProperties:
        """``n`` dofs without limits, damping, friction or mimics, with unlimited effort."""
        inf = np.full(n, np.inf)
        return JointProperties(-inf, inf.copy(), inf.copy(), inf.copy(), np.zeros(n), np.zeros(n),
                               np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0),
                               np.zeros((0, n)), np.zeros(0))

    def with_equalities(self) -> JointProperties:
        """These properties with (0, n) / (0,) equality arrays where they are None."""
        if self.equality_jacobian is not None and self.equality_error is not None:
            return self
        return self._replace(equality_jacobian=np.zeros((0, len(self.lower))), equality_error=np.zeros(0))


class JointDrives(NamedTuple):
    """What each dof's actuator is told (``n`` dofs); gains finite and ≥ 0."""

    mode: np.ndarray             # (n,) int64 DRIVE_NONE / EFFORT / VELOCITY / POSITION
    target_position: np.ndarray  # (n,) q* (position mode)
    target_velocity: np.ndarray  # (n,) qd* (velocity mode; position mode's feed-forward, usually 0)
    target_effort: np.ndarray    # (n,) τ_cmd (effort mode; clamped to ±effort_limit) [N m / N]
    stiffness: np.ndarray        # (n,) kp (position mode) [N m/rad / N/m]
    damping: np.ndarray          # (n,) kd (velocity and position modes) [N m s/rad / N s/m]

    @staticmethod
    def none(n: int) -> JointDrives:
        z = np.zeros(n)
        return JointDrives(np.zeros(n, np.int64), z, z.copy(), z.copy(), z.copy(), z.copy())


class ContactRows(NamedTuple):
    """The robot's contact points this sub-step (``c`` points, ``n`` dofs), each three rows [normal, t₁, t₂];
    the direction d of a row points from the other side (a free body or the static world) to the robot."""

    joint_jacobian: np.ndarray  # (c, 3, n) d · J_point(q): the robot point's velocity along d per joint velocity
    body: np.ndarray            # (c,) int64 row of the free body on the other side in FreeBodies, −1: static world
    body_jacobian: np.ndarray   # (c, 3, 6) [−d, −r × d] of that body, r = point − its COM [m] (ignored for −1)
    separation: np.ndarray      # (c,) gap along the normal at the sub-step's start [m] (< 0: penetration)
    friction: np.ndarray        # (c,) Coulomb μ
    key: np.ndarray             # (c,) int64 ≥ 0, < 2**37: the point's identity across sub-steps (warm start)

    @staticmethod
    def empty(n: int) -> ContactRows:
        return ContactRows(np.zeros((0, 3, n)), np.zeros(0, np.int64), np.zeros((0, 3, 6)), np.zeros(0),
                           np.zeros(0), np.zeros(0, np.int64))


@njit
def link_contact_rows(robots, island, bodies, contact):
    """The :class:`ContactRows` arrays ``(joint_jacobian (c, 3, n), body (c,), body_jacobian (c, 3, 6))`` of an
    island's link contacts (the robot stage's, :meth:`cgp_core.robots.world.Robots._contact_rows`): per point the
    three directions (n, t₁, t₂) of the contact solver (:func:`~cgp_core.solver.sequential_impulse.
    tangent_basis_scalar`), from A to B; a link side adds ± d · J_point(q) in its robot's columns of the island, a
    free body side is the point's free body with the row ± [d, r × d], r = point − its COM.  One call per sub-step
    (the numpy of it per point and side cost ~0.2 ms a sub-step for a few points).  Plain tuples:

    - ``robots``: ``(models, starts, rotation, position)`` — every robot's arrays stacked, their
      :class:`~cgp_core.robots.model.RobotStarts`, and their body poses side by side, (B, 3, 3) and (B, 3);
    - ``island``: ``(offsets, n)`` — (robots,) int64 each robot's first dof in the island (−1: not in it), its dofs;
    - ``bodies``: ``(body_robot, body_link, position)`` — each world body's robot and link ((b,) int64, −1: none)
      and COM (b, 3);
    - ``contact``: ``(body_a, body_b, point, normal, free_a, free_b)`` — the island's contacts ((c,) int64 ×2, a
      side −1 the static world; (c, 3) ×2) and whether each side is a free body the rows move ((c,) bool ×2)."""
    models, starts, rotation, position = robots
    starts = RobotStarts(*starts)
    offsets, n = island
    body_robot, body_link, body_position = bodies
    body_a, body_b, point, normal, free_a, free_b = contact
    m = len(body_a)
    J = np.zeros((m, 3, n))
    body = np.full(m, -1, np.int64)
    body_jacobian = np.zeros((m, 3, 6))
    D = np.empty((3, 3))
    for c in range(m):
        t = tangent_basis_scalar(normal[c, 0], normal[c, 1], normal[c, 2])
        for k in range(3):
            D[0, k] = normal[c, k]
            D[1, k] = t[k]
            D[2, k] = t[3 + k]
        for side in range(2):
            s = body_a[c] if side == 0 else body_b[c]
            sign = -1.0 if side == 0 else 1.0
            if s < 0:
                continue
            k = body_robot[s]
            if k >= 0:
                b0, b1 = starts.body[k], starts.body[k + 1]
                Jp = point_jacobian(robot_view(models, starts, k), rotation[b0:b1], position[b0:b1], body_link[s],
                                    point[c])
                P = np.dot(D, Jp)
                o = offsets[k]
                for e in range(3):
                    for d in range(Jp.shape[1]):
                        J[c, e, o + d] += sign * P[e, d]
            elif (free_a[c] if side == 0 else free_b[c]):
                body[c] = s
                ax = point[c, 0] - body_position[s, 0]
                ay = point[c, 1] - body_position[s, 1]
                az = point[c, 2] - body_position[s, 2]
                for e in range(3):
                    dx, dy, dz = sign * D[e, 0], sign * D[e, 1], sign * D[e, 2]
                    body_jacobian[c, e, 0], body_jacobian[c, e, 1], body_jacobian[c, e, 2] = dx, dy, dz
                    body_jacobian[c, e, 3] = ay * dz - az * dy
                    body_jacobian[c, e, 4] = az * dx - ax * dz
                    body_jacobian[c, e, 5] = ax * dy - ay * dx
    return J, body, body_jacobian


class FreeBodies(NamedTuple):
    """The free rigid bodies the contacts may touch (``b`` rows; the World's bodies, or only those touched)."""

    inv_mass: np.ndarray          # (b,) 1/m (0: cannot move)
    inv_inertia: np.ndarray       # (b, 3, 3) world-frame I⁻¹ at the current pose
    velocity: np.ndarray          # (b, 6) [v, ω] over the sub-step (M⁻¹ (momentum + h·force)); the rows' changes
    #                               are written back in place
    linear_momentum: np.ndarray   # (b, 3) P [kg m/s]: the contact impulses are added in place
    angular_momentum: np.ndarray  # (b, 3) L about the COM [kg m²/s]: the contact impulses are added in place

    @staticmethod
    def empty() -> FreeBodies:
        return FreeBodies(np.zeros(0), np.zeros((0, 3, 3)), np.zeros((0, 6)), np.zeros((0, 3)), np.zeros((0, 3)))


class JointSolverMemory(NamedTuple):
    """What a sub-step leaves for the next one's warm start (``w`` rows)."""

    key: np.ndarray      # (w,) int64 row identity (kind · KEY_SLOTS + index), ascending
    impulse: np.ndarray  # (w,) accumulated impulse λ [N m s / N s]

    @staticmethod
    def empty() -> JointSolverMemory:
        return JointSolverMemory(np.zeros(0, np.int64), np.zeros(0))


class JointSettings(NamedTuple):
    """The numbers the stages take."""

    h: float                    # sub-step [s]
    velocity_iterations: int    # sweeps at most
    velocity_tolerance: float   # a sweep changing no row velocity by more than this ends them [rad/s / m/s]
    warm_start: bool            # start from the previous sub-step's impulses
    position_iterations: int    # sweeps of the position stage (0: off)
    position_correction: float  # β, the fraction of a limit's / mimic's position error removed per sub-step
    contact_correction: float   # β of the contacts with the static world (the contact solver's position_correction)
    penetration_slop: float     # contact penetration tolerated without correction [m]
    max_correction: float       # at most this much contact penetration removed per sub-step [m]

    @staticmethod
    def default(h: float) -> JointSettings:
        return JointSettings(h, 30, 1e-9, True, 10, 1.0, 0.2, 0.0005, 0.05)


class JointRows(NamedTuple):
    """One sub-step's ``R`` rows (order: drive, friction, velocity-limit, mimic, limit rows, then per contact
    point t₁, t₂, normal)."""

    kind: np.ndarray         # (R,) int64 ROW_*
    key: np.ndarray          # (R,) int64 warm-start identity
    J: np.ndarray            # (R, n) joint-space Jacobian row
    W: np.ndarray            # (R, n) A⁻¹ Jᵀ: what a unit impulse along the row does to qd
    body: np.ndarray         # (R,) int64 free body of a contact row, −1 none
    Jb: np.ndarray           # (R, 6) the body's Jacobian row (contacts with a body)
    Wb: np.ndarray           # (R, 6) M_b⁻¹ J_bᵀ
    eff: np.ndarray          # (R,) 1 / (J A⁻¹ Jᵀ + J_b M_b⁻¹ J_bᵀ + γ)
    stiff: np.ndarray        # (R,) J A⁻¹ Jᵀ + J_b M_b⁻¹ J_bᵀ: the row velocity per unit impulse
    softness: np.ndarray     # (R,) γ (saturated drives; 0 for hard rows)
    target: np.ndarray       # (R,) the row's target velocity
    lower: np.ndarray        # (R,) bounds of the accumulated impulse (tangent rows: ±μ, scaled by λₙ in the sweep)
    upper: np.ndarray        # (R,)
    error: np.ndarray        # (R,) position error at the sub-step's start: a limit's gap s, a mimic's C
    dof: np.ndarray          # (R,) int64 the dof i of a row J = ±e_i (drive, friction, velocity-limit, limit rows);
    #                          −1 for the others
    lo: np.ndarray           # (R,) int64 J's and W's columns outside lo … hi − 1 are zero: the blocks of A (one per
    hi: np.ndarray           # (R,) int64   robot of an island) that J touches (:func:`prepare_rows`)


class Implicit(NamedTuple):
    """The implicit solve of the drives and damping."""

    factor: np.ndarray       # (n, n) lower-triangular Cholesky factor L of A (L Lᵀ = A)
    velocity: np.ndarray     # (n,) qd_free = A⁻¹ (M qd + h (...)): the velocity before any row
    implicit: np.ndarray     # (n,) bool: the dof's drive is in A (not saturated)
    block_start: np.ndarray  # (n,) int64 A is block-diagonal (one block per robot of an island, or finer): dof
    block_end: np.ndarray    # (n,) int64   i's block is block_start[i] … block_end[i] − 1 (:func:`diagonal_blocks`)


class JointStep(NamedTuple):
    """What one sub-step gives the caller."""

    velocity: np.ndarray         # (n,) qd⁺
    pseudo_velocity: np.ndarray  # (n,) the position stage's Δq / h: integrate with qd⁺, never add to qd
    effort: np.ndarray           # (n,) the joint torque/force this sub-step (see the module docstring) [N m / N]
    contact_impulse: np.ndarray  # (c, 3) the contact points' accumulated impulses [normal, t₁, t₂] [N s]
    sweeps: int                  # velocity sweeps run (summed over the passes a row-saturated drive caused)
    body_displacement: np.ndarray  # (b, 6) the position stage's displacement of each free body [Δx m, Δθ rad]:
    #                                the caller moves the bodies by it after the integrator (their momenta not)


# ---- dense linear algebra (our own loops: bit-identical compiled and plain) ----------------------------------

@njit
def envelope(A):
    """(n,) int64: the first column of each row of the symmetric A (n, n) that is not zero (its diagonal if none
    is) — A's *envelope* (profile), which its Cholesky factor keeps (George & Liu, *Computer Solution of Large
    Sparse Positive Definite Systems*, 1981, ch. 4): L[i, k] = 0 for k < first[i]."""
    n = A.shape[0]
    first = np.empty(n, np.int64)
    for i in range(n):
        first[i] = i
        for k in range(i):
            if A[i, k] != 0.0:
                first[i] = k
                break
    return first


@njit
def diagonal_blocks(first):
    """``(block_start, block_end)`` (n,) int64 each: the diagonal blocks of a symmetric matrix of envelope
    ``first`` (:func:`envelope`) — dof i starts a block when no row from i on reaches a column before i.  An
    island of robots has one block per robot at least (block-diagonal M: the robots share no dof)."""
    n = len(first)
    block_start = np.empty(n, np.int64)
    block_end = np.empty(n, np.int64)
    reach = n  # the smallest first[k] over the rows k ≥ i
    end = n
    for i in range(n - 1, -1, -1):
        reach = min(reach, first[i])
        block_end[i] = end
        if reach == i:  # a block starts here: the rows before it end at i
            end = i
    start = 0
    for i in range(n):
        if block_end[i] != block_end[start]:
            start = i
        block_start[i] = start
    return block_start, block_end


@njit
def cholesky(A, first):
    """The lower-triangular L with L Lᵀ = A for a symmetric positive definite A (n, n), within A's envelope
    ``first`` (:func:`envelope`): the terms outside it are zeros, so an island of k robots costs the sum of each
    robot's factorization, not that of one system of all their dofs (a block-diagonal A: cubic in each robot's
    dofs, not in their sum; the same numbers as the dense loops, which only added those zeros)."""
    n = A.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        s = A[j, j]
        for k in range(first[j], j):
            s -= L[j, k] * L[j, k]
        d = math.sqrt(s) if s > 0.0 else 0.0
        L[j, j] = d
        for i in range(j + 1, n):
            if first[i] > j:
                continue  # outside the envelope: L[i, j] = 0
            s = A[i, j]
            for k in range(max(first[i], first[j]), j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
    return L


@njit
def cholesky_solve_into(L, b, lo, hi, x):
    """x with L Lᵀ x = b for a block-diagonal A = L Lᵀ and a b that is zero outside lo … hi − 1, a whole number
    of A's blocks (:func:`diagonal_blocks`): x is zero there too, and only x[lo:hi] is written (the rest of ``x``
    (n,) left as it is).  The same numbers as :func:`cholesky_solve`, whose loops outside only added zeros."""
    for i in range(lo, hi):
        s = b[i]
        for k in range(lo, i):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]
    for i in range(hi - 1, lo - 1, -1):
        s = x[i]
        for k in range(i + 1, hi):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]


@njit
def cholesky_solve(L, b):
    """x with L Lᵀ x = b (b (n,))."""
    n = len(b)
    y = np.zeros(n)
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    x = np.zeros(n)
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]
    return x


# ---- 1. prepare: the implicit drives, then the rows ----------------------------------------------------------

class DriveTerms(NamedTuple):
    """Each dof's drive, reduced to the numbers the stages read (``n`` dofs), computed once per sub-step.

    Why once: the stages read them per dof in several loops, and a bundle handed to a small compiled helper costs
    a reference-count update per array per call (measured: ~130 ns for ``_drive_gains(drives, joints, i)``, more
    than its arithmetic), so the helpers below take numbers, not bundles."""

    kp: np.ndarray       # (n,) stiffness of the position drive that acts (0: none) [N m/rad / N/m]
    kd: np.ndarray       # (n,) damping of the position or velocity drive that acts (0: none) [N m s/rad / N s/m]
    push: np.ndarray     # (n,) kp (q* − q) + kd qd*: the drive's torque at zero end velocity, before the
    #                      −(h kp + kd) qd⁺ term [N m / N]
    command: np.ndarray  # (n,) an effort drive's command clamped to ±effort_limit (0 for other modes) [N m / N]


@njit
def _drive_gains(mode, stiffness, damping, effort_limit):
    """(kp, kd) of a dof's position / velocity drive, (0, 0) if it has none that acts."""
    if effort_limit <= 0.0:
        return 0.0, 0.0
    if mode == DRIVE_POSITION:
        return stiffness, damping
    if mode == DRIVE_VELOCITY:
        return 0.0, damping
    return 0.0, 0.0


@njit
def drive_terms(system, joints, drives):
    """The :class:`DriveTerms` of every dof at the sub-step's start."""
    n = len(system.velocity)
    kp, kd, push, command = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    for i in range(n):
        kp[i], kd[i] = _drive_gains(drives.mode[i], drives.stiffness[i], drives.damping[i], joints.effort_limit[i])
        push[i] = kd[i] * drives.target_velocity[i]
        if kp[i] > 0.0:
            push[i] += kp[i] * (drives.target_position[i] - system.position[i])
        if drives.mode[i] == DRIVE_EFFORT:
            limit = joints.effort_limit[i]
            command[i] = min(max(drives.target_effort[i], -limit), limit)
    return DriveTerms(kp, kd, push, command)


@njit
def implicit_drives(system, joints, terms, h, allowed):
    """The :class:`Implicit` solve A qd_free = M qd + h (τ − b + τ_effort + Kp (q* − q) + Kd qd*) with the
    drives that do not saturate (``terms``: :class:`DriveTerms`): solved with every acting drive that ``allowed``
    (n,) bool lets in A, then again without those whose torque exceeds their effort limit, until none more does."""
    M, n = system.mass_matrix, len(system.velocity)
    implicit = np.zeros(n, np.bool_)
    for i in range(n):
        implicit[i] = (terms.kp[i] > 0.0 or terms.kd[i] > 0.0) and allowed[i]
    base = np.zeros(n)
    for i in range(n):
        s = 0.0
        for k in range(n):
            s += M[i, k] * system.velocity[k]
        base[i] = s + h * (system.applied[i] - system.bias[i] + terms.command[i])
    first = envelope(M)  # A's too: A is M plus diagonal terms
    while True:  # at most n + 1 passes: each but the last takes a drive out of A
        A = M.copy()
        rhs = base.copy()
        for i in range(n):
            A[i, i] += h * joints.damping[i]
            if implicit[i]:
                kp, kd = terms.kp[i], terms.kd[i]
                A[i, i] += h * kd + h * h * kp
                rhs[i] += h * terms.push[i]
        L = cholesky(A, first)
        v = cholesky_solve(L, rhs)
        saturated = False
        for i in range(n):
            if implicit[i]:
                torque = terms.push[i] - (h * terms.kp[i] + terms.kd[i]) * v[i]
                if abs(torque) > joints.effort_limit[i] * (1.0 + 1e-12):
                    implicit[i] = False
                    saturated = True
        if not saturated:
            block_start, block_end = diagonal_blocks(first)
            return Implicit(L, v, implicit, block_start, block_end)


@njit
def _count_rows(joints, terms, implicit, n_contacts):
    n = len(implicit)
    count = len(joints.mimic_follower) + len(joints.equality_error) + 3 * n_contacts
    for i in range(n):
        if (terms.kp[i] > 0.0 or terms.kd[i] > 0.0) and not implicit[i]:
            count += 1
        if joints.friction[i] > 0.0:
            count += 1
        if joints.velocity_limit[i] > 0.0 and joints.velocity_limit[i] < np.inf:
            count += 2
        if joints.lower[i] > -np.inf:
            count += 1
        if joints.upper[i] < np.inf:
            count += 1
    return count


@njit
def _empty_rows(R, n):
    return JointRows(np.zeros(R, np.int64), np.zeros(R, np.int64), np.zeros((R, n)), np.zeros((R, n)),
                     np.full(R, -1, np.int64), np.zeros((R, 6)), np.zeros((R, 6)), np.zeros(R), np.zeros(R),
                     np.zeros(R), np.zeros(R), np.zeros(R), np.zeros(R), np.zeros(R), np.full(R, -1, np.int64),
                     np.zeros(R, np.int64), np.full(R, n, np.int64))


# (inlined: its callers pass literal kinds and a row counter that starts as the literal 0, and numba compiled a
# separate function for each such combination of literal types, ten of them; inlined, none)
@njit(inline="always")
def _dof_row(kinds, keys, dofs, J, r, kind, index, dof, sign):
    """Row r (of the rows' ``kind``, ``key``, ``dof`` and ``J`` arrays: not the bundle, see :class:`DriveTerms`):
    kind, key, J = sign · e_dof (bounds and target left to the caller)."""
    kinds[r] = kind
    keys[r] = kind * KEY_SLOTS + index
    dofs[r] = dof
    J[r, dof] = sign


@njit
def _joint_rows(system, joints, terms, implicit, rows, h):
    """Fill the joint's own rows (drive, friction, velocity limit, mimic, limit) from row 0; returns the next."""
    n = len(implicit)
    kinds, keys, dofs, J = rows.kind, rows.key, rows.dof, rows.J
    r = 0
    for i in range(n):  # saturated drives: soft rows with the drive's softness, |λ| ≤ h effort_limit
        kp, kd = terms.kp[i], terms.kd[i]
        if (kp > 0.0 or kd > 0.0) and not implicit[i]:
            _dof_row(kinds, keys, dofs, J, r, ROW_DRIVE, i, i, 1.0)
            gamma = 1.0 / (h * kd + h * h * kp)
            rows.softness[r] = gamma
            rows.target[r] = gamma * h * terms.push[i]
            rows.lower[r], rows.upper[r] = -h * joints.effort_limit[i], h * joints.effort_limit[i]
            r += 1
    for i in range(n):
        if joints.friction[i] > 0.0:
            _dof_row(kinds, keys, dofs, J, r, ROW_FRICTION, i, i, 1.0)
            rows.lower[r], rows.upper[r] = -h * joints.friction[i], h * joints.friction[i]
            r += 1
    for i in range(n):
        vmax = joints.velocity_limit[i]
        if vmax > 0.0 and vmax < np.inf:
            for side in range(2):  # qd ≥ −vmax, then −qd ≥ −vmax
                _dof_row(kinds, keys, dofs, J, r, ROW_VELOCITY_LIMIT, 2 * i + side, i, 1.0 - 2.0 * side)
                rows.target[r], rows.upper[r] = -vmax, np.inf
                r += 1
    for j in range(len(joints.mimic_follower)):
        f, lead, mult = joints.mimic_follower[j], joints.mimic_leader[j], joints.mimic_multiplier[j]
        _dof_row(kinds, keys, dofs, J, r, ROW_MIMIC, j, f, 1.0)
        J[r, lead] -= mult
        dofs[r] = -1  # two dofs: not a unit row
        rows.lower[r], rows.upper[r] = -np.inf, np.inf
        rows.error[r] = system.position[f] - mult * system.position[lead] - joints.mimic_offset[j]
        r += 1
    for i in range(n):
        for side in range(2):  # lower limit: J = e_i, gap q − lower; upper: J = −e_i, gap upper − q
            bound = joints.lower[i] if side == 0 else joints.upper[i]
            if bound == np.inf or bound == -np.inf or bound != bound:
                continue
            sign = 1.0 - 2.0 * side
            _dof_row(kinds, keys, dofs, J, r, ROW_LIMIT, 2 * i + side, i, sign)
            gap = sign * (system.position[i] - bound)
            rows.error[r] = gap
            rows.target[r] = -max(gap, 0.0) / h
            rows.upper[r] = np.inf
            r += 1
    for j in range(len(joints.equality_error)):  # the caller's equalities: hard, free λ, after the limits
        rows.kind[r] = ROW_EQUALITY
        rows.key[r] = ROW_EQUALITY * KEY_SLOTS + j
        for i in range(n):
            rows.J[r, i] = joints.equality_jacobian[j, i]
        rows.lower[r], rows.upper[r] = -np.inf, np.inf
        rows.error[r] = joints.equality_error[j]
        r += 1
    return r


@njit
def _contact_rows(contacts, bodies, rows, first, h):
    """Fill the contact points' rows from row ``first``: per point t₁, t₂, normal."""
    for c in range(len(contacts.key)):
        for slot in range(3):
            r = first + 3 * c + slot
            d = (slot + 1) % 3  # the rows t₁, t₂, normal take directions 1, 2, 0 of the point
            rows.kind[r] = ROW_NORMAL if d == 0 else ROW_TANGENT
            rows.key[r] = rows.kind[r] * KEY_SLOTS + 3 * contacts.key[c] + d
            for k in range(rows.J.shape[1]):
                rows.J[r, k] = contacts.joint_jacobian[c, d, k]
            b = contacts.body[c]
            rows.body[r] = b
            if b >= 0:
                for k in range(6):
                    rows.Jb[r, k] = contacts.body_jacobian[c, d, k]
                for k in range(3):
                    rows.Wb[r, k] = bodies.inv_mass[b] * rows.Jb[r, k]
                    rows.Wb[r, 3 + k] = (bodies.inv_inertia[b, k, 0] * rows.Jb[r, 3]
                                         + bodies.inv_inertia[b, k, 1] * rows.Jb[r, 4]
                                         + bodies.inv_inertia[b, k, 2] * rows.Jb[r, 5])
            if d == 0:
                rows.error[r] = contacts.separation[c]
                rows.target[r] = -max(contacts.separation[c], 0.0) / h
                rows.upper[r] = np.inf
            else:
                rows.lower[r], rows.upper[r] = -contacts.friction[c], contacts.friction[c]


@njit
def prepare_joints(system, joints, terms, contacts, bodies, h, allowed):
    """Box2D's prepare stage in joint space: the :class:`Implicit` solve (drives ``allowed`` in A, (n,) bool;
    ``terms``: :class:`DriveTerms`) and the sub-step's :class:`JointRows` with A⁻¹ Jᵀ and their effective masses."""
    implicit = implicit_drives(system, joints, terms, h, allowed)
    return implicit, prepare_rows(system, joints, terms, implicit, contacts, bodies, h)


@njit
def prepare_rows(system, joints, terms, implicit, contacts, bodies, h):
    """The sub-step's :class:`JointRows` with A⁻¹ Jᵀ and their effective masses, A the :class:`Implicit` solve's."""
    n = len(system.velocity)
    rows = _empty_rows(_count_rows(joints, terms, implicit.implicit, len(contacts.key)), n)
    first = _joint_rows(system, joints, terms, implicit.implicit, rows, h)
    _contact_rows(contacts, bodies, rows, first, h)
    # A⁻¹ e_i once per dof (column i of `unit`, solved at its first row): the rows of one dof (a drive, its
    # friction, two velocity limits, two limits) share it, J = ±e_i giving ±A⁻¹ e_i exactly (rounding is
    # symmetric in sign)
    # Every row's J and W live in the blocks of A its J touches (rows.lo … rows.hi − 1; an island's robot rows in
    # their robot's block): the solves, the products here and every sweep's loops run there only, so k robots cost
    # k times one robot, not k² (the dense loops only added zeros: the same numbers)
    unit = np.zeros((n, n))
    solved = np.zeros(n, np.bool_)
    e = np.zeros(n)
    block_start, block_end = implicit.block_start, implicit.block_end
    for r in range(len(rows.kind)):
        lo, hi = n, 0
        for c in range(n):
            if rows.J[r, c] != 0.0:
                lo = min(lo, c)
                hi = c + 1
        if hi == 0:
            lo = 0  # no column at all (a point on a link that no dof moves)
        else:
            lo, hi = block_start[lo], block_end[hi - 1]
        rows.lo[r], rows.hi[r] = lo, hi
        i = rows.dof[r]
        if i < 0:
            cholesky_solve_into(implicit.factor, rows.J[r], lo, hi, rows.W[r])
        else:
            if not solved[i]:
                e[i] = 1.0
                cholesky_solve_into(implicit.factor, e, block_start[i], block_end[i], unit[i])
                e[i] = 0.0
                solved[i] = True
            for c in range(lo, hi):  # (written in place: a temporary per row costs more than the products)
                rows.W[r, c] = unit[i, c] * rows.J[r, i]
        k = 0.0
        for i in range(lo, hi):
            k += rows.J[r, i] * rows.W[r, i]
        for i in range(6):
            k += rows.Jb[r, i] * rows.Wb[r, i]
        rows.stiff[r] = k
        rows.eff[r] = 1.0 / (k + rows.softness[r]) if k + rows.softness[r] > 0.0 else 0.0
    return rows


# ---- 2.–3. warm start and the sweeps -------------------------------------------------------------------------

@njit
def _row_velocity(J, Jb, b, r, v, V, lo, hi):
    """Row r's velocity J v (+ J_b V of its free body ``b``, −1: none) (the rows' arrays, not the bundle: see
    :class:`DriveTerms`); J's columns ``lo`` … ``hi`` − 1 (:class:`JointRows`: the others are zero)."""
    s = 0.0
    for i in range(lo, hi):
        s += J[r, i] * v[i]
    if b >= 0:
        for k in range(6):
            s += Jb[r, k] * V[b, k]
    return s


@njit
def _apply_row(W, Wb, b, r, delta, v, V, lo, hi):
    """Row r's impulse change ``delta`` applied to v (and to its free body ``b``'s V); W's columns ``lo`` …
    ``hi`` − 1 (the others are zero)."""
    for i in range(lo, hi):
        v[i] += W[r, i] * delta
    if b >= 0:
        for k in range(6):
            V[b, k] += Wb[r, k] * delta


@njit
def warm_start_joints(rows, memory, v, V, warm_start):
    """The accumulated impulses λ (R,), from the previous sub-step's of the same keys (clamped to this
    sub-step's bounds; a tangent row to its cone), applied to v (n,) and V (b, 6); zeros without warm start."""
    R = len(rows.kind)
    lam = np.zeros(R)
    if not warm_start or len(memory.key) == 0:
        return lam
    for r in range(R):
        o = np.searchsorted(memory.key, rows.key[r])
        if o < len(memory.key) and memory.key[o] == rows.key[r]:
            lam[r] = memory.impulse[o]
            if rows.kind[r] != ROW_TANGENT:  # (tangent rows: to their cone, below)
                lam[r] = min(max(lam[r], rows.lower[r]), rows.upper[r])
    for r in range(R):
        if rows.kind[r] == ROW_TANGENT and (r + 1 < R and rows.kind[r + 1] == ROW_TANGENT):
            _clamp_cone(rows.upper[r], r, lam)
    for r in range(R):
        if lam[r] != 0.0:
            _apply_row(rows.W, rows.Wb, rows.body[r], r, lam[r], v, V, rows.lo[r], rows.hi[r])
    return lam


@njit
def _clamp_cone(friction, r, lam):
    """Clamp the tangent pair (r, r + 1) to |λ_t| ≤ μ λₙ (the normal is row r + 2, μ = ``friction``: the pair's
    upper bound)."""
    limit = friction * lam[r + 2]
    norm = math.sqrt(lam[r] * lam[r] + lam[r + 1] * lam[r + 1])
    if norm > limit:
        scale = limit / norm if norm > 0.0 else 0.0
        lam[r] *= scale
        lam[r + 1] *= scale


@njit
def solve_joints(rows, lam, v, V, settings):
    """Projected Gauss–Seidel over the rows, in place on λ, v, V; returns the sweeps run."""
    sweeps = 0
    for _ in range(settings.velocity_iterations):
        sweeps += 1
        if sweep_joints(rows, lam, v, V) <= settings.velocity_tolerance:
            break
    return sweeps


@njit
def sweep_joints(rows, lam, v, V):
    """One Gauss–Seidel sweep over the rows, in place on λ, v, V (also a sweep of the one loop that solves robot
    rows and body rows together, :mod:`cgp_core.robots.coupled`); returns the largest change of a row's velocity
    it made (the early stop's measure)."""
    R = len(rows.kind)
    J, W, Jb, Wb, body, lo, hi = rows.J, rows.W, rows.Jb, rows.Wb, rows.body, rows.lo, rows.hi
    change = 0.0
    r = np.int64(0)  # (not the literal 0: numba would compile the row helpers once more for a literal row index)
    while r < R:
        if rows.kind[r] == ROW_TANGENT:  # t₁ and t₂ of a point together, clamped to its cone
            b = body[r]
            d1 = rows.eff[r] * (rows.target[r] - _row_velocity(J, Jb, b, r, v, V, lo[r], hi[r]))
            d2 = rows.eff[r + 1] * (rows.target[r + 1] - _row_velocity(J, Jb, b, r + 1, v, V, lo[r + 1], hi[r + 1]))
            old1, old2 = lam[r], lam[r + 1]
            lam[r], lam[r + 1] = old1 + d1, old2 + d2
            _clamp_cone(rows.upper[r], r, lam)
            d1, d2 = lam[r] - old1, lam[r + 1] - old2
            _apply_row(W, Wb, b, r, d1, v, V, lo[r], hi[r])
            _apply_row(W, Wb, b, r + 1, d2, v, V, lo[r + 1], hi[r + 1])
            change = max(change, abs(d1) * rows.stiff[r], abs(d2) * rows.stiff[r + 1])
            r += 2
            continue
        b = body[r]
        delta = rows.eff[r] * (rows.target[r] - _row_velocity(J, Jb, b, r, v, V, lo[r], hi[r])
                               - rows.softness[r] * lam[r])
        old = lam[r]
        lam[r] = min(max(old + delta, rows.lower[r]), rows.upper[r])
        delta = lam[r] - old
        _apply_row(W, Wb, b, r, delta, v, V, lo[r], hi[r])
        change = max(change, abs(delta) * (rows.stiff[r] + rows.softness[r]))
        r += 1
    return change


@njit
def saturated_by_rows(joints, terms, implicit, v, h, allowed):
    """Whether a drive left in A has a torque beyond its effort limit at the solved velocity v (n,); such drives
    are taken out of ``allowed`` (in place)."""
    found = False
    for i in range(len(v)):
        if implicit.implicit[i]:
            torque = terms.push[i] - (h * terms.kp[i] + terms.kd[i]) * v[i]
            if abs(torque) > joints.effort_limit[i] * (1.0 + 1e-9):
                allowed[i] = False
                found = True
    return found


# ---- 4. the position stage -----------------------------------------------------------------------------------

@njit
def _positional(kind):
    """Whether a row of ``kind`` takes part in the position stage: limits, mimics, equalities, contact normals."""
    return kind == ROW_LIMIT or kind == ROW_MIMIC or kind == ROW_EQUALITY or kind == ROW_NORMAL


@njit
def relax_positions(rows, v, V, settings):
    """The position stage: the displacement Δq (as the pseudo-velocity Δq / h, (n,)) that removes the fraction
    β of the limits' and mimics' position errors predicted after the velocity step, and of the contacts'
    penetration beyond the slop (see the module docstring); and the displacement D (len(V), 6) [m, rad] of the
    free bodies those contacts push, M_b⁻¹ J_bᵀ λ, which the caller applies to their poses after the integrator
    (never to their momenta: split impulses add no energy).  ``V`` (b, 6): the free bodies' solved velocities."""
    n, R, h = len(v), len(rows.kind), settings.h
    d = np.zeros(n)
    D = np.zeros((len(V), 6))
    goal = position_goals(rows, v, V, settings)
    lam = np.zeros(R)
    for _ in range(settings.position_iterations):
        if relax_sweep(rows, goal, lam, d, D) <= POSITION_TOLERANCE:  # nothing (more) to correct: the usual
            break                                                     # case, one sweep
    for i in range(n):
        d[i] /= h
    return d, D


@njit
def position_goals(rows, v, V, settings):
    """(R,) what the position stage asks of each row's displacement J Δq + J_b D (0 for the rows without a
    position error): −β times the error predicted after the velocity step (v (n,), the free bodies' V (b, 6)); a
    contact's penetration beyond the slop, at most ``max_correction`` (see :func:`relax_positions`)."""
    R, h = len(rows.kind), settings.h
    goal = np.zeros(R)
    for r in range(R):
        if _positional(rows.kind[r]):
            predicted = rows.error[r] + h * _row_velocity(rows.J, rows.Jb, rows.body[r], r, v, V, rows.lo[r],
                                                          rows.hi[r])
            if rows.kind[r] == ROW_NORMAL:  # as the contact solver's position stage: slop, β, a cap
                goal[r] = min(-settings.contact_correction * (predicted + settings.penetration_slop),
                              settings.max_correction)
            else:
                goal[r] = -settings.position_correction * predicted
    return goal


@njit
def relax_sweep(rows, goal, lam, d, D):
    """One Gauss–Seidel sweep of the position stage over the rows with a position error towards ``goal``
    (:func:`position_goals`), in place on their accumulated λ (R,), the robot's displacement d (n,) and the free
    bodies' D (b, 6) (also a sweep of the one position loop of :mod:`cgp_core.robots.coupled`); returns the
    largest change of a row's displacement it made."""
    change = 0.0
    for r in range(len(rows.kind)):
        if not _positional(rows.kind[r]) or rows.stiff[r] <= 0.0:
            continue
        delta = (goal[r] - _row_velocity(rows.J, rows.Jb, rows.body[r], r, d, D, rows.lo[r], rows.hi[r])) \
            / rows.stiff[r]
        if rows.kind[r] != ROW_MIMIC and rows.kind[r] != ROW_EQUALITY:  # one-sided
            delta = max(lam[r] + delta, 0.0) - lam[r]
        lam[r] += delta
        _apply_row(rows.W, rows.Wb, rows.body[r], r, delta, d, D, rows.lo[r], rows.hi[r])
        change = max(change, abs(delta) * rows.stiff[r])
    return change


# ---- 5. store: impulses to the free bodies, the effort, the memory -------------------------------------------

@njit
def drive_efforts(joints, terms, implicit, v, h):
    """The effort (n,) [N m / N] of the drives and the damping at the solved velocity v (n,): an effort drive's
    command, −c qd⁺, and an implicit drive's torque at qd⁺ (the rows' share is :func:`store_joints`')."""
    effort = np.zeros(len(v))
    for i in range(len(v)):
        effort[i] = terms.command[i] - joints.damping[i] * v[i]
        if implicit.implicit[i]:
            effort[i] += terms.push[i] - (h * terms.kp[i] + terms.kd[i]) * v[i]
    return effort


@njit
def store_joints(joints, terms, implicit, rows, lam, v, bodies, h):
    """Adds the contact rows' impulses to the free bodies' momenta (in place); returns the effort (n,) (see the
    module docstring), the contact impulses (c, 3) and the new :class:`JointSolverMemory`."""
    R = len(rows.kind)
    effort = drive_efforts(joints, terms, implicit, v, h)
    n_joint_rows = 0  # rows before the contacts: the joint's own and the equalities
    for r in range(R):
        if rows.kind[r] < ROW_TANGENT:
            n_joint_rows += 1
        if rows.kind[r] <= ROW_LIMIT:
            for i in range(rows.lo[r], rows.hi[r]):
                effort[i] += rows.J[r, i] * lam[r] / h
        b = rows.body[r]
        if b >= 0:
            for k in range(3):
                bodies.linear_momentum[b, k] += rows.Jb[r, k] * lam[r]
                bodies.angular_momentum[b, k] += rows.Jb[r, 3 + k] * lam[r]
    c = (R - n_joint_rows) // 3
    impulse = np.zeros((c, 3))
    for p in range(c):
        r = n_joint_rows + 3 * p
        impulse[p, 0], impulse[p, 1], impulse[p, 2] = lam[r + 2], lam[r], lam[r + 1]
    order = np.argsort(rows.key, kind="mergesort")
    return effort, impulse, JointSolverMemory(rows.key[order], lam[order])


# ---- a robot at rest against its rows -------------------------------------------------------------------------
#
# The usual sub-step of a robot that touches nothing (an arm holding a pose, following a trajectory in free space):
# its only rows are its joint limits and velocity limits, none near, and every one of them ends the sub-step at
# zero impulse — the answer is the implicit solve's qd_free.  Building the rows (A⁻¹ Jᵀ per dof), sweeping them
# once, the position stage's sweep and the memory's sort cost about four times the implicit solve (measured on a
# 7-dof arm: ~6 µs of the sub-step's ~8), so such a sub-step is recognised first and answered without them.

# (rows_at_rest and rest_step inlined into step_joints, their one caller: each call handed over ~25 arrays of the
# bundles, ~0.1 µs a call, measured)
@njit(inline="always")
def rows_at_rest(system, joints, terms, implicit, memory, settings):
    """Whether every row :func:`prepare_rows` would build for this sub-step (no contact rows: the caller's
    condition) stays at zero impulse, so that the stages would return qd⁺ = qd_free, no pseudo-velocity, the
    drives' own effort and zero impulses (:func:`rest_step` returns exactly that).  True only when

    - the rows are one-sided unit rows: velocity and position limits (no saturated drive, no friction, no mimic,
      no equality: rows that take an impulse whenever qd moves or a position error exists);
    - each is satisfied strictly at qd_free, J qd_free > target (the first sweep's Δλ < 0 is clamped to 0), and a
      limit's position stage has nothing to correct, −β (gap + h J qd_free) < 0 (its Δλ too) — the expressions
      :func:`sweep_joints` and :func:`relax_positions` evaluate;
    - no warm-start impulse would be applied (with warm starting on, the memory's impulses are all zero);
    - A's factor has a positive finite diagonal and qd_free is finite (otherwise the stages' numbers are inf or
      nan, and they are left to give them);
    - the sweeps end after the first (``velocity_tolerance`` ≥ 0: a sweep that changed nothing stops them)."""
    h, n = settings.h, len(system.velocity)
    if len(joints.mimic_follower) > 0 or len(joints.equality_error) > 0 or settings.velocity_tolerance < 0.0:
        return False
    if settings.warm_start:
        for w in range(len(memory.impulse)):
            if memory.impulse[w] != 0.0:
                return False
    v = implicit.velocity
    for i in range(n):
        if not (implicit.factor[i, i] > 0.0 and implicit.factor[i, i] < np.inf and abs(v[i]) < np.inf):
            return False
        if (terms.kp[i] > 0.0 or terms.kd[i] > 0.0) and not implicit.implicit[i]:
            return False  # a saturated drive: a soft row that takes its clamped impulse
        if joints.friction[i] > 0.0:
            return False
        vmax = joints.velocity_limit[i]
        if vmax > 0.0 and vmax < np.inf and not (v[i] > -vmax and -v[i] > -vmax):
            return False  # a velocity limit reached (its rows: qd ≥ −vmax, −qd ≥ −vmax)
        for side in range(2):  # the limit rows as :func:`_joint_rows` makes them
            bound = joints.lower[i] if side == 0 else joints.upper[i]
            if bound == np.inf or bound == -np.inf or bound != bound:
                continue
            sign = 1.0 - 2.0 * side
            gap = sign * (system.position[i] - bound)
            speed = sign * v[i]  # the row's J qd_free
            if not speed > -max(gap, 0.0) / h:
                return False  # the speculative row holds the joint back
            if settings.position_iterations > 0 and not -settings.position_correction * (gap + h * speed) < 0.0:
                return False  # the position stage corrects the predicted penetration
    return True


@njit(inline="always")
def rest_step(joints, terms, implicit, n_bodies, settings):
    """The sub-step's :class:`JointStep` and memory when :func:`rows_at_rest` holds: qd⁺ = qd_free, no
    pseudo-velocity or body displacement ((``n_bodies``, 6) zeros), the drives' effort (:func:`drive_efforts`),
    the sweeps :func:`solve_joints` would count (one, or none if it may run none) and the memory of the rows' keys
    (ascending: kind, then index, as :func:`_joint_rows` makes them) with zero impulses."""
    h, n = settings.h, len(implicit.velocity)
    v = implicit.velocity.copy()
    keys = np.empty(4 * n, np.int64)
    count = 0
    for i in range(n):
        vmax = joints.velocity_limit[i]
        if vmax > 0.0 and vmax < np.inf:
            for side in range(2):
                keys[count] = ROW_VELOCITY_LIMIT * KEY_SLOTS + 2 * i + side
                count += 1
    for i in range(n):
        for side in range(2):
            bound = joints.lower[i] if side == 0 else joints.upper[i]
            if bound == np.inf or bound == -np.inf or bound != bound:
                continue
            keys[count] = ROW_LIMIT * KEY_SLOTS + 2 * i + side
            count += 1
    step = JointStep(v, np.zeros(n), drive_efforts(joints, terms, implicit, v, h), np.zeros((0, 3)),
                     1 if settings.velocity_iterations > 0 else 0, np.zeros((n_bodies, 6)))
    return step, JointSolverMemory(keys[:count].copy(), np.zeros(count))


# ---- the sub-step ---------------------------------------------------------------------------------------------

@njit
def step_joints(system, joints, drives, contacts, bodies, memory, settings, profile):
    """One sub-step of an articulation's joints (the stages in order, each timed into ``profile``,
    (len(STAGES),)).  Bundles (plain tuples from Python, see "Bundles" in :mod:`cgp_core.jit`):
    :class:`JointSystem`, :class:`JointProperties`, :class:`JointDrives`, :class:`ContactRows`,
    :class:`FreeBodies` (velocity and momenta updated in place), :class:`JointSolverMemory`,
    :class:`JointSettings`.  Returns the :class:`JointStep` and the new memory."""
    system, joints, drives = JointSystem(*system), JointProperties(*joints), JointDrives(*drives)
    contacts, bodies = ContactRows(*contacts), FreeBodies(*bodies)
    memory, settings = JointSolverMemory(*memory), JointSettings(*settings)
    h, n = settings.h, len(system.velocity)
    allowed = np.ones(n, np.bool_)
    sweeps = 0
    start = clock()
    terms = drive_terms(system, joints, drives)
    implicit = implicit_drives(system, joints, terms, h, allowed)
    if len(contacts.key) == 0 and rows_at_rest(system, joints, terms, implicit, memory, settings):
        start = lap(profile, PREPARE, start)
        rested = rest_step(joints, terms, implicit, len(bodies.inv_mass), settings)
        lap(profile, STORE, start)
        return rested
    while True:  # at most n + 1 passes: each but the last takes a drive out of A
        rows = prepare_rows(system, joints, terms, implicit, contacts, bodies, h)
        v = implicit.velocity.copy()
        V = bodies.velocity.copy()
        start = lap(profile, PREPARE, start)
        lam = warm_start_joints(rows, memory, v, V, settings.warm_start)
        start = lap(profile, WARM_START, start)
        sweeps += solve_joints(rows, lam, v, V, settings)
        start = lap(profile, SOLVE, start)
        # the rows may have held a drive back (a contact, a limit): one whose torque now exceeds its limit is
        # taken out of A and the sub-step solved again with it as a clamped row
        if not saturated_by_rows(joints, terms, implicit, v, h, allowed):
            break
        implicit = implicit_drives(system, joints, terms, h, allowed)
    for b in range(len(V)):
        for k in range(6):
            bodies.velocity[b, k] = V[b, k]
    pseudo, displacement = relax_positions(rows, v, V, settings)
    start = lap(profile, RELAX, start)
    effort, impulse, memory = store_joints(joints, terms, implicit, rows, lam, v, bodies, h)
    lap(profile, STORE, start)
    return JointStep(v, pseudo, effort, impulse, sweeps, displacement), memory


def integrate_dofs(position: np.ndarray, step: JointStep, h: float) -> np.ndarray:
    """q⁺ = q + h (qd⁺ + pseudo) for robots of 1-dof joints (revolute, prismatic); others integrate
    ``step.velocity + step.pseudo_velocity`` with their own integrator."""
    return position + h * (step.velocity + step.pseudo_velocity)


def position_gains(mass_matrix: np.ndarray, h: float, fraction: float = 0.25,
                   damping_ratio: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Default position-drive gains (kp, kd), each (n,): per dof the spring of natural frequency ``fraction`` of
    the sub-step rate (Box2D's cap on joint stiffness: 0.25 × 1/h Hz) on the dof's own inertia M[i, i], with
    damping ratio ``damping_ratio``: kp = I ω², kd = 2 ζ I ω, ω = 2π fraction / h.  At h = 1/240 s, 1 kg m² gets
    kp ≈ 1.4e5 N m/rad: a 20 N m gravity load holds to ~1.4e-4 rad."""
    inertia = np.diag(np.asarray(mass_matrix, float)).copy()
    omega = 2.0 * math.pi * fraction / h
    return inertia * omega * omega, 2.0 * damping_ratio * inertia * omega


def _shape(array, shape, what: str, dtype=np.float64) -> None:
    a = np.asarray(array)
    if a.shape != shape or a.dtype != dtype:
        raise ValueError(f"{what} must be a {dtype.__name__} array of shape {shape}, got {a.dtype} {a.shape}")


def check_bundles(system: JointSystem, joints: JointProperties, drives: JointDrives, contacts: ContactRows,
                  bodies: FreeBodies) -> None:
    """``ValueError`` naming the array unless every array has the shape and dtype its bundle documents and the
    indices (mimic dofs, contact bodies, drive modes) are in range: the compiled kernels do not check bounds."""
    n = len(system.velocity)
    _shape(system.mass_matrix, (n, n), "mass_matrix")
    for name in ("bias", "applied", "position", "velocity"):
        _shape(getattr(system, name), (n,), name)
    for name in ("lower", "upper", "effort_limit", "velocity_limit", "damping", "friction"):
        _shape(getattr(joints, name), (n,), name)
    k = len(joints.mimic_follower)
    for name, dtype in (("mimic_follower", np.int64), ("mimic_leader", np.int64), ("mimic_multiplier", np.float64),
                        ("mimic_offset", np.float64)):
        _shape(getattr(joints, name), (k,), name, dtype)
    if k and not (0 <= min(joints.mimic_follower.min(), joints.mimic_leader.min())
                  and max(joints.mimic_follower.max(), joints.mimic_leader.max()) < n):
        raise ValueError(f"mimic dofs must be in [0, {n})")
    e = len(joints.equality_error)
    _shape(joints.equality_jacobian, (e, n), "equality_jacobian")
    _shape(joints.equality_error, (e,), "equality_error")
    _shape(drives.mode, (n,), "mode", np.int64)
    if n and not (DRIVE_NONE <= drives.mode.min() and drives.mode.max() <= DRIVE_POSITION):
        raise ValueError("drive modes must be DRIVE_NONE, DRIVE_EFFORT, DRIVE_VELOCITY or DRIVE_POSITION")
    for name in ("target_position", "target_velocity", "target_effort", "stiffness", "damping"):
        _shape(getattr(drives, name), (n,), f"drive {name}")
    if n and (drives.stiffness.min() < 0 or drives.damping.min() < 0 or not np.all(np.isfinite(drives.stiffness))
              or not np.all(np.isfinite(drives.damping))):
        raise ValueError("drive gains must be finite and >= 0")
    c, b = len(contacts.key), len(bodies.inv_mass)
    _shape(contacts.joint_jacobian, (c, 3, n), "joint_jacobian")
    _shape(contacts.body, (c,), "contact body", np.int64)
    _shape(contacts.body_jacobian, (c, 3, 6), "body_jacobian")
    _shape(contacts.separation, (c,), "separation")
    _shape(contacts.friction, (c,), "contact friction")
    _shape(contacts.key, (c,), "contact key", np.int64)
    if c and not (-1 <= contacts.body.min() and contacts.body.max() < b):
        raise ValueError(f"contact bodies must be -1 (the static world) or in [0, {b})")
    if c and not (0 <= contacts.key.min() and contacts.key.max() < 2 ** 37):
        raise ValueError("contact keys must be in [0, 2**37)")
    _shape(bodies.inv_inertia, (b, 3, 3), "inv_inertia")
    for name, width in (("velocity", 6), ("linear_momentum", 3), ("angular_momentum", 3)):
        _shape(getattr(bodies, name), (b, width), name)


class JointSolver:
    """The Python side of :func:`step_joints`: keeps the warm-start memory, the settings and the stage
    profile between sub-steps.

    ``step(system, joints, drives, contacts=None, bodies=None)`` runs one sub-step and returns its
    :class:`JointStep`; :meth:`reset` forgets the warm start (a teleport, a new model).  ``check`` (default on):
    every call checks the bundles' shapes and indices first (:func:`check_bundles`, ~25 µs for 7 dofs); a caller
    that built them itself and proved them turns it off."""

    def __init__(self, h: float, *, check: bool = True, **overrides):
        self.settings = JointSettings.default(positive(h, "the sub-step h"))._replace(**overrides)
        self.check = check
        self.profile = StageProfile(STAGES)
        self.memory = JointSolverMemory.empty()

    def reset(self) -> None:
        self.memory = JointSolverMemory.empty()

    def step(self, system: JointSystem, joints: JointProperties, drives: JointDrives,
             contacts: ContactRows | None = None, bodies: FreeBodies | None = None) -> JointStep:
        n = len(system.velocity)
        contacts = ContactRows.empty(n) if contacts is None else contacts
        bodies = FreeBodies.empty() if bodies is None else bodies
        joints = JointProperties(*joints).with_equalities()
        if self.check:
            check_bundles(system, joints, drives, contacts, bodies)
        result, memory = step_joints(tuple(system), tuple(joints), tuple(drives), tuple(contacts), tuple(bodies),
                                     tuple(self.memory), tuple(self.settings), self.profile.seconds)
        self.memory = JointSolverMemory(*memory)
        self.profile.calls += 1
        return JointStep(*result)


__all__ = ["DRIVE_EFFORT", "DRIVE_NONE", "DRIVE_POSITION", "DRIVE_VELOCITY", "STAGES", "ContactRows", "FreeBodies",
           "JointDrives", "JointProperties", "JointSettings", "JointSolver", "JointSolverMemory", "JointStep",
           "JointSystem", "check_bundles", "integrate_dofs", "position_gains", "step_joints"]


# ---- many robots in one call ----------------------------------------------------------------------------------

class RobotStack(NamedTuple):
    """Every robot's bundles in one, each array the robots' side by side (concatenated along axis 0; robot ``k``'s
    part at its :class:`~cgp_core.robots.model.RobotStarts`): what :func:`step_lone_robots` takes.  Why not a list
    of per-robot bundles: numba's dispatcher types a ``numba.typed.List`` of tuples in Python and hashes its nested
    type at every call (~41 µs a call, measured with numba 0.68), plain tuples of arrays in C (~0.1 µs an array);
    robot ``k``'s bundles are views taken inside the compiled call (:func:`robot_properties`, ...)."""

    models: tuple      # RobotArrays stacked (cgp_core.robots.model.stack_robot_arrays)
    properties: tuple  # JointProperties: the per-dof fields at starts.dof, mimic_* at starts.mimic, equality_error
    #                    at starts.equality, equality_jacobian flattened to (Σ e_k n_k,) at starts.equality_entry
    #                    (robot k's (e_k, n_k) rows, row-major)
    drives: tuple      # JointDrives of every dof ((n_dofs,) each: the world's drive arrays)


class RobotMemories(NamedTuple):
    """Every robot's :class:`JointSolverMemory` side by side (``W`` rows in all)."""

    key: np.ndarray      # (W,) int64 robot k's keys at start[k] … start[k + 1], ascending within each robot
    impulse: np.ndarray  # (W,) their accumulated impulses [N m s / N s]
    start: np.ndarray    # (robots + 1,) int64

    @staticmethod
    def empty(robots: int) -> RobotMemories:
        return RobotMemories(np.zeros(0, np.int64), np.zeros(0), np.zeros(robots + 1, np.int64))


class RobotsState(NamedTuple):
    """All robots' joint-space arrays side by side (robot ``k``'s at its starts)."""

    q: np.ndarray           # (n_q,) positions
    qd: np.ndarray          # (n_dofs,) velocities (written: q̇ after the sub-step)
    applied: np.ndarray     # (n_dofs,) applied joint efforts (wrench commands as Jᵀ F) [N m / N]
    pseudo: np.ndarray      # (n_dofs,) the position stage's pseudo-velocity (written)
    effort_sum: np.ndarray  # (n_dofs,) the joints' efforts summed over the tick's sub-steps (added to)
    q_of_dof: np.ndarray    # (n_dofs,) int64 each 1-dof joint's position index within its robot (−1: none)


def stack_properties(properties: list) -> tuple[JointProperties, np.ndarray, np.ndarray, np.ndarray]:
    """Every robot's :class:`JointProperties` (each with its equality arrays) stacked as :attr:`RobotStack.properties`
    says, with the starts of its mimic couplings, equality rows and equality Jacobian entries ((robots + 1,) int64
    each)."""
    fields = [np.concatenate([getattr(p, name) for p in properties]) for name in JointProperties._fields[:10]]
    jacobian = np.concatenate([p.equality_jacobian.reshape(-1) for p in properties])
    error = np.concatenate([p.equality_error for p in properties])
    return (JointProperties(*(np.ascontiguousarray(f) for f in fields), np.ascontiguousarray(jacobian, float),
                            np.ascontiguousarray(error, float)),
            row_starts([len(p.mimic_follower) for p in properties]),
            row_starts([len(p.equality_error) for p in properties]),
            row_starts([p.equality_jacobian.size for p in properties]))


@njit
def robot_properties(properties, starts, k):
    """Robot ``k``'s :class:`JointProperties` as views into the stacked ones (:attr:`RobotStack.properties`), a
    plain tuple as Python passes it to :func:`step_joints` (a namedtuple there compiled step_joints twice)."""
    p = JointProperties(*properties)
    d0, d1 = starts.dof[k], starts.dof[k + 1]
    m0, m1 = starts.mimic[k], starts.mimic[k + 1]
    e0, e1 = starts.equality[k], starts.equality[k + 1]
    jacobian = p.equality_jacobian[starts.equality_entry[k]:starts.equality_entry[k + 1]].reshape((e1 - e0, d1 - d0))
    return JointProperties(p.lower[d0:d1], p.upper[d0:d1], p.effort_limit[d0:d1], p.velocity_limit[d0:d1],
                           p.damping[d0:d1], p.friction[d0:d1], p.mimic_follower[m0:m1], p.mimic_leader[m0:m1],
                           p.mimic_multiplier[m0:m1], p.mimic_offset[m0:m1], jacobian, p.equality_error[e0:e1])[:]


@njit
def robot_drives(drives, starts, k):
    """Robot ``k``'s :class:`JointDrives` as views into every dof's (a plain tuple: see :func:`robot_properties`)."""
    d = JointDrives(*drives)
    d0, d1 = starts.dof[k], starts.dof[k + 1]
    return JointDrives(d.mode[d0:d1], d.target_position[d0:d1], d.target_velocity[d0:d1], d.target_effort[d0:d1],
                       d.stiffness[d0:d1], d.damping[d0:d1])[:]


@njit
def robot_memory(memories, k):
    """Robot ``k``'s :class:`JointSolverMemory` as views into :class:`RobotMemories` (a plain tuple: see
    :func:`robot_properties`)."""
    a, b = memories.start[k], memories.start[k + 1]
    return JointSolverMemory(memories.key[a:b], memories.impulse[a:b])[:]


@njit
def replace_memories(memories, stepped, fresh):
    """New :class:`RobotMemories`: robot ``k``'s is ``fresh[stepped[k]]`` (a :class:`JointSolverMemory`), or its
    old one where ``stepped[k]`` (robots,) int64 is −1."""
    count = len(memories.start) - 1
    start = np.zeros(count + 1, np.int64)
    for k in range(count):
        size = memories.start[k + 1] - memories.start[k] if stepped[k] < 0 else len(fresh[stepped[k]].key)
        start[k + 1] = start[k] + size
    key, impulse = np.empty(start[count], np.int64), np.empty(start[count])
    for k in range(count):
        memory = JointSolverMemory(*robot_memory(memories, k)) if stepped[k] < 0 else fresh[stepped[k]]
        for i in range(len(memory.key)):
            key[start[k] + i] = memory.key[i]
            impulse[start[k] + i] = memory.impulse[i]
    return RobotMemories(key, impulse, start)


@njit
def step_lone_robots(which, stack, memories, state, starts, gravity, settings, profile):
    """One sub-step of the robots ``which`` (int64 indices) that touch nothing this sub-step, in one compiled call
    (what :meth:`cgp_core.robots.world.Robots.solve` does per robot from Python, without the Python): per robot
    ``k`` its M and bias (:func:`~cgp_core.robots.algorithms.joint_space_terms`), :func:`step_joints` without
    contact rows, q̇ written into ``qd``, the pseudo-velocity into ``pseudo``, the effort added to
    ``effort_sum``.  Bundles as plain tuples: :class:`RobotStack`, :class:`RobotMemories`, :class:`RobotsState`,
    :class:`~cgp_core.robots.model.RobotStarts`.  Returns the :class:`RobotMemories`: the same arrays, written in
    place, when every robot's new memory has as many rows as its old one (the usual case: the same rows every
    sub-step), new ones otherwise (the robots not stepped keep theirs).  Robot ``k``'s q, q̇ and applied efforts
    are handed on as views (read only: q̇ is written after its step)."""
    models, properties, drives = stack
    memories = RobotMemories(*memories)
    q, qd, applied, pseudo, effort_sum, q_of_dof = state
    starts = RobotStarts(*starts)
    stepped = np.full(len(starts.body) - 1, -1, np.int64)  # robot k's entry in `fresh`, −1: kept or written in place
    bodies = (np.zeros(0), np.zeros((0, 3, 3)), np.zeros((0, 6)), np.zeros((0, 3)), np.zeros((0, 3)))  # none touched
    no_body, no_body_jacobian = np.zeros(0, np.int64), np.zeros((0, 3, 6))  # contacts: none (one set for all robots)
    no_number, no_key = np.zeros(0), np.zeros(0, np.int64)
    fresh = []  # the new memories of a changed size
    for w in range(len(which)):
        k = which[w]
        qs, qe, ds, de = starts.q[k], starts.q[k + 1], starts.dof[k], starts.dof[k + 1]
        n = de - ds
        qk, qdk = q[qs:qe], qd[ds:de]
        M, bias = joint_space_terms(robot_view(models, starts, k), qk, qdk, gravity)
        coordinate = np.zeros(n)
        for i in range(n):
            j = q_of_dof[ds + i]
            if j >= 0:
                coordinate[i] = qk[j]
        system = (M, bias, applied[ds:de], coordinate, qdk)
        contacts = (np.zeros((0, 3, n)), no_body, no_body_jacobian, no_number, no_number, no_key)
        step, memory = step_joints(system, robot_properties(properties, starts, k), robot_drives(drives, starts, k),
                                   contacts, bodies, robot_memory(memories, k), settings, profile)
        for i in range(n):
            qd[ds + i] = step.velocity[i]
            pseudo[ds + i] = step.pseudo_velocity[i]
            effort_sum[ds + i] += step.effort[i]
        first = memories.start[k]
        if len(memory.key) == memories.start[k + 1] - first:
            for i in range(len(memory.key)):
                memories.key[first + i] = memory.key[i]
                memories.impulse[first + i] = memory.impulse[i]
        else:
            stepped[k] = len(fresh)
            fresh.append(memory)
    if len(fresh) == 0:
        return memories
    return replace_memories(memories, stepped, fresh)

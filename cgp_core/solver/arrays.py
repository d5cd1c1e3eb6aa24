"""What the sequential-impulse solver's stages hand each other: named bundles of arrays (numba compiles them as
structs; see "Bundles" in :mod:`cgp_core.jit`).

Sizes: ``n`` bodies; ``m`` contacts that can move something (sorted by body pair); ``G`` manifolds (body pairs);
``w`` contacts in the warm-start memory.  Body arrays of the solver have ``n + 1`` rows: row ``n`` is the static
ground (and any contact's side with a body that cannot move acts like it), so every contact has two body rows and
no branch.  The order of the stages is :func:`.sequential_impulse.solve_step`'s:

    prepare_bodies → prepare_contacts → warm_start_contacts → solve_contacts → bounce_time_shift
    → apply_impulses → store_impulses              (the velocity stage; after the integrator:)
    recover_penetration_kernel                       (the position stage, from the velocity stage's Handover)

A new per-contact array (a contact's rolling radius, a material's torsional friction ...) is a field of
:class:`Manifolds` (or :class:`Targets`) filled in ``prepare_contacts``; no signature changes.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class BodyArrays(NamedTuple):
    """The bodies' state as the velocity stage reads (and writes: the momenta) it; ``n`` rows."""

    inv_mass: np.ndarray          # (n,) 1/m; 0 for fixed bodies
    movable: np.ndarray           # (n,) bool: the velocity may change (movable and awake)
    inv_inertia: np.ndarray       # (n, 3, 3) world-frame I⁻¹ at the current poses
    position: np.ndarray          # (n, 3) centres of mass x̄ [m]
    linear_momentum: np.ndarray   # (n, 3) P [kg m/s]; the contact impulses are added in place
    angular_momentum: np.ndarray  # (n, 3) L [kg m²/s]; the contact impulses are added in place
    force: np.ndarray             # (n, 3) F accumulated for this sub-step [N]
    torque: np.ndarray            # (n, 3) τ accumulated for this sub-step [N m]


class SolverBodies(NamedTuple):
    """The bodies as the contact rows see them: ``n + 1`` rows, the last (row n) the static ground."""

    inv_mass: np.ndarray         # (n + 1,) 1/m of the dynamic rows, else 0
    inv_inertia: np.ndarray      # (n + 1, 3, 3) world-frame I⁻¹ of the dynamic rows, else 0
    position: np.ndarray         # (n + 1, 3) x̄ (row n: 0) — the lever arms' origins
    dynamic: np.ndarray          # (n + 1,) bool: the row's velocity may change
    velocity: np.ndarray         # (n + 1, 6) [v, ω] being solved for: from momentum + h·force, then + impulses
    velocity_before: np.ndarray  # (n + 1, 6) [v, ω] from momentum alone (the approach speed restitution needs)


class Manifolds(NamedTuple):
    """The ``m`` contacts that can move something, sorted by body pair: manifold g is the run
    ``group_start[g] : group_start[g + 1]``."""

    a: np.ndarray            # (m,) int64 body row of side A (n: the ground, or a body that cannot move)
    b: np.ndarray            # (m,) int64 body row of side B
    group_start: np.ndarray  # (G + 1,) int64 first contact of each manifold; group_start[G] = m
    normal: np.ndarray       # (m, 3) unit normal from A to B
    separation: np.ndarray   # (m,) signed gap [m] at the start of the sub-step (negative: penetration)
    point: np.ndarray        # (m, 3) world contact point (both lever arms go to it)
    friction: np.ndarray     # (m,) combined Coulomb μ
    restitution: np.ndarray  # (m,) combined coefficient of restitution e
    key: np.ndarray          # (m,) int64 contact identity (primitive pair, feature), see collision.contacts
    previous: np.ndarray     # (m,) int64 row of the same contact in the warm-start memory, −1 if new


class Rows(NamedTuple):
    """The constraint rows of the ``m`` contacts (directions n, t₁, t₂) and the manifolds' block cache."""

    J: np.ndarray       # (m, 3, 12) rows [n, t₁, t₂] of J: body A's six entries [−d, −r_a × d], then B's [d, r_b × d]
    MJ: np.ndarray      # (m, 3, 12) the same rows of M⁻¹ Jᵀ (what an impulse along the row does to V)
    eff: np.ndarray     # (m, 3) effective masses 1 / (J M⁻¹ Jᵀ)
    lever: np.ndarray   # (m, 2, 3) lever arms r_a = p − x̄_a, r_b = p − x̄_b
    A: np.ndarray       # (G, 4, 4) normal-row Delassus blocks of the manifolds of ≤ 4 points (see .manifold)
    cache: np.ndarray   # (G, 16, 4, 4) their subsets' pseudo-inverses, filled when first needed
    cached: np.ndarray  # (G, 16) bool: which of them are filled


class Targets(NamedTuple):
    """What the sweeps drive each normal row to, and where restitution put a bounce."""

    bias: np.ndarray       # (m,) target normal velocity: −max(s, 0)/h, or −e·(approach) for a bounce [m/s]
    lower: np.ndarray      # (m,) lower bound of the accumulated normal impulse (0: a contact only pushes)
    approach: np.ndarray   # (m,) normal velocity J V before the sub-step's forces [m/s] (< 0: approaching)
    bounce: np.ndarray     # (m,) bool: the contact bounces (restitution) this sub-step
    impact: np.ndarray     # (m,) bool: an impact: it approaches faster than the restitution threshold and its gap
    # closes within the sub-step (a bounce, or an inelastic impact); its manifold's friction step stays split among
    # all its points, and its earliest impact is the manifold's time of impact (see bounce_time_shift)
    toi_shift: np.ndarray  # (m,) the position stage's target for a bounce placed at its time of impact [m], NaN
    # where none (see bounce_time_shift)


class WarmStart(NamedTuple):
    """What a sub-step leaves for the next one's warm start: its contacts' impulses, sorted by ``key``."""

    key: np.ndarray       # (w,) int64 contact identity, ascending
    normal: np.ndarray    # (w,) accumulated normal impulse λₙ [N s]
    friction: np.ndarray  # (w, 3) world-frame friction impulse λ₁ t₁ + λ₂ t₂ [N s]
    point: np.ndarray     # (w, 3) world contact point (matching is by position within a primitive pair)

    @staticmethod
    def empty() -> WarmStart:
        return WarmStart(np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)))


class StepSettings(NamedTuple):
    """The numbers the stages take (:class:`~cgp_core.solver.base.SolverSettings` and the sub-step)."""

    h: float                      # sub-step [s]
    velocity_iterations: int      # regular sweeps at most
    velocity_tolerance: float     # a sweep changing no row velocity by more than this [m/s] ends them
    restitution_threshold: float  # approach speed [m/s] below which nothing bounces
    warm_start: bool              # start from the previous sub-step's impulses
    rolling_resistance: float     # c_rr
    impact_sweeps: int            # extra sweeps over the manifolds holding a bouncing point
    position_iterations: int      # sweeps of the position stage (0: off)
    position_correction: float    # β, the fraction of the excess penetration removed per sub-step
    penetration_slop: float       # penetration tolerated [m]
    max_correction: float         # at most this much penetration removed per sub-step [m]


class Scratch(NamedTuple):
    """Work space of the normal-row updates, allocated once per stage."""

    block: np.ndarray  # (2, 4) a manifold's right-hand side b and solution x (see .manifold)
    must: np.ndarray   # (4,) bool: two-sided rows of the manifold
    big: np.ndarray    # (m, 2) per-point increments of a Jacobi step (big groups, friction of multi-point groups)


class Solving(NamedTuple):
    """What the sweeps take from the stages before them (:func:`.sequential_impulse.solve_step`'s middle)."""

    bodies: SolverBodies   # the n + 1 body rows; their velocity is solved for
    manifolds: Manifolds   # the contacts, by body pair
    rows: Rows             # their constraint rows
    targets: Targets       # what the normal rows are driven to
    lam: np.ndarray        # (m, 3) accumulated impulses (normal, t₁, t₂), warm-started [N s]
    deepest: float         # the deepest penetration at the start of the sub-step [m]


class Handover(NamedTuple):
    """What the velocity stage hands back to Python: the position stage's inputs (the manifolds' body pairs, runs
    and gaps, their rows, the time-of-impact targets) and the statistics.  Narrower than everything the stage ends
    with on purpose: every array a kernel returns to Python is boxed one by one (~0.5–1 µs each: numba unpickles the
    array type for each), and a 5-body scene's whole sub-step is ~50 µs — returning all of the manifolds, rows,
    targets and impulses (24 arrays) cost it 15–25 %.  The contact report, which needs the rest, is summed inside
    the kernel (:func:`.sequential_impulse.solve_step` with ``report``)."""

    a: np.ndarray            # (m,) int64 = Manifolds.a
    b: np.ndarray            # (m,) int64 = Manifolds.b
    group_start: np.ndarray  # (G + 1,) int64 = Manifolds.group_start
    separation: np.ndarray   # (m,) = Manifolds.separation
    rows: Rows               # the contacts' rows (the position stage solves the normal rows again)
    toi_shift: np.ndarray    # (m,) = Targets.toi_shift
    sweeps: int              # = Solved.sweeps
    deepest: float           # = Solved.deepest


class RecoveryBodies(NamedTuple):
    """The bodies the position stage moves (``n`` rows)."""

    position_before: np.ndarray     # (n, 3) x̄ at the start of the sub-step (when the contacts were found)
    orientation_before: np.ndarray  # (n, 4) q at the start of the sub-step
    position: np.ndarray            # (n, 3) x̄ after the integrator; corrected in place
    orientation: np.ndarray         # (n, 4) q after the integrator; corrected in place
    angular_momentum: np.ndarray    # (n, 3) L; turned with a corrected body in place
    dynamic: np.ndarray             # (n,) bool: the body may be moved (movable and awake)

"""Sequential impulses (Catto, GDC 2005–2014; Box2D) with warm starting, restitution, Coulomb friction and
split-impulse penetration recovery — compiled loops (:mod:`cgp_core.jit`), one contact manifold at a time.

**Rows.**  Per contact point three constraint rows act along d ∈ {n, t₁, t₂} (normal, two tangents).  With
a body's generalized velocity V = (v, ω) and lever arms r_a = p − x_a, r_b = p − x_b to the *same* contact
point p, a row's relative velocity is

    J V = d · (v_b + ω_b × r_b − v_a − ω_a × r_a),   J = [−d, −r_a × d, d, r_b × d]

and an impulse λ along it changes the velocities by ΔV = M⁻¹ Jᵀ λ (M⁻¹ = diag(1/m, I_world⁻¹), zero for
fixed bodies and the ground); its effective mass is 1 / (J M⁻¹ Jᵀ).  Sequential impulses solve the rows one
after another, each for the increment that makes its own velocity right, and *clamp the accumulated*
impulse, not the increment (normal λₙ ≥ 0; friction |λ_t| ≤ μ λₙ, a cone), so later sweeps can take back
what earlier ones overdid: projected Gauss–Seidel on the velocity LCP.

**What the velocities must satisfy** (pipeline stage "solve contacts").  V starts as the velocity the body
would move with over the sub-step without contacts, V₀ = M⁻¹ (momentum + h·force) — gravity is inside the
solve, so a resting body gets exactly the impulse that cancels it — and the rows require

- normal: J V ≥ −max(separation, 0) / h.  A touching or penetrating contact may not approach; a
  *speculative* contact (gap s > 0) may approach by at most s in this sub-step, i.e. exactly close the gap
  (no tunnelling, no early stop).  No Baumgarte term: pushing penetrating bodies apart is the position
  stage's job, so it never ends up in the momenta (no energy gain);
- friction: the two tangent rows drive the slip to zero within the cone |λ_t| ≤ μ λₙ, solved before the
  normal rows in each update (Box2D v2's order: the normal rows, solved last, are the ones kept most exact);
- restitution: a contact that approached faster than ``restitution_threshold`` *before the sub-step*
  (velocity from the momentum alone) and whose gap closes within it asks instead for
  J V ≥ −e · (J V)_before (Box2D v2's velocity bias; the threshold keeps resting contacts from
  micro-bouncing).  A bounce off the static world from a speculative contact is also put at its time of
  impact (see :func:`bounce_time_shift`).

The accumulated impulses are added to P and L at the start of the sub-step: ΔP = Σ J_linᵀ λ, ΔL = Σ J_angᵀ λ
(= Σ r × impulse), equal and opposite on the two bodies at the same point, so momentum is conserved to
round-off.

**Warm starting.**  Each contact point is matched with last sub-step's nearest point of the same primitive
pair (:func:`match_previous`); its normal impulse and world-frame friction impulse are applied before the
first sweep (the friction vector re-projected onto the new tangents and clamped to the cone).  For resting
contacts that is already nearly the answer, which is what lets a stack stand.

**Manifolds, one at a time.**  Contacts are grouped by body pair (the ≤ 4 points of one box-on-box manifold, a
particle body's spheres on the ground ...), and a sweep visits the manifolds in a fixed order (by body pair),
each updated against the velocities the previous ones left: plain Gauss–Seidel, as Box2D v2 does.  Inside a
manifold the friction rows are updated point by point (the two tangent rows of a point together, then clamped
to its cone), then the normal rows of a manifold of ≤ 4 points are solved exactly, as a block LCP
(:mod:`.manifold`) — not one corner after another: sequential corners favour whichever comes first, a tiny
tilt every sweep, and in a tall stack those tilts pump a rocking motion (measured: a 10-box stack jitters at
~1 cm/s with per-point normal rows; with the block it stands, turned and shifted, and a flat box bounces
right).  Bigger groups (a particle plate on the ground) update their normal rows point by point.  The sweeps
stop early once one changes no row velocity by more than ``velocity_tolerance``.  (An earlier numpy version
batched the manifolds by graph colouring to vectorize Gauss–Seidel; compiled, the plain order is simpler and
converges at least as well.)

**Big worlds on two cores** (issue 37): the sweeps shared among threads, as Box2D v3 shares its solver's — but
split in space, not by the constraint graph's colours as Box2D v3 does (why: below). From
:data:`SPLIT_MIN_CONTACTS` contacts on, the moving bodies are split in two regions by the plane through the
median of the manifolds' positions along the widest axis (:func:`_split_regions`); each sweep updates the two
regions' manifolds at the same time, each region in the plain order on a thread of its own (one launch of numba's
pool per sweep), then, on one thread, the manifolds joining a body of each region (:func:`_sweep_regions`). Two
regions share no moving body, so each sees what it would see alone: the same bits on one thread as on two, compiled
or as plain Python. It is another order than the plain one (other bits than the serial sweep would give), so worlds
below the threshold keep the plain order, and so does :func:`solve_step` (the regions' code is kept out of it: it
is compiled for every world, the default scene's too). Graph colouring was measured first and dropped: on the
200-body pile a sweep colour by colour took ~145 pool launches a tick at ~8 µs each, and its colours of ~90
manifolds were too small to pay a second thread — 14.6 % slower than the serial sweep (7.78 → 8.92 ms a tick); the
two regions make it ~12 % faster (8.35 → 7.34 ms a tick; sphere_pile 23.5 → 20.7 ms; and a few % faster on one
thread). A big world's :func:`solve_step` runs as three calls, the sweeps in a kernel of their own compiled with
``prange`` (:func:`solve_sweeps_by_regions`): numba refuses to cache a compiled caller of a parallel kernel.

**Penetration recovery** (pipeline stage "recover penetration", after the integrator): split impulses /
pseudo-velocities (Catto 2006; Bullet's ``splitImpulse``) in the form of Box2D v2's position solver,
linearized.  The separation after the integrator is estimated from the contact's start value and the
bodies' actual displacement, s = s₀ + J Δ (Δ = (Δx, Δθ)); a displacement-level solve of the normal rows with
the same Jacobians and manifolds finds position / orientation corrections D with J D ≥ β (−s − slop) (at most
``max_correction``), λ ≥ 0.  D moves the bodies; P is not touched and L is turned with the body (the
body-frame angular momentum stays the same), so the kinetic energy is unchanged exactly.

**The stages** (Box2D v3's ``b2PrepareContactsTask``, ``b2WarmStartContactsTask``, ``b2SolveContactsTask``,
``b2ApplyRestitutionTask``, ``b2StoreImpulsesTask``, here one compiled function each), run in this order by
:func:`solve_step`, which times each into :attr:`SequentialImpulseSolver.profile`:

1. :func:`prepare_bodies` — the n + 1 body rows (row n: the static ground) and their velocities V, V_before;
2. :func:`prepare_contacts` — the contacts that can move something sorted into manifolds, matched with the
   previous sub-step's, their rows J, M⁻¹Jᵀ and effective masses, the manifolds' blocks, the targets;
3. :func:`warm_start_contacts` — the matched impulses applied;
4. :func:`solve_contacts` — the sweeps;
5. :func:`bounce_time_shift` — bounces off the static world placed at their time of impact;
6. :func:`apply_impulses` — the accumulated impulses (and rolling resistance) added to P and L;
7. :func:`store_impulses` — the warm-start memory for the next sub-step;

and after the integrator, :func:`recover_penetration_kernel` (the position stage).  What they hand each other
is named in :mod:`.arrays` (``SolverBodies``, ``Manifolds``, ``Rows``, ``Targets``, ``WarmStart``, every array
with its shape).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import ClassVar, NamedTuple

import numpy as np

from ..bodies import BodyModel, BodyState, tensor_times
from ..collision import CollisionDetector, ContactSet
from ..collision.detector import FEATURE_SLOTS
from ..jit import StageProfile, clock, lap, njit, prange
from ..rotation import (
    quat_multiply_scalar,
    quat_rotate_scalar,
    quat_to_matrix,
    quat_to_rotvec_scalar,
    rotvec_to_quat_scalar,
)
from .arrays import (
    BodyArrays,
    Handover,
    Manifolds,
    RecoveryBodies,
    Rows,
    Scratch,
    SolverBodies,
    Solving,
    StepSettings,
    Targets,
    WarmStart,
)
from .base import SolverSettings
from .manifold import MAX_BLOCK, solve_manifold_lcp
from .report import ContactReport, ContactTally, finish_report, tally_contacts

#: extra sweeps over the manifolds holding a bouncing point (see solve_contacts)
IMPACT_SWEEPS = 16

#: from this many contacts (rows of the manifolds: :func:`moving_contacts`) on, the sweeps go by two regions of the
#: contact graph, the two on numba's thread pool, then their border (see the module's docstring); fewer, one after
#: another in the plain order, in :func:`solve_step` (a sub-step of this many contacts takes the three calls of
#: :func:`_solve_step_by_regions`).  Contacts, not manifolds: a manifold's work grows with its points (a block LCP
#: from two).  Measured with a free second core, two regions against the plain order from 64 manifolds on
#: (2026-12-07, probe python ~11.5 ms): the 100-hull pile (~350 contacts in ~150 manifolds) 5.9 -> 4.9 ms a tick at
#: rest; bench_rigid's pile of 100 bodies (~310 contacts, ~190 manifolds) 3.74 -> 3.58 ms; of 50 bodies (~146
#: contacts, 78 manifolds) 1.63 -> 1.91 ms
SPLIT_MIN_CONTACTS = 256

#: numba's ``parallel`` options that turn ``prange`` loops alone into parallel loops
PRANGE_ONLY = {"prange": True, "comprehension": False, "reduction": False, "inplace_binop": False, "setitem": False,
               "numpy": False, "stencil": False, "fusion": False}

#: the stages of :attr:`SequentialImpulseSolver.profile`, in order (the velocity stage's, then the position stage)
STAGES = ("prepare", "warm_start", "solve", "bounce_time_shift", "apply_impulses", "store_impulses",
          "recover_penetration")
PREPARE, WARM_START, SOLVE, BOUNCE_TIME_SHIFT, APPLY_IMPULSES, STORE_IMPULSES, RECOVER = range(len(STAGES))


class Tangents(NamedTuple):
    """Two unit tangents t₁, t₂ completing a unit normal to a right-handed frame (n, t₁, t₂)."""

    t1x: float
    t1y: float
    t1z: float
    t2x: float
    t2y: float
    t2z: float


@njit
def tangent_basis_scalar(x, y, z):
    """The :class:`Tangents` of the unit normal (x, y, z), by the branch-free construction of Duff et al. (JCGT
    2017, "Building an orthonormal basis, revisited"); a pure function of n, so a contact whose normal does not
    change keeps its tangents (the ground's are x and y)."""
    sign = 1.0 if z >= 0.0 else -1.0
    a = -1.0 / (sign + z)
    b = x * y * a
    return Tangents(1.0 + sign * x * x * a, sign * b, -sign * x, b, sign + y * y * a, -y)


# ---- warm-start matching -----------------------------------------------------------------------------------

@njit
def match_previous(key, point, old_key, old_point):
    """Index into last sub-step's (key-sorted) contacts of the same contact, −1 if new.

    A contact is the same if it joins the same primitive pair (``key // FEATURE_SLOTS``) and is the pair's
    nearest old point (each old point taken at most once, by its nearest new one; on a tie the first).
    Matching by position rather than by exact feature keeps the warm start when a manifold point changes the
    feature that produced it — a corner of a box resting on another is now an incident corner, now a clipped
    edge crossing, as the box rocks by a micro-radian — which would otherwise throw away its impulse and make a
    stack jitter.
    """
    m = len(key)
    prev = np.full(m, -1, np.int64)
    best = np.full(m, np.inf)
    if len(old_key) == 0:
        return prev
    for c in range(m):
        pair = key[c] // FEATURE_SLOTS
        lo = np.searchsorted(old_key, pair * FEATURE_SLOTS)
        hi = np.searchsorted(old_key, (pair + 1) * FEATURE_SLOTS)
        for o in range(lo, hi):
            dx = point[c, 0] - old_point[o, 0]
            dy = point[c, 1] - old_point[o, 1]
            dz = point[c, 2] - old_point[o, 2]
            d = dx * dx + dy * dy + dz * dz
            if d < best[c]:
                best[c] = d
                prev[c] = o
    # one old point, one new point: where several new points chose the same old one, the nearest keeps it
    owner = np.full(len(old_key), -1, np.int64)
    for c in range(m):
        o = prev[c]
        if o < 0:
            continue
        if owner[o] < 0 or best[c] < best[owner[o]]:
            if owner[o] >= 0:
                prev[owner[o]] = -1
            owner[o] = c
        else:
            prev[c] = -1
    return prev


# ---- row helpers --------------------------------------------------------------------------------------------

#: the rows of a contact in ``J``, ``MJ``, ``eff`` and ``lam``: the normal and the two tangents.  numpy integers,
#: not Python ints: numba compiles a kernel called with a literal int once for each value (three copies of each
#: row helper below, ~1.5 s more of the cold compile)
NORMAL, TANGENT_1, TANGENT_2 = np.int64(0), np.int64(1), np.int64(2)


@njit
def _row_velocity(J, c, r, V, a, b):
    """J V for row ``r`` of contact ``c`` (``J (m, 3, 12)``) between body rows a and b of ``V (n + 1, 6)``."""
    return (J[c, r, 0] * V[a, 0] + J[c, r, 1] * V[a, 1] + J[c, r, 2] * V[a, 2] + J[c, r, 3] * V[a, 3]
            + J[c, r, 4] * V[a, 4] + J[c, r, 5] * V[a, 5] + J[c, r, 6] * V[b, 0] + J[c, r, 7] * V[b, 1]
            + J[c, r, 8] * V[b, 2] + J[c, r, 9] * V[b, 3] + J[c, r, 10] * V[b, 4] + J[c, r, 11] * V[b, 5])


@njit
def _apply(MJ, c, r, delta, V, a, b):
    """V += M⁻¹ Jᵀ Δλ for row ``r`` of contact ``c`` (``MJ (m, 3, 12)``)."""
    for k in range(6):
        V[a, k] += MJ[c, r, k] * delta
        V[b, k] += MJ[c, r, 6 + k] * delta


# ---- 1. prepare the bodies --------------------------------------------------------------------------------

@njit(inline="always")
def prepare_bodies(bodies, h):
    """The n + 1 :class:`SolverBodies` rows of the n bodies in ``bodies`` (:class:`BodyArrays`) and the static
    row n: the movable ones dynamic, with V = M⁻¹ (momentum + h·force) — gravity is inside the solve, so a
    resting body gets exactly the impulse that cancels it — and V_before = M⁻¹ momentum."""
    n = len(bodies.position)
    inv_mass = np.zeros(n + 1)
    dynamic = np.zeros(n + 1, np.bool_)
    inv_inertia = np.zeros((n + 1, 3, 3))
    pos = np.zeros((n + 1, 3))
    V = np.zeros((n + 1, 6))  # the velocities being solved for: from momentum + h·force ...
    V_before = np.zeros((n + 1, 6))  # ... and before this sub-step's forces (restitution)
    position, P, L = bodies.position, bodies.linear_momentum, bodies.angular_momentum
    F, T = bodies.force, bodies.torque
    # element by element, not pos[i] = position[i]: numba compiles a row copy with a shape check whose error
    # message alone takes seconds to compile (measured: 3 s of this module's ~20 s)
    for i in range(n):
        for k in range(3):
            pos[i, k] = position[i, k]
        if not bodies.movable[i]:
            continue
        dynamic[i] = True
        inv_mass[i] = bodies.inv_mass[i]
        for r in range(3):
            for c in range(3):
                inv_inertia[i, r, c] = bodies.inv_inertia[i, r, c]
        for k in range(3):
            V[i, k] = (P[i, k] + h * F[i, k]) * inv_mass[i]
            V_before[i, k] = P[i, k] * inv_mass[i]
        # ω = I_world⁻¹ L (bodies.tensor_times), with and without this sub-step's torque
        V[i, 3], V[i, 4], V[i, 5] = tensor_times(inv_inertia[i], L[i, 0] + h * T[i, 0], L[i, 1] + h * T[i, 1],
                                                 L[i, 2] + h * T[i, 2])
        V_before[i, 3], V_before[i, 4], V_before[i, 5] = tensor_times(inv_inertia[i], L[i, 0], L[i, 1], L[i, 2])
    return SolverBodies(inv_mass, inv_inertia, pos, dynamic, V, V_before)


# ---- 2. prepare the contacts ------------------------------------------------------------------------------

@njit(inline="always")
def prepare_contacts(contacts, bodies, memory, settings):
    """Box2D's prepare stage for a :class:`ContactSet`: the contacts that can move something (a contact between
    two bodies that cannot move needs no impulse, and has no effective mass) sorted by body pair into
    :class:`Manifolds`, each matched with the previous sub-step's (``memory``, :class:`WarmStart`); their
    :class:`Rows`; their :class:`Targets`.  Returns those three and the deepest penetration among all the
    contacts given."""
    n = len(bodies.position) - 1
    deepest = 0.0
    count = 0
    pair = np.empty(len(contacts.body_b), np.int64)
    kept = np.empty(len(contacts.body_b), np.int64)
    for c in range(len(contacts.body_b)):
        deepest = max(deepest, -contacts.separation[c])
        ia = n if contacts.body_a[c] < 0 else contacts.body_a[c]
        if bodies.dynamic[ia] or bodies.dynamic[contacts.body_b[c]]:
            pair[count] = ia * (n + 1) + contacts.body_b[c]
            kept[count] = c
            count += 1
    order = kept[:count][np.argsort(pair[:count], kind="mergesort")]
    m = len(order)
    a = np.empty(m, np.int64)
    b = np.empty(m, np.int64)
    group_start = np.empty(m + 1, np.int64)
    G = 0
    for q in range(m):
        c = order[q]
        a[q] = n if contacts.body_a[c] < 0 else contacts.body_a[c]
        b[q] = contacts.body_b[c]
        if q == 0 or a[q] != a[q - 1] or b[q] != b[q - 1]:
            group_start[G] = q
            G += 1
    group_start[G] = m
    group_start = group_start[:G + 1].copy()
    key, point = contacts.key[order], contacts.point[order]
    manifolds = Manifolds(a, b, group_start, contacts.normal[order], contacts.separation[order], point,
                          contacts.friction[order], contacts.restitution[order], key,
                          match_previous(key, point, memory.key, memory.point))
    J, MJ, eff, lever = build_rows(manifolds, bodies)
    A, cache, cached = manifold_blocks(group_start, J, MJ)
    rows = Rows(J, MJ, eff, lever, A, cache, cached)
    return manifolds, rows, velocity_targets(manifolds, rows, bodies, settings), deepest


@njit
def build_rows(manifolds, bodies):
    """The rows of the m contacts: ``J, MJ (m, 3, 12)`` (directions n, t₁, t₂; see the module docstring), the
    effective masses ``eff (m, 3)`` and the lever arms ``r_a, r_b (m, 2, 3)``."""
    a, b, normal, point = manifolds.a, manifolds.b, manifolds.normal, manifolds.point
    position, inv_mass, inv_inertia = bodies.position, bodies.inv_mass, bodies.inv_inertia
    m = len(a)
    J = np.zeros((m, 3, 12))
    MJ = np.zeros((m, 3, 12))
    eff = np.empty((m, 3))
    lever = np.empty((m, 2, 3))
    d = np.empty((3, 3))
    for c in range(m):
        ia, ib = a[c], b[c]
        d[0, 0], d[0, 1], d[0, 2] = normal[c, 0], normal[c, 1], normal[c, 2]
        d[1, 0], d[1, 1], d[1, 2], d[2, 0], d[2, 1], d[2, 2] = tangent_basis_scalar(normal[c, 0], normal[c, 1],
                                                                                    normal[c, 2])
        for k in range(3):
            lever[c, 0, k] = point[c, k] - position[ia, k]
            lever[c, 1, k] = point[c, k] - position[ib, k]
        ra, rb = lever[c, 0], lever[c, 1]
        for r in range(3):
            row, mrow = J[c, r], MJ[c, r]
            for k in range(3):
                row[k] = -d[r, k]
                row[6 + k] = d[r, k]
            row[3] = -(ra[1] * d[r, 2] - ra[2] * d[r, 1])
            row[4] = -(ra[2] * d[r, 0] - ra[0] * d[r, 2])
            row[5] = -(ra[0] * d[r, 1] - ra[1] * d[r, 0])
            row[9] = rb[1] * d[r, 2] - rb[2] * d[r, 1]
            row[10] = rb[2] * d[r, 0] - rb[0] * d[r, 2]
            row[11] = rb[0] * d[r, 1] - rb[1] * d[r, 0]
            for k in range(3):
                mrow[k] = row[k] * inv_mass[ia]
                mrow[6 + k] = row[6 + k] * inv_mass[ib]
                # angular parts: times the (symmetric) I_world⁻¹
                mrow[3 + k] = (inv_inertia[ia, k, 0] * row[3] + inv_inertia[ia, k, 1] * row[4]
                               + inv_inertia[ia, k, 2] * row[5])
                mrow[9 + k] = (inv_inertia[ib, k, 0] * row[9] + inv_inertia[ib, k, 1] * row[10]
                               + inv_inertia[ib, k, 2] * row[11])
            acc = 0.0
            for k in range(12):
                acc += row[k] * mrow[k]
            eff[c, r] = 1.0 / acc
    return J, MJ, eff, lever


@njit
def manifold_blocks(group_start, J, MJ):
    """Normal-row Delassus blocks ``A (G, 4, 4)`` (A_ij = J_n,i · M⁻¹J_n,jᵀ) of the manifolds of ≤ 4 points,
    and an empty pseudo-inverse cache for them (see :mod:`.manifold`)."""
    G = len(group_start) - 1
    A = np.zeros((G, MAX_BLOCK, MAX_BLOCK))
    for g in range(G):
        lo, hi = group_start[g], group_start[g + 1]
        if hi - lo > MAX_BLOCK:
            continue
        for i in range(lo, hi):
            for j in range(lo, hi):
                acc = 0.0
                for k in range(12):
                    acc += J[i, 0, k] * MJ[j, 0, k]
                A[g, i - lo, j - lo] = acc
    return A, np.empty((G, 1 << MAX_BLOCK, MAX_BLOCK, MAX_BLOCK)), np.zeros((G, 1 << MAX_BLOCK), np.bool_)


@njit
def velocity_targets(manifolds, rows, bodies, settings):
    """The :class:`Targets`: speculative contacts close their gap and no more; fast approaches bounce."""
    a, b, separation, restitution = manifolds.a, manifolds.b, manifolds.separation, manifolds.restitution
    J, V, V_before, h = rows.J, bodies.velocity, bodies.velocity_before, settings.h
    m = len(a)
    bias = np.empty(m)
    lower = np.zeros(m)
    vn_before = np.empty(m)
    bounce = np.zeros(m, np.bool_)
    impact = np.zeros(m, np.bool_)
    for c in range(m):
        bias[c] = -max(separation[c], 0.0) / h
        vn_before[c] = _row_velocity(J, c, NORMAL, V_before, a[c], b[c])
        vn_free = _row_velocity(J, c, NORMAL, V, a[c], b[c])
        # an impact: a contact approaching faster than the threshold before the sub-step whose gap closes within it
        # (at the contact-free velocity); with restitution it bounces: its target is −e times the approach speed
        impact[c] = vn_before[c] < -settings.restitution_threshold and separation[c] + h * vn_free < 0.0
        if restitution[c] > 0.0 and impact[c]:
            bounce[c] = True
            bias[c] = max(bias[c], -restitution[c] * vn_before[c])
    return Targets(bias, lower, vn_before, bounce, impact, np.full(m, np.nan))


# ---- 3. warm start ----------------------------------------------------------------------------------------

@njit(inline="always")
def warm_start_contacts(manifolds, rows, bodies, memory, warm_start):
    """The accumulated impulses ``lam (m, 3)`` to start from: the matched contacts' of the previous sub-step
    (``memory``; the friction vector re-projected onto the new tangents and clamped to the cone), applied to
    ``bodies.velocity``; zeros for the rest (and for all with ``warm_start`` off)."""
    a, b, J, MJ, V = manifolds.a, manifolds.b, rows.J, rows.MJ, bodies.velocity
    m = len(a)
    lam = np.zeros((m, 3))
    if warm_start:
        for c in range(m):
            o = manifolds.previous[c]
            if o < 0:
                continue
            lam[c, 0] = memory.normal[o]
            f = memory.friction[o]
            t1 = f[0] * J[c, 1, 6] + f[1] * J[c, 1, 7] + f[2] * J[c, 1, 8]  # J[c, r, 6:9] is the direction
            t2 = f[0] * J[c, 2, 6] + f[1] * J[c, 2, 7] + f[2] * J[c, 2, 8]
            scale = min(1.0, manifolds.friction[c] * lam[c, 0] / max(math.sqrt(t1 * t1 + t2 * t2), 1e-300))
            lam[c, 1], lam[c, 2] = t1 * scale, t2 * scale
            for r in range(3):
                _apply(MJ, c, r, lam[c, r], V, a[c], b[c])
    return lam


# ---- 4. solve: the sweeps ---------------------------------------------------------------------------------

@njit(inline="always")
def impact_manifolds(manifolds, targets):
    """(G,) bool: the multi-point manifolds holding a bouncing point, which get the impact sweeps; and whether
    any does (shared with the robots' coupled loop, cgp_core.robots.coupled.solve_together)."""
    group_start = manifolds.group_start
    G = len(group_start) - 1
    impact = np.zeros(G, np.bool_)
    any_impact = False
    for g in range(G):
        if group_start[g + 1] - group_start[g] > 1:
            for c in range(group_start[g], group_start[g + 1]):
                if targets.bounce[c]:
                    impact[g] = True
                    any_impact = True
    return impact, any_impact


@njit(inline="always")
def solve_contacts(manifolds, rows, targets, lam, bodies, settings):
    """The sweeps: manifold after manifold (:func:`_solve_manifold`), updating ``lam`` and ``bodies.velocity``
    in place, until a whole sweep changed no row velocity by more than ``velocity_tolerance`` (a warm-started
    resting stack is converged after one) or ``velocity_iterations`` sweeps; then the impact sweeps
    (:func:`_sweeps_go_on`).  Returns the number of sweeps run.  (A big world's sweeps take
    :func:`solve_contacts_by_regions` instead: kept apart, so that this one, compiled into :func:`solve_step` for
    every world, carries no code of theirs — with it in, the default scene's solver compiled 18 → 26 s of CPU and
    its tick ran ~2 % slower.)"""
    group_start = manifolds.group_start
    m = len(manifolds.a)
    G = len(group_start) - 1
    lam_n = np.empty(m)
    scratch = Scratch(np.empty((2, MAX_BLOCK)), np.zeros(MAX_BLOCK, np.bool_), np.empty((m, 2)))
    # impacts: manifolds (multi-point groups) converge slowest exactly when the impulse changes most, so the
    # manifolds holding a bouncing point get up to ``impact_sweeps`` extra sweeps after the regular ones
    # (impacts are rare; resting manifolds are warm)
    impact, any_impact = impact_manifolds(manifolds, targets)
    sweeps = 0
    impact_done = 0
    regular = True  # the regular sweeps over every manifold first, then the impact sweeps
    go_on = True
    while go_on:
        change = 0.0
        for g in range(G):
            if regular or impact[g]:
                change = max(change, _solve_manifold(g, manifolds, rows, targets, lam, lam_n, bodies.velocity,
                                                     scratch))
        go_on, regular, sweeps, impact_done = _sweeps_go_on(change, regular, sweeps, impact_done, any_impact,
                                                            settings)
    return sweeps


@njit(inline="always")
def _sweeps_go_on(change, regular, sweeps, impact_done, any_impact, settings):
    """The sweeps' stopping rule, after a sweep that changed a row velocity by at most ``change``: each kind of
    sweep stops once a whole sweep changed no row velocity by more than the tolerance (a warm-started resting stack
    is converged after one), or after its number of sweeps — the regular ones (``velocity_iterations``), then, if a
    manifold holds a bouncing point (``any_impact``), the impact sweeps (``impact_sweeps``).  Returns ``(go on,
    regular, sweeps, impact_done)``."""
    if regular:
        sweeps += 1
        if change <= settings.velocity_tolerance or sweeps >= settings.velocity_iterations:
            regular = False
            if not any_impact or settings.impact_sweeps == 0:
                return False, regular, sweeps, impact_done
        return True, regular, sweeps, impact_done
    impact_done += 1
    if change <= settings.velocity_tolerance or impact_done >= settings.impact_sweeps:
        return False, regular, sweeps, impact_done
    return True, regular, sweeps, impact_done


@njit(inline="always")
def solve_contacts_by_regions(manifolds, rows, targets, lam, bodies, settings):
    """:func:`solve_contacts` for a big world, in :func:`solve_sweeps_by_regions` (compiled with ``prange``): from
    :data:`SPLIT_MIN_CONTACTS` contacts on, each sweep goes by two regions and their border
    (:func:`_split_regions`, :func:`_sweep_regions`; the module's docstring says why); fewer (called so only in
    tests), one run in the plain order — through :func:`_solve_region` all the same (the update must not be inlined
    here, see there), so the same bits as :func:`solve_contacts`.  The same stopping rule (:func:`_sweeps_go_on`).
    Returns the number of sweeps run."""
    m = len(manifolds.a)
    G = len(manifolds.group_start) - 1
    lam_n = np.empty(m)
    impact, any_impact = impact_manifolds(manifolds, targets)
    regions = _split_regions(manifolds, bodies, m >= SPLIT_MIN_CONTACTS)
    every = np.ones(G, np.bool_)
    sweeps = 0
    impact_done = 0
    regular = True
    go_on = True
    while go_on:
        change = _sweep_regions(regions, every if regular else impact, manifolds, rows, targets, lam, lam_n,
                                bodies.velocity)
        go_on, regular, sweeps, impact_done = _sweeps_go_on(change, regular, sweeps, impact_done, any_impact,
                                                            settings)
    return sweeps


@njit(inline="always")
def _split_regions(manifolds, bodies, split):
    """Two regions of the contact graph and their border: ``order (G,)`` int64, the manifolds of region 0, of
    region 1, then those joining a body of each (each run in the manifolds' own order); ``region_start (4,)``;
    ``changes (3,)``; ``bigs (2, m, 2)``, each region's Scratch.big.  A moving body is in region 1 if its position
    along the widest axis of the moving bodies is at least the median of the manifolds' positions (a manifold's:
    its moving body's, or the mean of its two); a manifold touching moving bodies of one region only is that
    region's (the static row is in none: its velocity never changes).  Depends on the manifolds and the positions
    only, never on the number of threads.  Not ``split``: no regions, every manifold the border, in the plain
    order (the same bits as :func:`solve_contacts`' sweep)."""
    G = len(manifolds.group_start) - 1
    m = len(manifolds.a)
    if not split:
        region_start = np.zeros(4, np.int64)
        region_start[3] = G
        return np.arange(G), region_start, np.zeros(3), np.empty((2, m, 2))
    position, dynamic = bodies.position, bodies.dynamic
    n1 = len(dynamic)
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for i in range(n1):
        if dynamic[i]:
            for k in range(3):
                lo[k] = min(lo[k], position[i, k])
                hi[k] = max(hi[k], position[i, k])
    axis = 0
    for k in range(1, 3):
        if hi[k] - lo[k] > hi[axis] - lo[axis]:
            axis = k
    keys = np.empty(G)
    for g in range(G):
        first = manifolds.group_start[g]
        i, j = manifolds.a[first], manifolds.b[first]
        if dynamic[i] and dynamic[j]:
            keys[g] = 0.5 * (position[i, axis] + position[j, axis])
        elif dynamic[i]:
            keys[g] = position[i, axis]
        else:
            keys[g] = position[j, axis]
    median = np.sort(keys)[G // 2]
    region = np.empty(G, np.int64)
    count = np.zeros(3, np.int64)
    for g in range(G):
        first = manifolds.group_start[g]
        i, j = manifolds.a[first], manifolds.b[first]
        ri = (1 if position[i, axis] >= median else 0) if dynamic[i] else -1
        rj = (1 if position[j, axis] >= median else 0) if dynamic[j] else -1
        if ri < 0:
            r = rj
        elif rj < 0 or rj == ri:
            r = ri
        else:
            r = 2
        region[g] = r
        count[r] += 1
    region_start = np.zeros(4, np.int64)
    for r in range(3):
        region_start[r + 1] = region_start[r] + count[r]
    order = np.empty(G, np.int64)
    fill = region_start[:3].copy()
    for g in range(G):
        order[fill[region[g]]] = g
        fill[region[g]] += 1
    return order, region_start, np.zeros(3), np.empty((2, m, 2))


@njit(inline="always")
def _sweep_regions(regions, visit, manifolds, rows, targets, lam, lam_n, V):
    """One sweep over the manifolds ``visit (G,)`` marks, by the regions of :func:`_split_regions`: regions 0 and 1
    at the same time (one launch of numba's pool in :func:`solve_sweeps_by_regions`; they share no moving body, so
    each sees what it would see alone — the same bits on any number of threads), then the border.  Each region's
    run is one call of :func:`_solve_region` (the manifold update inlined there, in a function compiled without
    prange).  Returns the largest change."""
    order, region_start, changes, bigs = regions[0], regions[1], regions[2], regions[3]
    # the parallel loop's body sees arrays only, and makes its bundles inside (numba cannot hand a loop run on the
    # pool a named tuple made outside it)
    a, b, group_start, normal, separation, point, friction, restitution, key, previous = (
        manifolds[0], manifolds[1], manifolds[2], manifolds[3], manifolds[4], manifolds[5], manifolds[6],
        manifolds[7], manifolds[8], manifolds[9])
    J, MJ, eff, lever, A, cache, cached = rows[0], rows[1], rows[2], rows[3], rows[4], rows[5], rows[6]
    bias, lower, approach, bounce, impact, toi_shift = (targets[0], targets[1], targets[2], targets[3], targets[4],
                                                   targets[5])
    for r in prange(2):
        changes[r] = _solve_region(
            order[region_start[r]:region_start[r + 1]], visit,
            Manifolds(a, b, group_start, normal, separation, point, friction, restitution, key, previous),
            Rows(J, MJ, eff, lever, A, cache, cached), Targets(bias, lower, approach, bounce, impact, toi_shift),
            lam, lam_n, V, bigs[r])
    changes[2] = _solve_region(order[region_start[2]:region_start[3]], visit, manifolds, rows, targets, lam, lam_n,
                               V, bigs[0])
    return max(changes[0], max(changes[1], changes[2]))


@njit
def _solve_region(run, visit, manifolds, rows, targets, lam, lam_n, V, big):
    """The manifolds ``run`` that ``visit`` marks, one after another (:func:`_solve_manifold`, inlined here), with
    scratch of their own; returns the largest change.  A function of its own, compiled without ``prange``: inlined
    into the function that numba compiles with ``prange`` on, the manifold update read garbage —
    nondeterministically, on one thread as on two (a 64-box pile's captured sweep input gave λ sums of 57,361, 128
    and 124.6 on three calls; plain Python and the serial compile 124.6), the kind of parfor miscompile numba's
    tracker holds for functions with a prange in one branch (numba#7630, #9829).  The robots' coupled loop
    (:func:`cgp_core.robots.coupled.solve_together`) calls it for its body-row sweeps too, so the manifold update is
    compiled once for both (issue 34: the robots' compile worker −1 s of CPU; a call per sweep there, not per
    manifold)."""
    scratch = Scratch(np.empty((2, MAX_BLOCK)), np.zeros(MAX_BLOCK, np.bool_), big)
    change = 0.0
    for q in range(len(run)):
        g = run[q]
        if visit[g]:
            c = _solve_manifold(g, manifolds, rows, targets, lam, lam_n, V, scratch)
            if c > change:
                change = c
    return change


@njit(inline="always")
def _solve_manifold(g, manifolds, rows, targets, lam, lam_n, V, scratch):
    """One Gauss–Seidel update of manifold ``g``: each point's two friction rows (a step on both from the same
    velocities, clamped to the Coulomb cone |λ_t| ≤ μ λₙ with the current λₙ), then the normal rows.  Returns
    the largest change of a row's own velocity, |Δλ| / eff [m/s] (for the early stop)."""
    a, b, J, MJ, eff, mu = manifolds.a, manifolds.b, rows.J, rows.MJ, rows.eff, manifolds.friction
    lo, hi = manifolds.group_start[g], manifolds.group_start[g + 1]
    change = 0.0
    P = hi - lo
    jacobi = P > 1
    # Jacobi with mass splitting within a manifold (Tonge et al. 2012; see _solve_normal_rows), among the points that
    # act: a point without a cone (λₙ = 0) and without a friction impulse would clamp its step to zero, so it
    # takes no share of the bodies' mass.  A round hull on the ground touches with one of its 4 points (the others
    # speculative): split four ways, that point got a quarter of its step per sweep and the sweeps ran to their
    # cap (issue 38).  A point that touches (separation ≤ 0) counts as acting even before its cone opens, so that
    # a settling manifold keeps the cautious share while its normal impulses grow.
    # An impact (a point closing fast: targets.impact) keeps the split among all P points: its normal impulses
    # grow from zero within the sweeps and the cone with them, and the friction iterate at the sweep cap is far
    # from converged (the bullet scene's hull, 300 m/s into a wall at 30 Hz, left the impact at 6.2 m/s sideways
    # with the acting-points split, 0.97 m/s with 500 sweeps either way, −2.3 m/s with 1/P: the cautious step is
    # the nearer one at 8 sweeps).
    split = 1.0
    if jacobi:  # (one point: its whole step)
        acting = 0
        impact = False
        for c in range(lo, hi):
            if manifolds.separation[c] <= 0.0 or mu[c] * lam[c, 0] != 0.0 or lam[c, 1] != 0.0 or lam[c, 2] != 0.0:
                acting += 1
            impact = impact or targets.impact[c]
        split = 1.0 / (P if impact else max(acting, 1))
    for c in range(lo, hi):
        if mu[c] * lam[c, 0] == 0.0 and lam[c, 1] == 0.0 and lam[c, 2] == 0.0:
            # no cone (a speculative point: λₙ = 0) and no friction impulse: the step would clamp to zero again
            # (3 of the 4 points of a round hull on the ground; issue 38)
            if jacobi:
                scratch.big[c - lo, 0], scratch.big[c - lo, 1] = 0.0, 0.0
            continue
        v1 = _row_velocity(J, c, TANGENT_1, V, a[c], b[c])
        v2 = _row_velocity(J, c, TANGENT_2, V, a[c], b[c])
        t1 = lam[c, 1] - split * eff[c, 1] * v1
        t2 = lam[c, 2] - split * eff[c, 2] * v2
        scale = min(1.0, mu[c] * lam[c, 0] / max(math.sqrt(t1 * t1 + t2 * t2), 1e-300))
        t1 *= scale
        t2 *= scale
        d1, d2 = t1 - lam[c, 1], t2 - lam[c, 2]
        lam[c, 1], lam[c, 2] = t1, t2
        if not jacobi:
            _apply(MJ, c, TANGENT_1, d1, V, a[c], b[c])
            _apply(MJ, c, TANGENT_2, d2, V, a[c], b[c])
        else:
            scratch.big[c - lo, 0], scratch.big[c - lo, 1] = d1, d2
        change = max(change, abs(d1) / eff[c, 1], abs(d2) / eff[c, 2])
    if jacobi:
        for c in range(lo, hi):
            if scratch.big[c - lo, 0] != 0.0 or scratch.big[c - lo, 1] != 0.0:  # (adding zeros changes nothing)
                _apply(MJ, c, TANGENT_1, scratch.big[c - lo, 0], V, a[c], b[c])
                _apply(MJ, c, TANGENT_2, scratch.big[c - lo, 1], V, a[c], b[c])
    for c in range(lo, hi):
        lam_n[c] = lam[c, 0]
    if P == 1:  # the common case, without the call
        change = max(change, _push_normal_row(lo, rows, lam_n, targets.bias, targets.lower, V, a[lo], b[lo]))
    else:
        change = max(change, _solve_normal_rows(g, manifolds, rows, lam_n, targets.bias, targets.lower, V,
                                                scratch))
    for c in range(lo, hi):
        lam[c, 0] = lam_n[c]
    return change


# inline: called per manifold and sweep with whole bundles (~20 arrays); as a call, numba passes each array's
# pointer, shape and strides by value — the 200-body pile's solve took 11 % longer than inlined (measured,
# tools/compare_trees.py speed, 5 interleaved rounds)
@njit(inline="always")
def _solve_normal_rows(g, manifolds, rows, lam, target, lower, V, scratch):
    """Update the normal rows of manifold ``g`` towards J V ≥ target with accumulated λ ≥ ``lower`` (0: a
    contact only pushes; −inf: a two-sided row, J V = target): exactly as a block for ≤ 4 points (falling back
    to one point at a time if the block has no exact solution), else one point at a time.  ``lam (m,)`` is
    updated in place, V too.  Returns the largest |Δλ| / eff."""
    a, b, J, MJ, eff = manifolds.a, manifolds.b, rows.J, rows.MJ, rows.eff
    lo, hi = manifolds.group_start[g], manifolds.group_start[g + 1]
    P = hi - lo
    change = 0.0
    if 1 < P <= MAX_BLOCK:
        bvec, x, must = scratch.block[0], scratch.block[1], scratch.must
        # the points pushing now (the last update's active set): the LCP's first guess (an int64 from the start: a
        # literal 0 had numba compile solve_manifold_lcp a second time, for the constant, while typing solve_step)
        support = np.int64(0)
        for i in range(P):
            c = lo + i
            bvec[i] = _row_velocity(J, c, NORMAL, V, a[c], b[c]) - target[c]
            for j in range(P):
                bvec[i] -= rows.A[g, i, j] * lam[lo + j]
            must[i] = lower[c] == -np.inf
            if lam[c] != 0.0:
                support |= 1 << i
        if solve_manifold_lcp(rows.A[g], P, bvec, must, rows.cache[g], rows.cached[g], support, x):
            for i in range(P):
                c = lo + i
                delta = x[i] - lam[c]
                lam[c] = x[i]
                _apply(MJ, c, NORMAL, delta, V, a[c], b[c])
                change = max(change, abs(delta) / eff[c, 0])
            return change
    if P > MAX_BLOCK:
        # a big group (a particle plate on the ground): a Jacobi step on all its points from the same
        # velocities, each seeing its bodies with 1/P of their mass (mass splitting, Tonge et al. 2012), so the
        # increments add up without overshooting; point-by-point Gauss–Seidel on 16 rigidly coupled points
        # converges too slowly to bring a plate to rest in 8 sweeps
        big = scratch.big
        for i in range(P):
            c = lo + i
            vn = _row_velocity(J, c, NORMAL, V, a[c], b[c])
            new = max(lam[c] - eff[c, 0] / P * (vn - target[c]), lower[c])
            big[i, 0] = new - lam[c]
            lam[c] = new
        for i in range(P):
            c = lo + i
            _apply(MJ, c, NORMAL, big[i, 0], V, a[c], b[c])
            change = max(change, abs(big[i, 0]) / eff[c, 0])
        return change
    for c in range(lo, hi):
        change = max(change, _push_normal_row(c, rows, lam, target, lower, V, a[c], b[c]))
    return change


@njit(inline="always")
def _push_normal_row(c, rows, lam, target, lower, V, a, b):
    """One sequential-impulse update of the normal row of contact ``c`` alone (accumulated λ ≥ ``lower[c]``);
    returns |Δλ| / eff."""
    vn = _row_velocity(rows.J, c, NORMAL, V, a, b)
    new = max(lam[c] - rows.eff[c, 0] * (vn - target[c]), lower[c])
    delta = new - lam[c]
    lam[c] = new
    _apply(rows.MJ, c, NORMAL, delta, V, a, b)
    return abs(delta) / rows.eff[c, 0]


# ---- 5. bounce time shift: bounces off the static world placed at their time of impact -------------------------

@njit(inline="always")
def bounce_time_shift(manifolds, rows, targets, bodies, h):
    """The position target that puts a bounce off the static world at its time of impact; it applies no
    restitution (issue 35: it was misnamed ``apply_restitution``).  Restitution is a target of the sweeps
    (:func:`velocity_targets`); what is left after them — Box2D's place for it — is *when* a bounce off the static
    world (ground, fixed bodies) happens.  A speculative contact (gap s > 0) that bounced did so
    t* = s / |vₙ before| into the sub-step, not at its start.  The velocity is right (e times the impact speed),
    but moving with it for the whole sub-step would leave the body t* (vₙ after + |vₙ before|) too far from the
    surface, which the position stage takes back with a two-sided row: writes that target into
    ``targets.toi_shift``.  This is what makes a dropped ball rebound to e² of its height instead of bouncing
    early by up to one step of travel.  Not done between two moving bodies: the shift is not an impulse, so it
    would spoil their total angular momentum; they bounce at the start of the sub-step, as in Box2D.

    One time of impact per manifold, the earliest of its impact points (0 — no shift — if one of them touches
    already): the body hits when its *first* point arrives, and the shift is then one rigid motion of the body,
    t* (V before − V after), whose row i is t* (vₙ,i before − vₙ,i after).  Each point's own t* instead asks the
    rows for displacements no rigid motion has: two-sided rows (exact, any sign) at nearly collinear points of a
    hull on the terrain (a block condition number of 10⁴–10⁶) were then met through the block's near-null mode —
    a turn of up to 4 rad, convex_pile's rock_5 moved 0.53 m, hull_7 0.31 m in one sub-step at ≤ 1 mm
    penetration (7.8 m before RCOND was 1e-6)."""
    a, b, separation, dynamic = manifolds.a, manifolds.b, manifolds.separation, bodies.dynamic
    group_start = manifolds.group_start
    for g in range(len(group_start) - 1):
        lo, hi = group_start[g], group_start[g + 1]
        if dynamic[a[lo]] and dynamic[b[lo]]:
            continue  # (one body pair per manifold)
        # the manifold's time of impact (its earliest impact point's), that point's gap and approach speed
        first, gap, approach = np.inf, 0.0, 1.0
        for c in range(lo, hi):
            if targets.impact[c]:
                speed = -targets.approach[c]
                closing = min(max(separation[c], 0.0), speed * h)
                if closing / speed < first:
                    first, gap, approach = closing / speed, closing, speed
        if gap <= 0.0:
            continue  # no impact, or one that touches already: no shift
        for c in range(lo, hi):
            if targets.bounce[c] and separation[c] > 0.0:
                vn_after = max(_row_velocity(rows.J, c, NORMAL, bodies.velocity, a[c], b[c]), 0.0)
                # = −t* (|vₙ before| + vₙ after), written so that the earliest point's is its own gap (1 + ...) exactly
                targets.toi_shift[c] = -gap * (-targets.approach[c] / approach + vn_after / approach)


# ---- 6. impulses → momenta ---------------------------------------------------------------------------------

@njit(inline="always")
def apply_impulses(manifolds, rows, lam, bodies, momenta, rolling_resistance):
    """Add the accumulated impulses to the momenta, equal and opposite at the same point: ΔP = Σ J_linᵀ λ,
    ΔL = Σ J_angᵀ λ (= Σ r × impulse); with rolling resistance (:func:`resist_rolling`) on top.  ``momenta``:
    the :class:`BodyArrays` whose ``linear_momentum`` / ``angular_momentum`` (n rows) change in place (the dynamic
    rows').  Returns every row's impulse ``(n + 1, 6)`` [ΔP, ΔL about its COM] — the fixed bodies' and the
    ground's too, the reactions the contact report (:mod:`.report`) sums."""
    a, b, J = manifolds.a, manifolds.b, rows.J
    n1 = len(bodies.velocity)
    impulse = np.zeros((n1, 6))
    for c in range(len(a)):
        for r in range(3):
            for k in range(6):
                impulse[a[c], k] += J[c, r, k] * lam[c, r]
                impulse[b[c], k] += J[c, r, 6 + k] * lam[c, r]
    if rolling_resistance > 0.0:
        resist_rolling(manifolds, rows, lam, bodies, rolling_resistance, impulse)
    for i in range(n1 - 1):
        if bodies.dynamic[i]:
            for k in range(3):
                momenta.linear_momentum[i, k] += impulse[i, k]
                momenta.angular_momentum[i, k] += impulse[i, 3 + k]
    return impulse


@njit
def resist_rolling(manifolds, rows, lam, bodies, coefficient, impulse):
    """Add the angular impulses of rolling resistance to ``impulse (n + 1, 6)``, after the contact impulses are
    solved.

    A rigid ball on a rigid plane rolls (or spins in place) for ever; real surfaces deform and resist with a
    torque of at most ``c_rr · N · r`` (N the normal force, r the rolling radius), the textbook
    rolling-resistance model.  Per contact and sub-step that is an angular impulse of at most ``c_rr · λₙ · r``
    (λₙ the normal impulse just solved; r the larger normal component of the two levers ``p − x̄``) about the
    axis of the relative rotation ``ω_t = ω_b − ω_a``, opposing it: ``−J ω̂_t`` on b, ``+J ω̂_t`` on a.  The spin
    about the normal is resisted by the same law (MuJoCo keeps separate torsional and rolling coefficients; one
    is enough here: it only has to bring spinning balls to rest too).  J is also capped at the impulse that
    stops the relative rolling, shared among the rolling contacts of the body, so it only ever removes energy
    and never reverses a rotation.  Friction then couples the slower rotation to the body's velocity in the
    following sub-steps: a rolling ball decelerates at ``(5/7) c_rr g`` (tests/test_rest_and_sleep.py checks
    this closed form).

    Reads the solved velocities ``bodies.velocity`` (n + 1, 6), the lever arms ``rows.lever`` (m, 2, 3) and
    ``lam`` (m, 3) (column 0: λₙ ≥ 0).
    """
    a, b, normal, lever = manifolds.a, manifolds.b, manifolds.normal, rows.lever
    V, inv_inertia, dynamic = bodies.velocity, bodies.inv_inertia, bodies.dynamic
    m = len(a)
    n1 = len(V)
    rolling = np.zeros(m, np.bool_)
    count = np.zeros(n1, np.int64)  # rolling contacts per body
    axis = np.empty(3)
    for c in range(m):
        wx, wy, wz = V[b[c], 3] - V[a[c], 3], V[b[c], 4] - V[a[c], 4], V[b[c], 5] - V[a[c], 5]
        if math.sqrt(wx * wx + wy * wy + wz * wz) > 1e-12 and lam[c, 0] > 0.0:
            rolling[c] = True
            count[a[c]] += 1
            count[b[c]] += 1
    for c in range(m):
        if not rolling[c]:
            continue
        ia, ib = a[c], b[c]
        wx, wy, wz = V[ib, 3] - V[ia, 3], V[ib, 4] - V[ia, 4], V[ib, 5] - V[ia, 5]
        speed = math.sqrt(wx * wx + wy * wy + wz * wz)
        ax, ay, az = wx / speed, wy / speed, wz / speed
        ra = abs(lever[c, 0, 0] * normal[c, 0] + lever[c, 0, 1] * normal[c, 1] + lever[c, 0, 2] * normal[c, 2])
        rb = abs(lever[c, 1, 0] * normal[c, 0] + lever[c, 1, 1] * normal[c, 1] + lever[c, 1, 2] * normal[c, 2])
        radius = max(ra if dynamic[ia] else 0.0, rb if dynamic[ib] else 0.0)
        axis[0], axis[1], axis[2] = ax, ay, az
        k = 0.0  # 1 / effective inertia about the axis
        for i in range(3):
            for j in range(3):
                k += axis[i] * (inv_inertia[ia, i, j] + inv_inertia[ib, i, j]) * axis[j]
        share = max(count[ia] if dynamic[ia] else 0, count[ib] if dynamic[ib] else 0)
        stop = speed / (max(k, 1e-300) * max(share, 1))
        size = min(coefficient * lam[c, 0] * radius, stop)
        impulse[ia, 3] += size * ax
        impulse[ia, 4] += size * ay
        impulse[ia, 5] += size * az
        impulse[ib, 3] -= size * ax
        impulse[ib, 4] -= size * ay
        impulse[ib, 5] -= size * az


# ---- 7. store the impulses for the next warm start --------------------------------------------------------

@njit(inline="always")
def store_impulses(manifolds, rows, lam):
    """The :class:`WarmStart` memory: each contact's normal impulse and world-frame friction impulse, by key."""
    key, J = manifolds.key, rows.J
    m = len(key)
    by_key = np.argsort(key, kind="mergesort")
    warm_normal = np.empty(m)
    warm_friction = np.empty((m, 3))
    for q in range(m):
        c = by_key[q]
        warm_normal[q] = lam[c, 0]
        for k in range(3):  # J[c, r, 6:9] is row r's direction
            warm_friction[q, k] = lam[c, 1] * J[c, 1, 6 + k] + lam[c, 2] * J[c, 2, 6 + k]
    return WarmStart(key[by_key], warm_normal, warm_friction, manifolds.point[by_key])


# ---- the velocity stage, in order ---------------------------------------------------------------------------

@njit
def solve_step(contacts, bodies, memory, settings, tally, report, profile):
    """The pipeline stage "solve contacts" of one sub-step: Box2D's stages in order, each timed into ``profile``
    (:data:`STAGES`).  ``contacts``: a :class:`ContactSet`; ``bodies``: :class:`BodyArrays` (its momenta get the
    impulses, in place); ``memory``: the previous sub-step's :class:`WarmStart`; ``settings``:
    :class:`StepSettings`; ``tally``: the tick's :class:`~.report.ContactTally` so far — each as a plain tuple from
    Python (see "Bundles" in :mod:`cgp_core.jit`).  ``report`` (a bool): whether the contact report is wanted this
    tick; if so ``tally`` is summed with this sub-step's contacts (:func:`~.report.tally_contacts`), else it is not
    read (an empty one will do).

    One compiled entry for both cases, ``report`` an argument and not a literal: numba compiles each entry point
    with the whole tree of functions it calls, so two entries sharing this body (with and without the report)
    cost the solver's compile twice (issue 34).  A big world's contacts take three calls instead, the sweeps by
    two regions on the thread pool (:func:`_solve_step_by_regions`): the same stages, but from
    :data:`SPLIT_MIN_CONTACTS` contacts on the sweeps visit the manifolds in the regions' order, so other bits
    than this function gives (the same on any number of threads).

    Returns what the position stage needs (:class:`Handover`), the new warm-start memory and the new tally (None
    without ``report``)."""
    contacts, bodies, memory, settings = (ContactSet(*contacts), BodyArrays(*bodies), WarmStart(*memory),
                                          StepSettings(*settings))
    solving = _velocity_head(contacts, bodies, memory, settings, profile)
    start = clock()
    sweeps = solve_contacts(solving.manifolds, solving.rows, solving.targets, solving.lam, solving.bodies, settings)
    lap(profile, SOLVE, start)
    return _velocity_tail(solving, bodies, settings, sweeps, tally, report, profile)


@njit(inline="always")
def _velocity_head(contacts, bodies, memory, settings, profile):
    """Stages 1–3 (prepare the bodies and the contacts, warm start): the :class:`Solving` the sweeps take."""
    start = clock()
    return _contacts_stages(contacts, prepare_bodies(bodies, settings.h), memory, settings, profile, start)[0]


@njit(inline="always")
def _contacts_stages(contacts, bodies, memory, settings, profile, start):
    """Stages 2–3 (prepare the contacts, warm start) on the prepared :class:`SolverBodies` ``bodies``, timed into
    ``profile`` from ``start`` on: ``(the Solving, the time it ended)`` — inlined into :func:`solve_step` (through
    :func:`_velocity_head`), a kernel of its own as :func:`contacts_head`."""
    manifolds, rows, targets, deepest = prepare_contacts(contacts, bodies, memory, settings)
    start = lap(profile, PREPARE, start)
    lam = warm_start_contacts(manifolds, rows, bodies, memory, settings.warm_start)
    return Solving(bodies, manifolds, rows, targets, lam, deepest), lap(profile, WARM_START, start)


@njit(inline="always")
def _velocity_tail(solving, bodies, settings, sweeps, tally, report, profile):
    """Stages 5–7 after the sweeps (bounce time shift, impulses to momenta, the warm-start memory): what
    :func:`solve_step` returns."""
    solver_bodies, manifolds, rows, targets, lam = (solving.bodies, solving.manifolds, solving.rows, solving.targets,
                                                    solving.lam)
    start = clock()
    bounce_time_shift(manifolds, rows, targets, solver_bodies, settings.h)
    start = lap(profile, BOUNCE_TIME_SHIFT, start)
    impulse = apply_impulses(manifolds, rows, lam, solver_bodies, bodies, settings.rolling_resistance)
    start = lap(profile, APPLY_IMPULSES, start)
    memory = store_impulses(manifolds, rows, lam)
    lap(profile, STORE_IMPULSES, start)
    handover = Handover(manifolds.a, manifolds.b, manifolds.group_start, manifolds.separation, rows,
                        targets.toi_shift, sweeps, solving.deepest)
    # (None without a report, not the tally handed back: numba boxes None for nothing, the tally's 9 arrays for
    # ~2 µs, which at 4 sub-steps a tick is 3 % of the 5-body default scene's tick)
    return handover, memory, (tally_contacts(manifolds, rows, lam, impulse, tally) if report else None)


@njit
def solve_head(contacts, bodies, memory, settings, profile):
    """A big world's :func:`solve_step`, first call: stages 1–3; returns the :class:`Solving` (boxed for Python:
    ~30 arrays, some tens of µs, against the milliseconds of a big world's sweeps)."""
    settings = StepSettings(*settings)
    start = clock()
    solver_bodies = prepare_bodies(BodyArrays(*bodies), settings.h)
    return contacts_head(ContactSet(*contacts), solver_bodies, WarmStart(*memory), settings, profile, start)[0]


@njit
def contacts_head(contacts, bodies, memory, settings, profile, start):
    """:func:`_contacts_stages` (stages 2–3: what :func:`_velocity_head` does after :func:`prepare_bodies`) as a
    kernel of its own (not inlined), compiled once for :func:`solve_head` and the robots' coupled loop
    (:func:`cgp_core.robots.coupled.step_coupled`, which prepares the bodies itself); :func:`solve_step`, which
    every world's sub-step calls, keeps its stages inlined
    (issue 34: solve_step calling :func:`solve_head` and :func:`solve_tail` saved ~3 s of the solver worker's
    compile CPU but made the 5-body default scene's tick 3–5 % slower — each call increfs and decrefs the ~25–50
    arrays it is passed)."""
    return _contacts_stages(contacts, bodies, memory, settings, profile, start)


# parallel: the prange loop of the two regions only (_sweep_regions) — not numpy's array expressions.  (A parallel
# kernel cannot be called from solve_step: numba then refuses to cache the caller, "dynamic globals"; and compiled
# with prange on, solve_step's stages trip numba's array analysis)
@njit(parallel=PRANGE_ONLY, twin=False)
def solve_sweeps_by_regions(solving, settings, profile):
    """A big world's :func:`solve_step`, second call: the sweeps (:func:`solve_contacts_by_regions`), two regions
    at a time on the thread pool; returns the number of sweeps."""
    settings = StepSettings(*settings)
    start = clock()
    sweeps = solve_contacts_by_regions(solving.manifolds, solving.rows, solving.targets, solving.lam, solving.bodies,
                                       settings)
    lap(profile, SOLVE, start)
    return sweeps


@njit
def solve_tail(solving, bodies, settings, sweeps, tally, report, profile):
    """A big world's :func:`solve_step`, third call: stages 5–7; returns what :func:`solve_step` returns.  The
    robots' coupled loop (:func:`cgp_core.robots.coupled.step_coupled`) ends with it too (compiled once for both,
    issue 34)."""
    return _velocity_tail(solving, BodyArrays(*bodies), StepSettings(*settings), sweeps, tally, report, profile)


def moving_contacts(contacts, movable: np.ndarray) -> int:
    """How many of ``contacts`` (a :class:`ContactSet`) :func:`prepare_contacts` keeps, ``movable (n,)`` bool the
    bodies that can move: those with a movable body (a contact of two that cannot move needs no impulse).  Python's
    choice between :func:`solve_step` and the three calls of a big world (:data:`SPLIT_MIN_CONTACTS`), asked only
    from that many contacts on: a world of fixed bodies touching each other would pay the three calls' boxing for
    sweeps in the plain order."""
    moving = np.append(movable, False)  # (index -1, the ground: not movable)
    return int(np.count_nonzero(moving[contacts.body_a] | moving[contacts.body_b]))


def _solve_step_by_regions(contacts, bodies, memory, settings, tally, report, profile):
    """:func:`solve_step` in three calls (:func:`solve_head`, :func:`solve_sweeps_by_regions`, :func:`solve_tail`),
    the sweeps on the thread pool: what a sub-step of :data:`SPLIT_MIN_CONTACTS` contacts or more runs
    (:func:`moving_contacts`)."""
    solving = solve_head(contacts, bodies, memory, settings, profile)
    sweeps = solve_sweeps_by_regions(solving, settings, profile)
    return solve_tail(solving, bodies, settings, sweeps, tally, report, profile)


# ---- the position stage ("recover penetration") --------------------------------------------------------------

@njit
def recover_penetration_kernel(handover, bodies, settings, profile):
    """Split-impulse penetration recovery (see the module docstring) for the contacts of the last
    :func:`solve_step` (its :class:`Handover`), in place on the :class:`RecoveryBodies` ``bodies`` (position,
    orientation, angular momentum of the dynamic ones); timed into ``profile[RECOVER]``.  Bundles as plain tuples
    from Python.  Returns the turn quaternions ``(n, 4)`` applied (identity where none) and the deepest
    penetration after the step, before recovery."""
    h = Handover(*handover)
    handover = Handover(h.a, h.b, h.group_start, h.separation, Rows(*h.rows), h.toi_shift, h.sweeps, h.deepest)
    bodies, settings = RecoveryBodies(*bodies), StepSettings(*settings)
    start = clock()
    turn, deepest = _recover_penetration(handover, bodies, settings)
    lap(profile, RECOVER, start)
    return turn, deepest


@njit(inline="always")
def position_target(separation, toi_shift, settings):
    """A contact normal row's goal in the position stage, from its separation ``separation`` [m] after the
    sub-step's motion: ``(target, lower)`` — the displacement β (−s − slop) asked of it, at most ``max_correction``,
    one-sided (λ ≥ 0); a bounce placed at its time of impact (``toi_shift`` not NaN: see
    :func:`bounce_time_shift`) is moved by that shift exactly instead, two-sided.  (This recovery's and the robots'
    one position loop's, :func:`cgp_core.robots.coupled.relax_together`.)"""
    if not math.isnan(toi_shift):
        return toi_shift, -np.inf
    return min(settings.position_correction * (-separation - settings.penetration_slop), settings.max_correction), 0.0


@njit(inline="always")
def relax_normal_rows(runs, rows, lam, target, lower, D, scratch):
    """One Gauss–Seidel sweep of the position stage over every manifold's normal rows towards ``target``
    (:func:`position_target`), in place on their λ (m,) and the bodies' displacement ``D`` (n + 1, 6); ``runs``:
    anything with the manifolds' ``a``, ``b`` and ``group_start`` (a :class:`Handover`, :class:`Manifolds`).
    Returns the largest |Δλ| / eff."""
    a, b, group_start = runs.a, runs.b, runs.group_start
    change = 0.0
    for g in range(len(group_start) - 1):
        lo = group_start[g]
        if group_start[g + 1] - lo == 1:
            change = max(change, _push_normal_row(lo, rows, lam, target, lower, D, a[lo], b[lo]))
        else:
            change = max(change, _solve_normal_rows(g, runs, rows, lam, target, lower, D, scratch))
    return change


@njit(inline="always")
def _recover_penetration(handover, bodies, settings):
    a, b, separation, rows = handover.a, handover.b, handover.separation, handover.rows
    position, orientation = bodies.position, bodies.orientation
    n = len(position)
    m = len(a)
    # the bodies' actual motion over the sub-step, as a generalized displacement Δ = (Δx, Δθ)
    disp = np.zeros((n + 1, 6))
    for i in range(n):
        for k in range(3):
            disp[i, k] = position[i, k] - bodies.position_before[i, k]
        q, p = orientation[i], bodies.orientation_before[i]
        rx, ry, rz, rw = quat_multiply_scalar(q[0], q[1], q[2], q[3], -p[0], -p[1], -p[2], p[3])
        disp[i, 3], disp[i, 4], disp[i, 5] = quat_to_rotvec_scalar(rx, ry, rz, rw)
    target = np.empty(m)
    lower = np.zeros(m)
    deepest = 0.0
    needed = False
    for c in range(m):
        s = separation[c] + _row_velocity(rows.J, c, NORMAL, disp, a[c], b[c])
        deepest = max(deepest, -s)
        target[c], lower[c] = position_target(s, handover.toi_shift[c], settings)
        needed = needed or lower[c] == -np.inf or target[c] > 0.0
    turn = np.zeros((n, 4))
    turn[:, 3] = 1.0
    if not needed:
        return turn, deepest
    correction = np.zeros((n + 1, 6))
    lam = np.zeros(m)
    scratch = Scratch(np.empty((2, MAX_BLOCK)), np.zeros(MAX_BLOCK, np.bool_), np.empty((m, 2)))
    for _ in range(settings.position_iterations):
        relax_normal_rows(handover, rows, lam, target, lower, correction, scratch)  # (its a, b, group_start)
    for i in range(n):
        if not bodies.dynamic[i]:
            continue
        for k in range(3):
            position[i, k] += correction[i, k]
        tx, ty, tz, tw = rotvec_to_quat_scalar(correction[i, 3], correction[i, 4], correction[i, 5])
        turn[i, 0], turn[i, 1], turn[i, 2], turn[i, 3] = tx, ty, tz, tw
        q = orientation[i]
        x, y, z, w = quat_multiply_scalar(tx, ty, tz, tw, q[0], q[1], q[2], q[3])
        norm = math.sqrt(x * x + y * y + z * z + w * w)
        sign = -1.0 if w < 0.0 else 1.0  # canonical w >= 0, as rotation.quat_normalize
        q[0], q[1], q[2], q[3] = sign * x / norm, sign * y / norm, sign * z / norm, sign * w / norm
        # keep the body-frame angular momentum (and so the kinetic energy ½ Lᵀ I_world⁻¹ L) unchanged
        L = bodies.angular_momentum[i]
        L[0], L[1], L[2] = quat_rotate_scalar(tx, ty, tz, tw, L[0], L[1], L[2])
    return turn, deepest


# ---- the solver object ----------------------------------------------------------------------------------------

#: the tally :func:`solve_step` is given when no contact report is wanted (it does not read it)
_NO_TALLY = tuple(ContactTally.start(0, 0))


class PendingRecovery(NamedTuple):
    """What :meth:`SequentialImpulseSolver.recover_penetration` needs from the last ``solve_velocities``."""

    model: BodyModel                # the model the contacts index (a new model: nothing to recover)
    handover: tuple                 # the velocity stage's Handover, as the plain tuple the kernel takes
    position_before: np.ndarray     # (n, 3) x̄ when the contacts were found
    orientation_before: np.ndarray  # (n, 4) q then
    dynamic: np.ndarray             # (n,) bool: the bodies the stage may move
    settings: tuple                 # the StepSettings, as the plain tuple the kernels take


class SequentialImpulseSolver:
    """Sequential impulses, one manifold at a time; see the module docstring.

    Args:
        settings: :class:`SolverSettings` (defaults if omitted); keyword overrides are applied on top, e.g.
            ``SequentialImpulseSolver(velocity_iterations=12)``.
        detector: the :class:`CollisionDetector` feeding this solver (a default one if omitted).

    Memory between sub-steps: the warm-start impulses (keyed on the contacts' primitive pairs, so valid only
    for the model object they were made with: a new model — bodies spawned or deleted — or a different body
    count starts cold), and what :meth:`recover_penetration` needs from the last :meth:`solve_velocities`.

    After each sub-step :attr:`stats` holds what a benchmark or a curious user wants to see (contact count,
    manifolds, sweeps, deepest penetration before and after the step); :attr:`profile` (a
    :class:`~cgp_core.jit.StageProfile`) accumulates the wall time of each stage (:data:`STAGES`) over the
    sub-steps until its ``reset()``.
    """

    name: ClassVar[str] = "sequential_impulse"

    def __init__(self, settings: SolverSettings | None = None, *, detector: CollisionDetector | None = None,
                 **overrides):
        settings = settings or SolverSettings()
        if overrides:
            unknown = set(overrides) - set(SolverSettings.__dataclass_fields__)
            if unknown:
                raise ValueError(f"unknown solver setting(s) {sorted(unknown)}; valid: "
                                 f"{sorted(SolverSettings.__dataclass_fields__)}")
            settings = replace(settings, **overrides)
        self.settings = settings
        self.detector = detector or CollisionDetector()
        self.stats: dict = {}
        self.profile = StageProfile(STAGES)
        self._step_settings: tuple | None = None  # (h, the settings object, StepSettings as a plain tuple)
        self._reporting = False  # a contact report is being summed (start_report ... finish_report)
        self._tally: ContactTally | None = None
        self.reset()

    def reset(self) -> None:
        """Forget the warm-start memory (call it when bodies are teleported en masse; World.reset does)."""
        self._memory = WarmStart.empty()  # sorted by key (store_impulses keeps it so): none yet
        self._warm_model = None  # the model the warm-start keys refer to (they index its primitives)
        self._warm_count = -1
        self._pending: PendingRecovery | None = None

    def start_report(self) -> None:
        """Sum the contact report (:mod:`.report`) over the sub-steps from here on: call it at the start of a tick
        whose contacts are wanted, and :meth:`finish_report` after its sub-steps.  Costs nothing otherwise."""
        self._reporting, self._tally = True, None

    def finish_report(self, dt: float) -> ContactReport:
        """The :class:`~.report.ContactReport` of the sub-steps since :meth:`start_report`, a tick of ``dt``
        seconds; stops summing."""
        tally, self._tally, self._reporting = self._tally, None, False
        return ContactReport.empty(dt) if tally is None else finish_report(tally, dt)

    def _settings_for(self, h: float) -> tuple:
        """The :class:`StepSettings` of sub-step ``h``, as the plain tuple the kernels take (kept while neither
        changes)."""
        s = self.settings
        cached = self._step_settings
        if cached is None or cached[0] != h or cached[1] != s:
            plain = tuple(StepSettings(
                float(h), int(s.velocity_iterations), float(s.velocity_tolerance), float(s.restitution_threshold),
                bool(s.warm_start), float(s.rolling_resistance), IMPACT_SWEEPS, int(s.position_iterations),
                float(s.position_correction), float(s.penetration_slop), float(s.max_correction)))
            self._step_settings = cached = (h, replace(s), plain)
        return cached[2]

    def solve_velocities(self, model: BodyModel, state: BodyState, contacts: ContactSet, h: float, *,
                         inv_inertia: np.ndarray | None = None, active: np.ndarray | None = None,
                         coupled=None) -> None:
        """Add contact impulses to ``state.linear_momentum`` / ``angular_momentum`` (see :mod:`.base`).
        ``inv_inertia`` (n, 3, 3): the world-frame I⁻¹ at ``state``'s poses if the caller has it already;
        ``active`` (n,) bool: the bodies being stepped (default: all; a sleeping body acts as static).
        ``coupled``: None, or rows of other solvers that act on the same bodies and are to be solved in the same
        loop as the contacts (the robots whose links touch free bodies: :class:`cgp_core.robots.world.
        CoupledRobots`): its ``solve`` is called instead of :func:`solve_step`, with the same arguments, and
        returns what ``solve_step`` returns (this module does not know the robots); it corrects these contacts'
        penetration too, in one position loop with its own rows (applied after the integrator by its owner), so
        :meth:`recover_penetration` has nothing to do after it."""
        n = model.count
        self._pending = None
        if model is not self._warm_model or n != self._warm_count:
            self.reset()
            self._warm_model, self._warm_count = model, n
        if not contacts.count and coupled is None and not self._reporting:
            # no contact (a lone robot in the air, bodies in free flight): solve_step would add zero impulses and
            # hand back an empty memory; its compiled call and its arguments cost more than the sub-step's rest
            self._memory = WarmStart.empty()
            self.profile.calls += 1
            self.stats = {"contacts": 0, "manifolds": 0, "sweeps": 0, "max_penetration": 0.0}
            return
        if inv_inertia is None:
            inv_inertia = state.inv_inertia_world(model)
        movable = model.inv_mass > 0.0 if active is None else (model.inv_mass > 0.0) & active
        settings = self._settings_for(float(h))
        bodies = (model.inv_mass, movable, np.ascontiguousarray(inv_inertia), state.position, state.linear_momentum,
                  state.angular_momentum, state.force, state.torque)  # a BodyArrays, as a plain tuple
        solve = solve_step if coupled is None else coupled.solve
        if coupled is None and contacts.count >= SPLIT_MIN_CONTACTS and moving_contacts(contacts, movable) >= \
                SPLIT_MIN_CONTACTS:
            solve = _solve_step_by_regions
        if self._reporting:
            tally = self._tally
            if tally is None or len(tally.touched) != n + 1:
                tally = ContactTally.start(n, len(self._memory.key))
            handover, memory, tally = solve(tuple(contacts), bodies, tuple(self._memory), settings, tuple(tally),
                                            True, self.profile.seconds)
            self._tally = ContactTally(*tally)
        else:
            handover, memory, _ = solve(tuple(contacts), bodies, tuple(self._memory), settings, _NO_TALLY, False,
                                        self.profile.seconds)
        self._memory = memory
        self.profile.calls += 1
        self.stats = {"contacts": contacts.count, "manifolds": len(handover.group_start) - 1,
                      "sweeps": handover.sweeps, "max_penetration": handover.deepest}
        if len(handover.a) and coupled is None:
            plain = handover[:4] + (tuple(handover.rows),) + handover[5:]  # plain tuples at the border (cgp_core.jit)
            self._pending = PendingRecovery(model, plain, state.position.copy(), state.orientation.copy(), movable,
                                            settings)

    def recover_penetration(self, model: BodyModel, state: BodyState, h: float) -> None:
        """Move penetrating bodies apart (positions / orientations only) for the contacts of the last
        :meth:`solve_velocities`, after the integrator has moved the bodies."""
        p, self._pending = self._pending, None
        if p is None or self.settings.position_iterations == 0 or p.model is not model:
            return
        bodies = (p.position_before, p.orientation_before, state.position, state.orientation, state.angular_momentum,
                  p.dynamic)  # a RecoveryBodies, as a plain tuple
        turn, deepest = recover_penetration_kernel(p.handover, bodies, p.settings, self.profile.seconds)
        self.stats["max_penetration_after_step"] = float(max(deepest, 0.0))
        if state.rotation is not None:  # an integrator that keeps its own matrix (explicit Euler)
            state.rotation[p.dynamic] = quat_to_matrix(turn[p.dynamic]) @ state.rotation[p.dynamic]

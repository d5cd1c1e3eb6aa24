"""Sequential impulses (Catto, GDC 2005–2014; Box2D) with warm starting, restitution, Coulomb friction and
split-impulse penetration recovery — made vectorized by graph colouring.

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
  normal row in each update (Box2D v2's order: the normal row, solved last, is the one kept most exact);
- restitution: a contact that approached faster than ``restitution_threshold`` *before the sub-step*
  (velocity from the momentum alone) and whose gap closes within it asks instead for
  J V ≥ −e · (J V)_before (Box2D v2's velocity bias; the threshold keeps resting contacts from
  micro-bouncing).  A bounce off the static world from a speculative contact is also put at its time of
  impact (see the code).

The accumulated impulses are added to P and L at the start of the sub-step: ΔP = Σ J_linᵀ λ, ΔL = Σ J_angᵀ λ
(= Σ r × impulse), equal and opposite on the two bodies at the same point, so momentum is conserved to
round-off.

**Warm starting.**  Each contact point is matched with last sub-step's nearest point of the same primitive
pair (:meth:`SequentialImpulseSolver._match_previous`); its normal impulse and world-frame friction impulse
are applied before the first sweep (the friction vector re-projected onto the new tangents and clamped to
the cone).  For resting contacts that is already nearly the answer, which is what lets a stack stand.

**Vectorization.**  Contacts are grouped by body pair (the ≤ 4 points of one box-on-box manifold, a
particle body's spheres on the ground ...) and the groups are graph-coloured (:mod:`.colouring`) into
batches with no dynamic body in common; a sweep solves batch after batch (Gauss–Seidel between batches) and
all groups of a batch at once with numpy (exact: they do not interact).  The points *inside* a group share
both bodies and are updated together: the normal rows of a manifold of ≤ 4 points exactly, as a block LCP
(:mod:`.manifold`), the friction rows — and every row of a bigger group — Jacobi-style with mass splitting
(Tonge et al. 2012: each point sees its bodies with 1/g of their mass when the group has g points; the
increments add up).  Not one corner after another: sequential corners favour whichever comes first, a tiny
tilt every sweep, and in a tall stack those tilts pump a rocking motion that 8 sweeps cannot damp
(measured: a 10-box stack jitters at ~1 cm/s with per-point batches; with mass-split Jacobi alone it stands
only if perfectly aligned, and a flat box lands with 70 % of its bounce; with the block it stands, turned
and shifted, and bounces right).  The per-row Jacobians J, M⁻¹Jᵀ and effective masses are built once per
sub-step, row-major ((3 rows, m contacts, 12), so each row's data is contiguous), and a sweep costs a few
dozen numpy calls per batch whatever its size; the sweeps stop early once one changes no row velocity by
more than ``velocity_tolerance``.  If a body has so many contact groups that the colours run out, the rest
form one *overflow* batch, solved Jacobi-style with the same mass splitting (each body's inverse mass and
inertia times its number of overflow contacts), which keeps the simultaneous updates from overshooting.

**Penetration recovery** (pipeline stage "recover penetration", after the integrator): split impulses /
pseudo-velocities (Catto 2006; Bullet's ``splitImpulse``) in the form of Box2D v2's position solver,
linearized.  The separation after the integrator is estimated from the contact's start value and the
bodies' actual displacement, s = s₀ + J Δ (Δ = (Δx, Δθ)); a displacement-level solve of the normal rows with
the same Jacobians and batches finds position / orientation corrections D with J D ≥ β (−s − slop) (at most
``max_correction``), λ ≥ 0.  D moves the bodies; P is not touched and L is turned with the body (the
body-frame angular momentum stays the same), so the kinetic energy is unchanged exactly.
"""

from __future__ import annotations

from dataclasses import replace
from typing import ClassVar

import numpy as np

from ..bodies import BodyModel, BodyState
from ..collision import CollisionDetector, ContactSet
from ..collision.detector import FEATURE_SLOTS
from ..rotation import norms, quat_conjugate, quat_from_rotvec, quat_multiply, quat_normalize, quat_rotate, \
    quat_to_matrix, quat_to_rotvec
from .base import SolverSettings
from .colouring import colour_contacts, contact_priorities
from .manifold import MAX_BLOCK, ManifoldBlocks

#: extra sweeps over the batches holding a bouncing multi-point manifold (see the sweeps in solve_velocities)
IMPACT_SWEEPS = 16

_SIX = np.arange(6)  # a body's six entries in the flattened (n + 1, 6) velocity array


def tangent_basis(normal: np.ndarray, out: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents ``(m, 3)`` completing the unit normals to a right-handed orthonormal frame
    (n, t₁, t₂), by the branch-free construction of Duff et al. (JCGT 2017, "Building an orthonormal basis,
    revisited"); a pure function of n, so a contact whose normal does not change keeps its tangents (the
    ground's are x and y).  ``out`` (2, m, 3), if given, receives (t₁, t₂) (the solver's row directions)."""
    x, y, z = normal[:, 0], normal[:, 1], normal[:, 2]
    sign = np.where(z >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    t = np.empty((2,) + normal.shape) if out is None else out
    t[0, :, 0] = 1.0 + sign * x * x * a
    t[0, :, 1] = sign * b
    t[0, :, 2] = -sign * x
    t[1, :, 0] = b
    t[1, :, 1] = sign + y * y * a
    t[1, :, 2] = -y
    return t[0], t[1]


GS, GROUPED, BLOCK, OVERFLOW = 0, 1, 2, 3  # batch kinds, see _Batch


class _Batch:
    """One colour: views into the colour-sorted, row-major contact arrays (rows n, t₁, t₂ first).

    kind GS:       every group is a single point: the contacts' body pairs are all distinct, ``flat`` holds
                   their entries in ``V.ravel()`` (``V.ravel()[flat]`` is the (k, 12) block [V_a, V_b]), so
                   gather and scatter are one call each.
    kind GROUPED:  multi-point groups: ``flat`` holds each *group's* body entries (distinct across groups),
                   ``group_of`` maps contacts to groups, ``group_start`` the groups' first contacts; the
                   contacts' increments are summed per group (``np.add.reduceat``).  Points of a group are
                   updated together, Jacobi-style with mass splitting.
    kind BLOCK:    as GROUPED, for groups of ≤ 4 points (manifolds): the normal rows of each group are solved
                   exactly as a block (:class:`~cgp_core.solver.manifold.ManifoldBlocks`, kept in ``blocks``),
                   with the Jacobi update as the fallback where it finds no exact solution; friction as
                   GROUPED.
    kind OVERFLOW: bodies may repeat across groups: increments are added with ``np.add.at``.
    ``eff`` is the effective mass, split (÷ contacts per body in the batch) for GROUPED and OVERFLOW.
    """

    __slots__ = ("kind", "sl", "rows", "flat", "group_of", "group_start", "J", "MJ", "eff", "w_nt", "lam",
                 "bias", "mu", "delta", "blocks")

    def __init__(self, kind, sl, rows, flat, group_of, group_start, J, MJ, eff, w_nt, lam, bias, mu):
        self.kind, self.sl, self.rows, self.flat = kind, sl, rows, flat
        self.group_of, self.group_start = group_of, group_start
        self.J, self.MJ, self.eff, self.w_nt, self.lam, self.bias, self.mu = J, MJ, eff, w_nt, lam, bias, mu
        self.delta = np.empty((3, len(rows)))  # scratch: impulse increments of one update
        self.blocks = ManifoldBlocks(group_of, group_start, J[0], MJ[0]) if kind == BLOCK else None

    def gather(self, Vf: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """The (k, 12) velocity blocks of the contacts (and, for GROUPED, the groups' own blocks)."""
        if self.kind in (GROUPED, BLOCK):
            Vg = Vf.take(self.flat).reshape(-1, 12)
            return Vg.take(self.group_of, axis=0), Vg
        return Vf.take(self.flat).reshape(-1, 12), None

    def scatter(self, Vf: np.ndarray, Vab: np.ndarray, Vg: np.ndarray | None, dV: np.ndarray) -> None:
        """Add the contacts' velocity increments ``dV (k, 12)`` to their bodies."""
        if self.kind == GS:
            Vab += dV
            Vf[self.flat] = Vab.ravel()
        elif self.kind in (GROUPED, BLOCK):
            Vg += np.add.reduceat(dV, self.group_start, axis=0)
            Vf[self.flat] = Vg.ravel()
        else:
            V = Vf.reshape(-1, 6)
            np.add.at(V, self.rows[:, 0], dV[:, :6])
            np.add.at(V, self.rows[:, 1], dV[:, 6:])
            V[-1] = 0.0  # the static row stays at rest


class SequentialImpulseSolver:
    """Graph-coloured sequential impulses; see the module docstring.

    Args:
        settings: :class:`SolverSettings` (defaults if omitted); keyword overrides are applied on top, e.g.
            ``SequentialImpulseSolver(velocity_iterations=12)``.
        detector: the :class:`CollisionDetector` feeding this solver (a default one if omitted).

    After each sub-step :attr:`stats` holds what a benchmark or a curious user wants to see (contact count,
    colour count, overflow size, deepest penetration before and after the step).
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
        self.reset()

    def reset(self) -> None:
        self._store_warm(np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)), np.zeros(0, np.int64),
                         np.zeros((0, 3)))
        self._warm_model = None  # the model the warm-start keys refer to (they index its primitives)
        self._pending = None  # what recover_penetration needs from the last solve

    def _store_warm(self, key, normal_impulse, friction_impulse, colour, point) -> None:
        order = np.argsort(key, kind="stable")
        self._warm_keys = key[order]
        self._warm_normal = normal_impulse[order]
        self._warm_friction = friction_impulse[order]
        self._warm_colour = colour[order]
        self._warm_point = point[order]

    def _match_previous(self, key: np.ndarray, point: np.ndarray) -> np.ndarray:
        """Index into last sub-step's (key-sorted) contacts of the same contact, −1 if new.

        A contact is the same if it joins the same primitive pair and is the pair's nearest old point (each
        old point taken at most once, by its nearest new one).  Matching by position rather than by exact
        feature keeps the warm start when a manifold point changes the feature that produced it — a corner
        of a box resting on another is now an incident corner, now a clipped edge crossing, as the box rocks
        by a micro-radian — which would otherwise throw away its impulse and make a stack jitter.
        """
        m = len(key)
        old = self._warm_keys
        if old.size == 0 or m == 0:
            return np.full(m, -1)
        pair = key // FEATURE_SLOTS
        lo = np.searchsorted(old, pair * FEATURE_SLOTS, side="left")
        hi = np.searchsorted(old, (pair + 1) * FEATURE_SLOTS, side="left")
        # candidates (m, c): the old points of the same pair, a handful (≤ 4 for boxes); the nearest wins,
        # the first one on a tie
        idx = lo[:, None] + np.arange(max(int((hi - lo).max()), 1))
        ok = idx < hi[:, None]
        np.minimum(idx, old.size - 1, out=idx)
        diff = point[:, None, :] - self._warm_point.take(idx, axis=0)  # (m, c, 3)
        d = np.add.reduce(np.square(diff, out=diff), axis=2)  # squared distances (m, c)
        d[~(ok & (d < np.inf))] = np.inf  # not a candidate (or a non-finite point): never matched
        nearest = np.argmin(d, axis=1)
        rows = np.arange(m)
        best = d[rows, nearest]
        prev = np.where(best < np.inf, idx[rows, nearest], -1)
        # one old point, one new point: where several new points chose the same old one, the nearest keeps it
        matched = np.flatnonzero(prev >= 0)
        if matched.size:
            order = matched[np.lexsort((best[matched], prev[matched]))]
            first = np.ones(order.size, dtype=bool)
            first[1:] = prev[order[1:]] != prev[order[:-1]]
            prev[order[~first]] = -1
        return prev

    # ---- stage "solve contacts" ----------------------------------------------------------------------

    def solve_velocities(self, model: BodyModel, state: BodyState, contacts: ContactSet, h: float, *,
                         inv_inertia: np.ndarray | None = None) -> None:
        s = self.settings
        n = model.count
        m = contacts.count
        self.stats = {"contacts": m, "colours": 0, "overflow": 0,
                      "max_penetration": float(contacts.penetration().max()) if m else 0.0}
        self._pending = None
        if m == 0 or model is not self._warm_model:
            self.reset()
            self._warm_model = model
            if m == 0:
                return

        # -- bodies, with one extra static row (index n) standing for the ground (`inv_inertia` from here on is
        #    that padded (n + 1, 3, 3) copy of the world-frame I⁻¹)
        world_inv_inertia = state.inv_inertia_world(model) if inv_inertia is None else inv_inertia
        inv_mass = np.zeros(n + 1)
        inv_mass[:n] = model.inv_mass
        dynamic = inv_mass > 0.0
        static = ~dynamic
        inv_inertia = np.zeros((n + 1, 3, 3))
        inv_inertia[:n] = world_inv_inertia
        V_before = np.zeros((n + 1, 6))  # velocities before this sub-step's forces (restitution)
        V_before[:n, :3] = state.linear_momentum * model.inv_mass[:, None]
        V_before[:n, 3:] = np.einsum("nij,nj->ni", inv_inertia[:n], state.angular_momentum)
        V = np.zeros((n + 1, 6))  # the velocities being solved for: from momentum + h·force ...
        V[:n, :3] = (state.linear_momentum + h * state.force) * model.inv_mass[:, None]
        V[:n, 3:] = np.einsum("nij,nj->ni", inv_inertia[:n], state.angular_momentum + h * state.torque)
        V[static] = 0.0
        V_before[static] = 0.0

        # -- a contact between two bodies that cannot move needs no impulse (and has no effective mass)
        a = np.where(contacts.body_a < 0, n, contacts.body_a)
        movable_pair = dynamic[a] | dynamic[contacts.body_b]
        if not movable_pair.all():
            contacts = contacts.select(movable_pair)
            m = contacts.count
            if m == 0:
                self._store_warm(np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)), np.zeros(0, np.int64),
                                 np.zeros((0, 3)))
                return
            a = a[movable_pair]

        # -- match last sub-step's contacts (warm start, persistent colours)
        b = contacts.body_b
        key = contacts.key
        prev = self._match_previous(key, contacts.point)
        hit = prev >= 0
        # groups = contacts between the same two bodies (a box-on-box manifold, a particle body's spheres on
        # the ground ...), coloured as a whole since their points share both bodies; a persisting group keeps
        # its colour
        groups, first, group = _unique(a * (n + 1) + b)
        group_preset = np.full(len(groups), -1)
        group_preset[group[hit]] = self._warm_colour[prev[hit]]
        if ((group_preset >= 0) & (group_preset < s.max_colours)).all():
            group_colour = group_preset  # every group persists with its colour (a resting pile): nothing to do
        else:
            group_colour = colour_contacts(a[first], b[first], dynamic, contact_priorities(groups), s.max_colours,
                                           preset=group_preset)
        colour = group_colour[group]

        # -- contact rows, in colour order, row-major: (row n / t1 / t2, contact, 12)
        order = np.argsort(colour * len(groups) + group, kind="stable")  # by colour, each group contiguous
        colour, group, a, b, key, prev, hit = (colour[order], group[order], a[order], b[order], key[order],
                                               prev[order], hit[order])
        normal = contacts.normal[order]
        separation = contacts.separation[order]
        mu = contacts.friction[order]
        e = contacts.restitution[order]
        D = np.empty((3, m, 3))  # (3, m, 3) row directions n, t₁, t₂
        D[0] = normal
        t1, t2 = tangent_basis(normal, out=D[1:])
        ab = np.empty((m, 2), dtype=np.intp)  # (m, 2) body rows
        ab[:, 0] = a
        ab[:, 1] = b
        position = np.zeros((n + 1, 3))
        position[:n] = state.position
        point = contacts.point[order]
        lever = point - position[ab.T]  # (2, m, 3): r_a, r_b
        r_x_d = _cross_rows(lever, D)  # (2, 3, m, 3): r_a × d, r_b × d
        J = np.empty((3, m, 12))  # [−d, −r_a × d, d, r_b × d]
        J[:, :, 0:3] = -D
        J[:, :, 3:6] = -r_x_d[0]
        J[:, :, 6:9] = D
        J[:, :, 9:12] = r_x_d[1]
        MJ = np.empty((3, m, 12))  # M⁻¹ Jᵀ
        MJ[:, :, 0:3] = J[:, :, 0:3] * inv_mass[a][:, None]
        # angular parts: each row times the (symmetric) I_world⁻¹, as a batched matmul per contact
        MJ[:, :, 3:6] = np.swapaxes(np.swapaxes(J[:, :, 3:6], 0, 1) @ inv_inertia[a], 0, 1)
        MJ[:, :, 6:9] = D * inv_mass[b][:, None]
        MJ[:, :, 9:12] = np.swapaxes(np.swapaxes(r_x_d[1], 0, 1) @ inv_inertia[b], 0, 1)
        eff = 1.0 / np.einsum("rmj,rmj->rm", J, MJ)  # effective masses 1 / (J M⁻¹ Jᵀ)
        # normal-row velocity change per unit tangent impulse (Delassus cross terms J_n M⁻¹ J_tᵀ): a batch
        # update gets the normal velocity after its friction update without a second product
        w_nt = np.einsum("mj,rmj->rm", J[0], MJ[1:])
        flat_ab = (ab[:, :, None] * 6 + _SIX).reshape(m, 12)  # their entries in V.ravel()
        vn_before = np.einsum("mj,mj->m", J[0], V_before.reshape(-1).take(flat_ab))
        bias = -np.maximum(separation, 0.0) / h  # speculative: close the gap, no more
        # restitution: a contact approaching faster than the threshold before the sub-step whose gap closes
        # within it (at the contact-free velocity) bounces: its target is −e times the approach speed
        vn_free = np.einsum("mj,mj->m", J[0], V.reshape(-1).take(flat_ab))
        bounce = (e > 0.0) & (vn_before < -s.restitution_threshold) & (separation + h * vn_free < 0.0)
        if bounce.any():
            bias[bounce] = np.maximum(bias[bounce], -e[bounce] * vn_before[bounce])

        # -- warm start: last sub-step's impulses of the same contacts (friction re-projected and clamped)
        lam = np.zeros((3, m))
        if s.warm_start and hit.any():
            p = prev[hit]
            lam[0, hit] = self._warm_normal[p]
            f = self._warm_friction[p]
            lt = np.empty((2, len(p)))  # (2, k) the old friction impulse along the new tangents
            tangents = D[1:, hit]
            np.einsum("mi,mi->m", f, tangents[0], out=lt[0])
            np.einsum("mi,mi->m", f, tangents[1], out=lt[1])
            lt *= np.minimum(1.0, mu[hit] * lam[0, hit] / np.maximum(np.hypot(lt[0], lt[1]), 1e-300))
            lam[1:, hit] = lt
            V += _accumulate(flat_ab, np.einsum("rm,rmj->mj", lam, MJ), n)
            V[n] = 0.0

        # -- batches: one per colour present; the groups (consecutive contacts of one body pair) never straddle
        #    two colours, so a batch is a run of whole groups
        new_group = np.empty(m, dtype=bool)
        new_group[0] = True
        np.not_equal(group[1:], group[:-1], out=new_group[1:])
        group_start = np.flatnonzero(new_group)  # (G,) first contact of each group
        group_size = np.empty(len(group_start), dtype=np.intp)  # (G,) its number of contacts
        group_size[:-1] = group_start[1:] - group_start[:-1]
        group_size[-1] = m - group_start[-1]
        group_rank = np.cumsum(new_group) - 1  # (m,) each contact's group, counted in this order
        run_colour = colour[group_start]  # (G,) sorted
        batch_first = np.flatnonzero(np.concatenate(([True], run_colour[1:] != run_colour[:-1])))
        batch_groups = zip(batch_first.tolist(), batch_first[1:].tolist() + [len(group_start)])
        batches = []
        for g_lo, g_hi in batch_groups:  # the batch's groups g_lo .. g_hi - 1
            lo = int(group_start[g_lo])
            hi = int(group_start[g_hi]) if g_hi < len(group_start) else m
            sl = slice(lo, hi)
            starts = group_start[g_lo:g_hi] - lo  # first contact of each group, within the batch
            if run_colour[g_lo] == s.max_colours:
                kind = OVERFLOW
            elif g_hi - g_lo == hi - lo:
                kind = GS
            else:
                kind = BLOCK if group_size[g_lo:g_hi].max() <= MAX_BLOCK else GROUPED
            if kind == GS:
                batch_eff, batch_w, flat, group_of = eff[:, sl], w_nt[:, sl], flat_ab[sl].ravel(), None
            else:
                # mass splitting: each body's inverse mass and inertia times its number of contacts here
                count = np.bincount(ab[sl].ravel(), minlength=n + 1).astype(float)
                split = (np.einsum("rmj,rmj->rm", J[:, sl, :6], MJ[:, sl, :6]) * count[a[sl]]
                         + np.einsum("rmj,rmj->rm", J[:, sl, 6:], MJ[:, sl, 6:]) * count[b[sl]])
                batch_eff, batch_w = 1.0 / split, np.zeros((2, hi - lo))  # Jacobi: no coupling inside either
                if kind in (GROUPED, BLOCK):
                    flat, group_of = flat_ab[sl][starts].ravel(), group_rank[sl] - g_lo
                else:
                    flat, group_of = flat_ab[sl].ravel(), None
            batches.append(_Batch(kind, sl, ab[sl], flat, group_of, starts, J[:, sl], MJ[:, sl], batch_eff,
                                  batch_w, lam[:, sl], bias[sl], mu[sl]))
        self.stats["colours"] = sum(1 for bt in batches if bt.kind != OVERFLOW)
        self.stats["overflow"] = int(np.count_nonzero(colour == s.max_colours))

        # -- sweeps
        Vf = V.reshape(-1)
        sweeps = 0
        for _ in range(s.velocity_iterations):
            sweeps += 1
            # stop once a whole sweep changed no row velocity by more than the tolerance (a warm-started
            # resting stack is converged after one)
            if max(_solve_batch(Vf, bt) for bt in batches) <= s.velocity_tolerance:
                break
        # impacts: manifolds (multi-point groups) converge slowest exactly when the impulse changes most, so
        # the batches holding a bouncing manifold get extra sweeps (impacts are rare; resting ones are warm)
        impact_batches = [bt for bt in batches if bt.kind != GS and bounce[bt.sl].any()]
        for _ in range(IMPACT_SWEEPS if impact_batches else 0):
            if max(_solve_batch(Vf, bt) for bt in impact_batches) <= s.velocity_tolerance:
                break
        self.stats["sweeps"] = sweeps

        # -- time of impact of bounces on the static world (ground, fixed bodies): a speculative contact
        #    (gap s > 0) that bounced did so t* = s / |vₙ before| into the sub-step, not at its start.  The
        #    velocity is right (e times the impact speed), but moving with it for the whole sub-step would
        #    leave the body s (1 + vₙ after / |vₙ before|) too far from the surface, which the position stage
        #    takes back with a two-sided row.  This is what makes a dropped ball rebound to e² of its height
        #    instead of bouncing early by up to one step of travel.  Not done between two moving bodies: the
        #    shift is not an impulse, so it would spoil their total angular momentum; they bounce at the start
        #    of the sub-step, as in Box2D.
        static_side = ~dynamic[a] | ~dynamic[b]
        toi_rows = np.flatnonzero(bounce & (separation > 0.0) & static_side)
        toi_shift = np.zeros(0)
        if toi_rows.size:
            approach = -vn_before[toi_rows]
            gap = np.minimum(separation[toi_rows], approach * h)
            vn_after = np.maximum(np.einsum("mj,mj->m", J[0, toi_rows], Vf.take(flat_ab[toi_rows])), 0.0)
            toi_shift = -gap * (1.0 + vn_after / approach)

        # -- impulses → momenta (equal and opposite at the same point)
        impulse = _accumulate(flat_ab, np.einsum("rm,rmj->mj", lam, J), n)
        if s.rolling_resistance > 0.0:
            impulse[:, 3:] += resist_rolling(V, a, b, normal, lever[0], lever[1], lam[0], inv_inertia, dynamic,
                                             s.rolling_resistance)
        impulse[static] = 0.0
        state.linear_momentum += impulse[:n, :3]
        state.angular_momentum += impulse[:n, 3:]

        self._store_warm(key, lam[0], lam[1, :, None] * t1 + lam[2, :, None] * t2, colour, point)
        self._pending = {
            "model": model, "n": n, "flat_ab": flat_ab, "Jn": J[0], "separation": separation,
            "batches": batches, "position": state.position.copy(), "orientation": state.orientation.copy(),
            "toi_rows": toi_rows, "toi_shift": toi_shift,
        }

    # ---- stage "recover penetration" -----------------------------------------------------------------

    def recover_penetration(self, model: BodyModel, state: BodyState, h: float) -> None:
        s = self.settings
        p = self._pending
        self._pending = None
        if p is None or s.position_iterations == 0 or p["model"] is not model:
            return
        n = p["n"]
        # the bodies' actual motion over the sub-step, as a generalized displacement Δ = (Δx, Δθ)
        disp = np.zeros((n + 1, 6))
        disp[:n, :3] = state.position - p["position"]
        disp[:n, 3:] = quat_to_rotvec(quat_multiply(state.orientation, quat_conjugate(p["orientation"])))
        separation = p["separation"] + np.einsum("mj,mj->m", p["Jn"], disp.reshape(-1).take(p["flat_ab"]))
        self.stats["max_penetration_after_step"] = float(np.maximum(-separation, 0.0).max())
        target = np.minimum(s.position_correction * (-separation - s.penetration_slop), s.max_correction)
        toi_rows = p["toi_rows"]
        if not (target > 0.0).any() and toi_rows.size == 0:
            return
        lower = np.zeros(len(target))
        if toi_rows.size:
            target[toi_rows] = p["toi_shift"]
            lower[toi_rows] = -np.inf
        correction = np.zeros((n + 1, 6))
        cf = correction.reshape(-1)
        lam = np.zeros(len(target))
        for _ in range(s.position_iterations):
            for bt in p["batches"]:
                _solve_normal_rows(cf, bt, bt.J[0], bt.MJ[0], bt.eff[0], lam[bt.sl], target[bt.sl],
                                   lower=lower[bt.sl])
        movable = model.inv_mass > 0.0
        state.position[movable] += correction[:n][movable, :3]
        turn = quat_from_rotvec(correction[:n][movable, 3:])
        state.orientation[movable] = quat_normalize(quat_multiply(turn, state.orientation[movable]))
        # keep the body-frame angular momentum (and so the kinetic energy ½ Lᵀ I_world⁻¹ L) unchanged
        state.angular_momentum[movable] = quat_rotate(turn, state.angular_momentum[movable])
        if state.rotation is not None:
            state.rotation[movable] = quat_to_matrix(turn) @ state.rotation[movable]


def _friction_update(bt: _Batch, v: np.ndarray):
    """The two friction rows of every contact of a batch: a Jacobi step from the row velocities ``v (3, k)``,
    then clamped to the Coulomb cone |λ_t| ≤ μ λₙ with the current normal impulse.  Writes the changes into
    ``bt.delta[1:]``; returns (λₙ before the update, new λ_t1, new λ_t2)."""
    lam, eff, delta = bt.lam, bt.eff, bt.delta
    normal_old = lam[0].copy()
    t1 = lam[1] - eff[1] * v[1]
    t2 = lam[2] - eff[2] * v[2]
    scale = np.minimum(1.0, bt.mu * normal_old / np.maximum(np.sqrt(t1 * t1 + t2 * t2), 1e-300))
    t1 *= scale
    t2 *= scale
    np.subtract(t1, lam[1], out=delta[1])
    np.subtract(t2, lam[2], out=delta[2])
    return normal_old, t1, t2


def _solve_batch(Vf: np.ndarray, bt: _Batch) -> float:
    """One update of every contact of a batch: the friction rows (cone clamp with the current λₙ), then the
    normal row.  ``Vf`` is the flattened (n + 1, 6) velocity array.  Returns the largest change of a row's
    own velocity the update made, |Δλ| / effective mass [m/s] (for the early stop)."""
    if bt.kind == BLOCK:
        return _solve_block_batch(Vf, bt)
    Vab, Vg = bt.gather(Vf)
    v = np.einsum("rkj,kj->rk", bt.J, Vab)  # row velocities (3, k)
    lam, eff, delta = bt.lam, bt.eff, bt.delta
    normal_old, t1, t2 = _friction_update(bt, v)
    vn = v[0] + bt.w_nt[0] * delta[1] + bt.w_nt[1] * delta[2]
    normal = np.maximum(normal_old - eff[0] * (vn - bt.bias), 0.0)
    np.subtract(normal, normal_old, out=delta[0])
    lam[0] = normal
    lam[1] = t1
    lam[2] = t2
    bt.scatter(Vf, Vab, Vg, np.einsum("rk,rkj->kj", delta, bt.MJ))
    return float((np.abs(delta) / eff).max(initial=0.0))


def _solve_block_batch(Vf: np.ndarray, bt: _Batch) -> None:
    """The BLOCK update: the friction rows with the mass-split Jacobi step (clamped to the cones), then each
    manifold's normal rows solved exactly (see :mod:`.manifold`)."""
    Vg = Vf.take(bt.flat).reshape(-1, 12)
    v = np.einsum("rkj,kj->rk", bt.J, Vg.take(bt.group_of, axis=0))
    lam, eff, delta = bt.lam, bt.eff, bt.delta
    normal_old, t1, t2 = _friction_update(bt, v)
    Vg += np.add.reduceat(np.einsum("rk,rkj->kj", delta[1:], bt.MJ[1:]), bt.group_start, axis=0)
    vn = np.einsum("kj,kj->k", bt.J[0], Vg.take(bt.group_of, axis=0))
    normal, exact = bt.blocks.solve_normal(vn, bt.bias, normal_old)
    if not exact.all():  # the rare manifold without an exact solution: a mass-split Jacobi update
        normal = np.where(exact, normal, np.maximum(normal_old - eff[0] * (vn - bt.bias), 0.0))
    np.subtract(normal, normal_old, out=delta[0])
    Vg += np.add.reduceat(bt.MJ[0] * delta[0][:, None], bt.group_start, axis=0)
    lam[0] = normal
    lam[1] = t1
    lam[2] = t2
    Vf[bt.flat] = Vg.ravel()
    return float((np.abs(delta) / eff).max(initial=0.0))


def _solve_normal_rows(Vf, bt: _Batch, Jn, MJn, eff_n, lam_n, target, lower=0.0) -> None:
    """One update of the normal rows of a batch only (penetration recovery): J V ≥ target with the
    accumulated λ ≥ ``lower`` (0: a contact only pushes; −inf: a two-sided row, J V = target).  ``lam_n`` is
    updated in place; ``Vf`` is a flattened (n + 1, 6) displacement (or velocity) array."""
    Vab, Vg = bt.gather(Vf)
    old = lam_n.copy()
    vn = np.einsum("kj,kj->k", Jn, Vab)
    new = np.maximum(old - eff_n * (vn - target), lower)
    if bt.kind == BLOCK:
        two_sided = np.broadcast_to(np.asarray(lower) == -np.inf, old.shape)
        exact, found = bt.blocks.solve_normal(vn, target, old, two_sided=two_sided if two_sided.any() else None)
        new = np.where(found, exact, new)
    lam_n[:] = new
    bt.scatter(Vf, Vab, Vg, MJn * (new - old)[:, None])


def resist_rolling(V: np.ndarray, a: np.ndarray, b: np.ndarray, normal: np.ndarray, lever_a: np.ndarray,
                   lever_b: np.ndarray, normal_impulse: np.ndarray, inv_inertia: np.ndarray, dynamic: np.ndarray,
                   coefficient: float) -> np.ndarray:
    """Angular impulses (n + 1, 3) of rolling resistance, after the contact impulses are solved.

    A rigid ball on a rigid plane rolls (or spins in place) for ever; real surfaces deform and resist with a
    torque of at most ``c_rr · N · r`` (N the normal force, r the rolling radius), the textbook
    rolling-resistance model.  Per contact (m of them) and sub-step that is an angular impulse of at most
    ``c_rr · λₙ · r`` (λₙ the normal impulse just solved; r the larger normal component of the two levers
    ``p − x̄``) about the axis of the relative rotation ``ω_t = ω_b − ω_a``, opposing it: ``−J ω̂_t`` on b,
    ``+J ω̂_t`` on a.  The spin about the normal is resisted by the same law (MuJoCo keeps separate torsional
    and rolling coefficients; one is enough here: it only has to bring spinning balls to rest too).  J is also capped at the impulse that stops the relative rolling, shared among the
    contacts of the body, so it only ever removes energy and never reverses a rotation.  Friction then couples
    the slower rotation to the body's velocity in the following sub-steps: a rolling ball decelerates at
    ``(5/7) c_rr g`` (tests/test_contacts.py checks this closed form).

    V: (n + 1, 6) solved velocities [v, ω] (row n: the ground); a, b: (m,) body rows; normal: (m, 3) from a to
    b; lever_a, lever_b: (m, 3) contact point minus each COM; normal_impulse: (m,) λₙ ≥ 0;
    inv_inertia: (n + 1, 3, 3) world-frame; dynamic: (n + 1,) bool.
    """
    n1 = V.shape[0]
    w_t = V[b, 3:] - V[a, 3:]
    speed = norms(w_t)
    rolling = (speed > 1e-12) & (normal_impulse > 0.0)
    if not rolling.any():
        return np.zeros((n1, 3))
    a, b, w_t, speed, normal = a[rolling], b[rolling], w_t[rolling], speed[rolling], normal[rolling]
    axis = w_t / speed[:, None]
    radius = np.maximum(np.abs(np.einsum("mi,mi->m", lever_a[rolling], normal)) * dynamic[a],
                        np.abs(np.einsum("mi,mi->m", lever_b[rolling], normal)) * dynamic[b])
    k = np.einsum("mi,mij,mj->m", axis, inv_inertia[a] + inv_inertia[b], axis)  # 1 / effective inertia
    ab = np.concatenate((a, b))
    contacts_per_body = np.bincount(ab, minlength=n1)
    share = np.maximum(contacts_per_body[a] * dynamic[a], contacts_per_body[b] * dynamic[b])
    stop = speed / (np.maximum(k, 1e-300) * np.maximum(share, 1))
    J = np.minimum(coefficient * normal_impulse[rolling] * radius, stop)[:, None] * axis
    # +J on a, −J on b, summed per body (one bincount over the 3 components of both ends)
    flat = (ab[:, None] * 3 + np.arange(3)).ravel()
    return np.bincount(flat, weights=np.concatenate((J, -J)).ravel(), minlength=3 * n1).reshape(n1, 3)


def _cross_rows(r: np.ndarray, D: np.ndarray) -> np.ndarray:
    """``r[s, m] × D[k, m]`` for levers ``r (2, m, 3)`` (both sides of each contact) and row directions
    ``D (3, m, 3)``: ``(2, 3, m, 3)`` (np.cross costs more here)."""
    x, y, z = r[:, None, :, 0], r[:, None, :, 1], r[:, None, :, 2]  # (2, 1, m)
    out = np.empty((len(r),) + D.shape)
    out[..., 0] = y * D[:, :, 2] - z * D[:, :, 1]
    out[..., 1] = z * D[:, :, 0] - x * D[:, :, 2]
    out[..., 2] = x * D[:, :, 1] - y * D[:, :, 0]
    return out


def _unique(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``np.unique(values, return_index=True, return_inverse=True)`` for a 1-d integer array (m ≥ 1): the sorted
    distinct values, the index of each one's first occurrence, and each entry's index among them — the same
    stable sort, without np.unique's overhead (it dominates at the few dozen contacts of a sub-step)."""
    order = np.argsort(values, kind="stable")
    ordered = values[order]
    new = np.empty(len(values), dtype=bool)
    new[0] = True
    np.not_equal(ordered[1:], ordered[:-1], out=new[1:])
    inverse = np.empty(len(values), dtype=np.intp)
    inverse[order] = np.cumsum(new) - 1
    return ordered[new], order[new], inverse


def _accumulate(flat_ab: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Per-body sums ``(n + 1, 6)`` of per-contact 12-vectors ``values (m, 12)`` = [for body a, for body b]
    (``flat_ab``: their entries in the flattened (n + 1, 6) array): one bincount; bodies may repeat."""
    return np.bincount(flat_ab.ravel(), weights=values.ravel(), minlength=6 * (n + 1)).reshape(n + 1, 6)

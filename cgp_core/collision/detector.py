"""Contact detection for one sub-step: broad phase → narrow phase → :class:`ContactSet`.

Three compiled stages, called from :meth:`CollisionDetector.detect`:
:func:`~cgp_core.collision.primitives.primitive_bounds` (primitive poses, AABBs grown by the speculative margins),
the broad phase (:func:`small_scene_pairs` for a handful of primitives, else the configured :mod:`.broadphase`
function) and :func:`narrow_phase` (one loop over the ground and the
candidate pairs, each pair handed to its shape pair's kernel in :mod:`.narrowphase` / :mod:`.box_box`).

Speculative contacts (Catto, "Continuous collision", GDC 2013; Box2D v3).  A pair is reported not only when
it touches but whenever its gap may close within the coming sub-step: each body gets a *margin*

    margin = speculative_distance + h (|v| + |ω| · reach)

(``reach`` = farthest surface point from the COM, so ``h |ω| reach`` bounds how far a turning surface moves),
AABBs are grown by it, and a contact is kept when its separation is below the sum of the two margins (one
margin against the ground).  The solver then lets such a contact close its gap exactly and no further
(target normal velocity ``−separation / h``), which is what stops a fast sphere from tunnelling through the
ground or a thin wall: no speed limit for translation, as long as the motion over one sub-step is close to a
straight line.  Known limits: the contact points are those of the start-of-step pose, so a box spinning by a
large angle in one sub-step can still pass through a thin object (rotation is only bounded, not swept), and
a fast body grazing past another may feel a small "ghost" impulse from a speculative point it would have
missed.
"""

from __future__ import annotations

import numpy as np

from ..bodies import BodyModel, BodyState, Shape
from ..jit import njit
from .box_box import box_box_contacts
from .broadphase import DEFAULT_BROAD_PHASE, get_broad_phase, sweep_and_prune_kernel, sweep_and_prune_pairs
from .contacts import FEATURE_SLOTS, GROUND, ContactSet
from .convex_phase import (
    TOI_TARGET,
    TOI_TOLERANCE,
    ShapeModel,
    build_shape_model,
    convex_phase,
    fast_turn_pairs,
    pose_shapes,
    sweep_times,
)
from .materials import Ground, combine_friction, combine_restitution
from .narrowphase import (
    box_capsule_contacts,
    box_plane_contacts,
    capsule_capsule_contacts,
    capsule_plane_contacts,
    sphere_box_point,
    sphere_capsule_point,
    sphere_plane_point,
    sphere_sphere_point,
    write_point,
)
from .primitives import CollisionModel, build_collision_model, primitive_bounds

#: default speculative distance [m]: contacts within this gap are kept even at rest, so a resting contact
#: does not flicker in and out (and lose its warm-start impulse) with the solver's tiny residual motion
DEFAULT_SPECULATIVE_DISTANCE = 0.002

#: up to this many primitives the broad phase tests every pair (compiled) whatever is configured
SMALL_SCENE = 64

#: most contact points one primitive pair (or a primitive and the ground) can give (box–box, box–plane)
MAX_POINTS_PER_PAIR = 4

SPHERE, BOX, CAPSULE = int(Shape.SPHERE), int(Shape.BOX), int(Shape.CAPSULE)


class CollisionDetector:
    """Finds the contacts of a body model at the current state.

    Args:
        broad_phase: ``"sweep_and_prune"`` (default, compiled), ``"grid"`` or ``"brute_force"`` (see
            :mod:`.broadphase`), used above ``SMALL_SCENE`` primitives.
        speculative_distance: gap [m] below which contacts are always reported (see the module docstring).

    The collision primitives of a model are built on first use and cached, keyed on the model object (the
    model is static; a new model — bodies spawned or deleted — is a new object and gets new primitives).
    """

    def __init__(self, broad_phase: str = DEFAULT_BROAD_PHASE,
                 speculative_distance: float = DEFAULT_SPECULATIVE_DISTANCE, *, continuous: bool = True):
        self.broad_phase_name = broad_phase
        self.broad_phase = get_broad_phase(broad_phase)
        if not (isinstance(speculative_distance, (int, float)) and 0.0 <= speculative_distance < np.inf):
            raise ValueError(f"speculative_distance must be a finite length >= 0 [m], got {speculative_distance!r}")
        self.speculative_distance = float(speculative_distance)
        #: grow the margins by the motion over the sub-step and sweep fast-turning bodies (see the module
        #: docstring and :mod:`.convex_phase`); False only to show, in tests, what they prevent
        self.continuous = bool(continuous)
        self._model: BodyModel | None = None
        self._cmodel: CollisionModel | None = None
        self._shapes: ShapeModel | None = None
        self._sweeps = None  # what sweep_fast_rotation needs from the last detect (convex_phase.FastTurns)

    def collision_model(self, model: BodyModel) -> CollisionModel:
        if model is not self._model or self._cmodel is None or len(self._cmodel.body_reach) != model.count:
            self._cmodel = build_collision_model(model)
            self._shapes = build_shape_model(model, self._cmodel) if model.has_convex_phase_shapes else None
            self._model = model
        return self._cmodel

    def shape_model(self, model: BodyModel) -> ShapeModel | None:
        """The primitives of the convex stage (:mod:`.convex_phase`), None for a model without its shapes."""
        self.collision_model(model)
        return self._shapes

    def detect(self, model: BodyModel, state: BodyState, h: float, *, ground: Ground | None,
               velocity: np.ndarray | None = None, angular_velocity: np.ndarray | None = None,
               rotation: np.ndarray | None = None, active: np.ndarray | None = None) -> ContactSet:
        """All contacts (touching, penetrating, or within the speculative margin) at ``state``'s poses.

        ``velocity`` / ``angular_velocity`` ``(n, 3)`` are the velocities the bodies will move with over the
        sub-step (default: the state's current ones); they only size the speculative margins.
        ``rotation`` ``(n, 3, 3)``: ``state.rotation_matrices()``, if the caller has it already.
        ``active`` ``(n,)`` bool: the bodies being stepped (default: every movable one).  Only pairs with an
        active body are tested; a sleeping movable body (movable, not active) is tested against the active ones
        and acts as static, and the contacts that touch one are reported in :attr:`touched_sleeping` (the
        caller wakes it: see :mod:`cgp_core.sleep`).
        """
        cm = self.collision_model(model)
        shapes = self._shapes
        self.touched_sleeping = np.zeros(0, np.intp)
        self._sweeps = None
        if cm.count == 0 and shapes is None:
            return ContactSet.empty()
        if velocity is None:
            velocity = state.linear_velocity(model)
        if angular_velocity is None:
            angular_velocity = state.angular_velocity(model)
        R = state.rotation_matrices() if rotation is None else rotation
        R = np.ascontiguousarray(R)
        movable = ~cm.fixed_body
        active = movable if active is None else active & movable
        h_motion = float(h) if self.continuous else 0.0  # (only the margins: h (|v| + |ω| reach))
        centre, lo, hi, margin = primitive_bounds(cm.body, cm.offset, cm.radius, cm.half_extents, cm.body_reach,
                                                  state.position, R, velocity, angular_velocity, h_motion,
                                                  self.speculative_distance)
        # a primitive whose body's state went non-finite (a numerical blow-up, which World contains after the
        # tick) takes no part in collisions rather than stopping everyone else's step: its bounds are NaN (see
        # primitive_bounds), so no overlap test passes
        if shapes is not None:
            return self._detect_with_shapes(model, state, shapes, cm, ground, velocity, angular_velocity, R, active,
                                            movable, h_motion, centre, lo, hi, margin)
        i, j = self._candidate_pairs(lo, hi, cm.body, active)
        contacts = narrow_phase(cm.body, cm.shape, cm.radius, cm.half_extents, model.friction, model.restitution,
                                active, movable, centre, R, lo, margin, i, j,
                                ground is not None, ground.friction if ground is not None else 0.0,
                                ground.restitution if ground is not None else 0.0)
        body_a, body_b, normal, separation, point, key, friction, restitution, touched = contacts
        if touched.any():
            self.touched_sleeping = np.flatnonzero(touched)
        return ContactSet(body_a, body_b, normal, separation, point, key, friction, restitution)

    def _candidate_pairs(self, lo, hi, prim_body, active):
        """The broad phase: primitive pairs ``i, j`` whose AABBs overlap."""
        count = len(lo)
        if count <= SMALL_SCENE:
            return small_scene_pairs(lo, hi, prim_body, active)
        if self.broad_phase is sweep_and_prune_pairs:
            # one compiled call, no same-body pair; the order of the pairs does not matter here
            return sweep_and_prune_kernel(lo, hi, prim_body)
        sane = np.flatnonzero(np.isfinite(lo).all(1) & np.isfinite(hi).all(1))
        if sane.size == count:
            i, j = self.broad_phase(lo, hi)
        else:
            i, j = self.broad_phase(lo[sane], hi[sane])
            i, j = sane[i], sane[j]
        return np.ascontiguousarray(i, np.int64), np.ascontiguousarray(j, np.int64)

    def _detect_with_shapes(self, model, state, shapes, cm, ground, velocity, angular_velocity, R, active, movable,
                            h_motion, centre_old, lo_old, hi_old, margin_old) -> ContactSet:
        """:meth:`detect` for a model with convex hulls, compound bodies or static meshes: every primitive into
        one broad phase; the pairs of two of :class:`CollisionModel`'s primitives to :func:`narrow_phase`
        (unchanged), every other pair and this stage's ground contacts to :func:`.convex_phase.convex_phase`;
        its contacts appended."""
        p, P = cm.count, shapes.count
        centre, lo, hi = np.empty((P, 3)), np.empty((P, 3)), np.empty((P, 3))
        margin, rotation = np.empty(P), np.empty((P, 3, 3))
        centre[:p], lo[:p], hi[:p], margin[:p] = centre_old, lo_old, hi_old, margin_old
        pose_shapes(shapes.primitives, shapes.hulls, shapes.meshes, shapes.body_reach, state.position, R, velocity,
                    angular_velocity, h_motion, self.speculative_distance, centre, rotation, lo, hi, margin)
        i, j = self._candidate_pairs(lo, hi, shapes.primitives.body, active)
        has_ground = ground is not None
        mu, e = (ground.friction, ground.restitution) if has_ground else (0.0, 0.0)
        parts = []
        touched = np.zeros(model.count, bool)
        if p:
            old = (i < p) & (j < p)
            (body_a, body_b, normal, separation, point, key, friction, restitution, touched_old) = narrow_phase(
                cm.body, cm.shape, cm.radius, cm.half_extents, model.friction, model.restitution, active, movable,
                centre_old, R, lo_old, margin_old, np.ascontiguousarray(i[old]), np.ascontiguousarray(j[old]),
                has_ground, mu, e)
            parts.append(ContactSet(body_a, body_b, normal, separation, point, key, friction, restitution))
            touched |= touched_old
        (body_a, body_b, normal, separation, point, key, friction, restitution, touched_new) = convex_phase(
            shapes.primitives, shapes.hulls, shapes.meshes, model.friction, model.restitution, active, movable,
            centre, rotation, lo, margin, i, j, has_ground, mu, e, np.int64((p + 1) ** 2))
        parts.append(ContactSet(body_a, body_b, normal, separation, point, key, friction, restitution))
        touched |= touched_new
        if touched.any():
            self.touched_sleeping = np.flatnonzero(touched)
        if self.continuous:
            moving, static = fast_turn_pairs(shapes.primitives, active, movable, angular_velocity, float(h_motion), i,
                                             j)
            if len(moving):
                self._sweeps = (model, moving, static, state.position.copy(), R.copy(), centre, rotation)
        return ContactSet.concatenate(parts)

    def sweep_fast_rotation(self, model: BodyModel, state: BodyState, h: float) -> None:
        """Continuous collision for fast rotation (pipeline stage 4, right after the integrator; see
        :mod:`.convex_phase`): every body that the last :meth:`detect` found turning by more than
        :data:`.convex_phase.TOI_ANGLE` next to a fixed hull, box or mesh is swept from its pose then to its pose
        now (constant velocity and angular velocity, :func:`.convex_phase.sweep_times`: conservative advancement);
        if it touched within the sub-step it is put back at its pose at that time of impact.  Its momenta are
        kept: the next sub-step's contact, made at that pose, stops it.  A no-op when nothing turned that fast."""
        sweeps, self._sweeps = self._sweeps, None
        if sweeps is None or sweeps[0] is not model or self._shapes is None:
            return
        from ..rotation import matrix_to_quat, quat_from_rotvec, quat_multiply, quat_to_rotvec
        from .toi import rotated

        _, moving, static, position0, rotation0, centre, prim_rotation = sweeps
        prims = self._shapes.primitives
        bodies = np.unique(prims.body[moving])
        R1 = state.rotation_matrices()
        velocity = np.zeros((model.count, 3))
        angular_velocity = np.zeros((model.count, 3))
        velocity[bodies] = (state.position[bodies] - position0[bodies]) / h
        turn = matrix_to_quat(R1[bodies] @ np.swapaxes(rotation0[bodies], -1, -2))  # R1 R0ᵀ
        angular_velocity[bodies] = quat_to_rotvec(turn) / h
        times = sweep_times(prims, self._shapes.hulls, self._shapes.meshes, moving, static, centre, prim_rotation,
                            position0, rotation0, velocity, angular_velocity, float(h), TOI_TARGET, TOI_TOLERANCE)
        first = np.ones(model.count)
        np.minimum.at(first, prims.body[moving], times)
        for b in np.flatnonzero(first < 1.0):
            t = first[b]
            state.position[b] = position0[b] + velocity[b] * h * t
            R = rotated(rotation0[b], *angular_velocity[b], h * t)
            q0 = matrix_to_quat(rotation0[b][None])[0]
            q = quat_multiply(quat_from_rotvec(angular_velocity[b] * h * t), q0)
            state.orientation[b] = q / np.linalg.norm(q)
            if state.rotation is not None:
                state.rotation[b] = R


@njit
def small_scene_pairs(lo, hi, prim_body, active):
    """Every overlapping pair ``i < j`` of AABBs of different bodies, at least one of them active, in (i, j)
    order: the broad phase for a handful of primitives, where building any structure costs more."""
    p = len(lo)
    count = 0
    pi = np.empty(p * (p - 1) // 2 + 1, np.int64)
    pj = np.empty(p * (p - 1) // 2 + 1, np.int64)
    for i in range(p):
        for j in range(i + 1, p):
            if prim_body[i] == prim_body[j] or not (active[prim_body[i]] or active[prim_body[j]]):
                continue
            if lo[i, 0] <= hi[j, 0] and lo[j, 0] <= hi[i, 0] and lo[i, 1] <= hi[j, 1] and lo[j, 1] <= hi[i, 1] \
                    and lo[i, 2] <= hi[j, 2] and lo[j, 2] <= hi[i, 2]:
                pi[count] = i
                pj[count] = j
                count += 1
    return pi[:count], pj[:count]


@njit
def narrow_phase(prim_body, prim_shape, prim_radius, prim_half, body_friction, body_restitution, active, movable,
                 centre, rotation, lo, margin, pair_i, pair_j, has_ground, ground_friction, ground_restitution):
    """Contact points of the active primitives with the ground and of the candidate pairs ``pair_i, pair_j``
    (primitive indices, AABBs overlapping), as the :class:`ContactSet` fields ``(body_a, body_b, normal,
    separation, point, key, friction, restitution)``, and ``touched (n,)``: the sleeping bodies in a contact;
    ground contacts first, in primitive order, then the pairs in the order given.  A pair's side A is the
    primitive whose shape comes first in SPHERE < BOX < CAPSULE.
    Materials: friction √(μ_a μ_b), restitution max(e_a, e_b) (see :mod:`.materials`)."""
    p = len(prim_body)
    cap = MAX_POINTS_PER_PAIR * (p + len(pair_i)) + 1
    normal = np.empty((cap, 3))
    separation = np.empty(cap)
    point = np.empty((cap, 3))
    feature = np.empty(cap, np.int64)
    prim_a = np.empty(cap, np.int64)  # −1: the ground
    prim_b = np.empty(cap, np.int64)
    axis_a = np.empty(3)
    axis_b = np.empty(3)
    # (an int64, not a literal 0: numba would also compile the kernels it is passed to for a literal 0)
    m = np.int64(0)

    # -- the ground plane z = 0 (side A) against every active primitive near it
    if has_ground:
        for k in range(p):
            if not active[prim_body[k]] or not lo[k, 2] < margin[k]:
                continue
            start = m
            shape = prim_shape[k]
            if shape == SPHERE:
                nx, ny, nz, s, px, py, pz = sphere_plane_point(centre[k], prim_radius[k])
                if s < margin[k]:
                    m = write_point(normal, separation, point, feature, m, nx, ny, nz, s, px, py, pz, 0)
            elif shape == BOX:
                m = box_plane_contacts(centre[k], rotation[prim_body[k]], prim_half[k], margin[k], normal,
                                       separation, point, feature, m)
            else:
                _column(rotation[prim_body[k]], 2, axis_b)
                m = capsule_plane_contacts(centre[k], axis_b, prim_half[k, 2], prim_radius[k], margin[k], normal,
                                           separation, point, feature, m)
            prim_a[start:m] = -1
            prim_b[start:m] = k

    # -- primitive pairs
    for q in range(len(pair_i)):
        i, j = pair_i[q], pair_j[q]
        bi, bj = prim_body[i], prim_body[j]
        if bi == bj or not (active[bi] or active[bj]):
            continue
        a, b = (j, i) if prim_shape[i] > prim_shape[j] else (i, j)
        sa, sb = prim_shape[a], prim_shape[b]
        Ra, Rb = rotation[prim_body[a]], rotation[prim_body[b]]
        limit = margin[a] + margin[b]
        start = m
        if sa == SPHERE and sb != BOX and sb != CAPSULE:
            nx, ny, nz, s, px, py, pz = sphere_sphere_point(centre[a, 0], centre[a, 1], centre[a, 2], prim_radius[a],
                                                            centre[b, 0], centre[b, 1], centre[b, 2], prim_radius[b])
            if s < limit:
                m = write_point(normal, separation, point, feature, m, nx, ny, nz, s, px, py, pz, 0)
        elif sa == SPHERE and sb == BOX:
            nx, ny, nz, s, px, py, pz = sphere_box_point(centre[a], prim_radius[a], centre[b], Rb, prim_half[b])
            if s < limit:
                m = write_point(normal, separation, point, feature, m, nx, ny, nz, s, px, py, pz, 0)
        elif sa == SPHERE:
            _column(Rb, 2, axis_b)
            nx, ny, nz, s, px, py, pz = sphere_capsule_point(centre[a], prim_radius[a], centre[b], axis_b,
                                                             prim_half[b, 2], prim_radius[b])
            if s < limit:
                m = write_point(normal, separation, point, feature, m, nx, ny, nz, s, px, py, pz, 0)
        elif sa == BOX and sb == BOX:
            m = box_box_contacts(centre[a], Ra, prim_half[a], centre[b], Rb, prim_half[b], limit, normal, separation,
                                 point, feature, m)
        elif sa == BOX:
            _column(Rb, 2, axis_b)
            m = box_capsule_contacts(centre[a], Ra, prim_half[a], centre[b], axis_b, prim_half[b, 2], prim_radius[b],
                                     limit, normal, separation, point, feature, m)
        else:
            _column(Ra, 2, axis_a)
            _column(Rb, 2, axis_b)
            m = capsule_capsule_contacts(centre[a], axis_a, prim_half[a, 2], prim_radius[a], centre[b], axis_b,
                                         prim_half[b, 2], prim_radius[b], limit, normal, separation, point, feature, m)
        prim_a[start:m] = a
        prim_b[start:m] = b

    # -- bodies, identity keys and materials; sleeping (movable, not active) bodies touched
    touched = np.zeros(len(active), np.bool_)
    body_a = np.empty(m, np.int64)
    body_b = np.empty(m, np.int64)
    key = np.empty(m, np.int64)
    friction = np.empty(m)
    restitution = np.empty(m)
    for c in range(m):
        body_b[c] = prim_body[prim_b[c]]
        if prim_a[c] < 0:
            body_a[c] = GROUND
            mu_a, e_a = ground_friction, ground_restitution
        else:
            body_a[c] = prim_body[prim_a[c]]
            mu_a, e_a = body_friction[body_a[c]], body_restitution[body_a[c]]
        friction[c] = combine_friction(mu_a, body_friction[body_b[c]])
        restitution[c] = combine_restitution(e_a, body_restitution[body_b[c]])
        key[c] = contact_key(prim_a[c], prim_b[c], feature[c], p)
        for body in (body_a[c], body_b[c]):
            if body >= 0 and movable[body] and not active[body]:
                touched[body] = True
    return (body_a, body_b, normal[:m].copy(), separation[:m].copy(), point[:m].copy(), key, friction,
            restitution, touched)


@njit
def contact_key(prim_a, prim_b, feature, primitive_count):
    """Contact identity: (primitive A + 1, primitive B, feature) packed into one int64 (A = −1: the ground)."""
    return ((prim_a + 1) * (primitive_count + 1) + prim_b) * FEATURE_SLOTS + feature


@njit
def _column(R, k, out):
    out[0] = R[0, k]
    out[1] = R[1, k]
    out[2] = R[2, k]

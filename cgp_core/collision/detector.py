"""Contact detection for one sub-step: broad phase → narrow phase → :class:`ContactSet`.

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
from . import narrowphase as nph
from .box_box import box_box
from .broadphase import DEFAULT_BROAD_PHASE, brute_force_pairs, get_broad_phase
from .contacts import GROUND, ContactSet
from .materials import Ground, combine_friction, combine_restitution
from .primitives import CollisionModel, build_collision_model, primitive_aabbs, primitive_poses

#: default speculative distance [m]: contacts within this gap are kept even at rest, so a resting contact
#: does not flicker in and out (and lose its warm-start impulse) with the solver's tiny residual motion
DEFAULT_SPECULATIVE_DISTANCE = 0.002

#: features per primitive pair in a contact key (box–box uses up to 296): ``key // FEATURE_SLOTS`` is the
#: primitive pair, which the solver uses to match contacts across sub-steps
FEATURE_SLOTS = 512

#: up to this many primitives the broad phase is brute force whatever is configured
SMALL_SCENE = 32

SPHERE, BOX, CAPSULE = int(Shape.SPHERE), int(Shape.BOX), int(Shape.CAPSULE)


class CollisionDetector:
    """Finds the contacts of a body model at the current state.

    Args:
        broad_phase: ``"grid"`` (default), ``"sweep_and_prune"`` or ``"brute_force"`` (see
            :mod:`.broadphase`).
        speculative_distance: gap [m] below which contacts are always reported (see the module docstring).

    The collision primitives of a model are built on first use and cached (the model is static).
    """

    def __init__(self, broad_phase: str = DEFAULT_BROAD_PHASE,
                 speculative_distance: float = DEFAULT_SPECULATIVE_DISTANCE):
        self.broad_phase_name = broad_phase
        self.broad_phase = get_broad_phase(broad_phase)
        if not (isinstance(speculative_distance, (int, float)) and 0.0 <= speculative_distance < np.inf):
            raise ValueError(f"speculative_distance must be a finite length >= 0 [m], got {speculative_distance!r}")
        self.speculative_distance = float(speculative_distance)
        self._model: BodyModel | None = None
        self._cmodel: CollisionModel | None = None

    def collision_model(self, model: BodyModel) -> CollisionModel:
        if model is not self._model:
            self._cmodel = build_collision_model(model)
            self._model = model
        return self._cmodel

    def margins(self, model: BodyModel, h: float, velocity: np.ndarray, angular_velocity: np.ndarray) -> np.ndarray:
        """Per-body speculative margin ``(n,)`` for a sub-step of ``h`` at the given velocities."""
        cm = self.collision_model(model)
        speed = np.linalg.norm(velocity, axis=1) + np.linalg.norm(angular_velocity, axis=1) * cm.body_reach
        return self.speculative_distance + h * speed

    def detect(self, model: BodyModel, state: BodyState, h: float, *, ground: Ground | None,
               velocity: np.ndarray | None = None, angular_velocity: np.ndarray | None = None,
               rotation: np.ndarray | None = None) -> ContactSet:
        """All contacts (touching, penetrating, or within the speculative margin) at ``state``'s poses.

        ``velocity`` / ``angular_velocity`` ``(n, 3)`` are the velocities the bodies will move with over the
        sub-step (default: the state's current ones); they only size the speculative margins.
        ``rotation`` ``(n, 3, 3)``: ``state.rotation_matrices()``, if the caller has it already.
        """
        cm = self.collision_model(model)
        if cm.count == 0:
            return ContactSet.empty()
        if velocity is None:
            velocity = state.linear_velocity(model)
        if angular_velocity is None:
            angular_velocity = state.angular_velocity(model)
        body_margin = self.margins(model, h, velocity, angular_velocity)
        R = state.rotation_matrices() if rotation is None else rotation
        centre, Rp = primitive_poses(cm, state.position, R)
        lo, hi = primitive_aabbs(cm, centre, Rp)
        margin = body_margin[cm.body]
        # a body whose state went non-finite (a numerical blow-up, which World contains after the tick)
        # takes no part in collisions rather than stopping everyone else's step
        sane = np.isfinite(lo).all(axis=1) & np.isfinite(hi).all(axis=1) & np.isfinite(margin)
        live = np.flatnonzero(sane) if not sane.all() else None

        parts = []
        if ground is not None:
            parts.append(self._ground_contacts(model, cm, centre, Rp, np.where(sane[:, None], lo, np.inf),
                                               margin, ground))

        # a handful of primitives: testing every pair is cheaper than building any structure
        broad_phase = brute_force_pairs if cm.count <= SMALL_SCENE else self.broad_phase
        if live is None:
            i, j = broad_phase(lo - margin[:, None], hi + margin[:, None])
        else:
            i, j = broad_phase(lo[live] - margin[live, None], hi[live] + margin[live, None])
            i, j = live[i], live[j]
        keep = (cm.body[i] != cm.body[j]) & ~(cm.fixed_body[cm.body[i]] & cm.fixed_body[cm.body[j]])
        i, j = i[keep], j[keep]
        if i.size:
            swap = cm.shape[i] > cm.shape[j]
            a = np.where(swap, j, i)
            b = np.where(swap, i, j)
            parts.append(self._pair_contacts(model, cm, centre, Rp, margin, a, b))
        return ContactSet.concatenate(parts)

    # ---- ground --------------------------------------------------------------------------------------

    def _ground_contacts(self, model, cm, centre, Rp, lo, margin, ground: Ground) -> ContactSet:
        near = (lo[:, 2] < margin) & cm.movable
        idx, normal, sep, point, feature = [], [], [], [], []  # per shape: primitive, contact geometry
        for shape, prims in cm.by_shape:
            p = prims[near[prims]]
            if p.size == 0:
                continue
            if shape == SPHERE:
                n_, s_, x_ = nph.sphere_plane(centre[p], cm.radius[p])
                ok = s_ < margin[p]
                k, f_ = np.flatnonzero(ok), np.zeros(int(ok.sum()), np.int64)
                n_, s_, x_ = n_[ok], s_[ok], x_[ok]
            elif shape == BOX:
                k, n_, s_, x_, f_ = nph.box_plane(centre[p], Rp[p], cm.half_extents[p], margin[p])
            else:
                k, n_, s_, x_, f_ = nph.capsule_plane(centre[p], Rp[p][:, :, 2], cm.half_extents[p, 2], cm.radius[p],
                                                      margin[p])
            idx.append(p[k])
            normal.append(n_)
            sep.append(s_)
            point.append(x_)
            feature.append(f_)
        if not idx:
            return ContactSet.empty()
        # one ContactSet for all shapes (in shape order), not one per shape and a concatenation
        idx = np.concatenate(idx)
        body = cm.body[idx]
        return ContactSet(
            body_a=np.full(len(idx), GROUND, dtype=np.intp), body_b=body.astype(np.intp),
            normal=np.concatenate(normal), separation=np.concatenate(sep), point=np.concatenate(point),
            key=self._keys(cm, -1, idx, np.concatenate(feature)),
            friction=combine_friction(ground.friction, model.friction[body]),
            restitution=combine_restitution(ground.restitution, model.restitution[body]))

    # ---- primitive pairs -----------------------------------------------------------------------------

    def _pair_contacts(self, model, cm, centre, Rp, margin, a, b) -> ContactSet:
        sa, sb = cm.shape[a], cm.shape[b]
        pair_margin = margin[a] + margin[b]
        out = []
        for ta, tb in ((SPHERE, SPHERE), (SPHERE, BOX), (SPHERE, CAPSULE), (BOX, BOX), (BOX, CAPSULE),
                       (CAPSULE, CAPSULE)):
            sel = np.flatnonzero((sa == ta) & (sb == tb))
            if sel.size == 0:
                continue
            pa, pb, m = a[sel], b[sel], pair_margin[sel]
            ca, cb = centre[pa], centre[pb]
            if (ta, tb) == (SPHERE, SPHERE):
                single = nph.sphere_sphere(ca, cm.radius[pa], cb, cm.radius[pb])
            elif (ta, tb) == (SPHERE, BOX):
                single = nph.sphere_box(ca, cm.radius[pa], cb, Rp[pb], cm.half_extents[pb])
            elif (ta, tb) == (SPHERE, CAPSULE):
                single = nph.sphere_capsule(ca, cm.radius[pa], cb, Rp[pb][:, :, 2], cm.half_extents[pb, 2],
                                            cm.radius[pb])
            else:
                single = None
            if single is not None:
                normal, sep, point = single
                ok = sep < m
                k = np.flatnonzero(ok)
                normal, sep, point, feature = normal[ok], sep[ok], point[ok], np.zeros(len(k), np.int64)
            elif (ta, tb) == (BOX, BOX):
                k, normal, sep, point, feature = box_box(ca, Rp[pa], cm.half_extents[pa], cb, Rp[pb],
                                                         cm.half_extents[pb], m)
            elif (ta, tb) == (BOX, CAPSULE):
                k, normal, sep, point, feature = nph.box_capsule(ca, Rp[pa], cm.half_extents[pa], cb,
                                                                 Rp[pb][:, :, 2], cm.half_extents[pb, 2],
                                                                 cm.radius[pb], m)
            else:
                k, normal, sep, point, feature = nph.capsule_capsule(
                    ca, Rp[pa][:, :, 2], cm.half_extents[pa, 2], cm.radius[pa],
                    cb, Rp[pb][:, :, 2], cm.half_extents[pb, 2], cm.radius[pb], m)
            if len(k) == 0:
                continue
            prim_a, prim_b = pa[k], pb[k]
            body_a, body_b = cm.body[prim_a], cm.body[prim_b]
            out.append(ContactSet(
                body_a=body_a.astype(np.intp), body_b=body_b.astype(np.intp), normal=normal, separation=sep,
                point=point, key=self._keys(cm, prim_a, prim_b, feature),
                friction=combine_friction(model.friction[body_a], model.friction[body_b]),
                restitution=combine_restitution(model.restitution[body_a], model.restitution[body_b])))
        return ContactSet.concatenate(out)

    @staticmethod
    def _keys(cm: CollisionModel, prim_a: np.ndarray, prim_b: np.ndarray, feature: np.ndarray) -> np.ndarray:
        """Contact identity: (primitive A + 1, primitive B, feature) packed into one int64 (A = −1: ground)."""
        p = np.int64(cm.count + 1)
        return ((np.asarray(prim_a, np.int64) + 1) * p + np.asarray(prim_b, np.int64)) * FEATURE_SLOTS + feature

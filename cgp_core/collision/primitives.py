"""Collision primitives: every body as one or more convex pieces the narrow phase knows.

Sphere, box and capsule bodies are one primitive each, centred on the body's COM.  A PARTICLES body (the
lecture's discrete body) is one small sphere of ``model.radius`` per particle, at the particle's body-frame
offset — so a particle body collides exactly as it is drawn.  The broad and narrow phases work on primitives;
contacts are reported per body.

The shapes of issue 25 (convex hulls, compound bodies — each part a primitive with its own offset *and rotation* —
and static meshes) are not in this :class:`CollisionModel`: they are the primitives of
:mod:`.convex_phase` (:class:`~.convex_phase.ShapeModel`), numbered after these, which takes every pair one of
them is in.  Keeping them apart keeps this model, its bounds and :func:`.detector.narrow_phase` exactly as they
were for the scenes without them.

Built once per :class:`~cgp_core.bodies.BodyModel` (the model is static); :func:`primitive_bounds` places the
primitives at the bodies' current poses and bounds them.

The :class:`CollisionModel` is a bundle the compiled stages take whole (see "Bundles" in :mod:`cgp_core.jit`):
a new primitive kind is a shape code and the field or two its geometry needs — per-primitive variable-size data
(a convex hull's vertices, faces, adjacency; a mesh's triangles) stored CSR-style, e.g. ``vertex_start (p + 1,)``
and ``vertices (V, 3)`` with primitive k's rows ``vertex_start[k] : vertex_start[k + 1]`` — filled in
:func:`build_collision_model`; the signatures of the detector's stages do not change.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..bodies import BodyModel, Shape
from ..jit import njit


class CollisionModel(NamedTuple):
    """``p`` primitives of ``n`` bodies, and the per-body numbers contact detection needs."""

    body: np.ndarray              # (p,) intp — owning body
    shape: np.ndarray             # (p,) int8 — ``Shape.SPHERE``, ``BOX`` or ``CAPSULE`` (particles become spheres)
    offset: np.ndarray            # (p, 3) — primitive centre in the body frame (0 except for particles)
    radius: np.ndarray            # (p,) — sphere / capsule radius (0 for boxes)
    half_extents: np.ndarray      # (p, 3) — box half sizes; capsule (0, 0, half_length); sphere zeros
    extent: np.ndarray            # (p,) — radius of the primitive's bounding sphere about its centre
    body_reach: np.ndarray        # (n,) — farthest distance from a body's COM to its surface: bounds how far any
    #                               surface point moves when the body turns by an angle θ (≤ reach · θ)
    fixed_body: np.ndarray        # (n,) bool — the body never moves (pairs of two fixed bodies are skipped)
    body_friction: np.ndarray     # (n,) — the body's Coulomb μ (a contact combines its two, see .materials)
    body_restitution: np.ndarray  # (n,) — the body's coefficient of restitution e

    @property
    def count(self) -> int:
        return len(self.body)


def build_collision_model(model: BodyModel) -> CollisionModel:
    """Primitives of every body of ``model``; ``ValueError`` naming the body for a shape it cannot collide."""
    body, shape, offset, radius, half = [], [], [], [], []
    for i in range(model.count):
        s = int(model.shape[i])
        if s == Shape.PARTICLES:
            pts = model.particles[i]
            if pts is None or len(pts) == 0:
                raise ValueError(f"body {model.names[i]!r}: a particles body needs at least one particle")
            pts = np.asarray(pts, dtype=float)
            k = len(pts)
            body.append(np.full(k, i))
            shape.append(np.full(k, int(Shape.SPHERE)))
            offset.append(pts[:, :3])
            radius.append(np.full(k, float(model.radius[i])))
            half.append(np.zeros((k, 3)))
        elif s in (Shape.SPHERE, Shape.BOX, Shape.CAPSULE):
            body.append(np.array([i]))
            shape.append(np.array([s]))
            offset.append(np.zeros((1, 3)))
            radius.append(np.array([float(model.radius[i])]) if s != Shape.BOX else np.zeros(1))
            he = np.asarray(model.half_extents[i], dtype=float).copy()
            if s == Shape.SPHERE:
                he[:] = 0.0
            elif s == Shape.CAPSULE:
                he[:2] = 0.0
            half.append(he[None, :])
        elif s in (Shape.CONVEX, Shape.COMPOUND, Shape.MESH):
            continue  # primitives of collision.convex_phase (see the module docstring)
        else:
            raise ValueError(f"body {model.names[i]!r}: unknown shape code {s}")
    friction, restitution = np.asarray(model.friction, dtype=float), np.asarray(model.restitution, dtype=float)
    if not body:  # (a model of hulls, compounds and meshes alone has none of these primitives)
        return CollisionModel(np.zeros(0, np.intp), np.zeros(0, np.int8), np.zeros((0, 3)), np.zeros(0),
                              np.zeros((0, 3)), np.zeros(0), np.zeros(model.count),
                              np.asarray(model.inv_mass) <= 0.0, friction, restitution)
    body_a = np.concatenate(body).astype(np.intp)
    shape_a = np.concatenate(shape).astype(np.int8)
    offset_a = np.concatenate(offset)
    radius_a = np.concatenate(radius)
    half_a = np.concatenate(half)
    for name, arr in (("radius", radius_a), ("half extents", half_a)):
        bad = ~np.isfinite(arr).reshape(len(body_a), -1).all(1) | (arr.reshape(len(body_a), -1) < 0).any(1)
        if bad.any():
            raise ValueError(f"body {model.names[body_a[np.argmax(bad)]]!r}: invalid collision {name}")
    extent = np.where(shape_a == Shape.BOX, np.linalg.norm(half_a, axis=1), radius_a + half_a[:, 2])
    reach_p = np.linalg.norm(offset_a, axis=1) + extent
    body_reach = np.zeros(model.count)
    np.maximum.at(body_reach, body_a, reach_p)
    return CollisionModel(body=body_a, shape=shape_a, offset=offset_a, radius=radius_a, half_extents=half_a,
                          extent=extent, body_reach=body_reach, fixed_body=np.asarray(model.inv_mass) <= 0.0,
                          body_friction=friction, body_restitution=restitution)


class BodyMotion(NamedTuple):
    """The ``n`` bodies' poses and the velocities they will move with over the sub-step."""

    position: np.ndarray          # (n, 3) centres of mass x̄ [m]
    rotation: np.ndarray          # (n, 3, 3) R (body → world)
    velocity: np.ndarray          # (n, 3) v [m/s]
    angular_velocity: np.ndarray  # (n, 3) ω, world [rad/s]


class PrimitivePoses(NamedTuple):
    """Where the ``p`` primitives are this sub-step, and how far they may get."""

    centre: np.ndarray    # (p, 3) primitive centres, world [m]
    rotation: np.ndarray  # (n, 3, 3) the bodies' rotations (a primitive turns with its body)
    lo: np.ndarray        # (p, 3) AABB lower corners grown by the margin (NaN: the body is not finite)
    hi: np.ndarray        # (p, 3) AABB upper corners grown by the margin
    margin: np.ndarray    # (p,) speculative margin of the primitive's body [m]


@njit
def primitive_bounds(primitives, motion, h, speculative_distance):
    """The :class:`PrimitivePoses` of the :class:`CollisionModel` ``primitives`` moving with the
    :class:`BodyMotion` ``motion`` over a sub-step of ``h``: centres, AABBs grown by the speculative margin (NaN
    for a primitive whose bounds or margin are not finite), margins (their bodies').  Bundles as plain tuples
    from Python (see :mod:`cgp_core.jit`).

    The margin of a body is ``speculative_distance + h (|v| + |ω| · reach)`` (see the module docstring).
    The tight AABB of a box is its centre ± ``|R| h`` along the world axes (Ericson 4.2.6); a capsule's is its
    segment's box grown by the radius.
    """
    primitives, motion = CollisionModel(*primitives), BodyMotion(*motion)
    prim_body, offset, radius, half_extents = (primitives.body, primitives.offset, primitives.radius,
                                               primitives.half_extents)
    body_reach, position, rotation = primitives.body_reach, motion.position, motion.rotation
    velocity, angular_velocity = motion.velocity, motion.angular_velocity
    p = len(prim_body)
    centre = np.empty((p, 3))
    lo = np.empty((p, 3))
    hi = np.empty((p, 3))
    margin = np.empty(p)
    for k in range(p):
        b = prim_body[k]
        R = rotation[b]
        v, w = velocity[b], angular_velocity[b]
        speed = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) \
            + math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]) * body_reach[b]
        margin[k] = speculative_distance + h * speed
        sane = math.isfinite(margin[k])
        for r in range(3):
            centre[k, r] = position[b, r] + R[r, 0] * offset[k, 0] + R[r, 1] * offset[k, 1] + R[r, 2] * offset[k, 2]
            half = abs(R[r, 0]) * half_extents[k, 0] + abs(R[r, 1]) * half_extents[k, 1] \
                + abs(R[r, 2]) * half_extents[k, 2] + radius[k]
            lo[k, r] = centre[k, r] - half - margin[k]
            hi[k, r] = centre[k, r] + half + margin[k]
            sane = sane and math.isfinite(lo[k, r]) and math.isfinite(hi[k, r])
        if not sane:
            # a body whose state or speed went non-finite (a numerical blow-up, which World contains after the
            # tick) takes no part in collisions rather than dragging others along: NaN bounds overlap nothing
            lo[k, :] = np.nan
            hi[k, :] = np.nan
    return PrimitivePoses(centre, rotation, lo, hi, margin)


def primitive_aabbs(cmodel: CollisionModel, position: np.ndarray, rotation: np.ndarray):
    """Tight world AABBs ``lo, hi (p, 3)`` of the primitives for body poses ``position (n, 3)``, ``rotation
    (n, 3, 3)`` (:func:`primitive_bounds` with no margin)."""
    n = len(position)
    motion = BodyMotion(np.ascontiguousarray(position, dtype=float), np.ascontiguousarray(rotation, dtype=float),
                        np.zeros((n, 3)), np.zeros((n, 3)))
    poses = primitive_bounds(tuple(cmodel), tuple(motion), 0.0, 0.0)
    return poses.lo, poses.hi

"""Collision primitives: every body as one or more convex pieces the narrow phase knows.

Sphere, box and capsule bodies are one primitive each, centred on the body's COM.  A PARTICLES body (the
lecture's discrete body) is one small sphere of ``model.radius`` per particle, at the particle's body-frame
offset — so a particle body collides exactly as it is drawn.  The broad and narrow phases work on primitives;
contacts are reported per body.

Built once per :class:`~cgp_core.bodies.BodyModel` (the model is static); :func:`primitive_poses` places the
primitives at the bodies' current poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..bodies import BodyModel, Shape


@dataclass
class CollisionModel:
    """``p`` primitives of ``n`` bodies.

    Attributes (shapes):
        body:          (p,) intp — owning body.
        shape:         (p,) int8 — ``Shape.SPHERE``, ``BOX`` or ``CAPSULE`` (particles become spheres).
        offset:        (p, 3) — primitive centre in the body frame (0 except for particles).
        radius:        (p,) — sphere / capsule radius (0 for boxes).
        half_extents:  (p, 3) — box half sizes; capsule (0, 0, half_length); sphere zeros.
        extent:        (p,) — radius of the primitive's bounding sphere about its centre.
        body_reach:    (n,) — farthest distance from a body's COM to its surface: bounds how far any surface
                       point moves when the body turns by an angle θ (≤ reach · θ).
        fixed_body:    (n,) bool — the body never moves (pairs of two fixed bodies are skipped).

    Derived (set on construction, for the per-sub-step loops):
        movable:       (p,) bool — the owning body moves.
        by_shape:      tuple of (shape, (p_s,) indices of its primitives), for each shape present.
    """

    body: np.ndarray
    shape: np.ndarray
    offset: np.ndarray
    radius: np.ndarray
    half_extents: np.ndarray
    extent: np.ndarray
    body_reach: np.ndarray
    fixed_body: np.ndarray

    def __post_init__(self) -> None:
        self.movable = ~self.fixed_body[self.body]
        self.by_shape = tuple((int(shape), np.flatnonzero(self.shape == shape))
                              for shape in (Shape.SPHERE, Shape.BOX, Shape.CAPSULE) if (self.shape == shape).any())

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
        else:
            raise ValueError(f"body {model.names[i]!r}: unknown shape code {s}")
    if not body:
        return CollisionModel(np.zeros(0, np.intp), np.zeros(0, np.int8), np.zeros((0, 3)), np.zeros(0),
                              np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0, bool))
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
                          extent=extent, body_reach=body_reach, fixed_body=np.asarray(model.inv_mass) <= 0.0)


def primitive_poses(cmodel: CollisionModel, position: np.ndarray, rotation: np.ndarray):
    """World centres ``(p, 3)`` and rotations ``(p, 3, 3)`` of the primitives for body poses
    ``position (n, 3)``, ``rotation (n, 3, 3)``."""
    R = rotation[cmodel.body]
    centre = position[cmodel.body] + np.einsum("pij,pj->pi", R, cmodel.offset)
    return centre, R


def primitive_aabbs(cmodel: CollisionModel, centre: np.ndarray, R: np.ndarray):
    """Tight world AABBs ``lo, hi (p, 3)`` (Ericson 4.2.6: the box's half widths along world axes are
    ``|R| h``; a capsule is its segment's box grown by the radius)."""
    half = np.einsum("pij,pj->pi", np.abs(R), cmodel.half_extents) + cmodel.radius[:, None]
    return centre - half, centre + half

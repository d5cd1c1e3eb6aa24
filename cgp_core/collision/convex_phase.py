"""The convex stage of contact detection (issue 25): every primitive pair in which a convex hull, a compound body's
part or a static triangle mesh takes part, and those shapes against the ground.  It runs after
:func:`.detector.narrow_phase` (which keeps the spheres, boxes, capsules and particle sets among themselves,
unchanged) and its contacts are appended to the same contact set.

**Primitives** (:class:`ShapeModel`, built once per body model).  The detector's own primitives
(:class:`.primitives.CollisionModel`: spheres, boxes, capsules, particles) come first, numbered ``0 .. p − 1``; this
stage's follow, ``p .. P − 1``:

- a ``convex`` body: one HULL primitive (an index into the model's :class:`.convex.HullSet`), at the COM;
- a ``compound`` body: one primitive per part, each with its body-frame offset **and its own rotation** (the
  part's axes in the body's): SPHERE, BOX, CAPSULE or HULL;
- a ``mesh`` body (fixed): one MESH primitive (an index into the packed static meshes, :class:`MeshSet`).

Every primitive of every body is posed here each sub-step (:func:`pose_shapes`: world centre and world rotation
``R_body · R_part``) and bounded like the others (an AABB grown by the body's speculative margin): a hull's AABB as
its local box (its vertices' bounding box in its own frame) turned, world half sizes |R| e, as Bullet and PhysX bound
a hull: O(1) per hull where turning every vertex cost most of a robot world's detection (512 link hulls of ~330
vertices), a little looser than the turned vertices' own box (a few more candidate pairs reach GJK, whose contacts
are the same); a mesh's the same way.

**Pairs** (side A first; a mesh or the ground is always A), one compiled stage, :func:`convex_phase`:

=====================  ===============================================================================
sphere / box / capsule  the exact kernels of :mod:`.narrowphase` / :mod:`.box_box`, called with each
(compound parts)        primitive's own world rotation — so a compound's box part is collided as a box
                        (SAT with face clipping), not as a hull: the kernels take the rotation as an
                        argument, the detector's loop only ever passed the body's
box – hull              the box as its 8-corner hull (:func:`.convex.box_hull`) → hull–hull: the hull
                        manifold of a box equals the box kernel's (tests/test_hull_manifold.py), so there is
                        no separate box–hull path to keep exact
hull – hull             :func:`.manifold.hull_hull_contacts` (SAT faces + GJK/EPA, face clipping, ≤ 4 points)
hull – sphere / capsule :func:`.manifold.hull_capsule_contacts` (GJK on the cores, EPA when the core is inside)
mesh – sphere / capsule :func:`.mesh_contacts.mesh_capsule_contacts` (BVH query, per-triangle GJK, ghost edges)
mesh – box / hull       :func:`.mesh_contacts.mesh_hull_contacts`; the points of one mesh–shape pair are
                        reduced to 4 (:func:`reduce_mesh_rows`): a hull resting across several triangles is
                        then one ≤ 4-point manifold, which the solver solves as a block (no rocking)
ground – each           :func:`.manifold.plane_hull_contacts` for hulls; the plane kernels for the parts
=====================  ===============================================================================

**Contact keys.**  ``key // FEATURE_SLOTS`` is the primitive pair the solver warm-starts by (it matches the
nearest old point of the same pair): pair ids here start after the detector's (``(p + 1)²``), as
``(a + 1)(P + 1) + b`` (a = −1: the ground).  The manifold kernels name their points by 64-bit geometric features
(face, incident face, clip code; triangle; vertex pairs); a pair gives at most 4 points, so the feature put into
the key is the point's rank among its pair's points in the order of those ids — below ``FEATURE_SLOTS``, and
stable while the same features make the manifold.

**Continuous collision: which pairs use what, and why.**  Every pair here uses the speculative margin
(:mod:`.detector`: a pair is reported when its gap may close within the sub-step, ``margin = speculative_distance +
h (|v| + |ω| reach)``, passed to the manifold kernels, which keep a point when its separation is below it; the
solver then lets the gap close exactly and no further).  It stops fast *translation* of any shape against any
shape, whatever the speed — a ball or a hull at 300 m/s against a 5 mm hull wall or a single mesh triangle at 30,
60 and 240 Hz (the ``bullet`` scene): the hull kernels report a lower bound of the gap when apart (the face
contact is lowered to the SAT separation), so a fast approach is never let through.  What the margin cannot
follow is fast *rotation*: the contact points are those of the start-of-step pose, and a thin shape turning by a
large angle in one sub-step can sweep through thin geometry whose closest points did not approach at the start.
So a body turning by more than :data:`TOI_ANGLE` in the sub-step and near a fixed hull, box or mesh triangle gets
a *time of impact* (:mod:`.toi`, conservative advancement, Ericson 5.5) after the integrator has moved it
(:meth:`.detector.CollisionDetector.sweep_fast_rotation`, Box2D v3's continuous step against static geometry): if it
touched within the sub-step, it is put back at its pose at that time (momenta kept: the next sub-step's contact
stops it).  Pairs of two movable bodies, and the ground (an infinite half space: penetration recovery pushes a
body back up whatever went through it), use the margin alone.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..bodies import BodyModel, Shape
from ..jit import njit
from .box_box import box_box_contacts
from .bvh import StaticMesh, TriangleMesh, bvh_overlap
from .contacts import FEATURE_SLOTS, GROUND, ContactSet
from .convex import BRUTE_FORCE_SUPPORT_VERTICES, ConvexPolyhedron, HullSet, box_hull, hull_of, posed, support_index
from .manifold import hull_capsule_contacts, hull_hull_contacts, plane_hull_contacts, reduce_to_four
from .materials import combine_friction, combine_restitution
from .mesh_contacts import add_point, cells_near, first_item, mesh_capsule_contacts, mesh_hull_contacts, near_points
from .narrowphase import (
    Box,
    Capsule,
    ContactBuffer,
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
from .primitives import BodyMotion, CollisionModel
from .toi import MovingCore, time_of_impact

SPHERE, BOX, CAPSULE = int(Shape.SPHERE), int(Shape.BOX), int(Shape.CAPSULE)
HULL, MESH = int(Shape.CONVEX), int(Shape.MESH)

#: a body turning by more than this angle [rad] in one sub-step (|ω| h) next to fixed geometry gets a time of
#: impact after the integrator (see the module docstring): 0.1 rad per 1/240 s is 24 rad/s, ~4 turns a second —
#: below it the start-of-step contact points move by at most 0.1 · reach within the step, which the margin's
#: h |ω| reach term covers as long as the motion is close to a straight line
TOI_ANGLE = 0.1
#: conservative advancement stops this far [m] short of contact (Box2D's target separation: the contact that
#: stops the body is then a speculative one, never a deep one)
TOI_TARGET = 1e-3
TOI_TOLERANCE = 2.5e-4

#: mesh pairs: the BVH query's first scratch size, grown 8x when a query finds more triangles (a box resting on a
#: 1 cm grid has 20,000 under it: one query more, the first time — the caller keeps the grown buffer, see
#: :func:`convex_phase`)
MESH_CANDIDATES = 4096


# ---- the static data: hulls, meshes, primitives ---------------------------------------------------------------

class MeshSet(NamedTuple):
    """``k`` static meshes packed as CSR arrays, every index inside a mesh local to it (as :class:`.bvh.StaticMesh`
    has them), so that one compiled kernel can slice mesh i (:func:`mesh_of`)."""

    vertex_start: np.ndarray         # (k + 1,) int64 — mesh i's vertices: rows vertex_start[i] .. [i + 1] − 1
    vertices: np.ndarray             # (V, 3) in the mesh's frame
    triangle_start: np.ndarray       # (k + 1,) int64 — mesh i's triangles (and their per-triangle rows below)
    triangles: np.ndarray            # (T, 3) int64 local vertex indices
    active_edges: np.ndarray         # (T,) uint8 (:func:`.bvh.active_edges`)
    triangle_order: np.ndarray       # (T,) int64 local triangle indices (the BVH's slots)
    triangle_lo: np.ndarray          # (T, 3) each triangle's box
    triangle_hi: np.ndarray          # (T, 3)
    node_start: np.ndarray           # (k + 1,) int64 — mesh i's BVH nodes
    node_lo: np.ndarray              # (N, 3)
    node_hi: np.ndarray              # (N, 3)
    node_child_or_first: np.ndarray  # (N,) int64 local node / slot
    node_count: np.ndarray           # (N,) int64
    centre: np.ndarray               # (k, 3) the centre of each mesh's vertex box, its frame (for its bounds)
    half: np.ndarray                 # (k, 3) that box's half sizes
    two_sided: np.ndarray            # (k,) bool — False: only the front faces push (a terrain, a closed mesh)


class ShapePrimitives(NamedTuple):
    """Every primitive, the detector's first (see the module docstring); P of them, of ``n`` bodies."""

    body: np.ndarray      # (P,) int64 owning body
    kind: np.ndarray      # (P,) int64 SPHERE, BOX, CAPSULE, HULL or MESH
    offset: np.ndarray    # (P, 3) centre in the body frame
    rotation: np.ndarray  # (P, 3, 3) the primitive's axes in body axes (identity but for compound parts)
    radius: np.ndarray    # (P,) sphere / capsule radius
    half: np.ndarray      # (P, 3) box half sizes; capsule (0, 0, half length); a HULL's box (below): its half sizes
    hull: np.ndarray      # (P,) int64 a HULL's hull in the :class:`.convex.HullSet`, a BOX's 8-corner hull, else −1
    mesh: np.ndarray      # (P,) int64 a MESH's mesh in the :class:`MeshSet`, else −1
    box_centre: np.ndarray  # (P, 3) a HULL's box (its vertices' bounding box in the primitive's frame): its centre
    first_new: np.int64   # the first primitive of this stage (= the detector's count p)


class ShapeModel(NamedTuple):
    """The convex stage's view of a body model (built once per model, :func:`build_shape_model`); the detector
    hands it to the compiled kernels as a plain tuple of plain tuples (:meth:`plain`)."""

    primitives: ShapePrimitives
    hulls: HullSet                # the hulls of convex bodies and parts, and of every box that may meet one
    meshes: MeshSet
    body_reach: np.ndarray        # (n,) farthest distance from each body's COM to its surface (every primitive)
    body_friction: np.ndarray     # (n,) the bodies' Coulomb μ
    body_restitution: np.ndarray  # (n,) their coefficients of restitution
    fixed_body: np.ndarray        # (n,) bool — the body never moves

    @property
    def count(self) -> int:
        return len(self.primitives.body)

    @property
    def first_new(self) -> int:
        return int(self.primitives.first_new)

    def plain(self) -> tuple:
        """The same as plain tuples (see "Bundles" in :mod:`cgp_core.jit`)."""
        return tuple(tuple(field) if isinstance(field, tuple) else field for field in self)


class ShapePoses(NamedTuple):
    """Where the P primitives are this sub-step (:func:`pose_shapes`), and how far they may get."""

    centre: np.ndarray    # (P, 3) world centres [m]
    rotation: np.ndarray  # (P, 3, 3) world axes: R_body · R_part
    lo: np.ndarray        # (P, 3) AABB lower corners grown by the margin (NaN: the body is not finite)
    hi: np.ndarray        # (P, 3) upper corners
    margin: np.ndarray    # (P,) speculative margin of the primitive's body [m]


def pack_meshes(meshes: list[StaticMesh], two_sided: list[bool]) -> MeshSet:
    """The :class:`MeshSet` of ``meshes`` (possibly none)."""
    def offsets(sizes):
        start = np.zeros(len(sizes) + 1, np.int64)
        start[1:] = np.cumsum(sizes)
        return start

    def cat(arrays, empty):
        return np.ascontiguousarray(np.concatenate(arrays)) if arrays else empty

    f3, i3 = np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    i1 = np.zeros(0, np.int64)
    centre = np.array([0.5 * (m.vertices.min(0) + m.vertices.max(0)) for m in meshes]).reshape(-1, 3)
    half = np.array([0.5 * (m.vertices.max(0) - m.vertices.min(0)) for m in meshes]).reshape(-1, 3)
    return MeshSet(offsets([len(m.vertices) for m in meshes]), cat([m.vertices for m in meshes], f3),
                  offsets([len(m.triangles) for m in meshes]), cat([m.triangles for m in meshes], i3),
                   cat([m.active_edges for m in meshes], np.zeros(0, np.uint8)),
                   cat([m.triangle_order for m in meshes], i1), cat([m.triangle_lo for m in meshes], f3),
                   cat([m.triangle_hi for m in meshes], f3), offsets([len(m.node_count) for m in meshes]),
                   cat([m.node_lo for m in meshes], f3), cat([m.node_hi for m in meshes], f3),
                   cat([m.node_child_or_first for m in meshes], i1), cat([m.node_count for m in meshes], i1),
                   centre, half, np.array(two_sided, dtype=np.bool_).reshape(-1))


def build_shape_model(model: BodyModel, cm: CollisionModel) -> ShapeModel:
    """The convex stage's primitives of ``model`` after the detector's ``cm`` (see the module docstring)."""
    p = cm.count
    body, kind, offset, rotation, radius, half, hull, mesh = [], [], [], [], [], [], [], []
    hulls: list[ConvexPolyhedron] = []
    box_hulls: dict[tuple, int] = {}
    meshes, two_sided = [], []

    def box_index(h) -> int:
        ident = tuple(np.round(np.asarray(h, float), 15))
        if ident not in box_hulls:
            box_hulls[ident] = len(hulls)
            hulls.append(box_hull(h))
        return box_hulls[ident]

    distinct: dict[tuple, int] = {}

    def hull_index(h: ConvexPolyhedron) -> int:
        # one entry per distinct hull: the copies of one mesh (a pile of them) share their arrays, so the kernels
        # walk one hull's vertices and edges, not each copy's (issue 38: 300 copies of a 1,000-vertex hull)
        ident = tuple(np.ascontiguousarray(a).tobytes() for a in (h.vertices, h.face_plane, h.face_vertex_start,
                                                                   h.face_vertices, h.adjacency_start, h.adjacency))
        if ident not in distinct:
            distinct[ident] = len(hulls)
            hulls.append(h)
        return distinct[ident]

    def add(b, k, o, R, r, he, hi, mi):
        body.append(b)
        kind.append(k)
        offset.append(o)
        rotation.append(R)
        radius.append(r)
        half.append(he)
        hull.append(hi)
        mesh.append(mi)

    eye = np.eye(3)
    for i in range(model.count):
        s = int(model.shape[i])
        if s == Shape.CONVEX:
            add(i, HULL, np.zeros(3), eye, 0.0, _box_half(model.hulls[i]), hull_index(model.hulls[i]), -1)
        elif s == Shape.COMPOUND:
            parts = model.parts[i]
            for k in range(parts.count):
                ks = int(parts.shape[k])
                he = np.asarray(parts.half_extents[k], float)
                if ks == Shape.CONVEX:
                    add(i, HULL, parts.position[k], parts.rotation[k], 0.0, _box_half(parts.hulls[k]),
                        hull_index(parts.hulls[k]), -1)
                else:
                    add(i, ks, parts.position[k], parts.rotation[k], float(parts.radius[k]), he,
                        box_index(he) if ks == BOX else -1, -1)
        elif s == Shape.MESH:
            add(i, MESH, np.zeros(3), eye, 0.0, np.zeros(3), -1, len(meshes))
            meshes.append(model.meshes[i])
            two_sided.append(bool(model.two_sided[i]))
    # the detector's primitives, first; its boxes get a hull when they may meet a hull or a mesh
    any_new = bool(body)
    old_hull = [box_index(cm.half_extents[k]) if any_new and int(cm.shape[k]) == BOX else -1 for k in range(p)]
    prims = ShapePrimitives(
        body=np.concatenate([cm.body, np.array(body, np.int64)]).astype(np.int64),
        kind=np.concatenate([cm.shape.astype(np.int64), np.array(kind, np.int64)]),
        offset=np.ascontiguousarray(np.concatenate([cm.offset, np.array(offset, float).reshape(-1, 3)])),
        rotation=np.ascontiguousarray(np.concatenate([np.tile(eye, (p, 1, 1)),
                                                      np.array(rotation, float).reshape(-1, 3, 3)])),
        radius=np.concatenate([cm.radius, np.array(radius, float)]),
        half=np.ascontiguousarray(np.concatenate([cm.half_extents, np.array(half, float).reshape(-1, 3)])),
        hull=np.array(old_hull + hull, np.int64),
        mesh=np.concatenate([np.full(p, -1, np.int64), np.array(mesh, np.int64)]),
        box_centre=np.zeros((p + len(body), 3)),
        first_new=np.int64(p))
    for q in range(p, len(prims.body)):  # a hull's box: its centre (its half sizes are in ``half``)
        if prims.kind[q] == HULL:
            prims.box_centre[q] = 0.5 * (hulls[prims.hull[q]].vertices.min(0) + hulls[prims.hull[q]].vertices.max(0))
    hull_tuple = HullSet.from_hulls(hulls)
    # reach: the detector's, and this stage's primitives' farthest points from their bodies' COMs
    reach = cm.body_reach.copy() if len(cm.body_reach) == model.count else np.zeros(model.count)
    for q in range(p, len(prims.body)):
        b, k = prims.body[q], prims.kind[q]
        if k == HULL:
            h = prims.hull[q]
            v = hull_tuple.vertices[hull_tuple.vertex_start[h]:hull_tuple.vertex_start[h + 1]]
            far = np.linalg.norm(v @ prims.rotation[q].T + prims.offset[q], axis=1).max()
        elif k == MESH:
            m = model.meshes[b]
            far = np.linalg.norm(m.vertices, axis=1).max()
        else:
            extent = np.linalg.norm(prims.half[q]) if k == BOX else prims.radius[q] + prims.half[q, 2]
            far = np.linalg.norm(prims.offset[q]) + extent
        reach[b] = max(reach[b], far)
    return ShapeModel(prims, hull_tuple, pack_meshes(meshes, two_sided), reach, cm.body_friction,
                      cm.body_restitution, cm.fixed_body)


def _box_half(hull: ConvexPolyhedron) -> np.ndarray:
    """The half sizes of the bounding box of ``hull``'s vertices, in its own frame."""
    return 0.5 * (hull.vertices.max(0) - hull.vertices.min(0))


# ---- poses and bounds --------------------------------------------------------------------------------------

@njit
def pose_shapes(shapes, motion, h, speculative_distance, poses):
    """World pose of every primitive of the :class:`ShapeModel` ``shapes`` moving with the
    :class:`.primitives.BodyMotion` ``motion``, written into the :class:`ShapePoses` ``poses`` (P rows, whose first
    ``first_new`` rows of centre, lo, hi and margin already hold the detector's
    :func:`.primitives.primitive_bounds`): the rotation R_body · R_part of all; the centre, the AABB grown by the
    margin and the margin of this stage's primitives (a hull's AABB: its local box turned, not its vertices'). A
    primitive whose body's state or speed is not finite gets NaN bounds (it overlaps nothing), as there. Bundles as
    plain tuples from Python (see :mod:`cgp_core.jit`)."""
    shapes, motion, poses = ShapeModel(*shapes), BodyMotion(*motion), ShapePoses(*poses)
    prims, meshes = ShapePrimitives(*shapes.primitives), MeshSet(*shapes.meshes)
    body_reach, position, rotation = shapes.body_reach, motion.position, motion.rotation
    velocity, angular_velocity = motion.velocity, motion.angular_velocity
    centre, prim_rotation, lo, hi, margin = poses
    P = len(prims.body)
    for k in range(P):
        b = prims.body[k]
        R = rotation[b]
        for r in range(3):
            for c in range(3):
                prim_rotation[k, r, c] = R[r, 0] * prims.rotation[k, 0, c] + R[r, 1] * prims.rotation[k, 1, c] \
                    + R[r, 2] * prims.rotation[k, 2, c]
    for k in range(prims.first_new, P):
        b = prims.body[k]
        R = rotation[b]
        Rk = prim_rotation[k]
        v, w = velocity[b], angular_velocity[b]
        speed = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) \
            + math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]) * body_reach[b]
        margin[k] = speculative_distance + h * speed
        for r in range(3):
            centre[k, r] = position[b, r] + R[r, 0] * prims.offset[k, 0] + R[r, 1] * prims.offset[k, 1] \
                + R[r, 2] * prims.offset[k, 2]
        kind = prims.kind[k]
        # the primitive's local box, turned (world half sizes |R| e: Bullet's and PhysX's bound of a hull, O(1) and
        # a little looser than the turned vertices' own box)
        if kind == MESH:
            mk = prims.mesh[k]
            cx, cy, cz = meshes.centre[mk, 0], meshes.centre[mk, 1], meshes.centre[mk, 2]
            ex, ey, ez, rad = meshes.half[mk, 0], meshes.half[mk, 1], meshes.half[mk, 2], 0.0
        else:  # a hull's box (its vertices'), a box, a sphere's or a capsule's core
            cx, cy, cz = prims.box_centre[k, 0], prims.box_centre[k, 1], prims.box_centre[k, 2]
            ex, ey, ez, rad = prims.half[k, 0], prims.half[k, 1], prims.half[k, 2], prims.radius[k]
        for r in range(3):
            mid = centre[k, r] + Rk[r, 0] * cx + Rk[r, 1] * cy + Rk[r, 2] * cz
            extent = abs(Rk[r, 0]) * ex + abs(Rk[r, 1]) * ey + abs(Rk[r, 2]) * ez + rad
            lo[k, r] = mid - extent - margin[k]
            hi[k, r] = mid + extent + margin[k]
        sane = math.isfinite(margin[k])
        for r in range(3):
            sane = sane and math.isfinite(lo[k, r]) and math.isfinite(hi[k, r])
        if not sane:
            lo[k, :] = np.nan
            hi[k, :] = np.nan


@njit
def tighten_hull_bounds(kind, hull, hulls, first_new, poses, pair_i, pair_j, ground, extreme):
    """The exact AABB (its turned vertices' extremes, grown by the margin) of every hull that the cheap bound of
    :func:`pose_shapes` (its local box turned) puts in a candidate pair ``pair_i, pair_j`` (q,) int64 or, with
    ``ground``, near the ground; written into ``poses`` (:class:`ShapePoses`, in place); and the pairs whose exact
    AABBs still overlap, in the order given.  So the pairs and the ground tests that reach the narrow phase are those
    of exact bounds, and only the hulls near something look at their vertices.  ``kind``, ``hull``, ``first_new``:
    those of :class:`ShapePrimitives`; ``hulls``: the :class:`.convex.HullSet`; ``poses`` as a plain tuple from
    Python.

    Each extreme is a support point (:func:`.convex.support_index`): a hull of more than
    :data:`.convex.BRUTE_FORCE_SUPPORT_VERTICES` vertices climbs its edge graph from ``extreme (P, 6)`` int64 — the
    local vertex found last time per primitive and direction (−x, +x, −y, +y, −z, +z), updated here — so a hull's
    bound costs a few steps, not all its vertices (issue 38: 300 hulls of 1,000 vertices on the ground).  The
    extreme's coordinate is the same product as the brute-force maximum's, so the bound is the same."""
    centre, prim_rotation, lo, hi, margin = poses
    vertex_start, vertices, adjacency_start, adjacency = hulls[0], hulls[1], hulls[2], hulls[3]
    P = len(kind)
    near = np.zeros(P, np.bool_)
    for q in range(len(pair_i)):
        near[pair_i[q]] = True
        near[pair_j[q]] = True
    if ground:
        for k in range(first_new, P):
            if lo[k, 2] < margin[k]:
                near[k] = True
    for k in range(first_new, P):
        if not near[k] or kind[k] != HULL or not math.isfinite(lo[k, 0]):
            continue
        Rk = prim_rotation[k]
        h0, h1 = vertex_start[hull[k]], vertex_start[hull[k] + 1]
        if h1 - h0 > BRUTE_FORCE_SUPPORT_VERTICES and len(adjacency) > 0:
            local, starts = vertices[h0:h1], adjacency_start[h0:h1 + 1]
            for r in range(3):
                i = support_index(local, starts, adjacency, -Rk[r, 0], -Rk[r, 1], -Rk[r, 2], extreme[k, 2 * r])
                extreme[k, 2 * r] = i
                low = Rk[r, 0] * local[i, 0] + Rk[r, 1] * local[i, 1] + Rk[r, 2] * local[i, 2]
                i = support_index(local, starts, adjacency, Rk[r, 0], Rk[r, 1], Rk[r, 2], extreme[k, 2 * r + 1])
                extreme[k, 2 * r + 1] = i
                high = Rk[r, 0] * local[i, 0] + Rk[r, 1] * local[i, 1] + Rk[r, 2] * local[i, 2]
                lo[k, r] = centre[k, r] + low - margin[k]
                hi[k, r] = centre[k, r] + high + margin[k]
        else:
            for r in range(3):
                low, high = np.inf, -np.inf
                for i in range(h0, h1):
                    x = Rk[r, 0] * vertices[i, 0] + Rk[r, 1] * vertices[i, 1] + Rk[r, 2] * vertices[i, 2]
                    low = min(low, x)
                    high = max(high, x)
                lo[k, r] = centre[k, r] + low - margin[k]
                hi[k, r] = centre[k, r] + high + margin[k]
        sane = True
        for r in range(3):
            sane = sane and math.isfinite(lo[k, r]) and math.isfinite(hi[k, r])
        if not sane:
            lo[k, :] = np.nan
            hi[k, :] = np.nan
    keep_i = np.empty(len(pair_i), np.int64)
    keep_j = np.empty(len(pair_i), np.int64)
    count = 0
    for q in range(len(pair_i)):
        i, j = pair_i[q], pair_j[q]
        if lo[i, 0] <= hi[j, 0] and lo[j, 0] <= hi[i, 0] and lo[i, 1] <= hi[j, 1] and lo[j, 1] <= hi[i, 1] \
                and lo[i, 2] <= hi[j, 2] and lo[j, 2] <= hi[i, 2]:
            keep_i[count] = i
            keep_j[count] = j
            count += 1
    return keep_i[:count], keep_j[:count]


# ---- the stage -------------------------------------------------------------------------------------------------

@njit
def mesh_of(meshes, k):
    """Mesh ``k`` of the :class:`MeshSet` as a :class:`.bvh.TriangleMesh` (slices, no copies)."""
    v0, v1 = meshes.vertex_start[k], meshes.vertex_start[k + 1]
    t0, t1 = meshes.triangle_start[k], meshes.triangle_start[k + 1]
    n0, n1 = meshes.node_start[k], meshes.node_start[k + 1]
    return TriangleMesh(meshes.vertices[v0:v1], meshes.triangles[t0:t1], meshes.active_edges[t0:t1],
                        meshes.node_lo[n0:n1], meshes.node_hi[n0:n1], meshes.node_child_or_first[n0:n1],
                        meshes.node_count[n0:n1], meshes.triangle_order[t0:t1], meshes.triangle_lo[t0:t1],
                        meshes.triangle_hi[t0:t1])


@njit
def _segment(centre, R, half_length, out):
    """A sphere's (half_length 0) or capsule's core: its segment's ends ``out (2, 3)`` along the axis R[:, 2]."""
    for r in range(3):
        out[0, r] = centre[r] - R[r, 2] * half_length
        out[1, r] = centre[r] + R[r, 2] * half_length


@njit
def _column(R, k, out):
    out[0] = R[0, k]
    out[1] = R[1, k]
    out[2] = R[2, k]


#: the rows a ground or pair contact may add (up to 4 points): a numpy integer, not a literal 4, for which numba
#: compiled :func:`_grown` once more (its other call passes a computed count; issue 34)
PAIR_ROWS = np.int64(4)


@njit
def _grown(out, owner_a, owner_b, m, need):
    """The :class:`.narrowphase.ContactBuffer` ``out`` and the rows' primitives ``owner_a``, ``owner_b`` with room
    for ``need`` more rows after row ``m`` (doubled when short)."""
    if m + need <= len(out.separation):
        return out, owner_a, owner_b
    cap = max(2 * len(out.separation), m + need)
    grown = ContactBuffer(np.empty((cap, 3)), np.empty(cap), np.empty((cap, 3)), np.empty(cap, np.int64))
    a2, b2 = np.empty(cap, np.int64), np.empty(cap, np.int64)
    # element by element, not grown.point[:m] = out.point[:m]: numba compiles a slice copy with a shape check whose
    # error message (formatting the shapes) alone costs ~1 s to compile (issue 34)
    for r in range(m):
        for k in range(3):
            grown.normal[r, k] = out.normal[r, k]
            grown.point[r, k] = out.point[r, k]
        grown.separation[r] = out.separation[r]
        grown.feature[r] = out.feature[r]
        a2[r] = owner_a[r]
        b2[r] = owner_b[r]
    return grown, a2, b2


@njit
def _copy_row(out, to, row):
    for r in range(3):
        out.normal[to, r] = out.normal[row, r]
        out.point[to, r] = out.point[row, r]
    out.separation[to] = out.separation[row]
    out.feature[to] = out.feature[row]


@njit
def merge_close_rows(out, start, m):
    """Rows ``start .. m − 1`` of ``out`` without near-duplicates: a hull vertex over a mesh vertex or edge is
    reported by each triangle around it, at (almost) the same point with (slightly) different normals and
    separations — two such rows make the solver's block singular with inconsistent targets.  Rows whose points are
    within 1e-3 of their span (+ 10 µm) of an earlier row's are merged into it, the deeper of the two kept (the
    points are the geometric midway points: a separation may be lowered to a face's SAT value, the point is not).
    Returns the new end row."""
    point, separation = out.point, out.separation
    k = m - start
    if k < 2:
        return m
    at = np.empty((k, 3))
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for s in range(k):
        for r in range(3):
            at[s, r] = point[start + s, r]
            lo[r] = min(lo[r], at[s, r])
            hi[r] = max(hi[r], at[s, r])
    span = max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2])
    radius = 1e-3 * span + 1e-5
    close = radius ** 2
    kept = start
    kept_at = np.empty((k, 3))
    grid = near_points(k, lo, radius, span)  # the kept rows (item: kept row − start), found in O(1)
    cells = np.empty((8, 3), np.int64)
    for s in range(start, m):
        twin = -1
        q = s - start
        for c in range(cells_near(grid, at[q, 0], at[q, 1], at[q, 2], radius, cells)):  # the first close kept row
            u = first_item(grid, cells, c)
            while u >= 0:
                if twin < 0 or start + u < twin:
                    d2 = (at[q, 0] - kept_at[u, 0]) ** 2 + (at[q, 1] - kept_at[u, 1]) ** 2 \
                        + (at[q, 2] - kept_at[u, 2]) ** 2
                    if d2 <= close:
                        twin = start + u
                u = grid.next[u]
        if twin < 0:
            if kept != s:
                _copy_row(out, kept, s)
            kept_at[kept - start] = at[q]
            add_point(grid, kept - start, at[q, 0], at[q, 1], at[q, 2])
            kept += 1
        elif separation[s] < separation[twin]:
            _copy_row(out, twin, s)
    return kept


#: :func:`reduce_mesh_rows`: a kept point within this of the deepest point's separation [m] counts as the deepest
DEEPEST_TIE = 1e-9


@njit
def reduce_mesh_rows(out, start, m):
    """At most 4 of the rows ``start .. m − 1`` of ``out`` (one mesh–shape pair's points, from several triangles),
    near-duplicates merged first (:func:`merge_close_rows`): those extreme along the diagonals of the plane across
    their mean normal (:func:`.manifold.reduce_to_four`, the box kernel's rule), and the deepest point always
    (unless a kept point is as deep within :data:`DEEPEST_TIE`); each keeps its own normal.  Returns the new end row."""
    m = merge_close_rows(out, start, m)
    normal, separation, point = out.normal, out.separation, out.point
    k = m - start
    if k <= 4:
        return m
    nx = ny = nz = 0.0
    deepest = start
    for s in range(start, m):
        nx += normal[s, 0]
        ny += normal[s, 1]
        nz += normal[s, 2]
        if separation[s] < separation[deepest]:
            deepest = s
    length = math.sqrt(nx * nx + ny * ny + nz * nz)
    if length < 1e-12:
        nx, ny, nz = normal[deepest, 0], normal[deepest, 1], normal[deepest, 2]
    else:
        nx, ny, nz = nx / length, ny / length, nz / length
    # a tangent basis of the mean normal (Duff et al. 2017)
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    bb = nx * ny * a
    ux, uy, uz = 1.0 + sign * nx * nx * a, sign * bb, -sign * nx
    vx, vy, vz = bb, sign + ny * ny * a, -ny
    X, Y = np.empty(k), np.empty(k)
    valid = np.ones(k, np.bool_)
    umin = vmin = np.inf
    umax = vmax = -np.inf
    for s in range(k):
        X[s] = ux * point[start + s, 0] + uy * point[start + s, 1] + uz * point[start + s, 2]
        Y[s] = vx * point[start + s, 0] + vy * point[start + s, 1] + vz * point[start + s, 2]
        umin, umax, vmin, vmax = min(umin, X[s]), max(umax, X[s]), min(vmin, Y[s]), max(vmax, Y[s])
    reduce_to_four(X, Y, max(0.5 * (umax - umin), 1e-12), max(0.5 * (vmax - vmin), 1e-12), valid)
    d = deepest - start
    for s in range(k):  # a kept point as deep to round-off stands for it (the corners of a box resting on a flat
        # grid are as deep as its every other point: the deepest by round-off alone would change from step to step)
        if valid[s] and separation[start + s] <= separation[deepest] + DEEPEST_TIE:
            d = s
            break
    if not valid[d]:  # the deepest point replaces the kept point nearest to it
        near, best = -1, np.inf
        for s in range(k):
            if valid[s]:
                dist = (X[s] - X[d]) ** 2 + (Y[s] - Y[d]) ** 2
                if dist < best:
                    near, best = s, dist
        valid[near] = False
        valid[d] = True
    kept = start
    for s in range(k):
        if valid[s]:
            if start + s != kept:
                _copy_row(out, kept, start + s)
            kept += 1
    return kept


@njit
def rank_features(feature, start, m):
    """Replace the features of rows ``start .. m − 1`` (one pair's points) by their ranks in the order of the
    kernels' feature ids: small numbers, stable while the same features make the manifold (see the module
    docstring)."""
    k = m - start
    rank = np.empty(k, np.int64)
    for s in range(k):
        below = 0
        for t in range(k):
            if feature[start + t] < feature[start + s] or (feature[start + t] == feature[start + s] and t < s):
                below += 1
        rank[s] = below
    for s in range(k):
        feature[start + s] = rank[s]


@njit(inline="always")  # (passed the bundles by value as a call: ~50 arrays increfed per hull; issue 38)
def _posed_hull(shapes, poses, k):
    """Primitive ``k``'s hull (a HULL's, or a BOX's 8 corners) as a :class:`.convex.PosedHull` at its pose."""
    return posed(hull_of(shapes.hulls, shapes.primitives.hull[k]), poses.centre[k], poses.rotation[k])


@njit(inline="always")  # (as _posed_hull)
def _ground_contacts(k, shapes, poses, axis, start, out, m):
    """The ground (A) against this stage's primitive ``k`` (B, not a mesh), written into ``out`` from row ``m``;
    returns the next free row.  ``axis (3,)``: work space; ``start``: a hull's vertex to look for its lowest from."""
    prims = shapes.primitives
    kind, centre, R, margin = prims.kind[k], poses.centre[k], poses.rotation[k], poses.margin[k]
    if kind == HULL:
        m = plane_hull_contacts(_posed_hull(shapes, poses, k), margin, start, out, m)
    elif kind == SPHERE:
        nx, ny, nz, s, px, py, pz = sphere_plane_point(centre, prims.radius[k])
        if s < margin:
            m = write_point(out, m, nx, ny, nz, s, px, py, pz, 0)
    elif kind == BOX:
        m = box_plane_contacts(Box(centre, R, prims.half[k]), margin, out, m)
    else:
        _column(R, 2, axis)
        m = capsule_plane_contacts(Capsule(centre, axis, prims.half[k, 2], prims.radius[k]), margin, out, m)
    return m


@njit(inline="always")  # (called once: compiled into convex_phase, not as a kernel of its own; issue 34)
def _primitive_pair_contacts(a, b, shapes, poses, work, out, m):
    """Primitives ``a`` (A) and ``b`` (B), neither a mesh, kinds in SPHERE < BOX < CAPSULE < HULL order, written
    into ``out`` from row ``m``: returns ``(next free row, flipped)`` — flipped when the hull kernels wanted the
    hull as side A (a sphere or capsule against a hull).  ``work`` (3, 3): axes and a segment."""
    prims = shapes.primitives
    sa, sb = prims.kind[a], prims.kind[b]
    centre, radius, half = poses.centre, prims.radius, prims.half
    Ra, Rb = poses.rotation[a], poses.rotation[b]
    limit = poses.margin[a] + poses.margin[b]
    axis_a, axis_b = work[0], work[1]
    if sb == HULL and (sa == HULL or sa == BOX):
        return hull_hull_contacts(_posed_hull(shapes, poses, a), _posed_hull(shapes, poses, b), limit, out, m), \
            False
    if sb == HULL:  # a sphere or a capsule and a hull: the hull is side A
        _segment(centre[a], Ra, half[a, 2], work[:2])
        return hull_capsule_contacts(_posed_hull(shapes, poses, b), work[:2], radius[a], limit, out, m), True
    if sa == SPHERE and sb == SPHERE:
        nx, ny, nz, s, px, py, pz = sphere_sphere_point(centre[a, 0], centre[a, 1], centre[a, 2], radius[a],
                                                        centre[b, 0], centre[b, 1], centre[b, 2], radius[b])
        if s < limit:
            m = write_point(out, m, nx, ny, nz, s, px, py, pz, 0)
    elif sa == SPHERE and sb == BOX:
        nx, ny, nz, s, px, py, pz = sphere_box_point(centre[a], radius[a], Box(centre[b], Rb, half[b]))
        if s < limit:
            m = write_point(out, m, nx, ny, nz, s, px, py, pz, 0)
    elif sa == SPHERE:
        _column(Rb, 2, axis_b)
        nx, ny, nz, s, px, py, pz = sphere_capsule_point(centre[a], radius[a],
                                                         Capsule(centre[b], axis_b, half[b, 2], radius[b]))
        if s < limit:
            m = write_point(out, m, nx, ny, nz, s, px, py, pz, 0)
    elif sa == BOX and sb == BOX:
        m = box_box_contacts(Box(centre[a], Ra, half[a]), Box(centre[b], Rb, half[b]), limit, out, m)
    elif sa == BOX:
        _column(Rb, 2, axis_b)
        m = box_capsule_contacts(Box(centre[a], Ra, half[a]), Capsule(centre[b], axis_b, half[b, 2], radius[b]),
                                 limit, out, m)
    else:
        _column(Ra, 2, axis_a)
        _column(Rb, 2, axis_b)
        m = capsule_capsule_contacts(Capsule(centre[a], axis_a, half[a, 2], radius[a]),
                                     Capsule(centre[b], axis_b, half[b, 2], radius[b]), limit, out, m)
    return m, False


@njit(inline="always")  # (called once: compiled into convex_phase, not as a kernel of its own; issue 34)
def _mesh_contacts(a, b, shapes, poses, candidates, work, out, m):
    """Mesh primitive ``a`` (A) against primitive ``b`` (B, not a mesh) into ``out`` from row ``m``: returns
    ``(next free row, done)`` — not done when the BVH query's ``candidates`` scratch or ``out``'s free rows were
    too few (the caller grows both and calls again)."""
    prims, meshes = shapes.primitives, shapes.meshes
    mk = prims.mesh[a]
    mesh = mesh_of(meshes, mk)
    Ra, Rb = poses.rotation[a], poses.rotation[b]
    limit = poses.margin[a] + poses.margin[b]
    if prims.kind[b] == HULL or prims.kind[b] == BOX:
        return mesh_hull_contacts(mesh, poses.centre[a], Ra, meshes.two_sided[mk], _posed_hull(shapes, poses, b),
                                  limit, candidates, out, m)
    _segment(poses.centre[b], Rb, prims.half[b, 2], work[:2])
    return mesh_capsule_contacts(mesh, poses.centre[a], Ra, meshes.two_sided[mk], work[:2], prims.radius[b], limit,
                                 candidates, out, m)


@njit
def convex_phase(shapes, poses, pairs, active, ground, key_base, candidates, extreme):
    """Contact points of this stage's active primitives with the ground and of the candidate pairs (primitive
    indices, AABBs overlapping) that this stage's primitives take part in (pairs of two of the detector's
    primitives are skipped: :func:`.detector.narrow_phase` has them): the :class:`.ContactSet` (ground contacts
    first, then the pairs in the order given), ``touched (n,)``: the sleeping bodies in a contact, and the BVH
    query's scratch ``candidates (c,)`` int64 (the one given, or a bigger one if a mesh pair needed it: the caller
    passes it to the next call, so a big query is not run twice every sub-step, once to learn its size; issue 38).
    Keys: pair ids from ``key_base`` (see the module docstring).  ``extreme (P, 6)`` int64: each hull's lowest vertex
    found by :func:`tighten_hull_bounds` (column 4), where its ground manifold's search starts.

    ``shapes``: :class:`ShapeModel`; ``poses``: :class:`ShapePoses`; ``pairs``: :class:`.detector.Pairs`;
    ``active (n,)`` bool: the bodies being stepped; ``ground``: :class:`.detector.GroundPlane` — bundles as plain
    tuples from Python (see :mod:`cgp_core.jit`)."""
    shapes = ShapeModel(ShapePrimitives(*shapes[0]), HullSet(*shapes[1]), MeshSet(*shapes[2]), *shapes[3:])
    poses = ShapePoses(*poses)
    pair_i, pair_j = pairs
    has_ground, ground_friction, ground_restitution = ground
    prims = shapes.primitives
    P = len(prims.body)
    first_new = prims.first_new
    cap = 4 * (P - first_new + len(pair_i)) + 16
    out = ContactBuffer(np.empty((cap, 3)), np.empty(cap), np.empty((cap, 3)), np.empty(cap, np.int64))
    prim_a = np.empty(cap, np.int64)  # −1: the ground
    prim_b = np.empty(cap, np.int64)
    work = np.empty((3, 3))
    m = np.int64(0)

    # -- the ground plane z = 0 (side A) against this stage's active primitives near it
    if has_ground:
        for k in range(first_new, P):
            if not active[prims.body[k]] or not poses.lo[k, 2] < poses.margin[k] or prims.kind[k] == MESH:
                continue
            out, prim_a, prim_b = _grown(out, prim_a, prim_b, m, PAIR_ROWS)
            start = m
            m = _ground_contacts(k, shapes, poses, work[0], extreme[k, 4], out, m)
            rank_features(out.feature, start, m)
            prim_a[start:m] = -1
            prim_b[start:m] = k

    # -- primitive pairs with one of this stage's primitives in them
    for q in range(len(pair_i)):
        i, j = pair_i[q], pair_j[q]
        if i < first_new and j < first_new:
            continue
        bi, bj = prims.body[i], prims.body[j]
        if bi == bj or not (active[bi] or active[bj]):
            continue
        ki, kj = prims.kind[i], prims.kind[j]
        if ki == MESH and kj == MESH:
            continue
        # side A: a mesh; else the shape first in SPHERE < BOX < CAPSULE < HULL
        if kj == MESH or (ki != MESH and ki > kj):
            a, b = j, i
        else:
            a, b = i, j
        out, prim_a, prim_b = _grown(out, prim_a, prim_b, m, PAIR_ROWS)
        start = m
        first, second = a, b  # the contact's side A and B
        if prims.kind[a] == MESH:
            # room for 4 rows per candidate before the first call: a kernel short of rows stops part way, and its
            # triangles' work until then is lost
            out, prim_a, prim_b = _grown(out, prim_a, prim_b, m, 4 * len(candidates))
            done = False
            while not done:
                m, done = _mesh_contacts(a, b, shapes, poses, candidates, work, out, m)
                if not done:  # more triangles than scratch, or too few free rows: bigger buffers, again
                    m = start
                    candidates = np.empty(8 * len(candidates), np.int64)
                    out, prim_a, prim_b = _grown(out, prim_a, prim_b, m, 4 * len(candidates))
            m = reduce_mesh_rows(out, start, m)
        else:
            m, flipped = _primitive_pair_contacts(a, b, shapes, poses, work, out, m)
            if flipped:
                first, second = b, a
        rank_features(out.feature, start, m)
        prim_a[start:m] = first
        prim_b[start:m] = second
    contacts, touched = _contact_set(shapes, out, prim_a, prim_b, m, active, ground, key_base)
    return contacts, touched, candidates


@njit
def _contact_set(shapes, out, prim_a, prim_b, m, active, ground, key_base):
    """The :class:`.ContactSet` of the ``m`` points in ``out`` (of primitives ``prim_a``, ``prim_b``: bodies,
    identity keys, materials), and ``touched (n,)``: the sleeping (movable, not active) bodies touched."""
    prims = shapes.primitives
    body_friction, body_restitution = shapes.body_friction, shapes.body_restitution
    P = len(prims.body)
    touched = np.zeros(len(active), np.bool_)
    body_a = np.empty(m, np.int64)
    body_b = np.empty(m, np.int64)
    key = np.empty(m, np.int64)
    friction = np.empty(m)
    restitution = np.empty(m)
    for c in range(m):
        body_b[c] = prims.body[prim_b[c]]
        if prim_a[c] < 0:
            body_a[c] = GROUND
            mu_a, e_a = ground[1], ground[2]
        else:
            body_a[c] = prims.body[prim_a[c]]
            mu_a, e_a = body_friction[body_a[c]], body_restitution[body_a[c]]
        friction[c] = combine_friction(mu_a, body_friction[body_b[c]])
        restitution[c] = combine_restitution(e_a, body_restitution[body_b[c]])
        key[c] = (key_base + (prim_a[c] + 1) * (P + 1) + prim_b[c]) * FEATURE_SLOTS + out.feature[c]
        for body in (body_a[c], body_b[c]):
            if body >= 0 and not shapes.fixed_body[body] and not active[body]:
                touched[body] = True
    contacts = ContactSet(body_a, body_b, out.normal[:m].copy(), out.separation[:m].copy(), out.point[:m].copy(),
                          key, friction, restitution)
    return contacts, touched


# ---- continuous collision for fast rotation: time of impact after the integrator --------------------------------

@njit
def fast_turn_pairs(shapes, active, angular_velocity, h, pairs):
    """The candidate pairs (:class:`.detector.Pairs`) this stage takes in which an active body turning by more
    than :data:`TOI_ANGLE` in the sub-step meets a fixed hull, box or mesh: ``(moving primitive, static
    primitive)`` arrays (see the module docstring).  Bundles as plain tuples from Python."""
    prims, fixed_body = ShapePrimitives(*shapes[0]), shapes[6]
    pair_i, pair_j = pairs
    first_new = prims.first_new
    moving = np.empty(len(pair_i), np.int64)
    static = np.empty(len(pair_i), np.int64)
    count = 0
    for q in range(len(pair_i)):
        i, j = pair_i[q], pair_j[q]
        if i < first_new and j < first_new:
            continue
        for side in range(2):
            k, s = (i, j) if side == 0 else (j, i)
            b, o = prims.body[k], prims.body[s]
            if b == o or not active[b] or not fixed_body[o]:
                continue
            if prims.kind[s] != HULL and prims.kind[s] != BOX and prims.kind[s] != MESH:
                continue
            w = angular_velocity[b]
            if math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]) * h > TOI_ANGLE:
                moving[count] = k
                static[count] = s
                count += 1
    return moving[:count], static[:count]


@njit
def _core_in_body(shapes, k):
    """Primitive k's core in its body's frame (about the COM): ``(vertices (c, 3), adjacency_start, adjacency,
    radius)`` — a hull's vertices (with its adjacency), a box's corners, a capsule's segment, a sphere's centre."""
    prims = shapes.primitives
    kind = prims.kind[k]
    R, o = prims.rotation[k], prims.offset[k]
    if kind == HULL:
        hull = hull_of(shapes.hulls, prims.hull[k])
        adjacency_start, adjacency = hull.adjacency_start, hull.adjacency
        local = hull.vertices
    else:
        adjacency_start, adjacency = np.zeros(9, np.int64), np.zeros(0, np.int64)
        hx, hy, hz = prims.half[k, 0], prims.half[k, 1], prims.half[k, 2]
        if kind == BOX:
            local = np.empty((8, 3))
            for c in range(8):
                local[c, 0] = hx if c & 4 else -hx
                local[c, 1] = hy if c & 2 else -hy
                local[c, 2] = hz if c & 1 else -hz
        else:
            local = np.zeros((2, 3))
            local[0, 2], local[1, 2] = -hz, hz
    out = np.empty((len(local), 3))
    for i in range(len(local)):
        for r in range(3):
            out[i, r] = o[r] + R[r, 0] * local[i, 0] + R[r, 1] * local[i, 1] + R[r, 2] * local[i, 2]
    radius = prims.radius[k] if kind == SPHERE or kind == CAPSULE else 0.0
    return out, adjacency_start, adjacency, radius


@njit
def _mesh_time(mesh, Rm, pm, moving, h, target, tolerance, candidates):
    """The earliest time of impact of the :class:`.toi.MovingCore` ``moving`` with the triangles of the
    :class:`.bvh.TriangleMesh` ``mesh`` (posed by ``pm``, ``Rm``) its swept ball meets; 1 if none."""
    x0, v = moving.position, moving.velocity
    zero, eye = np.zeros(3), np.eye(3)
    no_start, no_adjacency = np.zeros(4, np.int64), np.zeros(0, np.int64)
    triangle = np.empty((3, 3))
    core, radius = moving.vertices, moving.radius
    reach = radius
    for i in range(len(core)):
        reach = max(reach, math.sqrt(core[i, 0] ** 2 + core[i, 1] ** 2 + core[i, 2] ** 2) + radius)
    lo, hi = np.empty(3), np.empty(3)
    for r in range(3):
        a = Rm[0, r] * (x0[0] - pm[0]) + Rm[1, r] * (x0[1] - pm[1]) + Rm[2, r] * (x0[2] - pm[2])
        e = Rm[0, r] * (x0[0] + v[0] * h - pm[0]) + Rm[1, r] * (x0[1] + v[1] * h - pm[1]) \
            + Rm[2, r] * (x0[2] + v[2] * h - pm[2])
        lo[r] = min(a, e) - reach
        hi[r] = max(a, e) + reach
    found = candidates.shape[0] + 1
    while found > len(candidates):
        found = bvh_overlap(mesh, lo, hi, candidates)
        if found > len(candidates):
            candidates = np.empty(2 * found, np.int64)
    best = 1.0
    for c in range(found):
        t = candidates[c]
        for corner in range(3):
            vi = mesh.triangles[t, corner]
            for r in range(3):
                triangle[corner, r] = pm[r] + Rm[r, 0] * mesh.vertices[vi, 0] + Rm[r, 1] * mesh.vertices[vi, 1] \
                    + Rm[r, 2] * mesh.vertices[vi, 2]
        time, _, _, hit, _ = time_of_impact(moving, MovingCore(triangle, no_start, no_adjacency, zero, eye, zero,
                                                               zero, 0.0), h, target, tolerance)
        if hit and time > 0.0:
            best = min(best, time)
    return best


@njit
def sweep_times(shapes, moving, static, poses, start, h, target, tolerance):
    """Time of impact (fraction of the sub-step, :func:`.toi.time_of_impact`) of each pair ``moving[q]`` (turning
    about its body's COM from the :class:`.primitives.BodyMotion` ``start``: positions and rotations at the
    sub-step's start, the velocities and angular velocities over it) against ``static[q]`` (posed by the
    :class:`ShapePoses` ``poses``; a mesh: each triangle its swept box meets), ``(q,)``: 1 where it does not touch
    within the sub-step, and also where it touched at the start (t = 0: a resting contact, the contacts'
    business).  Bundles as plain tuples from Python."""
    shapes = ShapeModel(ShapePrimitives(*shapes[0]), HullSet(*shapes[1]), MeshSet(*shapes[2]), *shapes[3:])
    poses, start = ShapePoses(*poses), BodyMotion(*start)
    prims = shapes.primitives
    out = np.ones(len(moving))
    zero = np.zeros(3)
    candidates = np.empty(MESH_CANDIDATES, np.int64)
    for q in range(len(moving)):
        k, s = moving[q], static[q]
        b = prims.body[k]
        core, adjacency_start, adjacency, radius = _core_in_body(shapes, k)
        mover = MovingCore(core, adjacency_start, adjacency, start.position[b], start.rotation[b],
                           start.velocity[b], start.angular_velocity[b], radius)
        if prims.kind[s] == MESH:
            best = _mesh_time(mesh_of(shapes.meshes, prims.mesh[s]), poses.rotation[s], poses.centre[s], mover, h,
                              target, tolerance, candidates)
        else:
            best = 1.0
            other, other_start, other_adjacency, other_radius = _core_in_body(shapes, s)
            o = prims.body[s]
            time, _, _, hit, _ = time_of_impact(mover, MovingCore(other, other_start, other_adjacency,
                                                                  start.position[o], start.rotation[o], zero, zero,
                                                                  other_radius), h, target, tolerance)
            if hit and time > 0.0:
                best = min(best, time)
        out[q] = best
    return out

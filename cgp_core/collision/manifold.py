"""Contact manifolds of convex hulls: hull–hull, hull–ground plane, hull–sphere / capsule, hull–triangle (a static
mesh's triangle).  Compiled kernels writing into the narrow phase's :class:`.narrowphase.ContactBuffer`, as
:mod:`.narrowphase` and :mod:`.box_box` do (from row ``m`` on; each returns the next free row; normal from A to B; the
point midway between the surfaces; a point is kept only if its separation is below ``margin``).

**Hull–hull** (:func:`hull_hull_contacts`) — the box–box kernel's scheme (:mod:`.box_box`) for any two hulls, with
GJK/EPA in place of the 9 edge axes:

1. *Face axes* (SAT, Ericson 4.4 / Gregorius, GDC 2013): for every face of A, the separation of B from its plane,
   n · support_B(−n) − d; the best face of A, and likewise of B.  If one exceeds the margin, there is no contact.
2. *The true separation*: GJK's distance (:mod:`.gjk`) when the hulls are apart, minus EPA's penetration depth
   (:mod:`.epa`) when they overlap.  It is the maximum of the separation over all directions, so it is at least
   every face's; an edge–edge (or, apart, a vertex / edge) contact is one where it beats the best face.  This
   replaces the enumeration of all edge pairs (O(E_A E_B)), which is what makes SAT slow for hulls.
3. The choice, as in box–box: B's face only if it beats A's by :data:`.box_box.AXIS_RELATIVE_TOLERANCE` (relative)
   + :data:`.box_box.AXIS_ABSOLUTE_TOLERANCE`; an edge only if the true separation beats the chosen face by the
   same — so a resting hull keeps its reference face and features from step to step.
4. *Face contact*: the chosen face is the reference face, the *incident* face is the other hull's face most
   anti-parallel to it; the incident polygon is clipped against the reference face's side planes
   (Sutherland–Hodgman, Ericson 8.3.4), each clipped point's separation is its height above the reference plane,
   points at or above the margin are dropped, and more than 4 are reduced to 4 by :func:`reduce_to_four`.  When
   apart, the points are lowered together until the nearest reports the chosen face's separation (box–box's
   ``_lower_to``: a lower bound of the gap, so a fast approach is never let through).
5. *Edge contact*: one point midway between GJK's (apart) or EPA's (overlapping) witness points.

Reduction to 4 points — the box kernel's rule, not Bullet's "deepest point, then largest area": the 4 points
extreme along the reference face's diagonal directions (in units of the face's half spans).  Box–box measured
the deepest-first rule flipping between equally deep points of an octagonal contact region from step to step
(a stack of turned boxes jittered); the extremes do not flip, and they span nearly the largest quadrilateral.
With the same rule a box given as an 8-point hull gets the manifold of the box kernel (tested).

Features (stable while the contact persists): a face contact's point is ``FACE_FEATURE | flip << 60 |
reference face << 40 | incident face << 20 | clip code`` where the clip code names the two polygon edges the
point lies between (incident edge k → k, reference side k → 256 + k; code = in · 512 + out): an incident vertex,
an incident edge crossing a reference side, or a reference corner.  An edge contact's is ``EDGE_FEATURE`` with
the two hull vertex pairs of the witness features.

**Hull–plane** (the ground z = 0, A): every hull vertex below the margin, reduced to 4 by the same rule (in the
world's x, y).  **Hull–sphere / capsule** (a point or segment core with a radius): GJK (EPA when the core is
inside) gives one point; a capsule lying along a face (its axis within ``CAPSULE_PARALLEL_SINE`` of the face's
plane, the contact normal that face's) gives two, its segment clipped to the face.  **Hull–triangle**: the
triangle is a flat hull with two faces; see :func:`triangle_hull_contacts` for the internal-edge ("ghost")
treatment.

Bundles: each hull is a :class:`.convex.PosedHull` (its arrays as :meth:`.convex.HullSet.hull` slices them —
``vertices (k, 3)`` in the hull's frame, ``adjacency_start (k + 1,)`` / ``adjacency (a,)``, ``face_plane (f, 4)``
in the hull's frame, ``face_vertex_start (f + 1,)`` / ``face_vertices (fv,)`` (local vertex indices) — posed by
``position (3,)``, ``rotation (3, 3)``); the points go into a :class:`.narrowphase.ContactBuffer` ``out``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit import njit
from .box_box import AXIS_ABSOLUTE_TOLERANCE, AXIS_RELATIVE_TOLERANCE
from .convex import BRUTE_FORCE_SUPPORT_VERTICES, PosedHull, support_index
from .epa import epa
from .gjk import Core, empty_simplex, gjk, support_point
from .narrowphase import CAPSULE_PARALLEL_SINE, write_point

#: :func:`face_contact`'s ``flip``: numpy booleans, not Python's ``True`` / ``False``, which numba passes on as
#: literals, compiling :func:`face_contact` once for each (its callers linking both: ~2 s more of the convex part's
#: compile, issue 34)
FLIPPED, NOT_FLIPPED = np.bool_(True), np.bool_(False)

FACE_FEATURE = np.int64(1) << np.int64(62)
EDGE_FEATURE = np.int64(1) << np.int64(61)
#: a reference-side label in the clip codes (incident edges are 0..254)
_REFERENCE_SIDE = 256


class SignedDistance(NamedTuple):
    """What :func:`signed_distance` gives: the separation of two cores along the unit normal from A to B, the
    witness points a (on A) and b (on B), and an edge-contact feature id from the witness features' vertices."""

    separation: float
    nx: float
    ny: float
    nz: float
    ax: float
    ay: float
    az: float
    bx: float
    by: float
    bz: float
    feature: np.int64


@njit
def core_of(hull):
    """The :class:`.gjk.Core` of a :class:`.convex.PosedHull` (what GJK / EPA need of it)."""
    return Core(hull.vertices, hull.adjacency_start, hull.adjacency, hull.position, hull.rotation)


#: hull–triangle: a contact normal within this angle of the triangle's face normal is replaced by it (rad)
GHOST_NORMAL_ANGLE = math.radians(20.0)
#: a mesh edge whose two triangles' normals differ by less than this is *inactive* (flat or concave enough that
#: nothing can touch the edge itself): contacts on it use the triangle's face normal (rad)
ACTIVE_EDGE_ANGLE = math.radians(5.0)
#: hull–triangle edge flags: bit e set = edge (v_e, v_(e+1)%3) is active
ALL_EDGES_ACTIVE = np.uint8(7)


# ---- the reduction to 4 points ---------------------------------------------------------------------------

#: a hull–ground candidate this much [m] below every point the reduction kept replaces the nearest of them
#: (:func:`keep_deepest`); a fifth of the solver's penetration slop, far above the depth differences round-off and
#: a resting face's micro-tilt give its corners
DEEPEST_TOLERANCE = 1e-4


@njit
def reduce_to_four(X, Y, hu, hv, valid):
    """Keep at most 4 of the ``valid`` candidates (in place): those extreme along the diagonal directions
    (±1, ±1) in units of the half spans ``hu``, ``hv`` (see the module docstring; box–box's rule)."""
    count = 0
    for s in range(len(valid)):
        if valid[s]:
            count += 1
    if count <= 4:
        return
    keep = np.zeros(len(valid), np.bool_)
    for c in range(4):
        dx = 1.0 if c == 0 or c == 3 else -1.0
        dy = 1.0 if c < 2 else -1.0
        best, best_s = -np.inf, -1
        for s in range(len(valid)):
            if valid[s]:
                score = dx * (X[s] / hu) + dy * (Y[s] / hv)
                if score > best:
                    best, best_s = score, s
        keep[best_s] = True
    for s in range(len(valid)):
        valid[s] = keep[s]


# ---- pieces --------------------------------------------------------------------------------------------

@njit
def _world_plane(face_plane, f, position, rotation):
    """Face f's plane in world: unit normal (nx, ny, nz) and offset d (n · x = d on the face)."""
    a, b, c = face_plane[f, 0], face_plane[f, 1], face_plane[f, 2]
    nx = rotation[0, 0] * a + rotation[0, 1] * b + rotation[0, 2] * c
    ny = rotation[1, 0] * a + rotation[1, 1] * b + rotation[1, 2] * c
    nz = rotation[2, 0] * a + rotation[2, 1] * b + rotation[2, 2] * c
    return nx, ny, nz, face_plane[f, 3] + nx * position[0] + ny * position[1] + nz * position[2]


@njit
def _world_vertex(vertices, i, position, rotation):
    v0, v1, v2 = vertices[i, 0], vertices[i, 1], vertices[i, 2]
    return (position[0] + rotation[0, 0] * v0 + rotation[0, 1] * v1 + rotation[0, 2] * v2,
            position[1] + rotation[1, 0] * v0 + rotation[1, 1] * v1 + rotation[1, 2] * v2,
            position[2] + rotation[2, 0] * v0 + rotation[2, 1] * v1 + rotation[2, 2] * v2)


@njit
def best_face(hull, other, stop):
    """SAT over the faces of ``hull`` (a :class:`.convex.PosedHull`; the other side is a :class:`.gjk.Core`) (Ericson
    4.4): the face whose plane the other hull (``_o``) is farthest beyond,
    ``(face, separation)``; separation = n · support_other(−n) − d (negative: overlap along n).  Returns at the
    first face whose separation exceeds ``stop`` (a separating axis: the caller needs no more).

    Computed in this hull's frame: the other's vertices are turned into it once (Rᵀ (R_o v + p_o − p)), so a face
    costs one dot product per vertex; an other hull of more than
    :data:`.convex.BRUTE_FORCE_SUPPORT_VERTICES` vertices is asked for its support point by hill climbing."""
    face_plane, position, rotation = hull.face_plane, hull.position, hull.rotation
    vertices_o, adjacency_o, position_o, rotation_o = other.vertices, other.adjacency, other.position, other.rotation
    k = len(vertices_o)
    best_f, best = np.int64(0), -np.inf
    if k > BRUTE_FORCE_SUPPORT_VERTICES and len(adjacency_o) > 0:
        start = np.int64(0)
        for f in range(len(face_plane)):
            nx, ny, nz, d = _world_plane(face_plane, f, position, rotation)
            start, sx, sy, sz = support_point(other, -nx, -ny, -nz, start)
            s = nx * sx + ny * sy + nz * sz - d
            if s > best:
                best_f, best = f, s
                if s > stop:
                    return best_f, best
        return best_f, best
    # the relative pose: M = Rᵀ R_o, t = Rᵀ (p_o − p)
    M = np.empty((3, 3))
    t = np.empty(3)
    for i in range(3):
        t[i] = rotation[0, i] * (position_o[0] - position[0]) + rotation[1, i] * (position_o[1] - position[1]) \
            + rotation[2, i] * (position_o[2] - position[2])
        for j in range(3):
            M[i, j] = rotation[0, i] * rotation_o[0, j] + rotation[1, i] * rotation_o[1, j] \
                + rotation[2, i] * rotation_o[2, j]
    local = np.empty((k, 3))
    for v in range(k):
        for i in range(3):
            local[v, i] = t[i] + M[i, 0] * vertices_o[v, 0] + M[i, 1] * vertices_o[v, 1] + M[i, 2] * vertices_o[v, 2]
    for f in range(len(face_plane)):
        nx, ny, nz, d = face_plane[f, 0], face_plane[f, 1], face_plane[f, 2], face_plane[f, 3]
        low = np.inf
        for v in range(k):
            low = min(low, nx * local[v, 0] + ny * local[v, 1] + nz * local[v, 2])
        s = low - d
        if s > best:
            best_f, best = f, s
            if s > stop:
                return best_f, best
    return best_f, best


class FaceScratch(NamedTuple):
    """Work space of :func:`clip_incident` for polygons of up to ``c`` vertices (:func:`face_scratch`; the rows'
    meanings are listed where it is used)."""

    real: np.ndarray   # (13, c) float: the polygons' coordinates, the clipped points' face coordinates
    label: np.ndarray  # (4, c) int64: clip labels (in-edge, out-edge) before and after a side
    flags: np.ndarray  # (3, c) bool: valid, before the reduction, the first reduction's


@njit
def face_scratch(capacity):
    """A :class:`FaceScratch` of ``capacity`` columns: rows of three allocations, not eighteen (issue 38: a box on a
    fine mesh clips once per triangle under it, and each allocation costs ~30 ns)."""
    return FaceScratch(np.empty((13, capacity)), np.empty((4, capacity), np.int64), np.empty((3, capacity), np.bool_))


@njit(inline="always")  # (per triangle under a hull: a call passes every array of both hulls; issue 38)
def incident_face(reference, face_r, incident):
    """The face of hull I (``incident``) most anti-parallel to face ``face_r`` of hull R (``reference``), and the
    columns :func:`clip_incident` needs for the two: ``(face_i, capacity)``.  Clipping a convex polygon by a plane
    adds at most one vertex, so the incident loop plus one per reference side fits — twice that, and a check in the
    clipping, for a polygon that round-off has made slightly non-convex."""
    nx, ny, nz, _ = _world_plane(reference.face_plane, face_r, reference.position, reference.rotation)
    face_plane_i, position_i, rotation_i = incident.face_plane, incident.position, incident.rotation
    face_i, most = np.int64(0), np.inf
    for f in range(len(face_plane_i)):
        a, b, c, _ = _world_plane(face_plane_i, f, position_i, rotation_i)
        dot = a * nx + b * ny + c * nz
        if dot < most:
            face_i, most = f, dot
    k = incident.face_vertex_start[face_i + 1] - incident.face_vertex_start[face_i]
    return face_i, 2 * (k + reference.face_vertex_start[face_r + 1] - reference.face_vertex_start[face_r]) + 4


@njit
def face_contact(reference, face_r, incident, flip, best, margin, out, m):
    """Face contact: face ``face_r`` of hull R (``reference``, a :class:`.convex.PosedHull`) is the reference face,
    hull I's face most anti-parallel to it the incident face (:func:`incident_face`); :func:`clip_incident` in work
    space of its own."""
    face_i, capacity = incident_face(reference, face_r, incident)
    return clip_incident(reference, face_r, incident, face_i, flip, best, margin, out, m, face_scratch(capacity))


@njit
def clip_incident(reference, face_r, incident, face_i, flip, best, margin, out, m, scratch):
    """Face ``face_r`` of hull R (``reference``, a :class:`.convex.PosedHull`) the reference face, face ``face_i`` of
    hull I the incident face: Sutherland–Hodgman clipping of the incident polygon by the reference face's side
    planes (Ericson 8.3.4), points below ``margin`` kept, at most 4 (:func:`reduce_to_four`).  ``flip``: R is B (the
    normal written is reversed so that it still points from A to B).  ``best``: the reference face's SAT separation
    (the points are lowered to it when apart).  ``scratch``: a :class:`FaceScratch` of at least
    :func:`incident_face`'s capacity (one per mesh–hull pair serves all its triangles)."""
    vertices_r, face_plane_r, position_r, rotation_r = (reference.vertices, reference.face_plane, reference.position,
                                                        reference.rotation)
    face_vertex_start_r, face_vertices_r = reference.face_vertex_start, reference.face_vertices
    vertices_i, position_i, rotation_i = incident.vertices, incident.position, incident.rotation
    face_vertex_start_i, face_vertices_i = incident.face_vertex_start, incident.face_vertices
    nx, ny, nz, d_ref = _world_plane(face_plane_r, face_r, position_r, rotation_r)
    # the incident polygon in world, with its clip labels (in-edge, out-edge)
    i0, i1 = face_vertex_start_i[face_i], face_vertex_start_i[face_i + 1]
    k = i1 - i0
    capacity = 2 * (k + face_vertex_start_r[face_r + 1] - face_vertex_start_r[face_r]) + 4
    # the work arrays by row and column, not through row views: a view costs a reference count up and down
    # (atomic), and ~20 of them were most of a triangle's time (issue 38).  Rows: real 0–2 the polygon (x, y, z),
    # 3–5 the polygon being clipped, 6–8 the reference loop, 9–10 the points' face coordinates (X, Y), 11 their
    # separation Z (lowered when apart), 12 Z as clipped; label 0–1 the polygon's (in, out) labels, 2–3 the
    # clipped one's; flags 0 valid, 1 valid before the reduction, 2 the first reduction's choice
    real, label, flags = scratch
    for s in range(k):
        real[0, s], real[1, s], real[2, s] = _world_vertex(vertices_i, face_vertices_i[i0 + s], position_i, rotation_i)
        label[0, s], label[1, s] = (s - 1 if s > 0 else k - 1), s  # (the wraps as compares, not %: a division each)
    # the reference face's loop in world
    r0, r1 = face_vertex_start_r[face_r], face_vertex_start_r[face_r + 1]
    nref = r1 - r0
    for s in range(nref):
        real[6, s], real[7, s], real[8, s] = _world_vertex(vertices_r, face_vertices_r[r0 + s], position_r, rotation_r)
    # clip by each side plane: inward normal n × (edge), through the edge's start
    for side in range(nref):
        if k == 0:
            break
        e = side + 1 if side + 1 < nref else 0
        ex, ey, ez = real[6, e] - real[6, side], real[7, e] - real[7, side], real[8, e] - real[8, side]
        sx, sy, sz = ny * ez - nz * ey, nz * ex - nx * ez, nx * ey - ny * ex
        offset = sx * real[6, side] + sy * real[7, side] + sz * real[8, side]
        clipped = 0
        for s in range(k):
            if clipped + 2 > capacity:
                break  # never for a convex polygon (see above)
            t = s + 1 if s + 1 < k else 0
            ds = sx * real[0, s] + sy * real[1, s] + sz * real[2, s] - offset
            dt = sx * real[0, t] + sy * real[1, t] + sz * real[2, t] - offset
            if ds >= 0.0 and dt >= 0.0:  # both inside: keep the edge's end
                real[3, clipped], real[4, clipped], real[5, clipped] = real[0, t], real[1, t], real[2, t]
                label[2, clipped], label[3, clipped] = label[0, t], label[1, t]
                clipped += 1
            elif ds >= 0.0 or dt >= 0.0:  # crossing: the crossing point, then the end if it is inside
                u = ds / (ds - dt)
                real[3, clipped] = real[0, s] + u * (real[0, t] - real[0, s])
                real[4, clipped] = real[1, s] + u * (real[1, t] - real[1, s])
                real[5, clipped] = real[2, s] + u * (real[2, t] - real[2, s])
                if ds >= 0.0:  # leaving through this side
                    label[2, clipped], label[3, clipped] = label[1, s], _REFERENCE_SIDE + side
                else:  # entering
                    label[2, clipped], label[3, clipped] = _REFERENCE_SIDE + side, label[0, t]
                clipped += 1
                if dt >= 0.0:
                    real[3, clipped], real[4, clipped], real[5, clipped] = real[0, t], real[1, t], real[2, t]
                    label[2, clipped], label[3, clipped] = label[0, t], label[1, t]
                    clipped += 1
        for s in range(clipped):
            real[0, s], real[1, s], real[2, s] = real[3, s], real[4, s], real[5, s]
            label[0, s], label[1, s] = label[2, s], label[3, s]
        k = clipped
    if k == 0:
        return m
    # the reference face's 2-D frame: u along its first edge, v = n × u; half spans hu, hv of the face
    ux, uy, uz = real[6, 1] - real[6, 0], real[7, 1] - real[7, 0], real[8, 1] - real[8, 0]
    lu = math.sqrt(ux * ux + uy * uy + uz * uz)
    ux, uy, uz = ux / lu, uy / lu, uz / lu
    vx, vy, vz = ny * uz - nz * uy, nz * ux - nx * uz, nx * uy - ny * ux
    umin = vmin = np.inf
    umax = vmax = -np.inf
    for s in range(nref):
        a = ux * real[6, s] + uy * real[7, s] + uz * real[8, s]
        b = vx * real[6, s] + vy * real[7, s] + vz * real[8, s]
        umin, umax, vmin, vmax = min(umin, a), max(umax, a), min(vmin, b), max(vmax, b)
    hu, hv = 0.5 * (umax - umin), 0.5 * (vmax - vmin)
    for s in range(k):
        flags[0, s] = True
        real[9, s] = ux * real[0, s] + uy * real[1, s] + uz * real[2, s]
        real[10, s] = vx * real[0, s] + vy * real[1, s] + vz * real[2, s]
        real[11, s] = nx * real[0, s] + ny * real[1, s] + nz * real[2, s] - d_ref
        real[12, s] = real[11, s]
    # merge (near) duplicates, as box–box does: a point coinciding with an earlier one is dropped
    close = (1e-4 * (hu + hv)) ** 2
    for j in range(k):
        for i in range(j):
            if flags[0, i] and (real[9, j] - real[9, i]) ** 2 + (real[10, j] - real[10, i]) ** 2 <= close:
                flags[0, j] = False
                break
    apart = best > 0.0
    if apart:
        _lower_to(real[11, :k], flags[0, :k], best, apart)
    for s in range(k):
        flags[0, s] = flags[0, s] and real[11, s] < margin
    # the reduction, in the reference face's units (box–box's rule, which this then reproduces for boxes); where
    # that keeps fewer than 4 of more candidates — a small hull on a big face, whose diagonal extremes in the
    # face's units fall on the same two points: a line of support, on which it would rock — in the units of the
    # contact polygon's own half spans, if that keeps more
    candidates = 0
    for s in range(k):
        flags[1, s] = flags[0, s]
        candidates += flags[0, s]
    if candidates > 4:  # (reduce_to_four keeps 4 or fewer as they are)
        reduce_to_four(real[9, :k], real[10, :k], hu, hv, flags[0, :k])
    candidates = kept = 0
    cu_lo = cv_lo = np.inf
    cu_hi = cv_hi = -np.inf
    for s in range(k):
        if flags[1, s]:
            candidates += 1
            cu_lo, cu_hi = min(cu_lo, real[9, s]), max(cu_hi, real[9, s])
            cv_lo, cv_hi = min(cv_lo, real[10, s]), max(cv_hi, real[10, s])
        kept += flags[0, s]
    if kept < min(candidates, 4):
        for s in range(k):
            flags[2, s] = flags[0, s]
            flags[0, s] = flags[1, s]
        reduce_to_four(real[9, :k], real[10, :k], max(0.5 * (cu_hi - cu_lo), 1e-12),
                       max(0.5 * (cv_hi - cv_lo), 1e-12), flags[0, :k])
        if flags[0, :k].sum() <= kept:  # no better: the first
            for s in range(k):
                flags[0, s] = flags[2, s]
    if apart:
        _lower_to(real[11, :k], flags[0, :k], best, apart)
    sign = -1.0 if flip else 1.0
    base = FACE_FEATURE | (np.int64(1 if flip else 0) << np.int64(60)) | (np.int64(face_r) << np.int64(40)) \
        | (np.int64(face_i) << np.int64(20))
    for s in range(k):
        if flags[0, s]:
            half = 0.5 * real[12, s]
            m = write_point(out, m, sign * nx, sign * ny, sign * nz, real[11, s], real[0, s] - half * nx,
                            real[1, s] - half * ny, real[2, s] - half * nz, base | (label[0, s] * 512 + label[1, s]))
    return m


@njit
def _lower_to(Z, valid, best, apart):
    """If ``apart``, shift ``Z`` down (in place) so its smallest valid entry is at most ``best`` (box–box)."""
    if not apart:
        return
    nearest = np.inf
    for s in range(len(Z)):
        if valid[s] and Z[s] < nearest:
            nearest = Z[s]
    if nearest < np.inf:
        shift = max(nearest - best, 0.0)
        for s in range(len(Z)):
            Z[s] -= shift


@njit
def signed_distance(core_a, core_b):
    """GJK, and EPA if the cores (:class:`.gjk.Core`) overlap: a :class:`SignedDistance` (the witness points a on A,
    b on B, the normal from A to B and an edge-contact feature id built from the witness features' vertex
    indices)."""
    simplex = empty_simplex()
    simplex_a, simplex_b, simplex_ia, simplex_ib, weights = simplex
    count, intersecting, _ = gjk(core_a, core_b, 0, 0, simplex)
    ax = ay = az = bx = by = bz = 0.0
    for i in range(count):
        ax += weights[i] * simplex_a[i, 0]
        ay += weights[i] * simplex_a[i, 1]
        az += weights[i] * simplex_a[i, 2]
        bx += weights[i] * simplex_b[i, 0]
        by += weights[i] * simplex_b[i, 1]
        bz += weights[i] * simplex_b[i, 2]
    dist = math.sqrt((bx - ax) ** 2 + (by - ay) ** 2 + (bz - az) ** 2)
    a_lo, a_hi, b_lo, b_hi = simplex_ia[0], simplex_ia[0], simplex_ib[0], simplex_ib[0]
    for i in range(count):
        a_lo, a_hi = min(a_lo, simplex_ia[i]), max(a_hi, simplex_ia[i])
        b_lo, b_hi = min(b_lo, simplex_ib[i]), max(b_hi, simplex_ib[i])
    if not intersecting and dist > 0.0:
        sep = dist
        nx, ny, nz = (bx - ax) / dist, (by - ay) / dist, (bz - az) / dist
    else:
        depth, n, pa, pb, _ = epa(core_a, core_b, simplex, count)
        sep = -depth
        nx, ny, nz = n[0], n[1], n[2]
        ax, ay, az, bx, by, bz = pa[0], pa[1], pa[2], pb[0], pb[1], pb[2]
    feature = EDGE_FEATURE | (np.int64(a_lo) << np.int64(45)) | (np.int64(a_hi) << np.int64(30)) \
        | (np.int64(b_lo) << np.int64(15)) | np.int64(b_hi)
    return SignedDistance(sep, nx, ny, nz, ax, ay, az, bx, by, bz, feature)


# ---- hull–hull ------------------------------------------------------------------------------------------

@njit
def hull_hull_contacts(hull_a, hull_b, margin, out, m):
    """Hull A vs hull B (:class:`.convex.PosedHull` each): up to 4 points (see the module docstring) into ``out``
    from row ``m``, normal from A to B; returns the next free row."""
    core_a, core_b = core_of(hull_a), core_of(hull_b)
    fa, best_a = best_face(hull_a, core_b, margin)
    if not best_a < margin:
        return m
    fb, best_b = best_face(hull_b, core_a, margin)
    if not best_b < margin:
        return m
    sep, nx, ny, nz, ax, ay, az, bx, by, bz, edge_feature = signed_distance(core_a, core_b)
    if not sep < margin:
        return m
    use_b = best_b > best_a + AXIS_ABSOLUTE_TOLERANCE + AXIS_RELATIVE_TOLERANCE * abs(best_a)
    face_sep = best_b if use_b else best_a
    if sep > face_sep + AXIS_ABSOLUTE_TOLERANCE + AXIS_RELATIVE_TOLERANCE * abs(face_sep):
        return write_point(out, m, nx, ny, nz, sep, 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * (az + bz),
                           edge_feature)
    if use_b:
        return face_contact(hull_b, fb, hull_a, FLIPPED, best_b, margin, out, m)
    return face_contact(hull_a, fa, hull_b, NOT_FLIPPED, best_a, margin, out, m)


# ---- hull–plane --------------------------------------------------------------------------------------------

@njit
def plane_hull_contacts(hull, margin, start, out, m):
    """Ground z = 0 (A) vs hull (B, a :class:`.convex.PosedHull`): the hull's vertices below ``margin``, at most 4
    (:func:`reduce_to_four` in the world's x, y over the candidates' half spans); normal +z, feature = vertex
    index.

    A hull of more than :data:`.convex.BRUTE_FORCE_SUPPORT_VERTICES` vertices finds them from its lowest vertex
    (:func:`.convex.support_index`, climbing from vertex ``start``: the caller's warm start) over its edges, never
    looking past a vertex at or above the margin: the vertices of a convex polytope below a plane are connected
    through each other (from each, an edge leads down, to the lowest), so these are all of them, and the cost
    follows the contact, not the vertex count (issue 38).  They are taken in index order, as the brute-force scan
    of the small hulls does, so the points are the same."""
    vertices, position, rotation = hull.vertices, hull.position, hull.rotation
    k = len(vertices)
    if k > BRUTE_FORCE_SUPPORT_VERTICES and len(hull.adjacency) > 0:
        starts, adjacency = hull.adjacency_start, hull.adjacency
        lowest = support_index(vertices, starts, adjacency, -rotation[2, 0], -rotation[2, 1], -rotation[2, 2],
                               start)
        seen = np.zeros(k, np.bool_)
        stack = np.empty(k, np.int64)
        below = np.empty(k, np.int64)
        seen[lowest] = True
        stack[0] = lowest
        top = 1
        count = 0
        while top > 0:
            top -= 1
            i = stack[top]
            if not _world_vertex(vertices, i, position, rotation)[2] < margin:
                continue
            below[count] = i
            count += 1
            for e in range(starts[i], starts[i + 1]):
                j = adjacency[e]
                if not seen[j]:
                    seen[j] = True
                    stack[top] = j
                    top += 1
        candidates = np.sort(below[:count])
    else:
        candidates = np.arange(k)
    n = len(candidates)
    X, Y, Z = np.empty(n), np.empty(n), np.empty(n)
    valid = np.zeros(n, np.bool_)
    xmin = ymin = np.inf
    xmax = ymax = -np.inf
    for s in range(n):
        X[s], Y[s], Z[s] = _world_vertex(vertices, candidates[s], position, rotation)
        if Z[s] < margin:
            valid[s] = True
            xmin, xmax, ymin, ymax = min(xmin, X[s]), max(xmax, X[s]), min(ymin, Y[s]), max(ymax, Y[s])
    hu = max(0.5 * (xmax - xmin), 1e-12)
    hv = max(0.5 * (ymax - ymin), 1e-12)
    deepest = -1
    for s in range(n):
        if valid[s] and (deepest < 0 or Z[s] < Z[deepest]):
            deepest = s
    reduce_to_four(X, Y, hu, hv, valid)
    keep_deepest(X, Y, Z, hu, hv, valid, deepest)
    for s in range(n):
        if valid[s]:
            m = write_point(out, m, 0.0, 0.0, 1.0, Z[s], X[s], Y[s], 0.5 * Z[s], candidates[s])
    return m


@njit
def keep_deepest(X, Y, Z, hu, hv, valid, deepest):
    """After :func:`reduce_to_four`: if the candidate ``deepest`` (the lowest, Z its separation) was dropped and lies
    more than :data:`DEEPEST_TOLERANCE` below every kept point, it replaces the kept point nearest to it (in units of
    the half spans ``hu``, ``hv``).  The diagonal extremes are the corners of a flat contact, but of a round one
    (a 1,000-vertex sphere hull: the vertices below the margin a cap) they are on its rim, up to the margin above
    its lowest vertex: resting on them, the hull sank until they touched — 6 mm into the ground (issue 38)."""
    if deepest < 0 or valid[deepest]:
        return
    nearest, best, shallowest = -1, np.inf, np.inf
    for s in range(len(valid)):
        if valid[s]:
            shallowest = min(shallowest, Z[s])
            d = ((X[s] - X[deepest]) / hu) ** 2 + ((Y[s] - Y[deepest]) / hv) ** 2
            if d < best:
                nearest, best = s, d
    if Z[deepest] < shallowest - DEEPEST_TOLERANCE:
        valid[nearest] = False
        valid[deepest] = True


# ---- hull–sphere / capsule ------------------------------------------------------------------------------

@njit
def hull_capsule_contacts(hull, segment, radius, margin, out, m):
    """Hull A (a :class:`.convex.PosedHull`) vs capsule or sphere B: ``segment (2, 3)`` the core's ends in world (equal
    for a sphere) and its
    ``radius``.  One point (feature 2) from GJK / EPA; two (features 0, 1: the ends of the segment clipped to the
    face) when the capsule lies along the hull face the contact normal is."""
    vertices, face_plane, position, rotation = hull.vertices, hull.face_plane, hull.position, hull.rotation
    face_vertex_start, face_vertices = hull.face_vertex_start, hull.face_vertices
    identity = np.eye(3)
    origin = np.zeros(3)
    none = np.zeros(3, np.int64)
    sep, nx, ny, nz, ax, ay, az, bx, by, bz, _ = signed_distance(core_of(hull),
                                                                 Core(segment, none, none[:0], origin, identity))
    sep -= radius
    if not sep < margin:
        return m
    ex, ey, ez = segment[1, 0] - segment[0, 0], segment[1, 1] - segment[0, 1], segment[1, 2] - segment[0, 2]
    length = math.sqrt(ex * ex + ey * ey + ez * ez)
    if length > 0.0:
        # the face whose normal the contact normal is (if any), and is the segment along it?
        f_best, along = np.int64(-1), -np.inf
        for f in range(len(face_plane)):
            a, b, c, _ = _world_plane(face_plane, f, position, rotation)
            dot = a * nx + b * ny + c * nz
            if dot > along:
                f_best, along = f, dot
        fx, fy, fz, d = _world_plane(face_plane, f_best, position, rotation)
        if along > 1.0 - 1e-6 and abs(fx * ex + fy * ey + fz * ez) < CAPSULE_PARALLEL_SINE * length:
            # clip the segment [0, 1] by the face's side planes
            t0, t1 = 0.0, 1.0
            f0, f1 = face_vertex_start[f_best], face_vertex_start[f_best + 1]
            count = f1 - f0
            for s in range(count):
                p0x, p0y, p0z = _world_vertex(vertices, face_vertices[f0 + s], position, rotation)
                p1x, p1y, p1z = _world_vertex(vertices, face_vertices[f0 + (s + 1) % count], position, rotation)
                qx, qy, qz = p1x - p0x, p1y - p0y, p1z - p0z
                sx, sy, sz = fy * qz - fz * qy, fz * qx - fx * qz, fx * qy - fy * qx  # inward
                d0 = sx * (segment[0, 0] - p0x) + sy * (segment[0, 1] - p0y) + sz * (segment[0, 2] - p0z)
                de = sx * ex + sy * ey + sz * ez
                if de != 0.0:
                    t = -d0 / de
                    if de > 0.0:
                        t0 = max(t0, t)
                    else:
                        t1 = min(t1, t)
                elif d0 < 0.0:
                    t1 = -1.0
            if t1 - t0 > 1e-3:
                for end in range(2):
                    t = t0 if end == 0 else t1
                    cx, cy, cz = segment[0, 0] + t * ex, segment[0, 1] + t * ey, segment[0, 2] + t * ez
                    s_end = fx * cx + fy * cy + fz * cz - d - radius
                    if s_end < margin:
                        reach = radius + 0.5 * s_end
                        m = write_point(out, m, fx, fy, fz, s_end, cx - reach * fx, cy - reach * fy,
                                        cz - reach * fz, end)
                return m
    # one point: midway between the hull's surface point and the rounded core's
    bx, by, bz = bx - radius * nx, by - radius * ny, bz - radius * nz
    return write_point(out, m, nx, ny, nz, sep, 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * (az + bz), 2)


# ---- hull–triangle ---------------------------------------------------------------------------------------

@njit
def on_active_feature(triangle, active_edges, x, y, z):
    """Is the point (x, y, z) of ``triangle (3, 3)`` on one of its active edges (or a vertex of one)?  Barycentric
    weights (Ericson 3.4): edge e = (v_e, v_(e+1)%3) is where the third vertex's weight is 0; bit e of
    ``active_edges`` marks it active.  Interior points are on no edge."""
    ex, ey, ez = triangle[1, 0] - triangle[0, 0], triangle[1, 1] - triangle[0, 1], triangle[1, 2] - triangle[0, 2]
    fx, fy, fz = triangle[2, 0] - triangle[0, 0], triangle[2, 1] - triangle[0, 1], triangle[2, 2] - triangle[0, 2]
    px, py, pz = x - triangle[0, 0], y - triangle[0, 1], z - triangle[0, 2]
    d00 = ex * ex + ey * ey + ez * ez
    d01 = ex * fx + ey * fy + ez * fz
    d11 = fx * fx + fy * fy + fz * fz
    d20 = px * ex + py * ey + pz * ez
    d21 = px * fx + py * fy + pz * fz
    denom = d00 * d11 - d01 * d01
    w1 = (d11 * d20 - d01 * d21) / denom
    w2 = (d00 * d21 - d01 * d20) / denom
    w0 = 1.0 - w1 - w2
    eps = 1e-6
    return (w2 <= eps and (active_edges & 1) != 0) or (w0 <= eps and (active_edges & 2) != 0) \
        or (w1 <= eps and (active_edges & 4) != 0)


#: hull–triangle: what the upper bound of :func:`_separation_at_most` is padded by before it may stand in for GJK /
#: EPA's separation [m] (their own tolerance, 1e-11 of the shapes' size, with room to spare; the decisions it
#: replaces have tolerances of :data:`.box_box.AXIS_ABSOLUTE_TOLERANCE`, 5e-5 m)
SEPARATION_BOUND_SLACK = 1e-7
#: hulls of more faces than this skip the bound (its cost grows with the faces)
SEPARATION_BOUND_FACES = 32


@njit(inline="always")  # (one caller, per triangle: a call passes every array of both hulls; issue 38)
def _separation_at_most(triangle, hull, front_plane, sx, sy, sz, front_sep):
    """An upper bound of the true separation (GJK's distance, or minus EPA's depth) of ``triangle (3, 3)`` and
    the :class:`.convex.PosedHull` ``hull``, or inf if none is found cheaply.  The true separation is at most
    |a − b| for any a of the triangle and b of the hull (apart: the distance is the smallest such), and at most
    −δ for a corner a inside the hull at distance δ from its boundary (overlapping: moving the triangle by less
    than δ leaves a inside, so the depth is at least δ).  Tried: each corner (inside: −δ, the largest of its
    face-plane distances; outside: its height over the face it is farthest above, if its foot on that plane is
    in the hull), and the hull's support point along −n of the triangle's front ``(sx, sy, sz)``, ``front_sep``
    above it, if its foot is in the triangle."""
    face_plane, position, rotation = hull.face_plane, hull.position, hull.rotation
    faces = len(face_plane)
    best = np.inf
    if faces <= SEPARATION_BOUND_FACES:
        for c in range(3):
            # the corner in the hull's frame, where its planes are
            dx, dy, dz = triangle[c, 0] - position[0], triangle[c, 1] - position[1], triangle[c, 2] - position[2]
            lx = rotation[0, 0] * dx + rotation[1, 0] * dy + rotation[2, 0] * dz
            ly = rotation[0, 1] * dx + rotation[1, 1] * dy + rotation[2, 1] * dz
            lz = rotation[0, 2] * dx + rotation[1, 2] * dy + rotation[2, 2] * dz
            top, f_top = -np.inf, 0
            for f in range(faces):
                h = face_plane[f, 0] * lx + face_plane[f, 1] * ly + face_plane[f, 2] * lz - face_plane[f, 3]
                if h > top:
                    top, f_top = h, f
            if top <= 0.0:
                best = min(best, top)
                continue
            fx = lx - top * face_plane[f_top, 0]  # the foot on that face's plane
            fy = ly - top * face_plane[f_top, 1]
            fz = lz - top * face_plane[f_top, 2]
            inside = True
            for f in range(faces):
                if f != f_top and face_plane[f, 0] * fx + face_plane[f, 1] * fy + face_plane[f, 2] * fz \
                        - face_plane[f, 3] > 0.0:
                    inside = False
                    break
            if inside:
                best = min(best, top)
    if front_sep >= 0.0:
        # the support point's foot on the triangle's plane, in the triangle (the same-side test on each edge)
        nx, ny, nz = front_plane[0], front_plane[1], front_plane[2]
        px, py, pz = sx - front_sep * nx, sy - front_sep * ny, sz - front_sep * nz
        inside = True
        for e in range(3):
            a, b = e, (e + 1) % 3
            ex, ey = triangle[b, 0] - triangle[a, 0], triangle[b, 1] - triangle[a, 1]
            ez = triangle[b, 2] - triangle[a, 2]
            qx, qy, qz = px - triangle[a, 0], py - triangle[a, 1], pz - triangle[a, 2]
            # (e × q) · n: which side of edge e p is on; p is in the (closed) triangle if on the same side of all
            # three, whichever way the loop turns about n
            side = (ey * qz - ez * qy) * nx + (ez * qx - ex * qz) * ny + (ex * qy - ey * qx) * nz
            if e == 0:
                sign = 1.0 if side >= 0.0 else -1.0
            elif side * sign < 0.0:
                inside = False
                break
        if inside:
            best = min(best, front_sep)
    return best


class TriangleScratch(NamedTuple):
    """Work space of :func:`triangle_contacts_into` for one hull (:func:`triangle_scratch`): the triangle as a flat
    hull (its planes rewritten per triangle; its loops, unused adjacency and identity frame constant) and the
    clipping's :class:`FaceScratch`."""

    planes: np.ndarray   # (2, 4) the triangle's front and back planes
    indices: np.ndarray  # (13,) int64: loop starts [0:3], loops [3:9], adjacency starts [9:13] (zeros)
    frame: np.ndarray    # (4, 3): the identity rotation [0:3], the origin [3]
    faces: FaceScratch


@njit
def triangle_scratch(hull):
    """The :class:`TriangleScratch` for triangles against ``hull`` (a :class:`.convex.PosedHull`): its clipping
    columns cover a triangle against any of the hull's faces (:func:`incident_face`'s capacity either way round)."""
    indices = np.zeros(13, np.int64)
    indices[1], indices[2] = 3, 6
    indices[4], indices[5], indices[7], indices[8] = 1, 2, 2, 1
    frame = np.zeros((4, 3))
    frame[0, 0] = frame[1, 1] = frame[2, 2] = 1.0
    loop = 3
    for f in range(len(hull.face_vertex_start) - 1):
        loop = max(loop, hull.face_vertex_start[f + 1] - hull.face_vertex_start[f])
    return TriangleScratch(np.empty((2, 4)), indices, frame, face_scratch(2 * (loop + 3) + 4))


@njit(inline="always")  # (per triangle: a call passes every array of both hulls; issue 38)
def _clip_triangle(reference, face_r, incident, flip, best, margin, out, m, faces):
    """:func:`face_contact` of a triangle and a hull in the pair's :class:`FaceScratch` ``faces``: the triangle's
    face as reference with its corners inside the hull's incident face by :func:`_corners_under_face`, else by
    :func:`clip_incident`."""
    face_i, _ = incident_face(reference, face_r, incident)
    if not flip:
        done = _corners_under_face(reference, face_r, incident, face_i, best, margin, out, m)
        if done >= 0:
            return done
    return clip_incident(reference, face_r, incident, face_i, flip, best, margin, out, m, faces)


#: :func:`_corners_under_face` takes a triangle's corners as what the clipping would give when each is at least this
#: far inside the incident face, relative to the triangle's longest edge (the clipping's crossings are then far
#: from its sign tests' zero)
CORNER_INSIDE = 1e-6


@njit(inline="always")  # (one caller, per triangle: a call passes every array of both hulls; issue 38)
def _corners_under_face(flat, face_r, hull, face_i, best, margin, out, m):
    """The face contact of :func:`clip_incident` with the triangle ``flat`` (a flat :class:`.convex.PosedHull`,
    identity frame) as reference and the hull's face ``face_i`` as incident, when the triangle's three corners lie
    inside that face (seen along the triangle's normal; the face anti-parallel enough, winding the other way — a
    hull resting on a mesh, on every triangle under it but those along its outline): the clipped polygon is then
    the triangle itself, so its points are the corners lifted onto the incident face, with the clipping's labels
    (corner j of the loop: reference sides j in, j − 1 out), separations, lowering and features — what
    :func:`clip_incident` gives, to round-off, in ~a fifth of its time (issue 38: clipping a 4-gon by 3 sides was
    most of a triangle's cost).  Returns the next free row, or −1 if the corners are not all well inside (then the
    caller clips)."""
    nx, ny, nz, d_ref = _world_plane(flat.face_plane, face_r, flat.position, flat.rotation)
    a, b, c, d_i = _world_plane(hull.face_plane, face_i, hull.position, hull.rotation)
    facing = a * nx + b * ny + c * nz
    if not facing < -0.5:
        return -1
    r0 = flat.face_vertex_start[face_r]
    corners = flat.face_vertices
    q0x, q0y, q0z = _world_vertex(flat.vertices, corners[r0], flat.position, flat.rotation)
    q1x, q1y, q1z = _world_vertex(flat.vertices, corners[r0 + 1], flat.position, flat.rotation)
    q2x, q2y, q2z = _world_vertex(flat.vertices, corners[r0 + 2], flat.position, flat.rotation)
    longest = math.sqrt(max((q1x - q0x) ** 2 + (q1y - q0y) ** 2 + (q1z - q0z) ** 2,
                            (q2x - q1x) ** 2 + (q2y - q1y) ** 2 + (q2z - q1z) ** 2,
                            (q0x - q2x) ** 2 + (q0y - q2y) ** 2 + (q0z - q2z) ** 2))
    # each corner inside every edge of the incident loop, which must wind clockwise about n (the hull's outward
    # face seen from the triangle's front): (e × w) · n < 0 by a margin
    i0, i1 = hull.face_vertex_start[face_i], hull.face_vertex_start[face_i + 1]
    k = i1 - i0
    vertices_i, loop_i, position_i, rotation_i = hull.vertices, hull.face_vertices, hull.position, hull.rotation
    px, py, pz = _world_vertex(vertices_i, loop_i[i1 - 1], position_i, rotation_i)
    turn = 0.0
    for s in range(k):
        tx, ty, tz = _world_vertex(vertices_i, loop_i[i0 + s], position_i, rotation_i)
        ex, ey, ez = tx - px, ty - py, tz - pz
        cx, cy, cz = ey * nz - ez * ny, ez * nx - ex * nz, ex * ny - ey * nx  # e × n: (e × w) · n = −(e × n) · w
        turn += (py * ez - pz * ey) * nx + (pz * ex - px * ez) * ny + (px * ey - py * ex) * nz
        reach = CORNER_INSIDE * longest * math.sqrt(ex * ex + ey * ey + ez * ez)
        if not (cx * (q0x - px) + cy * (q0y - py) + cz * (q0z - pz) > reach
                and cx * (q1x - px) + cy * (q1y - py) + cz * (q1z - pz) > reach
                and cx * (q2x - px) + cy * (q2y - py) + cz * (q2z - pz) > reach):
            return -1
        px, py, pz = tx, ty, tz
    if not turn < 0.0:
        return -1
    # the points: each corner lifted along n onto the incident plane, in the reference face's frame as the clipping
    # has them (u along the loop's first edge, v = n × u), near-duplicates (a sliver) left to the clipping
    ux, uy, uz = q1x - q0x, q1y - q0y, q1z - q0z
    lu = math.sqrt(ux * ux + uy * uy + uz * uz)
    ux, uy, uz = ux / lu, uy / lu, uz / lu
    vx, vy, vz = ny * uz - nz * uy, nz * ux - nx * uz, nx * uy - ny * ux
    x0, x1, x2 = ux * q0x + uy * q0y + uz * q0z, ux * q1x + uy * q1y + uz * q1z, ux * q2x + uy * q2y + uz * q2z
    y0, y1, y2 = vx * q0x + vy * q0y + vz * q0z, vx * q1x + vy * q1y + vz * q1z, vx * q2x + vy * q2y + vz * q2z
    hu = 0.5 * (max(x0, x1, x2) - min(x0, x1, x2))
    hv = 0.5 * (max(y0, y1, y2) - min(y0, y1, y2))
    close = (1e-4 * (hu + hv)) ** 2
    if (x1 - x0) ** 2 + (y1 - y0) ** 2 <= close or (x2 - x0) ** 2 + (y2 - y0) ** 2 <= close \
            or (x2 - x1) ** 2 + (y2 - y1) ** 2 <= close:
        return -1
    lift0 = (d_i - (a * q0x + b * q0y + c * q0z)) / facing
    lift1 = (d_i - (a * q1x + b * q1y + c * q1z)) / facing
    lift2 = (d_i - (a * q2x + b * q2y + c * q2z)) / facing
    # Z: the lifted point's height over the reference plane (the corner is on it: the lift itself)
    z0 = nx * (q0x + lift0 * nx) + ny * (q0y + lift0 * ny) + nz * (q0z + lift0 * nz) - d_ref
    z1 = nx * (q1x + lift1 * nx) + ny * (q1y + lift1 * ny) + nz * (q1z + lift1 * nz) - d_ref
    z2 = nx * (q2x + lift2 * nx) + ny * (q2y + lift2 * ny) + nz * (q2z + lift2 * nz) - d_ref
    g0, g1, g2 = z0, z1, z2
    # the clipping's lowering when apart (to the reference face's SAT separation), before and after the margin
    if best > 0.0:
        shift = max(min(z0, z1, z2) - best, 0.0)
        z0, z1, z2 = z0 - shift, z1 - shift, z2 - shift
        nearest = min(z0 if z0 < margin else np.inf, z1 if z1 < margin else np.inf, z2 if z2 < margin else np.inf)
        if nearest < np.inf:
            shift = max(nearest - best, 0.0)
            z0, z1, z2 = z0 - shift, z1 - shift, z2 - shift
    base = FACE_FEATURE | (np.int64(face_r) << np.int64(40)) | (np.int64(face_i) << np.int64(20))
    for j in range(2, -1, -1):  # (the clipping's order for a loop inside a clockwise face)
        if j == 0:
            qx, qy, qz, lift, z, g = q0x, q0y, q0z, lift0, z0, g0
        elif j == 1:
            qx, qy, qz, lift, z, g = q1x, q1y, q1z, lift1, z1, g1
        else:
            qx, qy, qz, lift, z, g = q2x, q2y, q2z, lift2, z2, g2
        if z < margin:
            half = 0.5 * g
            label = (_REFERENCE_SIDE + j) * 512 + _REFERENCE_SIDE + (j + 2 if j == 0 else j - 1)
            m = write_point(out, m, nx, ny, nz, z, qx + lift * nx - half * nx, qy + lift * ny - half * ny,
                            qz + lift * nz - half * nz, base | label)
    return m


@njit(inline="always")  # (one caller, per triangle: a call passes every array of the hull; issue 38)
def _best_face_over_triangle(hull, triangle, stop):
    """:func:`best_face` of ``hull`` against ``triangle (3, 3)`` (world corners) without its work arrays (three
    allocations per triangle): the same arithmetic term by term — the corners turned into the hull's frame as
    t + M v with M = Rᵀ I and t = Rᵀ (0 − p), the flat triangle's frame being the identity — so the same bits."""
    face_plane = hull.face_plane
    x0, y0, z0 = _in_hull_frame(hull, triangle, 0)
    x1, y1, z1 = _in_hull_frame(hull, triangle, 1)
    x2, y2, z2 = _in_hull_frame(hull, triangle, 2)
    best_f, best = np.int64(0), -np.inf
    for f in range(len(face_plane)):
        nx, ny, nz, d = face_plane[f, 0], face_plane[f, 1], face_plane[f, 2], face_plane[f, 3]
        low = min(np.inf, nx * x0 + ny * y0 + nz * z0)
        low = min(low, nx * x1 + ny * y1 + nz * z1)
        low = min(low, nx * x2 + ny * y2 + nz * z2)
        s = low - d
        if s > best:
            best_f, best = f, s
            if s > stop:
                return best_f, best
    return best_f, best


@njit(inline="always")
def _in_hull_frame(hull, triangle, v):
    """Corner ``v`` of ``triangle`` in ``hull``'s frame as :func:`best_face` computes it (t + M v, M = Rᵀ I)."""
    R, p = hull.rotation, hull.position
    x, y, z = triangle[v, 0], triangle[v, 1], triangle[v, 2]
    out0 = R[0, 0] * (0.0 - p[0]) + R[1, 0] * (0.0 - p[1]) + R[2, 0] * (0.0 - p[2]) \
        + (R[0, 0] * 1.0 + R[1, 0] * 0.0 + R[2, 0] * 0.0) * x + (R[0, 0] * 0.0 + R[1, 0] * 1.0 + R[2, 0] * 0.0) * y \
        + (R[0, 0] * 0.0 + R[1, 0] * 0.0 + R[2, 0] * 1.0) * z
    out1 = R[0, 1] * (0.0 - p[0]) + R[1, 1] * (0.0 - p[1]) + R[2, 1] * (0.0 - p[2]) \
        + (R[0, 1] * 1.0 + R[1, 1] * 0.0 + R[2, 1] * 0.0) * x + (R[0, 1] * 0.0 + R[1, 1] * 1.0 + R[2, 1] * 0.0) * y \
        + (R[0, 1] * 0.0 + R[1, 1] * 0.0 + R[2, 1] * 1.0) * z
    out2 = R[0, 2] * (0.0 - p[0]) + R[1, 2] * (0.0 - p[1]) + R[2, 2] * (0.0 - p[2]) \
        + (R[0, 2] * 1.0 + R[1, 2] * 0.0 + R[2, 2] * 0.0) * x + (R[0, 2] * 0.0 + R[1, 2] * 1.0 + R[2, 2] * 0.0) * y \
        + (R[0, 2] * 0.0 + R[1, 2] * 0.0 + R[2, 2] * 1.0) * z
    return out0, out1, out2


@njit
def triangle_hull_contacts(triangle, active_edges, two_sided, hull, margin, out, m):
    """:func:`triangle_contacts_into` with work space of its own."""
    return triangle_contacts_into(triangle, active_edges, two_sided, hull, margin, out, m, triangle_scratch(hull))


@njit(inline="always")  # (per triangle: a call passes every array of the hull and the scratch; issue 38)
def triangle_contacts_into(triangle, active_edges, two_sided, hull, margin, out, m, scratch):
    """A static mesh's triangle (A: ``triangle (3, 3)`` world vertices, counter-clockwise seen from its front) vs
    hull B (a :class:`.convex.PosedHull`).  The triangle is a flat hull with two faces (front and back) and the contact
    is :func:`hull_hull_contacts`'s, except for internal edges ("ghost" collisions: a hull sliding across a flat mesh
    catching on the edge between two coplanar triangles, whose own normal is tilted): when the contact is an edge
    contact whose triangle feature is an *inactive* edge or vertex (``active_edges``: bit e for edge (v_e, v_e+1), from
    :func:`cgp_core.collision.bvh.active_edges`, computed at load), or whose normal is within :data:`GHOST_NORMAL_ANGLE`
    of the triangle's face normal, the contact becomes a face contact with the triangle's face as reference (Jolt's
    "active edges"; Bullet's internal-edge utility does the same with the normal).  A one-sided triangle (``two_sided``
    False: a closed mesh or a terrain) always pushes towards its front (an edge contact whose normal points behind it
    becomes a face contact too); a two-sided one towards the side the hull's centre is on.  ``scratch``: a
    :class:`TriangleScratch` for ``hull`` (:func:`triangle_scratch`; one serves every triangle of a mesh–hull pair)."""
    face_plane, position, rotation = hull.face_plane, hull.position, hull.rotation
    ex, ey, ez = triangle[1, 0] - triangle[0, 0], triangle[1, 1] - triangle[0, 1], triangle[1, 2] - triangle[0, 2]
    fx, fy, fz = triangle[2, 0] - triangle[0, 0], triangle[2, 1] - triangle[0, 1], triangle[2, 2] - triangle[0, 2]
    nx, ny, nz = ey * fz - ez * fy, ez * fx - ex * fz, ex * fy - ey * fx
    area2 = math.sqrt(nx * nx + ny * ny + nz * nz)
    if area2 == 0.0:
        return m
    nx, ny, nz = nx / area2, ny / area2, nz / area2
    d = nx * triangle[0, 0] + ny * triangle[0, 1] + nz * triangle[0, 2]
    front = 0
    if two_sided and nx * position[0] + ny * position[1] + nz * position[2] < d:
        front = 1
    # the triangle as a flat hull in world coordinates: face 0 = front, face 1 = back (its loops, the adjacency it
    # does not use and its frame are the scratch's constants)
    planes, indices, frame = scratch.planes, scratch.indices, scratch.frame
    planes[0, 0], planes[0, 1], planes[0, 2], planes[0, 3] = nx, ny, nz, d
    planes[1, 0], planes[1, 1], planes[1, 2], planes[1, 3] = -nx, -ny, -nz, -d
    flat = PosedHull(triangle, indices[9:13], indices[9:9], planes, indices[0:3], indices[3:9], frame[3], frame[0:3])
    core, flat_core = core_of(hull), core_of(flat)
    # the front face's SAT separation (one-sided: the only face of the triangle that counts)
    _, sx, sy, sz = support_point(core, -planes[front, 0], -planes[front, 1], -planes[front, 2], 0)
    front_sep = planes[front, 0] * sx + planes[front, 1] * sy + planes[front, 2] * sz - planes[front, 3]
    if not front_sep < margin:
        return m
    fb, best_b = _best_face_over_triangle(hull, triangle, margin)
    if not best_b < margin:
        return m
    use_b = best_b > front_sep + AXIS_ABSOLUTE_TOLERANCE + AXIS_RELATIVE_TOLERANCE * abs(front_sep)
    face_sep = best_b if use_b else front_sep
    edge_above = face_sep + AXIS_ABSOLUTE_TOLERANCE + AXIS_RELATIVE_TOLERANCE * abs(face_sep)
    # GJK / EPA only where they can change the outcome (issue 38: they were 2 of a triangle's ~4 µs, and a box
    # resting on a fine mesh has thousands of triangles under it): not when a cheap upper bound of the true
    # separation already shows no edge beats the face and the contact is within the margin, and no witness point
    # is needed (the hull's face as reference, tilted from the triangle's by more than GHOST_NORMAL_ANGLE, asks
    # whether the triangle's feature in the contact is an active edge)
    witness_needed = False
    if use_b:
        nx_b, ny_b, nz_b, _ = _world_plane(face_plane, fb, position, rotation)
        witness_needed = -(nx_b * planes[front, 0] + ny_b * planes[front, 1] + nz_b * planes[front, 2]) \
            < math.cos(GHOST_NORMAL_ANGLE)
    face = False  # the face contact decided without GJK / EPA
    if not witness_needed:
        bound = _separation_at_most(triangle, hull, planes[front], sx, sy, sz, front_sep) + SEPARATION_BOUND_SLACK
        face = bound <= edge_above and bound < margin
    if not face:
        sep, cx, cy, cz, ax, ay, az, bx, by, bz, edge_feature = signed_distance(flat_core, core)
        if not sep < margin:
            return m
        edge = sep > edge_above
        if edge or use_b:
            # the contact normal (A to B) and how far it is from the triangle's face normal
            if not edge:
                cx, cy, cz, _ = _world_plane(face_plane, fb, position, rotation)
                cx, cy, cz = -cx, -cy, -cz
            along = cx * planes[front, 0] + cy * planes[front, 1] + cz * planes[front, 2]
            if along < math.cos(GHOST_NORMAL_ANGLE) or (not two_sided and along <= 0.0):
                # the triangle's feature in the contact (EPA / GJK witness a): a ghost unless an active edge
                if not two_sided and along <= 0.0 or not on_active_feature(triangle, active_edges, ax, ay, az):
                    edge = use_b = False  # the triangle's face instead
            elif edge:
                edge = False  # nearly the face normal: the face contact
        if edge:
            return write_point(out, m, cx, cy, cz, sep, 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * (az + bz),
                               edge_feature)
    # (one call of each way round: the clipping is compiled into this kernel, once per call site; issue 38)
    if use_b:
        return _clip_triangle(hull, fb, flat, FLIPPED, best_b, margin, out, m, scratch.faces)
    return _clip_triangle(flat, front, hull, NOT_FLIPPED, front_sep, margin, out, m, scratch.faces)

"""GJK: distance and closest points between two convex shapes (Gilbert–Johnson–Keerthi 1988, in van den Bergen's
form, "A Fast and Robust GJK Implementation for Collision Detection of Convex Objects", 1999; Ericson 9.5).

Every shape is a *core* — a convex polytope given by its vertices in its own frame, posed by a position (3,) and
a rotation matrix (3, 3) (columns = the shape's axes in world) — swept by a sphere of ``radius``:

    sphere  = a point (1 vertex, the origin)            + radius
    capsule = a segment (2 vertices, ±half_length ẑ)     + radius
    box     = its 8 corners                              (radius 0)
    hull    = its vertices (:mod:`.convex`)              (radius 0)
    triangle= its 3 vertices                             (radius 0)

GJK runs on the cores only and the radii are subtracted afterwards (the standard trick, van den Bergen 1999 §4;
Box2D's b2ShapeDistance): the closest points of the rounded shapes lie on the line between the cores' closest
points, ``radius`` inside each.  So GJK needs nothing but the cores' support mapping (:func:`.convex.support_index`:
brute force for small cores, hill climbing over the adjacency for big hulls, warm-startable from the last
vertex).

The algorithm (van den Bergen 1999, Ericson 9.5.2).  The distance between A and B is the distance from the origin
to their Minkowski difference A − B = {a − b}.  GJK keeps a simplex W (1–4 points of A − B, each ``w = a − b``
remembered with its ``a`` and ``b``) and ``v``, the point of W's hull closest to the origin; it asks for the
support point w of A − B in the direction −v (A's support in −v minus B's in +v), adds it to W, replaces W by
the smallest sub-simplex containing the new closest point (:func:`closest_on_simplex`: the Voronoi regions of
Ericson 5.1.2 (segment), 5.1.5 (triangle), 5.1.6 (tetrahedron)), and repeats.  It stops (van den Bergen's
criteria) when

1. ``|v|² − v·w ≤ ε_rel |v|²``: w is no further along −v than v itself — v is the closest point up to the
   relative error ε_rel (:data:`RELATIVE_TOLERANCE`; for polytopes GJK reaches the exact closest feature);
2. the new support point is already in W (the same vertex pair of A and B): no progress is possible;
3. ``|v|²`` did not decrease (round-off in a nearly degenerate simplex): the previous simplex is kept;
4. ``|v|² ≤ ε_abs max |w|²`` or W is a tetrahedron containing the origin: the shapes overlap (or touch within
   round-off) — the *intersecting* flag; :mod:`.epa` then measures the penetration;
5. :data:`MAX_ITERATIONS` (never reached in the tests; the result is then the best so far).

Degenerate simplices (collinear triangles, flat tetrahedra) are handled in :func:`closest_on_simplex`: a flat
tetrahedron is never taken to contain the origin, a collinear triangle falls back to its edges.

Bundles (``typing.NamedTuple``, see "Bundles" in :mod:`cgp_core.jit`): each side is a :class:`Core` (its vertices,
their adjacency — a hull's, or empty arrays for the small cores — position and rotation); GJK's simplex travels as
a :class:`Simplex` of buffers; :func:`gjk_distance` gives a :class:`Distance`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit import njit
from .convex import support_index

#: criterion 1: stop when |v|² − v·w ≤ RELATIVE_TOLERANCE |v|² (distance error ≲ 1e-12 of the distance)
RELATIVE_TOLERANCE = 1e-12
#: criterion 4: |v|² ≤ ABSOLUTE_TOLERANCE max |w|² counts as touching / overlapping (|v| ≲ 1e-10 of the size)
ABSOLUTE_TOLERANCE = 1e-20
#: criterion 5: iteration cap (a polytope pair converges in a few more iterations than it has vertices on the
#: closest features; 128 is far above what the tests' 1000-vertex hulls need)
MAX_ITERATIONS = 128

#: an empty adjacency (cores without one: sphere, capsule, box, triangle — brute-force support)
NO_ADJACENCY = np.zeros(0, np.int64)


class Core(NamedTuple):
    """A posed convex core (see the module docstring): what GJK, EPA and the time of impact take for each side."""

    vertices: np.ndarray         # (k, 3) in the shape's own frame
    adjacency_start: np.ndarray  # (k + 1,) int64 — offsets into ``adjacency`` (a hull's), or zeros (small cores)
    adjacency: np.ndarray        # (a,) int64 — neighbour vertex indices (empty: brute-force support)
    position: np.ndarray         # (3,) world position of the frame's origin [m]
    rotation: np.ndarray         # (3, 3) the shape's axes (columns) in world


class Simplex(NamedTuple):
    """GJK's simplex W (up to 4 points of A − B, each remembered with its points on A and B), kept in buffers a
    kernel allocates once and passes around (so that an iteration allocates nothing)."""

    a: np.ndarray        # (4, 3) world support points on A
    b: np.ndarray        # (4, 3) world support points on B
    ia: np.ndarray       # (4,) int64 their vertex indices on A
    ib: np.ndarray       # (4,) int64 their vertex indices on B
    weights: np.ndarray  # (4,) barycentric weights of v, the point of W's hull closest to the origin


@njit
def empty_simplex():
    """A :class:`Simplex` of uninitialised buffers."""
    return Simplex(np.empty((4, 3)), np.empty((4, 3)), np.empty(4, np.int64), np.empty(4, np.int64), np.empty(4))


class WitnessPoints(NamedTuple):
    """The cores' closest points (world)."""

    ax: float
    ay: float
    az: float
    bx: float
    by: float
    bz: float


class Distance(NamedTuple):
    """What :func:`gjk_distance` gives."""

    distance: float          # between the rounded shapes [m] (cores' distance minus both radii)
    intersecting: bool       # the cores overlap (or touch within round-off): the rest is meaningless
    closest_a: np.ndarray    # (3,) closest point on A's rounded surface
    closest_b: np.ndarray    # (3,) closest point on B's rounded surface
    normal: np.ndarray       # (3,) unit direction from A to B (zeros when intersecting)


def point_core() -> np.ndarray:
    """(1, 3): a sphere's core."""
    return np.zeros((1, 3))


def segment_core(half_length: float) -> np.ndarray:
    """(2, 3): a capsule's core, the segment ±half_length along the shape's z axis."""
    return np.array([[0.0, 0.0, -half_length], [0.0, 0.0, half_length]])


def box_core(half_extents) -> np.ndarray:
    """(8, 3): a box's corners."""
    h = np.asarray(half_extents, dtype=float)
    return np.array([(sx, sy, sz) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float) * h


def no_adjacency(vertices: np.ndarray) -> np.ndarray:
    """(k + 1,) zeros: the ``adjacency_start`` of a core without adjacency."""
    return np.zeros(len(vertices) + 1, np.int64)


# ---- the support mapping of a posed core --------------------------------------------------------------------

@njit
def support_point(core, dx, dy, dz, start):
    """The :class:`Core`'s support vertex in the world direction d: ``(index, x, y, z)`` with x, y, z = position +
    rotation · vertices[index] and index maximizing d · (that point) (Ericson 9.1.2; d is turned into the
    shape's frame, d' = Rᵀ d, so the vertices are never transformed all at once)."""
    vertices, position, rotation = core.vertices, core.position, core.rotation
    lx = rotation[0, 0] * dx + rotation[1, 0] * dy + rotation[2, 0] * dz
    ly = rotation[0, 1] * dx + rotation[1, 1] * dy + rotation[2, 1] * dz
    lz = rotation[0, 2] * dx + rotation[1, 2] * dy + rotation[2, 2] * dz
    i = support_index(vertices, core.adjacency_start, core.adjacency, lx, ly, lz, start)
    v0, v1, v2 = vertices[i, 0], vertices[i, 1], vertices[i, 2]
    return (i, position[0] + rotation[0, 0] * v0 + rotation[0, 1] * v1 + rotation[0, 2] * v2,
            position[1] + rotation[1, 0] * v0 + rotation[1, 1] * v1 + rotation[1, 2] * v2,
            position[2] + rotation[2, 0] * v0 + rotation[2, 1] * v1 + rotation[2, 2] * v2)


# ---- the closest point of a simplex to the origin (Ericson 5.1) ----------------------------------------------

@njit
def _dot(ax, ay, az, bx, by, bz):
    return ax * bx + ay * by + az * bz


@njit
def closest_on_triangle(ax, ay, az, bx, by, bz, cx, cy, cz):
    """Barycentric weights ``(u, v, w)`` of the point of triangle abc closest to the origin (Ericson 5.1.5,
    ClosestPtPointTriangle with p = 0: the seven Voronoi regions — 3 vertices, 3 edges, the face — tested in
    order).  A zero weight means that vertex is not needed.  A degenerate (collinear) triangle gives the closest
    point of its longest-reaching edges."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    d1 = -_dot(abx, aby, abz, ax, ay, az)  # ab · (p − a), p = 0
    d2 = -_dot(acx, acy, acz, ax, ay, az)
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0  # vertex region a
    d3 = -_dot(abx, aby, abz, bx, by, bz)
    d4 = -_dot(acx, acy, acz, bx, by, bz)
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0  # vertex region b
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        return 1.0 - t, t, 0.0  # edge ab
    d5 = -_dot(abx, aby, abz, cx, cy, cz)
    d6 = -_dot(acx, acy, acz, cx, cy, cz)
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0  # vertex region c
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        return 1.0 - t, 0.0, t  # edge ac
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - t, t  # edge bc
    total = va + vb + vc
    if not total > 0.0:
        # collinear: the regions above overlap; take the closest of the three edges
        best, bu, bv, bw = np.inf, 1.0, 0.0, 0.0
        for e in range(3):
            if e == 0:
                px, py, pz, qx, qy, qz = ax, ay, az, bx, by, bz
            elif e == 1:
                px, py, pz, qx, qy, qz = ax, ay, az, cx, cy, cz
            else:
                px, py, pz, qx, qy, qz = bx, by, bz, cx, cy, cz
            ex, ey, ez = qx - px, qy - py, qz - pz
            ee = _dot(ex, ey, ez, ex, ey, ez)
            t = 0.0 if ee <= 0.0 else min(max(-_dot(ex, ey, ez, px, py, pz) / ee, 0.0), 1.0)
            rx, ry, rz = px + t * ex, py + t * ey, pz + t * ez
            dist = _dot(rx, ry, rz, rx, ry, rz)
            if dist < best:
                best = dist
                if e == 0:
                    bu, bv, bw = 1.0 - t, t, 0.0
                elif e == 1:
                    bu, bv, bw = 1.0 - t, 0.0, t
                else:
                    bu, bv, bw = 0.0, 1.0 - t, t
        return bu, bv, bw
    v = vb / total
    w = vc / total
    return 1.0 - v - w, v, w  # the face


@njit
def _origin_outside(w, i, j, k, o):
    """Is the origin on the other side of plane abc than d (a, b, c, d = the rows ``i, j, k, o`` of ``w``; Ericson
    5.1.6, PointOutsideOfPlane), or is the tetrahedron flat (then every face is tested)?"""
    ax, ay, az, bx, by, bz = w[i, 0], w[i, 1], w[i, 2], w[j, 0], w[j, 1], w[j, 2]
    cx, cy, cz, dx, dy, dz = w[k, 0], w[k, 1], w[k, 2], w[o, 0], w[o, 1], w[o, 2]
    nx = (by - ay) * (cz - az) - (bz - az) * (cy - ay)
    ny = (bz - az) * (cx - ax) - (bx - ax) * (cz - az)
    nz = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    sign_p = -_dot(nx, ny, nz, ax, ay, az)
    sign_d = _dot(nx, ny, nz, dx - ax, dy - ay, dz - az)
    scale = (abs(dx - ax) + abs(dy - ay) + abs(dz - az)) * math.sqrt(_dot(nx, ny, nz, nx, ny, nz))
    return sign_p * sign_d < 0.0 or abs(sign_d) <= 1e-12 * scale


@njit
def closest_on_simplex(simplex, count, w, lam):
    """Reduce the :class:`Simplex` W = {a_i − b_i, i < count} to the smallest sub-simplex whose hull holds the point of
    W's hull closest to the origin, in place (kept entries first, ``weights`` their barycentric weights), and
    return the new count; 4 means the tetrahedron contains the origin (the shapes overlap).  ``w (4, 3)`` and
    ``lam (4,)`` are scratch (the caller's, so that a GJK iteration allocates nothing)."""
    simplex_a, simplex_b, simplex_ia, simplex_ib, weights = simplex
    for i in range(count):
        for r in range(3):
            w[i, r] = simplex_a[i, r] - simplex_b[i, r]
    lam[:] = 0.0
    if count == 1:
        lam[0] = 1.0
    elif count == 2:  # Ericson 5.1.2 (closest point on a segment), p = 0
        ex, ey, ez = w[1, 0] - w[0, 0], w[1, 1] - w[0, 1], w[1, 2] - w[0, 2]
        ee = _dot(ex, ey, ez, ex, ey, ez)
        t = 0.0 if ee <= 0.0 else -_dot(ex, ey, ez, w[0, 0], w[0, 1], w[0, 2]) / ee
        t = min(max(t, 0.0), 1.0)
        lam[0], lam[1] = 1.0 - t, t
    elif count == 3:
        lam[0], lam[1], lam[2] = closest_on_triangle(w[0, 0], w[0, 1], w[0, 2], w[1, 0], w[1, 1], w[1, 2],
                                                     w[2, 0], w[2, 1], w[2, 2])
    else:  # Ericson 5.1.6: the closest point of each face the origin is outside of
        best = np.inf
        inside = True
        for f in range(4):
            # face (i, j, k) opposite vertex o
            if f == 0:
                i, j, k, o = 0, 1, 2, 3
            elif f == 1:
                i, j, k, o = 0, 2, 3, 1
            elif f == 2:
                i, j, k, o = 0, 3, 1, 2
            else:
                i, j, k, o = 1, 3, 2, 0
            if _origin_outside(w, i, j, k, o):
                inside = False
                u, v, s = closest_on_triangle(w[i, 0], w[i, 1], w[i, 2], w[j, 0], w[j, 1], w[j, 2],
                                              w[k, 0], w[k, 1], w[k, 2])
                px = u * w[i, 0] + v * w[j, 0] + s * w[k, 0]
                py = u * w[i, 1] + v * w[j, 1] + s * w[k, 1]
                pz = u * w[i, 2] + v * w[j, 2] + s * w[k, 2]
                dist = _dot(px, py, pz, px, py, pz)
                if dist < best:
                    best = dist
                    lam[:] = 0.0
                    lam[i], lam[j], lam[k] = u, v, s
        if inside:
            for i in range(4):
                weights[i] = 0.25
            return 4
    # compact: keep the vertices with a positive weight, in order
    kept = 0
    for i in range(count):
        if lam[i] > 0.0:
            for r in range(3):
                simplex_a[kept, r] = simplex_a[i, r]
                simplex_b[kept, r] = simplex_b[i, r]
            simplex_ia[kept] = simplex_ia[i]
            simplex_ib[kept] = simplex_ib[i]
            weights[kept] = lam[i]
            kept += 1
    return kept


# ---- GJK ---------------------------------------------------------------------------------------------------

@njit
def gjk(core_a, core_b, start_a, start_b, simplex):
    """GJK on two posed cores (:class:`Core`; see the module docstring for the algorithm and the stopping
    criteria).

    ``start_a``, ``start_b``: hill-climbing start vertices (the previous query's, or 0).  The final simplex is
    left in the :class:`Simplex` buffers (for :mod:`.epa`).  Returns ``(count, intersecting, iterations)``; the
    closest points are ``Σ weights[i] a[i]`` and ``Σ weights[i] b[i]`` over ``i < count``.
    """
    simplex_a, simplex_b, simplex_ia, simplex_ib, weights = simplex
    position_a, position_b = core_a.position, core_b.position
    # first support pair: A's point towards B, B's towards A (a good guess of the closest points)
    dx = position_b[0] - position_a[0]
    dy = position_b[1] - position_a[1]
    dz = position_b[2] - position_a[2]
    if dx * dx + dy * dy + dz * dz == 0.0:
        dx = 1.0
    ia, ax, ay, az = support_point(core_a, dx, dy, dz, start_a)
    ib, bx, by, bz = support_point(core_b, -dx, -dy, -dz, start_b)
    simplex_a[0, 0], simplex_a[0, 1], simplex_a[0, 2] = ax, ay, az
    simplex_b[0, 0], simplex_b[0, 1], simplex_b[0, 2] = bx, by, bz
    simplex_ia[0], simplex_ib[0] = ia, ib
    weights[0] = 1.0
    count = 1
    vx, vy, vz = ax - bx, ay - by, az - bz
    max_w2 = _dot(vx, vy, vz, vx, vy, vz)
    keep_a, keep_b = np.empty((4, 3)), np.empty((4, 3))
    keep_ia, keep_ib, keep_w = np.empty(4, np.int64), np.empty(4, np.int64), np.empty(4)
    scratch_w, scratch_lam = np.empty((4, 3)), np.empty(4)
    iterations = 0
    while iterations < MAX_ITERATIONS:
        iterations += 1
        vv = _dot(vx, vy, vz, vx, vy, vz)
        if vv <= ABSOLUTE_TOLERANCE * max_w2:
            return count, True, iterations  # criterion 4: touching within round-off
        # support point of A − B in the direction −v
        ia, ax, ay, az = support_point(core_a, -vx, -vy, -vz, ia)
        ib, bx, by, bz = support_point(core_b, vx, vy, vz, ib)
        duplicate = False
        for i in range(count):
            if simplex_ia[i] == ia and simplex_ib[i] == ib:
                duplicate = True
        if duplicate:
            break  # criterion 2
        wx, wy, wz = ax - bx, ay - by, az - bz
        if vv - _dot(vx, vy, vz, wx, wy, wz) <= RELATIVE_TOLERANCE * vv:
            break  # criterion 1
        for i in range(count):  # remember the simplex, for criterion 3
            for r in range(3):
                keep_a[i, r] = simplex_a[i, r]
                keep_b[i, r] = simplex_b[i, r]
            keep_ia[i], keep_ib[i], keep_w[i] = simplex_ia[i], simplex_ib[i], weights[i]
        kept = count
        simplex_a[count, 0], simplex_a[count, 1], simplex_a[count, 2] = ax, ay, az
        simplex_b[count, 0], simplex_b[count, 1], simplex_b[count, 2] = bx, by, bz
        simplex_ia[count], simplex_ib[count] = ia, ib
        count += 1
        max_w2 = max(max_w2, _dot(wx, wy, wz, wx, wy, wz))
        count = closest_on_simplex(simplex, count, scratch_w, scratch_lam)
        if count == 4:
            return count, True, iterations  # criterion 4: the origin is inside the tetrahedron
        nx = ny = nz = 0.0
        for i in range(count):
            nx += weights[i] * (simplex_a[i, 0] - simplex_b[i, 0])
            ny += weights[i] * (simplex_a[i, 1] - simplex_b[i, 1])
            nz += weights[i] * (simplex_a[i, 2] - simplex_b[i, 2])
        if _dot(nx, ny, nz, nx, ny, nz) >= vv:
            # criterion 3: no progress (round-off) — back to the previous simplex
            for i in range(kept):
                for r in range(3):
                    simplex_a[i, r] = keep_a[i, r]
                    simplex_b[i, r] = keep_b[i, r]
                simplex_ia[i], simplex_ib[i], weights[i] = keep_ia[i], keep_ib[i], keep_w[i]
            count = kept
            break
        vx, vy, vz = nx, ny, nz
    return count, False, iterations


@njit
def witness_points(simplex, count):
    """The closest points (:class:`WitnessPoints`): Σ weights[i] a[i], Σ weights[i] b[i] over the
    :class:`Simplex`'s first ``count`` points."""
    simplex_a, simplex_b, weights = simplex.a, simplex.b, simplex.weights
    ax = ay = az = bx = by = bz = 0.0
    for i in range(count):
        ax += weights[i] * simplex_a[i, 0]
        ay += weights[i] * simplex_a[i, 1]
        az += weights[i] * simplex_a[i, 2]
        bx += weights[i] * simplex_b[i, 0]
        by += weights[i] * simplex_b[i, 1]
        bz += weights[i] * simplex_b[i, 2]
    return WitnessPoints(ax, ay, az, bx, by, bz)


@njit
def gjk_distance(core_a, radius_a, core_b, radius_b):
    """Distance between two rounded cores (:class:`Core` + radius) and their closest points; from Python, the
    cores may be plain tuples (see "Bundles" in :mod:`cgp_core.jit`).

    Returns a :class:`Distance`: ``distance`` between the rounded shapes (the cores' distance minus both radii;
    negative only when the cores are apart but the spheres around them overlap), ``normal`` the unit direction
    from A to B (from closest_a to closest_b on the cores).  ``intersecting``: the cores overlap (or touch within
    round-off) — distance, points and normal are then meaningless and :func:`.epa.penetration` gives the depth.
    """
    core_a, core_b = Core(*core_a), Core(*core_b)
    simplex = empty_simplex()
    count, intersecting, _ = gjk(core_a, core_b, 0, 0, simplex)
    ax, ay, az, bx, by, bz = witness_points(simplex, count)
    closest_a, closest_b, normal = np.empty(3), np.empty(3), np.zeros(3)
    nx, ny, nz = bx - ax, by - ay, bz - az
    core = math.sqrt(nx * nx + ny * ny + nz * nz)
    if intersecting or core == 0.0:
        closest_a[0], closest_a[1], closest_a[2] = ax, ay, az
        closest_b[0], closest_b[1], closest_b[2] = bx, by, bz
        return Distance(0.0, True, closest_a, closest_b, normal)
    normal[0], normal[1], normal[2] = nx / core, ny / core, nz / core
    closest_a[0], closest_a[1], closest_a[2] = ax + radius_a * normal[0], ay + radius_a * normal[1], \
        az + radius_a * normal[2]
    closest_b[0], closest_b[1], closest_b[2] = bx - radius_b * normal[0], by - radius_b * normal[1], \
        bz - radius_b * normal[2]
    return Distance(core - radius_a - radius_b, False, closest_a, closest_b, normal)

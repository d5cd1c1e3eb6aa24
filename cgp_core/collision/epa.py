"""Penetration depth and normal of two overlapping convex cores: the Expanding Polytope Algorithm (EPA; van den
Bergen, "Proximity Queries and Penetration Depth Computation on 3D Game Objects", GDC 2001; Ericson 9.5 mentions
it; Jolt's ``EPAPenetrationDepth.h`` is the same algorithm).

Why EPA and not MPR (Minkowski Portal Refinement, Snethen, *Game Programming Gems 7*): MPR finds *a* portal of
the Minkowski difference along the line between the two centres and reports the depth along that line — fast,
but not the minimum translation, so its normal depends on where the centres are and a hull resting on a face at
an offset gets a tilted normal.  EPA finds the face of the Minkowski difference A − B closest to the origin: the
exact penetration depth of two polytopes (the minimum over A − B's face planes of the origin's distance) and the
face's normal, which for face contacts *is* a face normal of A or B — what the contact manifold (:mod:`.manifold`)
needs to pick the reference face, and what makes a box given as a hull behave like the box.

The algorithm.  GJK (:mod:`.gjk`) ends with a simplex of A − B containing the origin (a tetrahedron, or fewer
points when the shapes just touch; those are blown up to a tetrahedron by support points in new directions).
EPA keeps that polytope as triangles with outward normals and, repeatedly:

1. takes the face closest to the origin (distance d along its unit normal n);
2. asks for the support point w of A − B along n (A's support along n minus B's along −n);
3. stops if w is no further than the face (n · w − d ≤ :data:`TOLERANCE` × size) or is already a vertex: the
   face is on the boundary of A − B, d is the depth and n the normal;
4. otherwise removes every face w can see, and closes the hole with triangles from the horizon edges to w.

The witness points are the barycentric combination, over the face's three vertices, of their A and B support
points at the origin's projection d n on the face.  Capacity: :data:`MAX_VERTICES` vertices and
:data:`MAX_FACES` faces, the slots of removed faces reused (a polytope pair needs a few more iterations than the
Minkowski face has vertices; the result when the cap is hit is the best face so far, flagged not converged).  A
Minkowski difference without volume (a point or segment core against a triangle, two coplanar triangles) has
depth 0: EPA returns 0 and that flat set's normal.

Bundles as in :mod:`.gjk` (a :class:`.gjk.Core` per side); :func:`epa` gives a :class:`Penetration`.  Sign conventions:
``normal`` points from A to B; ``point_a`` (on A) lies ``depth`` beyond ``point_b`` (on B) along the normal: ``point_a −
point_b = depth · normal``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit import njit
from .gjk import Core, Simplex, empty_simplex, gjk, support_point, witness_points

#: polytope capacity
MAX_VERTICES = 96
#: a closed triangulated polytope of V vertices has 2V − 4 faces; removed faces' slots are reused
MAX_FACES = 2 * MAX_VERTICES + 8
#: step 3: a support point no further than TOLERANCE × (the polytope's size) beyond the closest face stops EPA
TOLERANCE = 1e-11

_BLOW_UP_DIRECTIONS = np.array([(1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0),
                                (0.0, 0.0, 1.0), (0.0, 0.0, -1.0)])


class Penetration(NamedTuple):
    """What :func:`epa` gives (see the module docstring for the sign conventions)."""

    depth: float          # penetration depth of the cores [m] (≥ 0)
    normal: np.ndarray    # (3,) unit, from A to B
    point_a: np.ndarray   # (3,) witness point on A
    point_b: np.ndarray   # (3,) witness point on B (point_a − point_b = depth · normal)
    converged: bool       # False: the polytope's capacity was reached (the best face so far)


@njit
def _support(core_a, core_b, dx, dy, dz, pa, pb, pia, pib, slot):
    """Support point of A − B (:class:`.gjk.Core` each) along d into polytope slot ``slot``."""
    start_a = pia[0] if slot > 0 else 0
    start_b = pib[0] if slot > 0 else 0
    ia, ax, ay, az = support_point(core_a, dx, dy, dz, start_a)
    ib, bx, by, bz = support_point(core_b, -dx, -dy, -dz, start_b)
    pa[slot, 0], pa[slot, 1], pa[slot, 2] = ax, ay, az
    pb[slot, 0], pb[slot, 1], pb[slot, 2] = bx, by, bz
    pia[slot], pib[slot] = ia, ib


@njit
def _face(pa, pb, i, j, k, face, normal, distance, alive, f):
    """Make face f = (i, j, k) (counter-clockwise seen from outside): its unit normal and the origin's distance
    to its plane.  A face without area gets a zero normal and an infinite distance (never the closest)."""
    ax, ay, az = pa[i, 0] - pb[i, 0], pa[i, 1] - pb[i, 1], pa[i, 2] - pb[i, 2]
    ux, uy, uz = pa[j, 0] - pb[j, 0] - ax, pa[j, 1] - pb[j, 1] - ay, pa[j, 2] - pb[j, 2] - az
    vx, vy, vz = pa[k, 0] - pb[k, 0] - ax, pa[k, 1] - pb[k, 1] - ay, pa[k, 2] - pb[k, 2] - az
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    length = math.sqrt(nx * nx + ny * ny + nz * nz)
    face[f, 0], face[f, 1], face[f, 2] = i, j, k
    alive[f] = True
    if length > 0.0:
        normal[f, 0], normal[f, 1], normal[f, 2] = nx / length, ny / length, nz / length
        distance[f] = (nx * ax + ny * ay + nz * az) / length
    else:
        normal[f, 0] = normal[f, 1] = normal[f, 2] = 0.0
        distance[f] = np.inf


@njit
def _w(pa, pb, i, r):
    return pa[i, r] - pb[i, r]


@njit
def epa(core_a, core_b, simplex, count):
    """EPA from GJK's final :class:`.gjk.Simplex` (``count`` points, see :func:`.gjk.gjk`) of two overlapping
    cores (:class:`.gjk.Core`).  Returns a :class:`Penetration` (see the module docstring).
    """
    simplex_a, simplex_b, simplex_ia, simplex_ib = simplex.a, simplex.b, simplex.ia, simplex.ib
    pa, pb = np.empty((MAX_VERTICES, 3)), np.empty((MAX_VERTICES, 3))
    pia, pib = np.empty(MAX_VERTICES, np.int64), np.empty(MAX_VERTICES, np.int64)
    for i in range(count):
        for r in range(3):
            pa[i, r], pb[i, r] = simplex_a[i, r], simplex_b[i, r]
        pia[i], pib[i] = simplex_ia[i], simplex_ib[i]
    scale = 0.0
    for i in range(count):
        scale = max(scale, abs(_w(pa, pb, i, 0)) + abs(_w(pa, pb, i, 1)) + abs(_w(pa, pb, i, 2)))
    normal_out, point_a, point_b = np.zeros(3), np.empty(3), np.empty(3)

    # -- blow the simplex up to a tetrahedron (the shapes may only touch: GJK then stops with 1–3 points)
    n = count
    if n == 1:
        for k in range(6):
            d = _BLOW_UP_DIRECTIONS[k]
            _support(core_a, core_b, d[0], d[1], d[2], pa, pb, pia, pib, 1)
            ex, ey, ez = _w(pa, pb, 1, 0) - _w(pa, pb, 0, 0), _w(pa, pb, 1, 1) - _w(pa, pb, 0, 1), \
                _w(pa, pb, 1, 2) - _w(pa, pb, 0, 2)
            reach = abs(ex) + abs(ey) + abs(ez)
            scale = max(scale, reach)
            if reach > 1e-9 * scale:
                n = 2
                break
    if n == 2:
        ex, ey, ez = _w(pa, pb, 1, 0) - _w(pa, pb, 0, 0), _w(pa, pb, 1, 1) - _w(pa, pb, 0, 1), \
            _w(pa, pb, 1, 2) - _w(pa, pb, 0, 2)
        # p ⟂ e (crossed with the axis least along e), q = e × p: six directions around the segment
        ax_ = abs(ex) <= abs(ey) and abs(ex) <= abs(ez)
        ay_ = not ax_ and abs(ey) <= abs(ez)
        if ax_:
            px, py, pz = 0.0, ez, -ey
        elif ay_:
            px, py, pz = -ez, 0.0, ex
        else:
            px, py, pz = ey, -ex, 0.0
        lp = math.sqrt(px * px + py * py + pz * pz)
        px, py, pz = px / lp, py / lp, pz / lp
        le = math.sqrt(ex * ex + ey * ey + ez * ez)
        qx, qy, qz = (ey * pz - ez * py) / le, (ez * px - ex * pz) / le, (ex * py - ey * px) / le
        normal_out[0], normal_out[1], normal_out[2] = px, py, pz
        for k in range(6):
            c, s = math.cos(k * math.pi / 3.0), math.sin(k * math.pi / 3.0)
            _support(core_a, core_b, c * px + s * qx, c * py + s * qy,
                     c * pz + s * qz, pa, pb, pia, pib, 2)
            # distance of the new point from the segment's line
            rx, ry, rz = _w(pa, pb, 2, 0) - _w(pa, pb, 0, 0), _w(pa, pb, 2, 1) - _w(pa, pb, 0, 1), \
                _w(pa, pb, 2, 2) - _w(pa, pb, 0, 2)
            cx, cy, cz = ry * ez - rz * ey, rz * ex - rx * ez, rx * ey - ry * ex
            if math.sqrt(cx * cx + cy * cy + cz * cz) > 1e-9 * scale * le:
                n = 3
                break
    if n == 3:
        ux, uy, uz = _w(pa, pb, 1, 0) - _w(pa, pb, 0, 0), _w(pa, pb, 1, 1) - _w(pa, pb, 0, 1), \
            _w(pa, pb, 1, 2) - _w(pa, pb, 0, 2)
        vx, vy, vz = _w(pa, pb, 2, 0) - _w(pa, pb, 0, 0), _w(pa, pb, 2, 1) - _w(pa, pb, 0, 1), \
            _w(pa, pb, 2, 2) - _w(pa, pb, 0, 2)
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        nx, ny, nz = nx / ln, ny / ln, nz / ln
        normal_out[0], normal_out[1], normal_out[2] = nx, ny, nz
        for sign in (1.0, -1.0):
            _support(core_a, core_b, sign * nx, sign * ny, sign * nz,
                     pa, pb, pia, pib, 3)
            h = sign * (nx * (_w(pa, pb, 3, 0) - _w(pa, pb, 0, 0)) + ny * (_w(pa, pb, 3, 1) - _w(pa, pb, 0, 1))
                        + nz * (_w(pa, pb, 3, 2) - _w(pa, pb, 0, 2)))
            if h > 1e-9 * scale:
                n = 4
                break
    if n < 4:
        # A − B has no volume (or GJK's simplex could not be extended): the depth is 0
        ax, ay, az, bx, by, bz = witness_points(Simplex(simplex_a, simplex_b, simplex_ia, simplex_ib,
                                                        np.full(count, 1.0 / count)), count)
        point_a[0], point_a[1], point_a[2] = ax, ay, az
        point_b[0], point_b[1], point_b[2] = bx, by, bz
        if n == 1:
            normal_out[2] = 1.0
        return Penetration(0.0, normal_out, point_a, point_b, False)

    # -- the tetrahedron's four faces, outward
    face = np.empty((MAX_FACES, 3), np.int64)
    normal = np.empty((MAX_FACES, 3))
    distance = np.empty(MAX_FACES)
    alive = np.zeros(MAX_FACES, np.bool_)
    nfaces = 0
    for f in range(4):
        if f == 0:
            i, j, k, opposite = 0, 1, 2, 3
        elif f == 1:
            i, j, k, opposite = 0, 3, 1, 2
        elif f == 2:
            i, j, k, opposite = 0, 2, 3, 1
        else:
            i, j, k, opposite = 1, 3, 2, 0
        _face(pa, pb, i, j, k, face, normal, distance, alive, nfaces)
        side = normal[nfaces, 0] * (_w(pa, pb, opposite, 0) - _w(pa, pb, i, 0)) \
            + normal[nfaces, 1] * (_w(pa, pb, opposite, 1) - _w(pa, pb, i, 1)) \
            + normal[nfaces, 2] * (_w(pa, pb, opposite, 2) - _w(pa, pb, i, 2))
        if side > 0.0:
            _face(pa, pb, i, k, j, face, normal, distance, alive, nfaces)
        nfaces += 1
    nverts = 4
    for i in range(4):
        scale = max(scale, abs(_w(pa, pb, i, 0)) + abs(_w(pa, pb, i, 1)) + abs(_w(pa, pb, i, 2)))

    horizon = np.empty((3 * MAX_FACES, 2), np.int64)
    removed = np.empty(MAX_FACES, np.int64)
    converged = False
    best = 0
    while True:
        # 1. the face closest to the origin
        best, best_d = -1, np.inf
        for f in range(nfaces):
            if alive[f] and distance[f] < best_d:
                best, best_d = f, distance[f]
        if best < 0 or nverts >= MAX_VERTICES:
            break
        nx, ny, nz = normal[best, 0], normal[best, 1], normal[best, 2]
        # 2. the support point along its normal
        _support(core_a, core_b, nx, ny, nz, pa, pb, pia, pib, nverts)
        wx, wy, wz = _w(pa, pb, nverts, 0), _w(pa, pb, nverts, 1), _w(pa, pb, nverts, 2)
        # 3. converged: no further than the face, or a vertex already in the polytope
        if nx * wx + ny * wy + nz * wz - best_d <= TOLERANCE * scale:
            converged = True
            break
        duplicate = False
        for v in range(nverts):
            if pia[v] == pia[nverts] and pib[v] == pib[nverts]:
                duplicate = True
        if duplicate:
            converged = True
            break
        # 4. remove the faces w sees; their edges not shared by two removed faces are the horizon
        nremoved = 0
        for f in range(nfaces):
            if alive[f]:
                i = face[f, 0]
                if f == best or normal[f, 0] * (wx - _w(pa, pb, i, 0)) + normal[f, 1] * (wy - _w(pa, pb, i, 1)) \
                        + normal[f, 2] * (wz - _w(pa, pb, i, 2)) > 1e-14 * scale:
                    alive[f] = False
                    removed[nremoved] = f
                    nremoved += 1
        nhorizon = 0
        for r in range(nremoved):
            f = removed[r]
            for e in range(3):
                u, v = face[f, e], face[f, (e + 1) % 3]
                shared = False
                for r2 in range(nremoved):
                    g = removed[r2]
                    if (face[g, 0] == v and face[g, 1] == u) or (face[g, 1] == v and face[g, 2] == u) \
                            or (face[g, 2] == v and face[g, 0] == u):
                        shared = True
                        break
                if not shared:
                    horizon[nhorizon, 0], horizon[nhorizon, 1] = u, v
                    nhorizon += 1
        if nfaces + max(nhorizon - nremoved, 0) > MAX_FACES:
            for r in range(nremoved):  # no room: undo and stop with the best face so far
                alive[removed[r]] = True
            break
        for e in range(nhorizon):  # the new faces, in the removed faces' slots first
            if e < nremoved:
                slot = removed[e]
            else:
                slot = nfaces
                nfaces += 1
            _face(pa, pb, horizon[e, 0], horizon[e, 1], nverts, face, normal, distance, alive, slot)
        scale = max(scale, abs(wx) + abs(wy) + abs(wz))
        nverts += 1

    # the origin's projection on the closest face, as barycentric weights of its three vertices (Ericson 3.4)
    depth = distance[best]
    nx, ny, nz = normal[best, 0], normal[best, 1], normal[best, 2]
    i, j, k = face[best, 0], face[best, 1], face[best, 2]
    qx, qy, qz = depth * nx, depth * ny, depth * nz
    v0x, v0y, v0z = _w(pa, pb, j, 0) - _w(pa, pb, i, 0), _w(pa, pb, j, 1) - _w(pa, pb, i, 1), \
        _w(pa, pb, j, 2) - _w(pa, pb, i, 2)
    v1x, v1y, v1z = _w(pa, pb, k, 0) - _w(pa, pb, i, 0), _w(pa, pb, k, 1) - _w(pa, pb, i, 1), \
        _w(pa, pb, k, 2) - _w(pa, pb, i, 2)
    v2x, v2y, v2z = qx - _w(pa, pb, i, 0), qy - _w(pa, pb, i, 1), qz - _w(pa, pb, i, 2)
    d00 = v0x * v0x + v0y * v0y + v0z * v0z
    d01 = v0x * v1x + v0y * v1y + v0z * v1z
    d11 = v1x * v1x + v1y * v1y + v1z * v1z
    d20 = v2x * v0x + v2y * v0y + v2z * v0z
    d21 = v2x * v1x + v2y * v1y + v2z * v1z
    denom = d00 * d11 - d01 * d01
    if denom > 0.0:
        bv = (d11 * d20 - d01 * d21) / denom
        bw = (d00 * d21 - d01 * d20) / denom
    else:
        bv = bw = 1.0 / 3.0
    bu = 1.0 - bv - bw
    for r in range(3):
        point_a[r] = bu * pa[i, r] + bv * pa[j, r] + bw * pa[k, r]
        point_b[r] = bu * pb[i, r] + bv * pb[j, r] + bw * pb[k, r]
    normal_out[0], normal_out[1], normal_out[2] = nx, ny, nz
    return Penetration(depth, normal_out, point_a, point_b, converged)


@njit
def penetration(core_a, radius_a, core_b, radius_b):
    """Signed distance of two rounded cores (:class:`.gjk.Core` + radius; from Python the cores may be plain
    tuples, see "Bundles" in :mod:`cgp_core.jit`): GJK, and EPA when the cores overlap.

    Returns ``(separation, normal (3,), point_a (3,), point_b (3,))``: ``separation`` > 0 apart (the distance),
    < 0 overlapping (minus the penetration depth: the cores' EPA depth plus both radii, or the radii's overlap
    when only the rounded parts overlap); ``normal`` the unit direction from A to B along which B must move by
    −separation to just touch; ``point_a``, ``point_b`` the surface points of A and B along it
    (``point_b − point_a = separation · normal``).
    """
    core_a, core_b = Core(*core_a), Core(*core_b)
    simplex = empty_simplex()
    count, intersecting, _ = gjk(core_a, core_b, 0, 0, simplex)
    normal, point_a, point_b = np.zeros(3), np.empty(3), np.empty(3)
    ax, ay, az, bx, by, bz = witness_points(simplex, count)
    core = math.sqrt((bx - ax) ** 2 + (by - ay) ** 2 + (bz - az) ** 2)
    if not intersecting and core > 0.0:
        normal[0], normal[1], normal[2] = (bx - ax) / core, (by - ay) / core, (bz - az) / core
        separation = core
    else:
        depth, n, pa, pb, _ = epa(core_a, core_b, simplex, count)
        normal[:] = n
        ax, ay, az, bx, by, bz = pa[0], pa[1], pa[2], pb[0], pb[1], pb[2]
        separation = -depth
    point_a[0], point_a[1], point_a[2] = ax + radius_a * normal[0], ay + radius_a * normal[1], \
        az + radius_a * normal[2]
    point_b[0], point_b[1], point_b[2] = bx - radius_b * normal[0], by - radius_b * normal[1], \
        bz - radius_b * normal[2]
    return separation - radius_a - radius_b, normal, point_a, point_b

"""Contacts of movable shapes with a static triangle mesh: the BVH (:mod:`.bvh`) finds the triangles near the shape,
and each triangle is a flat convex piece for :mod:`.manifold`'s kernels (hull–triangle with the internal-edge
rule; sphere / capsule against the triangle as a two-faced hull).

Everything is computed in the mesh's own frame (the shape's pose is turned into it, so the BVH built at load
serves any pose of the mesh body) and the points and normals are turned back into world coordinates.  The mesh
body is side A: normals point from the mesh to the shape.

Outputs as in :mod:`.narrowphase` (a :class:`.narrowphase.ContactBuffer` ``out``, from row ``m``).  Every triangle adds
up to 4 points (a shape resting across several triangles gets each one's — e.g. up to 16 for a box over a vertex of a
terrain grid; not reduced further). ``feature`` = ``triangle << 32`` | the low 32 bits of the triangle's own feature
(its incident face and clip code; for a sphere or capsule the end index), so points keep their identity while the shape
stays on a triangle. A point repeating one an earlier triangle gave (a vertex or an edge shared by several triangles) is
dropped.  ``candidates (c,)`` is scratch for the BVH query.  Each kernel returns ``(m, complete)``: ``complete`` False
means the buffers were too small (more candidate triangles than ``c``, or fewer than 4 free output rows before some
triangle) — the triangles not processed are missing; call again with bigger buffers.

The mesh: a :class:`.bvh.TriangleMesh` (a :class:`.bvh.StaticMesh`'s arrays), posed by ``mesh_position (3,)``,
``mesh_rotation (3, 3)``; ``two_sided``: False for a terrain or a closed mesh (only the front faces push).  The
hull: a :class:`.convex.PosedHull` in world.
"""

from __future__ import annotations

import numpy as np

from ..jit import njit
from .bvh import bvh_overlap
from .convex import PosedHull
from .manifold import hull_capsule_contacts, on_active_feature, triangle_hull_contacts

_LOW_32 = np.int64(0xFFFFFFFF)


@njit
def relative_pose(mesh_position, mesh_rotation, position, rotation):
    """The shape's pose in the mesh's frame: ``(Rmᵀ (p − pm) (3,), Rmᵀ R (3, 3))``."""
    p = np.empty(3)
    R = np.empty((3, 3))
    for i in range(3):
        p[i] = mesh_rotation[0, i] * (position[0] - mesh_position[0]) \
            + mesh_rotation[1, i] * (position[1] - mesh_position[1]) \
            + mesh_rotation[2, i] * (position[2] - mesh_position[2])
        for j in range(3):
            R[i, j] = mesh_rotation[0, i] * rotation[0, j] + mesh_rotation[1, i] * rotation[1, j] \
                + mesh_rotation[2, i] * rotation[2, j]
    return p, R


@njit
def _to_world(mesh_position, mesh_rotation, out, triangle, first, last):
    """Rows first .. last − 1 of the :class:`.narrowphase.ContactBuffer` ``out`` back to world coordinates, their
    features tagged with the triangle."""
    normal, point, feature = out.normal, out.point, out.feature
    for k in range(first, last):
        n0, n1, n2 = normal[k, 0], normal[k, 1], normal[k, 2]
        q0, q1, q2 = point[k, 0], point[k, 1], point[k, 2]
        for r in range(3):
            normal[k, r] = mesh_rotation[r, 0] * n0 + mesh_rotation[r, 1] * n1 + mesh_rotation[r, 2] * n2
            point[k, r] = mesh_position[r] + mesh_rotation[r, 0] * q0 + mesh_rotation[r, 1] * q1 \
                + mesh_rotation[r, 2] * q2
        feature[k] = (np.int64(triangle) << np.int64(32)) | (feature[k] & _LOW_32)


@njit
def _triangle(mesh_vertices, mesh_triangles, t, out):
    for k in range(3):
        for r in range(3):
            out[k, r] = mesh_vertices[mesh_triangles[t, k], r]


@njit
def _drop_repeats(out, start, first, m):
    """Remove the rows first .. m − 1 of ``out`` that repeat a row start .. first − 1 (the same point with the same
    normal: a shape touching a vertex or an edge shared by several triangles); returns the new end."""
    normal, separation, point, feature = out
    kept = first
    for k in range(first, m):
        repeat = False
        for j in range(start, first):
            dp = abs(point[k, 0] - point[j, 0]) + abs(point[k, 1] - point[j, 1]) + abs(point[k, 2] - point[j, 2])
            dn = abs(normal[k, 0] - normal[j, 0]) + abs(normal[k, 1] - normal[j, 1]) + abs(normal[k, 2] - normal[j, 2])
            if dp <= 1e-9 and dn <= 1e-9:
                repeat = True
                break
        if repeat:
            continue
        if kept != k:
            for r in range(3):
                normal[kept, r] = normal[k, r]
                point[kept, r] = point[k, r]
            separation[kept] = separation[k]
            feature[kept] = feature[k]
        kept += 1
    return kept


@njit
def mesh_hull_contacts(mesh, mesh_position, mesh_rotation, two_sided, hull, margin, candidates, out, m):
    """Static mesh (A) vs hull (B): every nearby triangle's :func:`.manifold.triangle_hull_contacts`."""
    vertices = hull.vertices
    p, R = relative_pose(mesh_position, mesh_rotation, hull.position, hull.rotation)
    local_hull = PosedHull(vertices, hull.adjacency_start, hull.adjacency, hull.face_plane, hull.face_vertex_start,
                           hull.face_vertices, p, R)
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for i in range(len(vertices)):  # the hull's box in the mesh frame, grown by the margin
        for r in range(3):
            x = p[r] + R[r, 0] * vertices[i, 0] + R[r, 1] * vertices[i, 1] + R[r, 2] * vertices[i, 2]
            lo[r] = min(lo[r], x - max(margin, 0.0))
            hi[r] = max(hi[r], x + max(margin, 0.0))
    found = bvh_overlap(mesh, lo, hi, candidates)
    complete = found <= len(candidates)
    triangle = np.empty((3, 3))
    start = m
    for c in range(min(found, len(candidates))):
        if len(out.separation) - m < 4:
            return m, False
        t = candidates[c]
        _triangle(mesh.vertices, mesh.triangles, t, triangle)
        first = m
        m = triangle_hull_contacts(triangle, mesh.active_edges[t], two_sided, local_hull, margin, out, m)
        _to_world(mesh_position, mesh_rotation, out, t, first, m)
        m = _drop_repeats(out, start, first, m)
    return m, complete


@njit
def mesh_capsule_contacts(mesh, mesh_position, mesh_rotation, two_sided, segment, radius, margin, candidates, out, m):
    """Static mesh (A) vs capsule or sphere (B: ``segment (2, 3)`` the core's ends in world, equal for a sphere).
    Per nearby triangle :func:`.manifold.hull_capsule_contacts` with the triangle as a two-faced flat hull; a
    point whose triangle feature is an inactive edge or vertex becomes a face contact (the triangle's normal, the
    core's height over its plane: no ghost normal), and one that pushes towards a one-sided triangle's back is
    dropped."""
    normal, separation, point, feature = out
    active_edges = mesh.active_edges
    local = np.empty((2, 3))
    for k in range(2):
        for i in range(3):
            local[k, i] = mesh_rotation[0, i] * (segment[k, 0] - mesh_position[0]) \
                + mesh_rotation[1, i] * (segment[k, 1] - mesh_position[1]) \
                + mesh_rotation[2, i] * (segment[k, 2] - mesh_position[2])
    reach = radius + max(margin, 0.0)
    lo = np.empty(3)
    hi = np.empty(3)
    for r in range(3):
        lo[r] = min(local[0, r], local[1, r]) - reach
        hi[r] = max(local[0, r], local[1, r]) + reach
    found = bvh_overlap(mesh, lo, hi, candidates)
    complete = found <= len(candidates)
    triangle = np.empty((3, 3))
    planes = np.empty((2, 4))
    loop_start = np.array([0, 3, 6], np.int64)
    loops = np.array([0, 1, 2, 0, 2, 1], np.int64)
    no_adjacency = np.zeros(4, np.int64)
    identity = np.eye(3)
    origin = np.zeros(3)
    start = m
    for c in range(min(found, len(candidates))):
        if len(separation) - m < 2:
            return m, False
        t = candidates[c]
        _triangle(mesh.vertices, mesh.triangles, t, triangle)
        ex, ey, ez = triangle[1, 0] - triangle[0, 0], triangle[1, 1] - triangle[0, 1], triangle[1, 2] - triangle[0, 2]
        fx, fy, fz = triangle[2, 0] - triangle[0, 0], triangle[2, 1] - triangle[0, 1], triangle[2, 2] - triangle[0, 2]
        nx, ny, nz = ey * fz - ez * fy, ez * fx - ex * fz, ex * fy - ey * fx
        length = np.sqrt(nx * nx + ny * ny + nz * nz)
        if length == 0.0:
            continue
        nx, ny, nz = nx / length, ny / length, nz / length
        d = nx * triangle[0, 0] + ny * triangle[0, 1] + nz * triangle[0, 2]
        planes[0, 0], planes[0, 1], planes[0, 2], planes[0, 3] = nx, ny, nz, d
        planes[1, 0], planes[1, 1], planes[1, 2], planes[1, 3] = -nx, -ny, -nz, -d
        first = m
        flat = PosedHull(triangle, no_adjacency, no_adjacency[:0], planes, loop_start, loops, origin, identity)
        m = hull_capsule_contacts(flat, local, radius, margin, out, m)
        # ghosts (a point on an inactive edge or vertex, its normal tilted from the face's) become face contacts:
        # the triangle's face normal (towards the core's side) and the core's height over the face's plane — what
        # the neighbouring triangle's face would give, so a ball rolling over a flat or gently convex edge feels
        # no bump and, right over it, is still held (dropping both triangles' edge points would let it sink);
        # one-sided, the back-facing points are dropped
        kept = first
        for k in range(first, m):
            half = 0.5 * separation[k]
            on_triangle_x = point[k, 0] - half * normal[k, 0]
            on_triangle_y = point[k, 1] - half * normal[k, 1]
            on_triangle_z = point[k, 2] - half * normal[k, 2]
            tilted = normal[k, 0] * nx + normal[k, 1] * ny + normal[k, 2] * nz
            if abs(tilted) < 1.0 - 1e-9 and not on_active_feature(triangle, active_edges[t], on_triangle_x,
                                                                   on_triangle_y, on_triangle_z):
                reach = radius + half  # from the midway point back to the core
                cx = point[k, 0] + reach * normal[k, 0]
                cy = point[k, 1] + reach * normal[k, 1]
                cz = point[k, 2] + reach * normal[k, 2]
                side = 1.0 if tilted >= 0.0 else -1.0
                fx, fy, fz = side * nx, side * ny, side * nz
                height = side * (nx * cx + ny * cy + nz * cz - d)
                separation[k] = height - radius
                normal[k, 0], normal[k, 1], normal[k, 2] = fx, fy, fz
                back_to = radius + 0.5 * separation[k]
                point[k, 0], point[k, 1], point[k, 2] = cx - back_to * fx, cy - back_to * fy, cz - back_to * fz
                if not separation[k] < margin:
                    continue
            back = not two_sided and normal[k, 0] * nx + normal[k, 1] * ny + normal[k, 2] * nz <= 0.0
            if back:
                continue
            if kept != k:
                for r in range(3):
                    normal[kept, r] = normal[k, r]
                    point[kept, r] = point[k, r]
                separation[kept] = separation[k]
                feature[kept] = feature[k]
            kept += 1
        m = kept
        _to_world(mesh_position, mesh_rotation, out, t, first, m)
        m = _drop_repeats(out, start, first, m)
    return m, complete

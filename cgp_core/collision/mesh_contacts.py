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

import math
from typing import NamedTuple

import numpy as np

from ..jit import njit
from .bvh import bvh_overlap
from .convex import PosedHull
from .manifold import hull_capsule_contacts, on_active_feature, triangle_contacts_into, triangle_scratch

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


# ---- near-duplicate points: a hash grid of the rows kept so far --------------------------------------------
# Issue 38: comparing each new row with every kept one was O(n²) — a box resting on a 1 cm grid of 20,000
# triangles under it gets 60,000 rows (3 per triangle), 0.3 s a sub-step.  The grid finds the kept rows near a
# point in O(1): cells at least twice the distance asked, so a ball of that radius meets at most 8 cells (the
# point's and, across each side it is that near, the neighbour there).  The cells are hashed into buckets without
# keys: two cells sharing a bucket only add candidates, which the caller's exact distance test sorts out, and
# the bucket index is masked, so coordinates of any size (even a NaN) index the table inside its bounds.

class NearPoints(NamedTuple):
    """A hash grid of points (:func:`near_points`): ``item`` rows of some array, found again by position."""

    origin: np.ndarray  # (3,) [m] where cell (0, 0, 0) starts
    cell: np.ndarray    # (1,) [m] the cells' edge, ≥ 2 (1 + 1e-6) × the distance asked
    head: np.ndarray    # (S,) int64 per bucket (S: a power of two, ≥ the items): its newest item, −1: none
    next: np.ndarray    # (n,) int64 per item: the next (older) item of its bucket, −1 at the end


@njit
def near_points(items, origin, radius, span):
    """An empty :class:`NearPoints` for up to ``items`` items, to find points within ``radius`` [m] of each other
    among points within ~``span`` [m] of ``origin (3,)``: cells of max(2 radius, 1e-6 span) (1 + 1e-6) (at most
    ~1e6 cells across the span, so a point's cell coordinate is exact to far better than the margin)."""
    buckets = 16
    while buckets < items:
        buckets *= 2
    cell = np.empty(1)
    cell[0] = max(2.0 * radius, 1e-6 * span, 1e-300) * (1.0 + 1e-6)
    return NearPoints(origin.copy(), cell, np.full(buckets, -1, np.int64), np.empty(max(items, 1), np.int64))


@njit
def _cell_of(grid, x, r):
    """The cell coordinate of coordinate ``x`` along axis ``r`` and where in the cell it is: (int, [0, 1))."""
    u = (x - grid.origin[r]) / grid.cell[0]
    if not abs(u) < 4e18:  # far outside (or NaN): any cell, the mask keeps the bucket in bounds
        return np.int64(0), 0.5
    f = math.floor(u)
    return np.int64(f), u - f


@njit
def _bucket(grid, cx, cy, cz):
    return ((cx * np.int64(73856093)) ^ (cy * np.int64(19349663)) ^ (cz * np.int64(83492791))) \
        & (len(grid.head) - 1)


@njit
def add_point(grid, item, x, y, z):
    """Put ``item`` (< the grid's items) at (x, y, z)."""
    cx, _ = _cell_of(grid, x, 0)
    cy, _ = _cell_of(grid, y, 1)
    cz, _ = _cell_of(grid, z, 2)
    bucket = _bucket(grid, cx, cy, cz)
    grid.next[item] = grid.head[bucket]
    grid.head[bucket] = item


@njit
def cells_near(grid, x, y, z, radius, cells):
    """The cells ``cells[:k] (8, 3)`` int64 a ball of ``radius`` (at most the grid's) about (x, y, z) can meet,
    and ``k``: the point's cell, and across each side the ball reaches (with a margin for the rounding of the
    cell coordinates) its neighbour there — mostly 1 cell for a small ball, at most 8."""
    cx, fx = _cell_of(grid, x, 0)
    cy, fy = _cell_of(grid, y, 1)
    cz, fz = _cell_of(grid, z, 2)
    reach = radius / grid.cell[0] + 1e-7  # in cells
    sx = -1 if fx < reach else (1 if fx > 1.0 - reach else 0)
    sy = -1 if fy < reach else (1 if fy > 1.0 - reach else 0)
    sz = -1 if fz < reach else (1 if fz > 1.0 - reach else 0)
    k = 0
    for i in range(2 if sx != 0 else 1):
        for j in range(2 if sy != 0 else 1):
            for n in range(2 if sz != 0 else 1):
                cells[k, 0], cells[k, 1], cells[k, 2] = cx + i * sx, cy + j * sy, cz + n * sz
                k += 1
    return k


@njit
def first_item(grid, cells, k):
    """The newest item of the bucket of cell ``cells[k]`` (follow ``grid.next``; a bucket may hold items of other
    cells too), −1 if none."""
    return grid.head[_bucket(grid, cells[k, 0], cells[k, 1], cells[k, 2])]


@njit
def _drop_repeats(out, grid, start, first, m, cells):
    """Remove the rows first .. m − 1 of ``out`` (one triangle's) that repeat a row start .. first − 1 (the earlier
    triangles' rows kept, in ``grid``: item = row − start): the same point with the same normal (within 1e-9 in
    each, summed over the axes: a shape touching a vertex or an edge shared by several triangles); then adds the
    rows kept to ``grid``.  Returns the new end."""
    normal, separation, point, feature = out
    kept = first
    for k in range(first, m):
        repeat = False
        for c in range(cells_near(grid, point[k, 0], point[k, 1], point[k, 2], 1e-9, cells)):
            item = first_item(grid, cells, c)
            while item >= 0 and not repeat:
                j = start + item
                dp = abs(point[k, 0] - point[j, 0]) + abs(point[k, 1] - point[j, 1]) + abs(point[k, 2] - point[j, 2])
                dn = abs(normal[k, 0] - normal[j, 0]) + abs(normal[k, 1] - normal[j, 1]) \
                    + abs(normal[k, 2] - normal[j, 2])
                repeat = dp <= 1e-9 and dn <= 1e-9
                item = grid.next[item]
            if repeat:
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
    for k in range(first, kept):
        add_point(grid, k - start, point[k, 0], point[k, 1], point[k, 2])
    return kept


@njit
def _repeat_grid(mesh_position, mesh_rotation, lo, hi, rows):
    """A :class:`NearPoints` for :func:`_drop_repeats` of up to ``rows`` rows near the query box ``lo, hi`` (mesh
    frame)."""
    centre = np.empty(3)
    for r in range(3):
        centre[r] = mesh_position[r] + mesh_rotation[r, 0] * 0.5 * (lo[0] + hi[0]) \
            + mesh_rotation[r, 1] * 0.5 * (lo[1] + hi[1]) + mesh_rotation[r, 2] * 0.5 * (lo[2] + hi[2])
    span = max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2])
    return near_points(rows, centre, 1e-9, span if span < np.inf else 0.0)


@njit
def _hull_in_mesh_frame(mesh_position, mesh_rotation, hull):
    """``hull`` posed in the mesh's frame with its axes turned into its vertices and face planes: at its origin
    there, the rotation the identity.  Issue 38: the hull–triangle kernel turns the hull's vertices and planes by its
    rotation at every use, once per triangle under it — here once per pair (exactly so: the identity's products add
    only zeros)."""
    p, R = relative_pose(mesh_position, mesh_rotation, hull.position, hull.rotation)
    vertices, planes = hull.vertices, hull.face_plane
    turned = np.empty((len(vertices), 3))
    for i in range(len(vertices)):
        for r in range(3):
            turned[i, r] = R[r, 0] * vertices[i, 0] + R[r, 1] * vertices[i, 1] + R[r, 2] * vertices[i, 2]
    turned_planes = np.empty((len(planes), 4))
    for f in range(len(planes)):
        for r in range(3):
            turned_planes[f, r] = R[r, 0] * planes[f, 0] + R[r, 1] * planes[f, 1] + R[r, 2] * planes[f, 2]
        turned_planes[f, 3] = planes[f, 3]  # (the offset from the hull's origin, which the turn keeps)
    return PosedHull(turned, hull.adjacency_start, hull.adjacency, turned_planes, hull.face_vertex_start,
                     hull.face_vertices, p, np.eye(3))


@njit
def mesh_hull_contacts(mesh, mesh_position, mesh_rotation, two_sided, hull, margin, candidates, out, m):
    """Static mesh (A) vs hull (B): every nearby triangle's :func:`.manifold.triangle_hull_contacts`."""
    local_hull = _hull_in_mesh_frame(mesh_position, mesh_rotation, hull)
    vertices, p = local_hull.vertices, local_hull.position
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for i in range(len(vertices)):  # the hull's box in the mesh frame, grown by the margin
        for r in range(3):
            x = p[r] + vertices[i, r]
            lo[r] = min(lo[r], x - max(margin, 0.0))
            hi[r] = max(hi[r], x + max(margin, 0.0))
    found = bvh_overlap(mesh, lo, hi, candidates)
    if found > len(candidates):
        return m, False  # (before any triangle's work: the caller calls again with room for them all)
    scratch = triangle_scratch(local_hull)
    triangle = np.empty((3, 3))
    start = m
    grid = _repeat_grid(mesh_position, mesh_rotation, lo, hi, min(4 * found, len(out.separation) - m))
    cells = np.empty((8, 3), np.int64)
    for c in range(found):
        if len(out.separation) - m < 4:
            return m, False
        t = candidates[c]
        _triangle(mesh.vertices, mesh.triangles, t, triangle)
        first = m
        m = triangle_contacts_into(triangle, mesh.active_edges[t], two_sided, local_hull, margin, out, m, scratch)
        _to_world(mesh_position, mesh_rotation, out, t, first, m)
        m = _drop_repeats(out, grid, start, first, m, cells)
    return m, True


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
    if found > len(candidates):
        return m, False  # (before any triangle's work: the caller calls again with room for them all)
    triangle = np.empty((3, 3))
    planes = np.empty((2, 4))
    loop_start = np.array([0, 3, 6], np.int64)
    loops = np.array([0, 1, 2, 0, 2, 1], np.int64)
    no_adjacency = np.zeros(4, np.int64)
    identity = np.eye(3)
    origin = np.zeros(3)
    start = m
    grid = _repeat_grid(mesh_position, mesh_rotation, lo, hi, min(2 * found, len(separation) - m))
    cells = np.empty((8, 3), np.int64)
    for c in range(found):
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
        m = _drop_repeats(out, grid, start, first, m, cells)
    return m, True

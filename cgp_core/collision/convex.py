"""Convex polyhedra (hulls) as flat arrays, and their support mapping (Ericson 9.1 / van den Bergen 1999).

A convex shape of the narrow phase is given by its vertices; every query on it (GJK, EPA, the contact manifold,
time of impact) asks it only for its *support point* in a direction d, the vertex v maximizing d · v (Ericson
9.1.2, "support mapping"), and the manifold asks for its faces.  This module builds hulls from points with qhull
(``scipy.spatial.ConvexHull``), merges qhull's coplanar triangles into polygon faces (the clipping needs whole
faces), and lays many hulls out as CSR arrays so that a compiled kernel can index hull ``h``'s data.

Layout of a :class:`HullSet` of ``h`` hulls (every index inside a hull is *local* to it, so a kernel can work on
the slices ``vertices[vertex_start[i]:vertex_start[i + 1]]`` ...):

    vertex_start       (h + 1,) int64  — hull i's vertices are rows vertex_start[i] .. vertex_start[i + 1] − 1
    vertices           (V, 3)   float  — in the hull's own frame (for a body: about its COM, in the shape's
                                         own axes — not rotated to principal axes; BodyModel keeps a full tensor)
    adjacency_start    (V + 1,) int64  — vertex v's neighbours are adjacency[adjacency_start[v]:adjacency_start[v+1]]
    adjacency          (A,)     int64  — local vertex indices (the hull's true edges, both directions)
    face_start         (h + 1,) int64  — hull i's faces are rows face_start[i] .. face_start[i + 1] − 1
    face_plane         (F, 4)   float  — unit outward normal n and offset d: the face is {x : n · x = d}
    face_vertex_start  (F + 1,) int64  — face f's loop is face_vertices[face_vertex_start[f]:face_vertex_start[f+1]]
    face_vertices      (FV,)    int64  — local vertex indices, counter-clockwise seen from outside

Support queries: :func:`support_index` takes the brute-force maximum over at most
:data:`BRUTE_FORCE_SUPPORT_VERTICES` vertices and otherwise climbs the vertex adjacency graph from a start vertex
(a linear function on a convex polytope has no local maximum on its edge graph that is not global — the simplex
method's argument), so a warm start from the previous query's vertex costs a few steps.

Limits (stated, checked): at most :data:`MAX_INPUT_POINTS` input points, at most :data:`MAX_HULL_VERTICES` hull
vertices, at most :data:`MAX_FACE_VERTICES` vertices on one face; degenerate input (fewer than 4 points,
non-finite, all coplanar or collinear, a volume below :data:`MIN_RELATIVE_VOLUME` of its extent cubed) is refused
with :class:`HullError` naming the reason.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..jit import njit
from ..limits import MAX_HULL_POINTS, MAX_HULL_VERTICES

#: input points accepted by :func:`convex_hull`, and hull vertices (:mod:`cgp_core.limits`, the one place of the
#: limits on what users give)
MAX_INPUT_POINTS = MAX_HULL_POINTS
#: vertices on one (merged) face: the manifold's feature ids reserve 8 bits for a face vertex
MAX_FACE_VERTICES = 255
#: a hull whose volume is below this fraction of the cube of its largest extent is refused as flat
MIN_RELATIVE_VOLUME = 1e-9
#: support queries on hulls of at most this many vertices take the brute-force maximum (cheaper than climbing)
BRUTE_FORCE_SUPPORT_VERTICES = 32
#: qhull triangles whose unit normals differ by less than this (and whose planes are as close, relative to the
#: hull's size) are one polygon face
COPLANAR_TOLERANCE = 1e-9


class HullError(ValueError):
    """Points (or a mesh) that do not make a usable convex hull; the message names what and why."""


@dataclass
class ConvexPolyhedron:
    """One convex hull.

    Attributes (shapes):
        vertices:          (k, 3) — hull vertices (the input points' frame, or shifted: see :meth:`shifted`).
        face_plane:        (f, 4) — unit outward normal and offset per (merged) face.
        face_vertex_start: (f + 1,) int64 — CSR offsets into ``face_vertices``.
        face_vertices:     (fv,) int64 — each face's loop, counter-clockwise seen from outside.
        adjacency_start:   (k + 1,) int64 — CSR offsets into ``adjacency``.
        adjacency:         (a,) int64 — each vertex's neighbours along the hull's edges.
        triangles:         (t, 3) int64 — qhull's triangles, outward (counter-clockwise seen from outside):
                           the closed surface the mass properties integrate over.
        interior_points:   how many input points are not hull vertices (inside the hull, on a face or edge, or
                           duplicates); > 0 means the input was not a convex polytope's vertex set.
    """

    vertices: np.ndarray
    face_plane: np.ndarray
    face_vertex_start: np.ndarray
    face_vertices: np.ndarray
    adjacency_start: np.ndarray
    adjacency: np.ndarray
    triangles: np.ndarray
    interior_points: int

    @property
    def face_count(self) -> int:
        return len(self.face_plane)

    def face(self, f: int) -> np.ndarray:
        """Local vertex indices of face ``f``'s loop."""
        return self.face_vertices[self.face_vertex_start[f]:self.face_vertex_start[f + 1]]

    def shifted(self, origin) -> ConvexPolyhedron:
        """The same hull with ``origin`` (3,) as the new frame origin (e.g. its centre of mass)."""
        origin = np.asarray(origin, dtype=float)
        plane = self.face_plane.copy()
        plane[:, 3] -= plane[:, :3] @ origin
        return ConvexPolyhedron(self.vertices - origin, plane, self.face_vertex_start, self.face_vertices,
                                self.adjacency_start, self.adjacency, self.triangles, self.interior_points)


def convex_hull(points, *, what: str = "points") -> ConvexPolyhedron:
    """The convex hull of ``points (n, 3)`` (qhull), coplanar triangles merged into polygon faces.

    ``what`` names the input in error messages (``"scene.yaml: bodies[2].points"``).  Raises :class:`HullError`
    for input that does not span a volume or exceeds the caps (see the module docstring).
    """
    from scipy.spatial import ConvexHull, QhullError

    try:
        pts = np.asarray(points, dtype=float)
    except (TypeError, ValueError):
        raise HullError(f"{what}: must be a list of [x, y, z] points (numbers)") from None
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise HullError(f"{what}: must be a list of [x, y, z] points, got an array of shape {pts.shape}")
    if len(pts) > MAX_INPUT_POINTS:
        raise HullError(f"{what}: {len(pts)} points, more than the {MAX_INPUT_POINTS} a hull may be built from")
    if not np.isfinite(pts).all():
        raise HullError(f"{what}: every coordinate must be a finite number")
    if len(pts) < 4:
        raise HullError(f"{what}: a convex hull needs at least 4 points that are not coplanar, got {len(pts)}")
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    size = float(np.max(hi - lo))
    if size <= 0.0:
        raise HullError(f"{what}: all {len(pts)} points are the same point (zero volume)")
    try:
        qhull = ConvexHull(pts)
    except QhullError as error:
        first = str(error).strip().splitlines()[0] if str(error).strip() else "qhull failed"
        raise HullError(f"{what}: the points are coplanar or collinear (no volume): qhull says {first!r}") \
            from None
    if qhull.volume <= MIN_RELATIVE_VOLUME * size**3:
        raise HullError(f"{what}: the points are (nearly) coplanar: hull volume {qhull.volume:.3g} m³ is below "
                        f"{MIN_RELATIVE_VOLUME:g} of the cube of their extent ({size:.3g} m)")
    used = np.unique(qhull.simplices)
    if len(used) > MAX_HULL_VERTICES:
        raise HullError(f"{what}: the hull has {len(used)} vertices, more than the {MAX_HULL_VERTICES} allowed "
                        "(simplify the shape)")
    # local numbering of the hull's vertices
    local = np.full(len(pts), -1, np.int64)
    local[used] = np.arange(len(used))
    vertices = pts[used].copy()
    triangles = local[qhull.simplices]
    normals = qhull.equations[:, :3].copy()
    offsets = -qhull.equations[:, 3]
    # qhull's simplices are not consistently oriented: make each counter-clockwise seen from outside
    a, b, c = vertices[triangles[:, 0]], vertices[triangles[:, 1]], vertices[triangles[:, 2]]
    flip = np.einsum("ij,ij->i", np.cross(b - a, c - a), normals) < 0.0
    triangles[flip] = triangles[flip][:, [0, 2, 1]]
    plane, face_vertex_start, face_vertices = _merge_coplanar(vertices, triangles, normals, offsets, size, what)
    adjacency_start, adjacency = _adjacency(len(vertices), face_vertex_start, face_vertices)
    return ConvexPolyhedron(vertices, plane, face_vertex_start, face_vertices, adjacency_start, adjacency,
                            triangles, int(len(pts) - len(used)))


def _merge_coplanar(vertices, triangles, normals, offsets, size, what):
    """Group edge-adjacent triangles with the same plane and trace each group's boundary loop.

    Every directed edge (u, v) finds its twin (v, u) — the neighbouring triangle — by a sorted search of the
    edges' keys; coplanar neighbours are joined, the groups are the connected components of that graph (scipy's,
    numbered in the order of their lowest triangle, as the faces are), and each group's boundary — its directed
    edges whose twin is not in the group — is followed from its lowest vertex.  (Issue 38: the per-edge Python
    loop and union-find this replaces took ~0.1 s for a 1,000-vertex hull; the result is the same, array for array,
    checked on random and coplanar-rich point sets.)
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    t = len(triangles)
    k = len(vertices)
    u = triangles.reshape(-1)
    v = triangles[:, [1, 2, 0]].reshape(-1)
    owner = np.repeat(np.arange(t), 3)
    key = u * k + v
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    twin_key = v * k + u
    at = np.minimum(np.searchsorted(sorted_key, twin_key), len(sorted_key) - 1)
    if not np.array_equal(sorted_key[at], twin_key):
        raise HullError(f"{what}: qhull returned an open surface (internal error)")
    i, j = owner, owner[order[at]]
    same = ((i < j) & (np.abs(normals[i] - normals[j]).max(axis=1) <= COPLANAR_TOLERANCE)
            & (np.abs(offsets[i] - offsets[j]) <= COPLANAR_TOLERANCE * size))
    graph = coo_matrix((np.ones(int(same.sum())), (i[same], j[same])), shape=(t, t))
    count, label = connected_components(graph, directed=False)
    members = np.argsort(label, kind="stable")
    bounds = np.searchsorted(label[members], np.arange(count + 1))
    tri = triangles.tolist()
    corner0, corner1, corner2 = (vertices[triangles[:, m]] for m in range(3))
    area_normals = np.cross(corner1 - corner0, corner2 - corner0)  # (t, 3): twice each triangle's area, outward
    planes, starts, loop_vertices = [], [0], []
    for g in range(count):
        group = members[bounds[g]:bounds[g + 1]]
        directed = {(tri[f][m], tri[f][(m + 1) % 3]) for f in group.tolist() for m in range(3)}
        boundary = {a: b for (a, b) in directed if (b, a) not in directed}
        start = min(boundary)
        loop = [start]
        while boundary[loop[-1]] != start:
            loop.append(boundary[loop[-1]])
            if len(loop) > len(boundary):
                raise HullError(f"{what}: a merged face has no simple boundary (internal error)")
        if len(loop) > MAX_FACE_VERTICES:
            raise HullError(f"{what}: a face has {len(loop)} vertices, more than the {MAX_FACE_VERTICES} allowed")
        n = area_normals[group].sum(axis=0)
        n /= np.linalg.norm(n)
        planes.append((*n, float(np.mean(vertices[loop] @ n))))
        loop_vertices.extend(loop)
        starts.append(len(loop_vertices))
    return np.array(planes), np.array(starts, np.int64), np.array(loop_vertices, np.int64)


def _adjacency(k, face_vertex_start, face_vertices):
    """Vertex neighbours along the faces' edges (each edge in both directions), as CSR arrays."""
    neighbours = [set() for _ in range(k)]
    for f in range(len(face_vertex_start) - 1):
        loop = face_vertices[face_vertex_start[f]:face_vertex_start[f + 1]]
        for i in range(len(loop)):
            u, v = int(loop[i]), int(loop[(i + 1) % len(loop)])
            neighbours[u].add(v)
            neighbours[v].add(u)
    start = np.zeros(k + 1, np.int64)
    start[1:] = np.cumsum([len(s) for s in neighbours])
    flat = np.array([v for s in neighbours for v in sorted(s)], np.int64)
    return start, flat


def box_hull(half_extents) -> ConvexPolyhedron:
    """The 8-corner hull of a box of ``half_extents (3,)`` centred at the origin (for tests and comparisons)."""
    h = np.asarray(half_extents, dtype=float)
    corners = np.array([(sx, sy, sz) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float) * h
    return convex_hull(corners, what="box corners")


class Hull(NamedTuple):
    """One hull's arrays as the kernels take them (:meth:`HullSet.hull`; indices local to the hull).  The two
    ``*_start`` slices keep their absolute offsets into the shared ``adjacency`` / ``face_vertices``."""

    vertices: np.ndarray           # (k, 3) float — in the hull's own frame
    adjacency_start: np.ndarray    # (k + 1,) int64 — vertex v's neighbours: adjacency[start[v]:start[v + 1]]
    adjacency: np.ndarray          # (A,) int64 — local vertex indices (the set's shared array)
    face_plane: np.ndarray         # (f, 4) float — unit outward normal n and offset d (n · x = d on the face)
    face_vertex_start: np.ndarray  # (f + 1,) int64 — face f's loop: face_vertices[start[f]:start[f + 1]]
    face_vertices: np.ndarray      # (FV,) int64 — local vertex indices, counter-clockwise from outside


class PosedHull(NamedTuple):
    """A :class:`Hull` placed in the world: its frame's origin at ``position``, its axes the columns of
    ``rotation`` (what the manifold kernels of :mod:`.manifold` take for each side)."""

    vertices: np.ndarray           # (k, 3) — as in :class:`Hull`
    adjacency_start: np.ndarray    # (k + 1,)
    adjacency: np.ndarray          # (A,)
    face_plane: np.ndarray         # (f, 4)
    face_vertex_start: np.ndarray  # (f + 1,)
    face_vertices: np.ndarray      # (FV,)
    position: np.ndarray           # (3,) world [m]
    rotation: np.ndarray           # (3, 3) body → world


@njit
def posed(hull, position, rotation):
    """The :class:`PosedHull` of a :class:`Hull` at ``position (3,)``, ``rotation (3, 3)``."""
    return PosedHull(hull.vertices, hull.adjacency_start, hull.adjacency, hull.face_plane, hull.face_vertex_start,
                     hull.face_vertices, position, rotation)


class HullSet(NamedTuple):
    """``h`` convex hulls as CSR arrays (see the module docstring for every array's shape and meaning)."""

    vertex_start: np.ndarray       # (h + 1,) int64
    vertices: np.ndarray           # (V, 3) float
    adjacency_start: np.ndarray    # (V + 1,) int64
    adjacency: np.ndarray          # (A,) int64
    face_start: np.ndarray         # (h + 1,) int64
    face_plane: np.ndarray         # (F, 4) float
    face_vertex_start: np.ndarray  # (F + 1,) int64
    face_vertices: np.ndarray      # (FV,) int64

    @property
    def count(self) -> int:
        return len(self.vertex_start) - 1

    @classmethod
    def from_hulls(cls, hulls: list[ConvexPolyhedron]) -> HullSet:
        vertex_start = np.zeros(len(hulls) + 1, np.int64)
        face_start = np.zeros(len(hulls) + 1, np.int64)
        vertex_start[1:] = np.cumsum([len(h.vertices) for h in hulls])
        face_start[1:] = np.cumsum([h.face_count for h in hulls])
        adjacency_start, face_vertex_start = [np.zeros(1, np.int64)], [np.zeros(1, np.int64)]
        adjacency_total = face_vertex_total = 0
        for h in hulls:
            adjacency_start.append(h.adjacency_start[1:] + adjacency_total)
            face_vertex_start.append(h.face_vertex_start[1:] + face_vertex_total)
            adjacency_total += len(h.adjacency)
            face_vertex_total += len(h.face_vertices)

        def stack(arrays, empty):
            return np.concatenate(arrays) if arrays else empty

        return cls(vertex_start=vertex_start,
                   vertices=np.ascontiguousarray(stack([h.vertices for h in hulls], np.zeros((0, 3))), float),
                   adjacency_start=np.concatenate(adjacency_start),
                   adjacency=stack([h.adjacency for h in hulls], np.zeros(0, np.int64)),
                   face_start=face_start,
                   face_plane=np.ascontiguousarray(stack([h.face_plane for h in hulls], np.zeros((0, 4))), float),
                   face_vertex_start=np.concatenate(face_vertex_start),
                   face_vertices=stack([h.face_vertices for h in hulls], np.zeros(0, np.int64)))

    def hull(self, i: int) -> Hull:
        """Hull ``i``'s arrays (:func:`hull_of`)."""
        return hull_of(self, i)


@njit
def hull_of(hulls, i):
    """Hull ``i`` of the :class:`HullSet` ``hulls`` as a :class:`Hull` (slices, no copies)."""
    v0, v1 = hulls.vertex_start[i], hulls.vertex_start[i + 1]
    f0, f1 = hulls.face_start[i], hulls.face_start[i + 1]
    return Hull(hulls.vertices[v0:v1], hulls.adjacency_start[v0:v1 + 1], hulls.adjacency, hulls.face_plane[f0:f1],
                hulls.face_vertex_start[f0:f1 + 1], hulls.face_vertices)


# ---- the support mapping (compiled) ------------------------------------------------------------------------

@njit
def support_index(vertices, adjacency_start, adjacency, dx, dy, dz, start):
    """Index of a vertex of ``vertices (k, 3)`` maximizing (dx, dy, dz) · v (Ericson 9.1.2).

    Brute force for k ≤ :data:`BRUTE_FORCE_SUPPORT_VERTICES` or an empty ``adjacency``; otherwise hill climbing
    from vertex ``start`` over the neighbours ``adjacency[adjacency_start[v]:adjacency_start[v + 1]]`` (local
    indices), moving to a strictly better neighbour until none is (van den Bergen 1999, "hill climbing").
    ``adjacency_start`` is this hull's slice (k + 1 offsets into the shared ``adjacency``).
    """
    k = len(vertices)
    if k <= BRUTE_FORCE_SUPPORT_VERTICES or len(adjacency) == 0:
        best_i, best = 0, -np.inf
        for i in range(k):
            s = dx * vertices[i, 0] + dy * vertices[i, 1] + dz * vertices[i, 2]
            if s > best:
                best_i, best = i, s
        return best_i
    current = start if 0 <= start < k else 0
    best = dx * vertices[current, 0] + dy * vertices[current, 1] + dz * vertices[current, 2]
    moved = True
    while moved:
        moved = False
        for a in range(adjacency_start[current], adjacency_start[current + 1]):
            j = adjacency[a]
            s = dx * vertices[j, 0] + dy * vertices[j, 1] + dz * vertices[j, 2]
            if s > best:
                current, best, moved = j, s, True
    return current


def centred_hull(hull: ConvexPolyhedron, *, mass=None, density=None,
                 what: str = "points") -> tuple[ConvexPolyhedron, float, np.ndarray, np.ndarray]:
    """A hull as a body's collision shape: its exact mass properties (:func:`cgp_core.inertia.
    polyhedron_mass_properties`, over qhull's outward triangles) and the hull shifted so that its COM is the
    frame's origin (the body frame: COM-centred, the input's axes — not principal axes).

    Returns ``(hull about its COM, mass, com (3,) in the input frame, inertia (3, 3) about the COM)``; give
    exactly one of ``mass`` [kg] and ``density`` [kg/m³].
    """
    from ..inertia import polyhedron_mass_properties

    body_mass, com, inertia, _ = polyhedron_mass_properties(hull.vertices, hull.triangles, mass=mass,
                                                            density=density, what=what)
    return hull.shifted(com), body_mass, com, inertia

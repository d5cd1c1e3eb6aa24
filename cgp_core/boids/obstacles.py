"""The rigid bodies of a world, seen by its flocks as obstacles (at one instant: built once per tick).

Boids steer around obstacles (``flock.py``: an acceleration away from the surface and sideways, starting
``obstacle_margin`` away from it) and never enter them: after moving, a boid inside a body inflated by half
its size is put back on the surface and loses its inward velocity.

:meth:`Obstacles.query` finds every (boid, shape) pair closer than a reach, with the signed distance and the
outward normal — Ericson's closest-point formulas (*Real-Time Collision Detection*, ch. 5), the same as
``geometry.py`` evaluates for points × shapes, here for one point and one shape at a time inside a compiled
loop over the boids (a test checks the two agree).  The cost is proportional to the boids near bodies, not
boids × bodies: the shapes are binned into a coarse grid of cells over the boids (each shape into the cells its
bounding sphere, grown by the reach, overlaps), and each boid looks only at the shapes of its own cell —
usually none.  Two passes over the boids, in parallel: count each boid's hits, then write them.

Issue 25's shapes: a compound body's parts are spheres, boxes and capsules here like any (at the part's pose);
convex hulls (convex bodies and parts) and static meshes are queried by a second compiled loop
(:func:`_convex_hits`), whose hits are appended (the consumers add the hits up per boid: order does not matter).
A hull's signed distance is taken from its face planes, max_f (n_f · p − d_f) (Ericson 5.1.x): exact inside (the
depth below the nearest face) and on the outside over a face; outside near an edge or a vertex it is a lower
bound of the true distance, so a fish there steers a little early — never late.  A static mesh's is the BVH's
closest point (:func:`cgp_core.collision.bvh.bvh_closest_point`) within the reach: a two-sided mesh has no inside
(the distance is the unsigned one, the normal points from the closest point to the fish); a one-sided mesh (a
terrain, whose triangles face up) counts a fish *behind* its closest triangle — below the terrain — as inside,
so that fish is pushed back up through the surface; a fish farther below it than the reach is not seen at all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..bodies import BodyModel, BodyState, Shape
from ..collision.bvh import TriangleMesh, bvh_closest_point
from ..jit import njit, prange
from .neighbors import bounding_box

_SPHERE, _BOX, _CAPSULE = 0, 1, 2
_TINY = 1e-12  # as geometry.py: below this a direction is undefined and a fallback normal is used
#: the coarse grid of the query: cells at least this many reaches wide, and at most this many cells
_CELL_REACHES = 2.0
_MAX_CELLS = 1 << 16


class ObstacleHits(NamedTuple):
    """(point, shape) pairs closer than the query reach (Q of them)."""

    point: np.ndarray     # (Q,) intp — index of the point (boid)
    distance: np.ndarray  # (Q,) — signed distance from the point to the shape's surface [m], negative inside
    normal: np.ndarray    # (3, Q) — unit outward direction (the way out / away from the shape)

    @property
    def count(self) -> int:
        return len(self.point)

    @staticmethod
    def concatenate(parts: list[ObstacleHits]) -> ObstacleHits:
        parts = [p for p in parts if p.count]
        if not parts:
            return ObstacleHits(np.zeros(0, np.intp), np.zeros(0), np.zeros((3, 0)))
        return ObstacleHits(np.concatenate([p.point for p in parts]),
                            np.concatenate([p.distance for p in parts]),
                            np.concatenate([p.normal for p in parts], axis=1))


class PackedShapes(NamedTuple):
    """Every obstacle shape in one set of arrays, as the compiled query takes them (K shapes)."""

    kind: np.ndarray      # (K,) int64 _SPHERE, _BOX or _CAPSULE
    center: np.ndarray    # (K, 3) [m]
    rotation: np.ndarray  # (K, 3, 3) boxes: columns = axes; capsules: column 2 = the axis; spheres: identity
    half: np.ndarray      # (K, 3) boxes: half extents; capsules: (0, 0, half length); spheres: 0
    radius: np.ndarray    # (K,) spheres, capsules (boxes: 0)
    bound: np.ndarray     # (K,) the shape's bounding-sphere radius [m]


class ShapeBins(NamedTuple):
    """The shapes binned into a coarse grid of cells over the query points (CSR lists per cell)."""

    low: np.ndarray        # (3,) the grid's lower corner [m]
    cell: float            # cell edge [m]
    dims: np.ndarray       # (3,) int64 cells per axis
    table: np.ndarray      # (cells + 1,) int64 where each cell's list begins in ``shape_ids``
    shape_ids: np.ndarray  # (E,) int64 the shapes whose grown bounding sphere overlaps the cell
    grown: np.ndarray      # (K,) the shapes' bounding-sphere radii grown by the reach [m]


class Query(NamedTuple):
    """What :func:`_point_hits` looks for."""

    points: np.ndarray    # (N, 3) one point per row
    selected: np.ndarray  # (S,) int64 the points to write (fill pass), else unused
    reach: float          # shapes and ground closer than this [m]
    ground: bool          # the plane z = ground_height is an obstacle
    ground_height: float  # [m]


@dataclass
class Obstacles:
    """Obstacle shapes in world coordinates.

    Attributes (shapes):
        sphere_centers:       (ks, 3) — spheres, and every particle of the particle-set bodies.
        sphere_radii:         (ks,)
        box_centers:          (kb, 3)
        box_rotations:        (kb, 3, 3) — columns are the box axes in world coordinates.
        box_half_extents:     (kb, 3)
        capsule_centers:      (kc, 3)
        capsule_axes:         (kc, 3) — unit axis of the segment (body z in world).
        capsule_half_lengths: (kc,) — half the segment length.
        capsule_radii:        (kc,)
        ground_height:        float or None — the plane z = ground_height (outward normal +z), or no ground.
        hull_centers:         (kh, 3) — convex hulls (convex bodies, compound parts): the origin of their vertices.
        hull_rotations:       (kh, 3, 3) — their axes (columns) in world.
        hull_face_start:      (kh + 1,) int64 — hull k's face planes are rows hull_face_start[k] .. [k + 1] − 1 of
        hull_face_plane:      (F, 4) — unit outward normal and offset in the hull's frame (n · x = d on the face).
        hull_bound:           (kh,) — radius of a sphere about the hull's origin holding it.
        meshes:               list of (StaticMesh, position (3,), rotation (3, 3), two_sided) — static meshes.
    """

    sphere_centers: np.ndarray
    sphere_radii: np.ndarray
    box_centers: np.ndarray
    box_rotations: np.ndarray
    box_half_extents: np.ndarray
    capsule_centers: np.ndarray
    capsule_axes: np.ndarray
    capsule_half_lengths: np.ndarray
    capsule_radii: np.ndarray
    ground_height: float | None = None
    hull_centers: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    hull_rotations: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    hull_face_start: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    hull_face_plane: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    hull_bound: np.ndarray = field(default_factory=lambda: np.zeros(0))
    meshes: list = field(default_factory=list)
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @staticmethod
    def empty(ground_height: float | None = None) -> Obstacles:
        return Obstacles(np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)),
                         np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0), ground_height)

    @staticmethod
    def from_bodies(model: BodyModel, state: BodyState, ground: bool = False) -> Obstacles:
        """The bodies of a world at their current poses (spheres, boxes, capsules, the particles of particle
        sets as spheres of the body's particle radius, convex hulls, compound bodies' parts at their poses,
        static meshes), plus the ground plane z = 0 if ``ground``."""
        shape = np.asarray(model.shape)
        rotations = state.rotation_matrices() if model.count else np.zeros((0, 3, 3))
        spheres = np.flatnonzero(shape == Shape.SPHERE)
        centers = [state.position[spheres]]
        radii = [model.radius[spheres]]
        for b in np.flatnonzero(shape == Shape.PARTICLES):
            local = np.asarray(model.particles[b])[:, :3]
            centers.append(state.position[b] + local @ rotations[b].T)
            radii.append(np.full(len(local), model.radius[b]))
        boxes = np.flatnonzero(shape == Shape.BOX)
        capsules = np.flatnonzero(shape == Shape.CAPSULE)
        box = [[state.position[boxes]], [rotations[boxes]], [model.half_extents[boxes]]]  # columns: lists of arrays
        capsule = [[state.position[capsules]], [rotations[capsules][:, :, 2]], [model.half_extents[capsules, 2]],
                   [model.radius[capsules]]]
        hulls = []  # (centre, rotation, hull)
        for b in np.flatnonzero(shape == Shape.CONVEX):
            hulls.append((state.position[b], rotations[b], model.hulls[b]))
        for b in np.flatnonzero(shape == Shape.COMPOUND):
            parts = model.parts[b]
            centre = state.position[b] + parts.position @ rotations[b].T
            turned = rotations[b] @ parts.rotation
            for k in range(parts.count):
                kind = int(parts.shape[k])
                if kind == Shape.SPHERE:
                    centers.append(centre[k][None])
                    radii.append(parts.radius[k:k + 1])
                elif kind == Shape.BOX:
                    for column, value in zip(box, (centre[k], turned[k], parts.half_extents[k])):
                        column.append(value[None])
                elif kind == Shape.CAPSULE:
                    for column, value in zip(capsule, (centre[k], turned[k][:, 2], parts.half_extents[k, 2],
                                                       parts.radius[k])):
                        column.append(np.reshape(value, (1, -1)) if np.ndim(value) else np.array([value]))
                else:
                    hulls.append((centre[k], turned[k], parts.hulls[k]))
        meshes = [(model.meshes[b], state.position[b].copy(), rotations[b].copy(), bool(model.two_sided[b]))
                  for b in np.flatnonzero(shape == Shape.MESH)]
        face_start = np.zeros(len(hulls) + 1, np.int64)
        face_start[1:] = np.cumsum([len(h.face_plane) for _, _, h in hulls])
        return Obstacles(
            sphere_centers=np.concatenate(centers).reshape(-1, 3),
            sphere_radii=np.concatenate(radii),
            box_centers=np.concatenate(box[0]).reshape(-1, 3),
            box_rotations=np.concatenate(box[1]).reshape(-1, 3, 3),
            box_half_extents=np.concatenate(box[2]).reshape(-1, 3),
            capsule_centers=np.concatenate(capsule[0]).reshape(-1, 3),
            capsule_axes=np.concatenate(capsule[1]).reshape(-1, 3),
            capsule_half_lengths=np.concatenate(capsule[2]).reshape(-1),
            capsule_radii=np.concatenate(capsule[3]).reshape(-1),
            ground_height=0.0 if ground else None,
            hull_centers=np.array([c for c, _, _ in hulls], float).reshape(-1, 3),
            hull_rotations=np.array([R for _, R, _ in hulls], float).reshape(-1, 3, 3),
            hull_face_start=face_start,
            hull_face_plane=np.concatenate([h.face_plane for _, _, h in hulls]) if hulls else np.zeros((0, 4)),
            hull_bound=np.array([np.linalg.norm(h.vertices, axis=1).max() for _, _, h in hulls], float),
            meshes=meshes,
        )

    @property
    def shape_count(self) -> int:
        """Number of shapes (the ground plane counts as one)."""
        return (len(self.sphere_radii) + len(self.box_centers) + len(self.capsule_centers)
                + (self.ground_height is not None) + len(self.hull_bound) + len(self.meshes))

    # ---- queries ---------------------------------------------------------------------------------------

    def query(self, points: np.ndarray, reach: float) -> ObstacleHits:
        """Every (point, shape) pair with signed distance < ``reach``; ``points (3, N)`` world coordinates.
        The hits come point by point (ascending), each point's shapes in order (spheres, boxes, capsules, then
        the ground plane); those on hulls and static meshes follow, point by point again."""
        rows = np.ascontiguousarray(np.asarray(points, dtype=np.float64).T)  # (N, 3): one point per row
        n = len(rows)
        if n == 0 or self.shape_count == 0:
            return ObstacleHits.concatenate([])
        if len(self.hull_bound) or self.meshes:
            return ObstacleHits.concatenate([self._primitive_hits(rows, reach), self._convex_hits(rows, reach)])
        return self._primitive_hits(rows, reach)

    def _convex_hits(self, rows: np.ndarray, reach: float) -> ObstacleHits:
        """The hits on hulls and static meshes (see the module docstring), ``rows (N, 3)``."""
        parts = []
        if len(self.hull_bound):
            parts.append(ObstacleHits(*_hull_hits(rows, float(reach), self.hull_centers, self.hull_rotations,
                                                  self.hull_face_start, self.hull_face_plane, self.hull_bound)))
        for mesh, position, rotation, two_sided in self.meshes:
            parts.append(ObstacleHits(*_mesh_hits(rows, float(reach), tuple(mesh.arrays), position, rotation,
                                                  two_sided)))
        return ObstacleHits.concatenate(parts)

    def _primitive_hits(self, rows: np.ndarray, reach: float) -> ObstacleHits:
        """The hits on spheres, boxes, capsules and the ground plane, ``rows (N, 3)``."""
        n = len(rows)
        if len(self.sphere_radii) + len(self.box_centers) + len(self.capsule_centers) == 0 \
                and self.ground_height is None:
            return ObstacleHits.concatenate([])
        shapes = self._packed()
        grown = shapes.bound + reach
        low, high = bounding_box(rows)
        extent = high - low
        cell = max(_CELL_REACHES * reach, float(np.prod(extent + 1e-9) / _MAX_CELLS) ** (1.0 / 3.0), 1e-6)
        dims = (np.floor(extent / cell) + 1).astype(np.int64)
        table, shape_ids = _bin_shapes(shapes.center, grown, low, cell, dims)
        bins = ShapeBins(low, cell, dims, table, shape_ids, grown)
        ground = self.ground_height is not None
        ground_height = float(self.ground_height) if ground else 0.0
        counts = np.empty(n, np.int64)
        no_hits = ObstacleHits(np.zeros(0, np.int64), np.zeros(0), np.zeros((3, 0)))
        query = Query(rows, np.arange(0), float(reach), ground, ground_height)
        _point_hits(False, query, shapes, bins, counts, no_hits)  # count, for every point
        # write, for the points that hit something: usually a few hundred of thousands of boids, so a second
        # pass over all of them would cost as much as the first
        hitting = np.flatnonzero(counts)
        if len(hitting) == 0:
            return no_hits
        counts = counts[hitting]
        start = np.zeros(len(hitting), np.int64)
        np.cumsum(counts[:-1], out=start[1:])
        total = int(start[-1] + counts[-1])
        hits = ObstacleHits(np.empty(total, np.int64), np.empty(total), np.empty((3, total)))
        _point_hits(True, query._replace(selected=hitting), shapes, bins, start, hits)
        return hits

    def _packed(self) -> PackedShapes:
        """Every shape in one set of arrays for the compiled query (computed once per Obstacles)."""
        if "packed" not in self._cache:
            ks, kb, kc = len(self.sphere_radii), len(self.box_centers), len(self.capsule_centers)
            k = ks + kb + kc
            kind = np.concatenate([np.full(ks, _SPHERE), np.full(kb, _BOX), np.full(kc, _CAPSULE)]).astype(np.int64)
            center = np.concatenate([self.sphere_centers, self.box_centers, self.capsule_centers]).reshape(k, 3)
            rotation = np.tile(np.eye(3), (k, 1, 1))
            rotation[ks:ks + kb] = self.box_rotations
            rotation[ks + kb:, :, 2] = self.capsule_axes
            half = np.zeros((k, 3))
            half[ks:ks + kb] = self.box_half_extents
            half[ks + kb:, 2] = self.capsule_half_lengths
            radius = np.concatenate([self.sphere_radii, np.zeros(kb), self.capsule_radii])
            bound = np.concatenate([self.sphere_radii, np.linalg.norm(self.box_half_extents, axis=1),
                                    self.capsule_half_lengths + self.capsule_radii])
            self._cache["packed"] = PackedShapes(kind, np.ascontiguousarray(center), rotation, half, radius, bound)
        return self._cache["packed"]


# ---- the compiled query: closest points (Ericson ch. 5), one point and one shape --------------------------

@njit
def sphere_distance_to(px, py, pz, cx, cy, cz, r):
    """Signed distance from a point to a sphere and the outward normal (+z for the centre itself)."""
    dx, dy, dz = px - cx, py - cy, pz - cz
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    if length < _TINY:
        return length - r, 0.0, 0.0, 1.0
    return length - r, dx / length, dy / length, dz / length


@njit
def box_distance_to(px, py, pz, center, rotation, half):
    """Signed distance from a point to an oriented box (``rotation`` columns = its axes) and the outward normal:
    outside, from the closest point of the box to the point; inside, the axis of the nearest face."""
    dx, dy, dz = px - center[0], py - center[1], pz - center[2]
    l0 = rotation[0, 0] * dx + rotation[1, 0] * dy + rotation[2, 0] * dz  # Rᵀ d: the point in box axes
    l1 = rotation[0, 1] * dx + rotation[1, 1] * dy + rotation[2, 1] * dz
    l2 = rotation[0, 2] * dx + rotation[1, 2] * dy + rotation[2, 2] * dz
    q0, q1, q2 = abs(l0) - half[0], abs(l1) - half[1], abs(l2) - half[2]  # distances outside each slab
    o0, o1, o2 = max(q0, 0.0), max(q1, 0.0), max(q2, 0.0)
    s0 = 1.0 if l0 >= 0.0 else -1.0
    s1 = 1.0 if l1 >= 0.0 else -1.0
    s2 = 1.0 if l2 >= 0.0 else -1.0
    out_len = math.sqrt(o0 * o0 + o1 * o1 + o2 * o2)
    if out_len > 0.0:
        n0, n1, n2 = s0 * o0 / out_len, s1 * o1 / out_len, s2 * o2 / out_len
        distance = out_len
    elif q0 >= q1 and q0 >= q2:
        n0, n1, n2, distance = s0, 0.0, 0.0, q0
    elif q1 >= q2:
        n0, n1, n2, distance = 0.0, s1, 0.0, q1
    else:
        n0, n1, n2, distance = 0.0, 0.0, s2, q2
    return (distance, rotation[0, 0] * n0 + rotation[0, 1] * n1 + rotation[0, 2] * n2,
            rotation[1, 0] * n0 + rotation[1, 1] * n1 + rotation[1, 2] * n2,
            rotation[2, 0] * n0 + rotation[2, 1] * n1 + rotation[2, 2] * n2)


@njit
def capsule_distance_to(px, py, pz, center, axis, half_length, r):
    """Signed distance from a point to a capsule (segment ``center ± half_length · axis`` swept by ``r``) and
    the outward normal (on the axis itself: a fixed perpendicular of it)."""
    ax, ay, az = center[0] - axis[0] * half_length, center[1] - axis[1] * half_length, center[2] - axis[2] * half_length
    bx, by, bz = center[0] + axis[0] * half_length, center[1] + axis[1] * half_length, center[2] + axis[2] * half_length
    abx, aby, abz = bx - ax, by - ay, bz - az
    denom = abx * abx + aby * aby + abz * abz
    t = ((px - ax) * abx + (py - ay) * aby + (pz - az) * abz) / (denom if denom > _TINY else 1.0)
    t = min(max(t, 0.0), 1.0)
    dx, dy, dz = px - (ax + t * abx), py - (ay + t * aby), pz - (az + t * abz)
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    if length < _TINY:  # on the axis: axis × x̂ (or × ŷ for an axis along x)
        hx, hy, hz = (1.0, 0.0, 0.0) if abs(axis[0]) < 0.9 else (0.0, 1.0, 0.0)
        dx, dy, dz = axis[1] * hz - axis[2] * hy, axis[2] * hx - axis[0] * hz, axis[0] * hy - axis[1] * hx
        norm = math.sqrt(dx * dx + dy * dy + dz * dz)
        return length - r, dx / norm, dy / norm, dz / norm
    return length - r, dx / length, dy / length, dz / length


@njit
def _bin_shapes(center, grown, low, cell, dims):
    """CSR lists of the shapes per cell: shape k goes into every cell its bounding sphere (radius
    ``grown[k]``) overlaps; ``(table (cells + 1,), shape_ids)``, shapes in ascending order within a cell."""
    cells = dims[0] * dims[1] * dims[2]
    table = np.zeros(cells + 1, np.int64)
    lo = np.empty(3, np.int64)
    hi = np.empty(3, np.int64)
    for sweep in range(2):  # count, then fill
        if sweep == 1:
            for c in range(cells):
                table[c + 1] += table[c]
            shape_ids = np.empty(table[cells], np.int64)
            cursor = table[:-1].copy()
        else:
            shape_ids = np.empty(0, np.int64)
            cursor = table[:-1]
        for k in range(center.shape[0]):
            empty = False
            for a in range(3):
                lo[a] = max(int(math.floor((center[k, a] - grown[k] - low[a]) / cell)), 0)
                hi[a] = min(int(math.floor((center[k, a] + grown[k] - low[a]) / cell)), dims[a] - 1)
                empty |= hi[a] < lo[a]
            if empty:
                continue
            for x in range(lo[0], hi[0] + 1):
                for y in range(lo[1], hi[1] + 1):
                    for z in range(lo[2], hi[2] + 1):
                        c = (x * dims[1] + y) * dims[2] + z
                        if sweep == 0:
                            table[c + 1] += 1
                        else:
                            shape_ids[cursor[c]] = k
                            cursor[c] += 1
    return table, shape_ids


@njit(parallel=True)
def _point_hits(fill, query, shapes, bins, counts_or_start, hits):
    """Per point of the :class:`Query`, the :class:`PackedShapes` of its cell (:class:`ShapeBins`) within the
    reach and the ground plane: counted for every point into ``counts_or_start[i]`` (``fill`` False), or, for
    the points ``query.selected[q]`` (``fill`` True), written into ``hits`` (:class:`ObstacleHits`) from
    ``counts_or_start[q]`` on."""
    points, selected, reach, ground, ground_height = query
    kind, center, rotation, half, radius, _ = shapes
    low, cell, dims, table, shape_ids, grown = bins
    hit_point, hit_distance, hit_normal = hits
    items = selected.shape[0] if fill else points.shape[0]
    for q in prange(items):
        i = selected[q] if fill else np.int64(q)  # (a prange index is unsigned: one integer type for both)
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        cx = min(int((px - low[0]) / cell), dims[0] - 1)
        cy = min(int((py - low[1]) / cell), dims[1] - 1)
        cz = min(int((pz - low[2]) / cell), dims[2] - 1)
        c = (cx * dims[1] + cy) * dims[2] + cz
        found = 0
        for e in range(table[c], table[c + 1] + 1):
            if e == table[c + 1]:  # after the cell's shapes: the ground
                if not ground or pz - ground_height >= reach:
                    continue
                d, nx, ny, nz = pz - ground_height, 0.0, 0.0, 1.0
            else:
                k = shape_ids[e]
                dx, dy, dz = px - center[k, 0], py - center[k, 1], pz - center[k, 2]
                if dx * dx + dy * dy + dz * dz >= grown[k] * grown[k]:
                    continue  # outside the bounding sphere grown by the reach
                if kind[k] == _SPHERE:
                    d, nx, ny, nz = sphere_distance_to(px, py, pz, center[k, 0], center[k, 1], center[k, 2],
                                                       radius[k])
                elif kind[k] == _BOX:
                    d, nx, ny, nz = box_distance_to(px, py, pz, center[k], rotation[k], half[k])
                else:
                    d, nx, ny, nz = capsule_distance_to(px, py, pz, center[k], rotation[k, :, 2], half[k, 2],
                                                        radius[k])
                if d >= reach:
                    continue
            if fill:
                slot = counts_or_start[q] + found
                hit_point[slot] = i
                hit_distance[slot] = d
                hit_normal[0, slot], hit_normal[1, slot], hit_normal[2, slot] = nx, ny, nz
            found += 1
        if not fill:
            counts_or_start[q] = found


# ---- hulls and static meshes (issue 25) ----------------------------------------------------------------------

@njit
def _hull_hits(points, reach, centers, rotations, face_start, face_plane, bound):
    """Every (point, hull) pair with the face-plane signed distance below ``reach`` (see the module docstring):
    ``(point (Q,), distance (Q,), normal (3, Q))``, point by point."""
    n, k = len(points), len(bound)
    cap = 16
    hit_point, hit_distance, hit_normal = np.empty(cap, np.int64), np.empty(cap), np.empty((3, cap))
    count = 0
    for i in range(n):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        for h in range(k):
            dx, dy, dz = px - centers[h, 0], py - centers[h, 1], pz - centers[h, 2]
            grown = bound[h] + reach
            if dx * dx + dy * dy + dz * dz >= grown * grown:
                continue
            R = rotations[h]
            lx = R[0, 0] * dx + R[1, 0] * dy + R[2, 0] * dz  # the point in the hull's frame
            ly = R[0, 1] * dx + R[1, 1] * dy + R[2, 1] * dz
            lz = R[0, 2] * dx + R[1, 2] * dy + R[2, 2] * dz
            best, best_f = -np.inf, -1
            for f in range(face_start[h], face_start[h + 1]):
                d = face_plane[f, 0] * lx + face_plane[f, 1] * ly + face_plane[f, 2] * lz - face_plane[f, 3]
                if d > best:
                    best, best_f = d, f
            if best >= reach or best_f < 0:
                continue
            if count == cap:
                cap *= 2
                p2, d2, n2 = np.empty(cap, np.int64), np.empty(cap), np.empty((3, cap))
                p2[:count], d2[:count], n2[:, :count] = hit_point[:count], hit_distance[:count], hit_normal[:, :count]
                hit_point, hit_distance, hit_normal = p2, d2, n2
            a, b, c = face_plane[best_f, 0], face_plane[best_f, 1], face_plane[best_f, 2]
            hit_point[count] = i
            hit_distance[count] = best
            for r in range(3):
                hit_normal[r, count] = R[r, 0] * a + R[r, 1] * b + R[r, 2] * c
            count += 1
    return hit_point[:count].copy(), hit_distance[:count].copy(), hit_normal[:, :count].copy()


@njit
def _mesh_hits(points, reach, mesh, position, rotation, two_sided):
    """Every point within ``reach`` of a static mesh (a :class:`~cgp_core.collision.bvh.TriangleMesh`, as a plain
    tuple from Python) posed by ``position``, ``rotation``: the BVH's closest point (see the module docstring for
    the sign): ``(point (Q,), distance (Q,), normal (3, Q))``."""
    mesh = TriangleMesh(*mesh)
    vertices, triangles = mesh.vertices, mesh.triangles
    n = len(points)
    hit_point, hit_distance, hit_normal = np.empty(n, np.int64), np.empty(n), np.empty((3, n))
    local = np.empty(3)
    count = 0
    for i in range(n):
        dx, dy, dz = points[i, 0] - position[0], points[i, 1] - position[1], points[i, 2] - position[2]
        for r in range(3):
            local[r] = rotation[0, r] * dx + rotation[1, r] * dy + rotation[2, r] * dz
        t, distance, cx, cy, cz = bvh_closest_point(mesh, local, reach)
        if t < 0 or distance >= reach:
            continue
        ox, oy, oz = local[0] - cx, local[1] - cy, local[2] - cz
        if distance > _TINY:
            ox, oy, oz = ox / distance, oy / distance, oz / distance
        a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        ex, ey, ez = vertices[b, 0] - vertices[a, 0], vertices[b, 1] - vertices[a, 1], vertices[b, 2] - vertices[a, 2]
        fx, fy, fz = vertices[c, 0] - vertices[a, 0], vertices[c, 1] - vertices[a, 1], vertices[c, 2] - vertices[a, 2]
        nx, ny, nz = ey * fz - ez * fy, ez * fx - ex * fz, ex * fy - ey * fx
        length = math.sqrt(nx * nx + ny * ny + nz * nz)
        nx, ny, nz = nx / length, ny / length, nz / length
        signed = distance
        if distance <= _TINY:  # on the surface: the triangle's front
            ox, oy, oz = nx, ny, nz
        elif not two_sided and ox * nx + oy * ny + oz * nz < 0.0:  # behind a one-sided mesh: inside
            signed = -distance
            ox, oy, oz = -ox, -oy, -oz
        hit_point[count] = i
        hit_distance[count] = signed
        for r in range(3):
            hit_normal[r, count] = rotation[r, 0] * ox + rotation[r, 1] * oy + rotation[r, 2] * oz
        count += 1
    return hit_point[:count].copy(), hit_distance[:count].copy(), hit_normal[:, :count].copy()

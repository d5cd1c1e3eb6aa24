"""The rigid bodies of a world, seen by its flocks as obstacles (at one instant: built once per tick).

Boids steer around obstacles (``flock.py``: an acceleration away from the surface and sideways, starting
``obstacle_margin`` away from it) and never enter them: after moving, a boid inside a body inflated by half
its size is put back on the surface and loses its inward velocity.  Distances come from ``geometry.py``
(Ericson's closest-point formulas); this module only finds which (boid, shape) pairs are close enough to
matter, so the cost is proportional to the boids near bodies, not boids × bodies:

- shapes whose bounding box (grown by the query reach) misses the flock's bounding box are dropped at once;
- each remaining shape tests its bounding sphere only against the boids of a few contiguous runs of a
  :class:`ColumnIndex` (boids sorted by x cell, then y), all shapes in one vectorized pass;
- many spheres (particle sets) go through a KD-tree of their centres instead;
- boxes and capsules then test the box (slab per axis) / the capsule (cylinder and end caps) grown by the
  reach, per pair: a long beam's or pillar's bounding sphere holds thousands of boids, its grown box a few;
- exact distances: one ``geometry.py`` call per shape type for the few candidates.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..bodies import BodyModel, BodyState, Shape
from ..geometry import box_distance, capsule_distance

# above this many spheres, candidate (boid, sphere) pairs come from a KD-tree of the sphere centres
_SPHERES_FOR_TREE = 64
_TREE_NEIGHBORS = 8
_SPHERE, _BOX, _CAPSULE = 0, 1, 2


@dataclass
class ObstacleHits:
    """(point, shape) pairs closer than the query reach.

    Attributes (shapes):
        point:    (Q,) intp — index of the point (boid).
        distance: (Q,) — signed distance from the point to the shape's surface [m], negative inside.
        normal:   (3, Q) — unit outward direction (the way out / away from the shape).
    """

    point: np.ndarray
    distance: np.ndarray
    normal: np.ndarray

    @property
    def count(self) -> int:
        return len(self.point)

    @staticmethod
    def concatenate(parts: list["ObstacleHits"]) -> "ObstacleHits":
        parts = [p for p in parts if p.count]
        if not parts:
            return ObstacleHits(np.zeros(0, np.intp), np.zeros(0), np.zeros((3, 0)))
        return ObstacleHits(np.concatenate([p.point for p in parts]),
                            np.concatenate([p.distance for p in parts]),
                            np.concatenate([p.normal for p in parts], axis=1))


class ColumnIndex:
    """Points sorted by (x cell, y): a shape's candidate points are then a few contiguous runs (one per x cell
    its grown bounding sphere overlaps, cut to its y range by binary search), not the whole cloud.

    Attributes (shapes):
        cell:   x cell size [m].
        order:  (N,) intp — points sorted by key.
        keys:   (N,) float64 — sorted keys ``x_cell · span + (y − y_low)``.
    Build it once per tick from the previous tick's index (nearly sorted: timsort is then close to O(N)).
    """

    def __init__(self, points: np.ndarray, cell: float, previous: "ColumnIndex | None" = None):
        self.cell = cell
        self.y_low = float(points[1].min())
        self.x_low = float(points[0].min())
        self.span = float(points[1].max()) - self.y_low + 1.0
        keys = np.floor((points[0] - self.x_low) / cell) * self.span + (points[1] - self.y_low)
        count = points.shape[1]
        start = previous.order if previous is not None and len(previous.order) == count else np.arange(count)
        self.order = np.take(start, np.argsort(np.take(keys, start), kind="stable"))
        self.keys = np.take(keys, self.order)

    def ranges(self, centers: np.ndarray, grown: np.ndarray):
        """For k spheres (``centers (k, 3)``, radii ``grown (k,)``): the (sphere, first, last) sorted-index
        ranges that hold every point with |x − cx| <= r and |y − cy| <= r."""
        first_cell = np.floor((centers[:, 0] - grown - self.x_low) / self.cell)
        last_cell = np.floor((centers[:, 0] + grown - self.x_low) / self.cell)
        cells = (last_cell - first_cell + 1).astype(np.int64)
        sphere = np.repeat(np.arange(len(centers)), cells)
        cell = np.repeat(first_cell, cells) + (np.arange(int(cells.sum())) - np.repeat(np.cumsum(cells) - cells, cells))
        base = cell * self.span
        y_low = np.maximum(centers[sphere, 1] - grown[sphere] - self.y_low, 0.0)
        y_high = np.minimum(centers[sphere, 1] + grown[sphere] - self.y_low, self.span)
        first = np.searchsorted(self.keys, base + y_low, side="left")
        last = np.searchsorted(self.keys, base + y_high, side="right")
        return sphere, first, np.maximum(last, first)


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
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @staticmethod
    def empty(ground_height: float | None = None) -> "Obstacles":
        return Obstacles(np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)),
                         np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0), ground_height)

    @staticmethod
    def from_bodies(model: BodyModel, state: BodyState, ground: bool = False) -> "Obstacles":
        """The bodies of a world at their current poses (spheres, boxes, capsules, the particles of particle
        sets as spheres of the body's particle radius), plus the ground plane z = 0 if ``ground``."""
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
        return Obstacles(
            sphere_centers=np.concatenate(centers).reshape(-1, 3),
            sphere_radii=np.concatenate(radii),
            box_centers=state.position[boxes],
            box_rotations=rotations[boxes],
            box_half_extents=model.half_extents[boxes],
            capsule_centers=state.position[capsules],
            capsule_axes=rotations[capsules][:, :, 2],
            capsule_half_lengths=model.half_extents[capsules, 2],
            capsule_radii=model.radius[capsules],
            ground_height=0.0 if ground else None,
        )

    @property
    def shape_count(self) -> int:
        """Number of shapes (the ground plane counts as one)."""
        return (len(self.sphere_radii) + len(self.box_centers) + len(self.capsule_centers)
                + (self.ground_height is not None))

    # ---- queries ---------------------------------------------------------------------------------------

    def query(self, points: np.ndarray, reach: float, index: ColumnIndex | None = None) -> ObstacleHits:
        """Every (point, shape) pair with signed distance < ``reach``; ``points (3, N)`` world coordinates.

        ``index`` optionally is a :class:`ColumnIndex` of these points (a flock keeps one from tick to tick);
        without it the query builds one."""
        if points.shape[1] == 0:
            return ObstacleHits.concatenate([])
        low = points.min(axis=1)
        high = points.max(axis=1)
        parts = []
        many_spheres = len(self.sphere_radii) > _SPHERES_FOR_TREE
        if many_spheres:
            parts.append(self._query_many_spheres(points, reach, low, high))
        # bounding spheres of all (other) shapes, culled and matched against the boids in one pass
        centers, bounds, kind, which = self._bounding_spheres(include_spheres=not many_spheres)
        keep = self._overlapping(centers, bounds, reach, low, high)
        if len(keep):
            if index is None:
                index = ColumnIndex(points, max(reach, 1e-3))
            shape, point = self._candidates(points, index, centers[keep], bounds[keep], reach)
            shape = keep[shape]
            for k, exact in ((_SPHERE, self._sphere_pairs), (_BOX, self._box_exact), (_CAPSULE, self._capsule_exact)):
                mine = np.flatnonzero(kind[shape] == k)
                if len(mine):
                    mine_point, mine_shape = point[mine], which[shape[mine]]
                    if k == _BOX:
                        mine_point, mine_shape = self._box_prefilter(points, mine_point, mine_shape, reach)
                    elif k == _CAPSULE:
                        mine_point, mine_shape = self._capsule_prefilter(points, mine_point, mine_shape, reach)
                    if len(mine_point):
                        parts.append(self._within(exact(points, mine_point, mine_shape), reach))
        if self.ground_height is not None:
            height = points[2] - self.ground_height
            near = np.flatnonzero(height < reach)
            normal = np.zeros((3, len(near)))
            normal[2] = 1.0
            parts.append(ObstacleHits(near, height[near], normal))
        return ObstacleHits.concatenate(parts)

    def _bounding_spheres(self, include_spheres: bool):
        """Centres (K, 3), radii (K,), shape kind (K,) and index within its kind (K,) of every shape's
        bounding sphere (computed once per Obstacles)."""
        key = ("bounds", include_spheres)
        if key not in self._cache:
            parts = [(self.box_centers, np.linalg.norm(self.box_half_extents, axis=1), _BOX),
                     (self.capsule_centers, self.capsule_half_lengths + self.capsule_radii, _CAPSULE)]
            if include_spheres:
                parts.insert(0, (self.sphere_centers, self.sphere_radii, _SPHERE))
            self._cache[key] = (np.concatenate([c for c, _, _ in parts]).reshape(-1, 3),
                                np.concatenate([r for _, r, _ in parts]),
                                np.concatenate([np.full(len(r), k) for _, r, k in parts]),
                                np.concatenate([np.arange(len(r)) for _, r, _ in parts]))
        return self._cache[key]

    @staticmethod
    def _overlapping(centers: np.ndarray, bounds: np.ndarray, reach: float, low, high) -> np.ndarray:
        """Shapes whose bounding sphere grown by ``reach`` can touch the points' bounding box."""
        grown = bounds + reach
        return np.flatnonzero(np.all((centers + grown[:, None] >= low) & (centers - grown[:, None] <= high),
                                     axis=1))

    @staticmethod
    def _candidates(points, index: ColumnIndex, centers, bounds, reach):
        """(shape, point) index pairs with |p − c| < bound + reach: each shape looks only at the points of
        the index's runs around it, all shapes in one vectorized pass."""
        grown = bounds + reach
        shape, first, last = index.ranges(centers, grown)
        counts = last - first
        total = int(counts.sum())
        if total == 0:
            return np.zeros(0, np.intp), np.zeros(0, np.intp)
        shape = np.repeat(shape, counts)
        ends = np.cumsum(counts)
        point = index.order[np.arange(total) - np.repeat(ends - counts - first, counts)]
        d2 = (points[0, point] - centers[shape, 0]) ** 2
        d2 += (points[1, point] - centers[shape, 1]) ** 2
        d2 += (points[2, point] - centers[shape, 2]) ** 2
        keep = d2 < grown[shape] ** 2
        return shape[keep], point[keep]

    def _query_many_spheres(self, points, reach, low, high) -> ObstacleHits:
        """Particle sets with many spheres: each boid near them asks a KD-tree of the centres for its
        nearest few (enough for non-overlapping particles)."""
        keep = self._overlapping(self.sphere_centers, self.sphere_radii, reach, low, high)
        if len(keep) == 0:
            return ObstacleHits.concatenate([])
        centers = self.sphere_centers[keep]
        grown = self.sphere_radii[keep].max() + reach
        inside = np.flatnonzero(np.all((points >= (centers.min(axis=0) - grown)[:, None])
                                       & (points <= (centers.max(axis=0) + grown)[:, None]), axis=0))
        k = min(_TREE_NEIGHBORS, len(keep))
        _, nearest = cKDTree(centers).query(points[:, inside].T, k=k, distance_upper_bound=grown)
        nearest = nearest.reshape(len(inside), k)
        rows, cols = np.nonzero(nearest < len(keep))
        return self._within(self._sphere_pairs(points, inside[rows], keep[nearest[rows, cols]]), reach)

    def _sphere_pairs(self, points, point, sphere) -> ObstacleHits:
        """Point-vs-sphere for (point, sphere) pairs: the diagonal of ``geometry.sphere_distance`` (which is
        points × spheres), with the same fallback normal (+z) for a point at the centre."""
        offset = points[:, point] - self.sphere_centers[sphere].T
        length = np.sqrt(offset[0] * offset[0] + offset[1] * offset[1] + offset[2] * offset[2])
        at_centre = length < 1e-12
        normal = offset / np.where(at_centre, 1.0, length)
        normal[2, at_centre] = 1.0
        return ObstacleHits(point, length - self.sphere_radii[sphere], normal)

    # Prefilters: necessary conditions for ``distance < reach``, so they drop only pairs the exact test would
    # drop too (then the hits, and their order, are the same as without them).  Padded by a relative 1e-9 so
    # that rounding differences with ``geometry.py``'s formulas can never drop a pair.

    def _box_prefilter(self, points, point, box, reach):
        """(point, box) pairs with the point inside the box grown by ``reach`` on every side: the distance to
        a box is at least its largest per-axis slab distance ``|local_a| − h_a``."""
        offset = points[:, point] - self.box_centers[box].T  # (3, m) world offsets
        rotation = self.box_rotations[box]  # (m, 3, 3), columns = box axes
        half = self.box_half_extents[box]  # (m, 3)
        keep = np.ones(len(point), dtype=bool)
        for axis in range(3):
            local = (rotation[:, 0, axis] * offset[0] + rotation[:, 1, axis] * offset[1]
                     + rotation[:, 2, axis] * offset[2])  # component along the box axis
            keep &= np.abs(local) < (half[:, axis] + reach) * (1.0 + 1e-9) + 1e-9
        return point[keep], box[keep]

    def _capsule_prefilter(self, points, point, capsule, reach):
        """(point, capsule) pairs with the point inside the capsule's cylinder-with-caps grown by ``reach``:
        the distance to a capsule is at least the distance to its axis line minus the radius, and at least the
        distance along the axis beyond the segment's end minus the radius."""
        offset = points[:, point] - self.capsule_centers[capsule].T  # (3, m)
        axis = self.capsule_axes[capsule].T  # (3, m) unit
        along = offset[0] * axis[0] + offset[1] * axis[1] + offset[2] * axis[2]
        grown = (self.capsule_radii[capsule] + reach) * (1.0 + 1e-9) + 1e-9
        radial2 = offset[0] * offset[0] + offset[1] * offset[1] + offset[2] * offset[2] - along * along
        keep = (np.abs(along) < self.capsule_half_lengths[capsule] + grown) & (radial2 < grown * grown)
        return point[keep], capsule[keep]

    def _box_exact(self, points, point, box) -> ObstacleHits:
        """Point-vs-box for (point, box) pairs: one ``geometry.box_distance`` call on the distinct points ×
        distinct boxes involved (few near a flock), then the pairs' entries."""
        unique_points, row = np.unique(point, return_inverse=True)
        boxes, column = np.unique(box, return_inverse=True)
        distance, normal = box_distance(points[:, unique_points].T, self.box_centers[boxes],
                                        self.box_rotations[boxes], self.box_half_extents[boxes])
        return ObstacleHits(point, distance[row, column], normal[row, column].T)

    def _capsule_exact(self, points, point, capsule) -> ObstacleHits:
        """Point-vs-capsule for (point, capsule) pairs, like :meth:`_box_exact`."""
        unique_points, row = np.unique(point, return_inverse=True)
        capsules, column = np.unique(capsule, return_inverse=True)
        distance, normal = capsule_distance(points[:, unique_points].T, self.capsule_centers[capsules],
                                            self.capsule_axes[capsules], self.capsule_half_lengths[capsules],
                                            self.capsule_radii[capsules])
        return ObstacleHits(point, distance[row, column], normal[row, column].T)

    @staticmethod
    def _within(hits: ObstacleHits, reach: float) -> ObstacleHits:
        keep = hits.distance < reach
        return ObstacleHits(hits.point[keep], hits.distance[keep], hits.normal[:, keep])

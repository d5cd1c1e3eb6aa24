"""A boid flock: state and one step (Reynolds' rules + what a real flock also needs).

One step of ``dt`` (all boids at once, no per-boid Python loop):

1. **neighbours** — every pair closer than d (``neighbors.py``; in a periodic world with ghost images);
2. **flocking** — cohesion, separation, alignment summed over each boid's neighbours (``rules.py``) and the
   optional goal: the acceleration the flock *wants*;
3. **avoidance** — soft walls and the world's bodies (``obstacles.py``): the acceleration the boid *needs*.
   It has priority: the flocking part gets only what is left of ``max_acceleration`` (Reynolds' prioritized
   acceleration allocation), so a flock cannot push its members into a wall or a body;
4. **integrate** — semi-implicit Euler: ``b_v += a dt``, speed clamped to [min_speed, max_speed],
   ``b += b_v dt`` (Slide erratum: the slide's ``b = b + b_v`` has no dt, see ``rules.py``);
5. **constraints** — soft walls: a boid that still reaches the box is put back on it and loses its
   outward velocity (so boids never leave the box); wrap: positions are taken modulo the box; bodies: a boid
   inside a body inflated by ``boid_size / 2`` is projected back to its surface and loses its inward
   velocity (so boids never enter a body, even when avoidance was not enough);
6. **frames** — heading and banked dorsal axis, then quaternions (``frames.py``).

State is stored component-major, ``(3, N)`` rows per axis, because numpy is much faster on long contiguous
rows than on many short ``(N, 3)`` rows; the public ``positions`` / ``velocities`` / ``orientations`` are
``(N, 3)`` / ``(N, 4)`` *views* of that storage (writable; ``np.ascontiguousarray`` gives a row-major copy).
"""

from __future__ import annotations

import math

import numpy as np

from . import couzin as couzin_rules  # issue 14: the zonal rule set
from .frames import frames_to_quaternions, initial_dorsal, unit_headings, update_frames
from .neighbors import NeighborPairs, make_search, periodic_images
from .obstacles import ColumnIndex, ObstacleHits, Obstacles
from .params import FlockParams
from .predators import Predators, flee_acceleration
from .rules import neighbor_sums, steering
from .topological import topological_pairs

_PROJECTION_PASSES = 4  # a boid pushed out of one body into an overlapping one gets a few more passes
_SURFACE_CLEARANCE = 1e-9  # projected boids land this far outside the inflated surface (no re-entry by rounding)


def _norm(a: np.ndarray) -> np.ndarray:
    return np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def _limit_norm(a: np.ndarray, limit: np.ndarray | float) -> None:
    """Scale the columns of ``a (3, N)`` in place so that ``|a| <= limit``."""
    length = _norm(a)
    over = length > limit
    if np.any(over):
        a[:, over] *= (np.broadcast_to(limit, length.shape)[over] / length[over])


class Flock:
    """N boids of one :class:`FlockParams`.

    Attributes (public views, shapes):
        positions:    (N, 3) float64 — b, world frame [m].
        velocities:   (N, 3) float64 — b_v [m/s].
        orientations: (N, 4) float64 — unit quaternions (x, y, z, w) of the boid frames: x along the
                      velocity, z dorsal (see ``frames.py``).
        headings:     (N, 3) float64 — the frames' x axes (unit velocity directions).
        dorsals:      (N, 3) float64 — the frames' z axes.
        time:         float — simulated time since the last reset [s].
        steps:        int — steps since the last reset.
        mean_neighbors: float — after a step: mean number of neighbours within d per boid (whatever the
                      field of view); ``mean_visible_neighbors``: those inside the field of view.
    """

    def __init__(self, params: FlockParams):
        if not isinstance(params, FlockParams):
            raise TypeError(f"Flock needs FlockParams, got {type(params).__name__}")
        self.params = params
        self._search = make_search(params.neighbor_search)
        n = params.count
        self._x = np.empty((3, n))
        self._v = np.empty((3, n))
        self._heading = np.empty((3, n))
        self._dorsal = np.empty((3, n))
        self._q = np.empty((4, n))
        self.reset()

    # ---- state -----------------------------------------------------------------------------------------

    def reset(self) -> None:
        """Back to the seeded initial state: positions uniform in the spawn box, directions uniform on the
        sphere, speeds uniform in [min_speed, max_speed], level frames."""
        p = self.params
        n = p.count
        rng = np.random.default_rng(p.seed)
        self._x[:] = p.spawn_center[:, None] + (rng.random((3, n)) - 0.5) * p.spawn_extent[:, None]
        direction = rng.normal(size=(3, n))
        direction /= np.maximum(_norm(direction), 1e-12)
        self._v[:] = direction * rng.uniform(p.min_speed, p.max_speed, n)
        self._heading[:] = unit_headings(self._v)
        self._dorsal[:] = initial_dorsal(self._heading)
        frames_to_quaternions(self._heading, self._dorsal, out=self._q)
        self._search.reset()
        # issue 14: the Couzin model's noise, its own stream (the initial state above is the same for both rules)
        self._noise = np.random.default_rng((p.seed, couzin_rules.NOISE_STREAM))
        self._obstacle_index: ColumnIndex | None = None
        self.time = 0.0
        self.steps = 0
        self.mean_neighbors = 0.0
        self.mean_visible_neighbors = 0.0

    @property
    def count(self) -> int:
        return self.params.count

    @property
    def name(self) -> str:
        return self.params.name

    @property
    def positions(self) -> np.ndarray:
        return self._x.T

    @property
    def velocities(self) -> np.ndarray:
        return self._v.T

    @property
    def orientations(self) -> np.ndarray:
        return self._q.T

    @property
    def headings(self) -> np.ndarray:
        return self._heading.T

    @property
    def dorsals(self) -> np.ndarray:
        return self._dorsal.T

    def polarization(self) -> float:
        """Vicsek order parameter |Σ v̂_i| / N in [0, 1] (1: all boids fly the same way)."""
        return float(_norm(self._heading.sum(axis=1)[:, None])[0] / self.count)

    # ---- step ------------------------------------------------------------------------------------------

    def step(self, dt: float, obstacles: Obstacles | None = None, predators: Predators | None = None) -> None:
        """Advance by ``dt`` seconds, avoiding ``obstacles`` (the world's bodies at this tick) and fleeing
        ``predators`` (``predators.py``) if given."""
        if not (isinstance(dt, (int, float, np.floating)) and math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"flock {self.name!r}: dt must be a finite number > 0, got {dt!r}")
        p = self.params
        x, v = self._x, self._v
        boid_radius = 0.5 * p.boid_size
        use_obstacles = obstacles is not None and obstacles.shape_count > 0

        # ---- issue 14 hook: a Couzin flock decides a direction (couzin.py), not a flocking acceleration
        couzin = p.rules == "couzin"
        if couzin:
            desired = self._couzin_directions()
            wanted = np.zeros((3, p.count))
        else:
            wanted = self._flocking_acceleration()
        if p.goal is not None and p.goal_weight > 0.0 and not couzin:
            to_goal = p.goal[:, None] - x
            wanted += to_goal * (p.goal_weight / np.maximum(_norm(to_goal), 1e-9))

        needed = self._wall_acceleration()
        near: ObstacleHits | None = None
        if use_obstacles:
            # one query serves steering now and the no-entry projection after the move: a boid moves at most
            # max_speed·dt, so any body it can end up inside is within this reach now
            reach = boid_radius + (p.obstacle_margin if p.avoid_bodies else 0.0) + p.max_speed * dt + 1e-6
            near = obstacles.query(x, reach, self._column_index(reach))
            if p.avoid_bodies and p.obstacle_margin > 0.0:
                needed += self._avoidance_acceleration(near, boid_radius)
        # ---- issue 14 hook: predators are fled like obstacles are avoided (priority over flocking)
        if predators is not None and predators.count:
            needed += flee_acceleration(x, predators, p.fright_radius, p.max_acceleration)

        # prioritized allocation: avoidance first, the flock gets what is left of max_acceleration
        _limit_norm(needed, p.max_acceleration)
        if couzin:  # ---- issue 14 hook: turn by at most θ·dt, constant speed s (frames follow v below)
            np.multiply(couzin_rules.couzin_headings(self, desired, needed, dt), p.couzin.speed, out=v)
        else:
            _limit_norm(wanted, np.maximum(p.max_acceleration - _norm(needed), 0.0))
            acceleration = needed
            acceleration += wanted
            v += acceleration * dt
            self._limit_speed()
        x += v * dt

        if p.bounds_mode == "soft":
            self._clamp_to_box()
        elif p.bounds_mode == "wrap":
            size = p.bounds_max - p.bounds_min
            x -= p.bounds_min[:, None]
            np.mod(x, size[:, None], out=x)
            x += p.bounds_min[:, None]
        if use_obstacles:
            if p.bounds_mode == "wrap":
                # a boid that wrapped now faces bodies it was not near: check everyone
                candidates = np.arange(p.count)
            else:
                # signed distance is 1-Lipschitz: only a boid that was within its radius plus one step of a
                # body can be inside it now
                candidates = np.unique(near.point[near.distance < boid_radius + p.max_speed * dt + 1e-9])
            if len(candidates):
                self._project_out_of_bodies(obstacles, candidates, boid_radius)

        self._heading[:], self._dorsal[:] = update_frames(self._heading, self._dorsal, v, dt, p.bank_gain,
                                                          p.orientation_time_constant)
        frames_to_quaternions(self._heading, self._dorsal, out=self._q)
        self.time += dt
        self.steps += 1

    # ---- stages ----------------------------------------------------------------------------------------

    def _column_index(self, cell: float) -> ColumnIndex:
        """The boids sorted by (x cell, y) for the obstacle queries, refreshed from the previous tick's index
        (nearly sorted already: timsort is then close to O(N))."""
        self._obstacle_index = ColumnIndex(self._x, cell, self._obstacle_index)
        return self._obstacle_index

    def _work_points(self) -> tuple[np.ndarray, np.ndarray | None]:
        """float32 work coordinates (3, W) for the neighbour search, and for a periodic box the real boid of
        each of the W points (ghosts appended after the N boids), else None.

        float32 halves the memory traffic of the pair stages; coordinates are taken relative to the flock's
        (or the box's) lower corner so their magnitude, hence the rounding, stays that of the flock's size."""
        p = self.params
        if p.bounds_mode == "wrap":
            size = p.bounds_max - p.bounds_min
            work = (self._x - p.bounds_min[:, None]).astype(np.float32)
            # float32 rounding can put a coordinate just below L onto L itself
            np.minimum(work, np.nextafter(size.astype(np.float32), np.float32(0.0))[:, None], out=work)
            return periodic_images(work, size, p.radius)
        low = self._x.min(axis=1)
        return (self._x - low[:, None]).astype(np.float32), None

    def neighbor_pairs(self) -> tuple[NeighborPairs, np.ndarray, np.ndarray]:
        """The current neighbour pairs, the work points (3, W) they index (via ``pairs.order``) and the boid
        index of each work point (W,) (ghosts map to the boid they copy)."""
        points, source = self._work_points()
        # ghosts come and go as boids cross the faces of a periodic box: never the same points twice
        pairs = self._search.pairs(points, self.params.radius, reuse=source is None)
        point_boid = np.arange(points.shape[1]) if source is None else source
        return pairs, points, point_boid

    # ---- issue 14 hook: topological neighbours and the Couzin rule set sit on the same pairs
    def interaction_pairs(self) -> tuple[NeighborPairs, np.ndarray, np.ndarray, tuple | None]:
        """:meth:`neighbor_pairs` plus who counts whom: ``(pairs, points, point_boid, weights)`` with
        ``weights`` None in metric mode (everyone within the radius counts) or, in topological mode, the
        ``(forward, backward)`` (P,) float32 weights of ``topological.py`` (the k nearest, at any distance)."""
        pairs, points, point_boid = self.neighbor_pairs()
        if self.params.neighbor_mode != "topological":
            return pairs, points, point_boid, None
        pairs, forward, backward = topological_pairs(pairs, np.take(points, pairs.order, axis=1),
                                                     self.params.neighbor_k)
        return pairs, points, point_boid, (forward, backward)

    def _couzin_directions(self) -> np.ndarray:
        """The zonal model's desired directions (3, N) (``couzin.py``)."""
        pairs, _, point_boid, weights = self.interaction_pairs()
        desired, perceived = couzin_rules.social_directions(pairs, point_boid, self._heading, self.count,
                                                            self.params, weights)
        self.mean_neighbors = 2.0 * pairs.count / self.count
        self.mean_visible_neighbors = float(perceived.mean())
        return desired

    def _flocking_acceleration(self) -> np.ndarray:
        """w1 v1 + w2 v2 + w3 v3 for every boid, (3, N) float64."""
        p = self.params
        n = p.count
        pairs, points, point_boid, weights = self.interaction_pairs()
        slot_boid = np.take(point_boid, pairs.order)  # boid of each slot
        positions = np.take(points, pairs.order, axis=1)
        velocities = np.take(self._v, slot_boid, axis=1).astype(np.float32)
        headings = np.zeros((len(slot_boid), 4), dtype=np.float32)  # rows [hx, hy, hz, 0]
        for axis in range(3):
            headings[:, axis] = np.take(self._heading[axis], slot_boid)
        sums = neighbor_sums(pairs, positions, velocities, headings, p.separation_radius,
                             p.cos_half_fov if p.fov_deg < 360.0 else -1.0, counts=weights)
        per_slot = steering(sums, positions, velocities, p.cohesion_weight, p.separation_weight,
                            p.alignment_weight)
        acceleration = np.empty((3, n))
        if len(point_boid) == n:  # no ghosts: the slots are a permutation of the boids
            acceleration[:, pairs.order] = per_slot
            self.mean_neighbors = 2.0 * pairs.count / n
            self.mean_visible_neighbors = float(sums.count.mean())
        else:
            real = pairs.order < n
            acceleration[:, pairs.order[real]] = per_slot[:, real]
            ends_real = np.count_nonzero(pairs.order[pairs.i] < n) + np.count_nonzero(pairs.order[pairs.j] < n)
            self.mean_neighbors = ends_real / n
            self.mean_visible_neighbors = float(sums.count[real].mean())
        return acceleration

    def _wall_acceleration(self) -> np.ndarray:
        """Soft walls: per axis, an acceleration back into the box growing linearly from 0 at
        ``bounds_margin`` inside the wall to ``bounds_strength`` at the wall, (3, N)."""
        p = self.params
        a = np.zeros((3, p.count))
        if p.bounds_mode != "soft" or p.bounds_strength == 0.0:
            return a
        margin = max(p.bounds_margin, 1e-9)
        x = self._x
        gain = p.bounds_strength / margin
        below = (p.bounds_min + margin)[:, None] - x
        above = x - (p.bounds_max - margin)[:, None]
        np.maximum(below, 0.0, out=below)
        np.maximum(above, 0.0, out=above)
        a += below
        a -= above
        a *= gain
        return a

    def _avoidance_acceleration(self, near: ObstacleHits, boid_radius: float) -> np.ndarray:
        """Steer around bodies, (3, N): for each (boid, body) closer than ``obstacle_margin`` (surface to
        boid surface), ``max_acceleration · w · (n + approach · t)`` with ``w = ((margin − clearance) /
        margin)²`` (0 at the margin, 1 at contact), n the outward normal, and — for a boid flying into the
        body (``approach = −v̂·n > 0``) — t the unit sideways direction of its velocity along the surface, so it
        turns around the body instead of only braking (a boid aimed at the centre gets a fixed perpendicular)."""
        p = self.params
        a = np.zeros((3, p.count))
        clearance = near.distance - boid_radius
        active = clearance < p.obstacle_margin
        if not np.any(active):
            return a
        boid = near.point[active]
        normal = near.normal[:, active]
        weight = np.clip((p.obstacle_margin - clearance[active]) / p.obstacle_margin, 0.0, 1.0) ** 2
        heading = self._heading[:, boid]
        along = np.einsum("ij,ij->j", heading, normal)
        approach = np.maximum(-along, 0.0)
        sideways = heading - along * normal
        length = _norm(sideways)
        head_on = length < 1e-6
        if np.any(head_on):
            # any perpendicular of n will do; pick one deterministically (n × world z, or n × world x)
            n_h = normal[:, head_on]
            helper = np.zeros_like(n_h)
            use_x = np.abs(n_h[2]) > 0.9
            helper[2, ~use_x] = 1.0
            helper[0, use_x] = 1.0
            sideways[:, head_on] = np.cross(n_h.T, helper.T).T
            length[head_on] = _norm(sideways[:, head_on])
        sideways /= length
        push = (normal + approach * sideways) * (p.max_acceleration * weight)
        for axis in range(3):
            a[axis] = np.bincount(boid, weights=push[axis], minlength=p.count)
        return a

    def _limit_speed(self, fallback: np.ndarray | None = None) -> None:
        """Clamp |b_v| to [min_speed, max_speed]; a boid whose velocity vanished keeps its last heading."""
        p = self.params
        v = self._v
        speed = _norm(v)
        stopped = speed < 1e-9
        if np.any(stopped):
            v[:, stopped] = self._heading[:, stopped] * p.min_speed
            speed[stopped] = p.min_speed
        scale = np.clip(speed, p.min_speed, p.max_speed) / speed
        v *= scale

    def _clamp_to_box(self) -> None:
        """Soft-wall mode guarantee: a boid past a wall is put back on it and loses its outward velocity."""
        p = self.params
        x, v = self._x, self._v
        low = x < p.bounds_min[:, None]
        high = x > p.bounds_max[:, None]
        if np.any(low) or np.any(high):
            np.clip(x, p.bounds_min[:, None], p.bounds_max[:, None], out=x)
            v[low] = np.maximum(v[low], 0.0)
            v[high] = np.minimum(v[high], 0.0)

    def _project_out_of_bodies(self, obstacles: Obstacles, candidates: np.ndarray, boid_radius: float) -> None:
        """No-entry guarantee: a boid closer than ``boid_radius`` to a body (centre inside the inflated body)
        is moved along the outward normal to the inflated surface, and its inward velocity is removed."""
        x, v = self._x, self._v
        for _ in range(_PROJECTION_PASSES):
            hits = obstacles.query(x[:, candidates], boid_radius)
            if hits.count == 0:
                return
            boid = candidates[hits.point]
            depth = boid_radius - hits.distance + _SURFACE_CLEARANCE
            normal = hits.normal
            inward = np.minimum(np.einsum("ij,ij->j", v[:, boid], normal), 0.0)
            for axis in range(3):
                np.add.at(x[axis], boid, depth * normal[axis])
                np.add.at(v[axis], boid, -inward * normal[axis])
            candidates = np.unique(boid)

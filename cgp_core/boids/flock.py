"""A boid flock: state and one step (Reynolds' rules + what a real flock also needs).

One step of ``dt`` (all boids at once; the per-boid loops are compiled):

1. **neighbours** — every boid's neighbours within d (``neighbors.py``; minimum images in a periodic world),
   or its k nearest (``neighbor_mode: topological``, ``topological.py``: Ballerini et al. 2008);
2. **flocking** — cohesion, separation, alignment summed over each boid's neighbours (``rules.py``) and the
   optional goal: the acceleration the flock *wants*.  A ``rules: couzin`` flock decides a *direction*
   instead, from its zones of repulsion, orientation and attraction (``couzin.py``: Couzin et al. 2002);
3. **avoidance** — soft walls, the world's bodies (``obstacles.py``) and the predators among them
   (``predators.py``): the acceleration the boid *needs*.  It has priority: the flocking part gets only what is
   left of ``max_acceleration`` (Reynolds' prioritized acceleration allocation), so a flock cannot push its
   members into a wall or a body; a Couzin flock lets it take over the desired direction in proportion;
4. **integrate** — semi-implicit Euler: ``b_v += a dt``, speed clamped to [min_speed, max_speed],
   ``b += b_v dt`` (Slide erratum: the slide's ``b = b + b_v`` has no dt, see ``rules.py``).  A Couzin flock
   adds its noise, turns by at most θ·dt towards its direction and moves at its constant speed s;
5. **constraints** — soft walls: a boid that still reaches the box is put back on it and loses its
   outward velocity (so boids never leave the box); wrap: positions are taken modulo the box; bodies: a boid
   inside a body inflated by ``boid_size / 2`` is projected back to its surface and loses its inward
   velocity (so boids never enter a body, even when avoidance was not enough);
6. **frames** — heading and banked dorsal axis, then quaternions (``frames.py``).

State is ``(N, 3)`` row-major (``(N, 4)`` for the quaternions): one boid's numbers side by side, which is what
the compiled per-boid loops read.  What runs where: the neighbour search, the rules, the obstacle query, the
flight from predators, stages 3-5 for every boid (:func:`_move` for Reynolds' rules, :func:`_turn` for
Couzin's: walls, allocation or turn, integration, box) and the frames are numba kernels, parallel over the
boids (both cores, the GIL released; one core for flocks under 2,000 boids, see ``cgp_core/jit.py``); numpy
handles what concerns few boids: the avoidance pushes from the obstacle hits, the no-entry projection of the
boids that ended up inside a body, the goal, a Couzin flock's noise (drawn from the flock's own generator,
seeded by its ``seed``: a Couzin flock is a deterministic function of its seed too).

The order parameters (:meth:`Flock.order`, ``order.py``) reuse the last step's neighbour list for the
nearest-neighbour distances.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit import njit, prange, threads_for
from . import couzin
from .frames import initial_dorsal, low_pass_weight, quaternions_rows, unit_headings, update_frames_rows
from .neighbors import BoidArrays, NeighborList, make_search
from .obstacles import ObstacleHits, Obstacles
from .order import FlockOrder, flock_order, nearest_neighbor_distances
from .params import FlockParams
from .predators import Predators, flee
from .rules import neighbor_sums, steering
from .topological import k_nearest

_PROJECTION_PASSES = 4  # a boid pushed out of one body into an overlapping one gets a few more passes
_SURFACE_CLEARANCE = 1e-9  # projected boids land this far outside the inflated surface (no re-entry by rounding)


def _column_sums(a: np.ndarray) -> np.ndarray:
    """Σ over the rows of an (N, 3) array, (3,): one column at a time.  ``a.sum(axis=0)`` on row-major (N, 3)
    takes ~15 times longer (numpy walks it row by row, three numbers per step: 175 µs at 15k boids, every
    tick)."""
    return np.array([a[:, 0].sum(), a[:, 1].sum(), a[:, 2].sum()])


def _norm(a: np.ndarray) -> np.ndarray:
    """Row norms of an (N, 3) array."""
    return np.sqrt(a[:, 0] * a[:, 0] + a[:, 1] * a[:, 1] + a[:, 2] * a[:, 2])


@njit
def _scaled_to(x: float, y: float, z: float, limit: float):
    """(x, y, z) shortened to length ``limit`` if it is longer."""
    length = math.sqrt(x * x + y * y + z * z)
    if length > limit:
        scale = limit / length
        return x * scale, y * scale, z * scale
    return x, y, z


#: bounds modes as the compiled stages take them
_OPEN, _SOFT, _WRAP = 0, 1, 2


class Walls(NamedTuple):
    """The flock's box as the per-boid kernels take it."""

    mode: int           # _OPEN, _SOFT or _WRAP
    low: np.ndarray     # (3,) lower corner [m]
    high: np.ndarray    # (3,) upper corner [m]
    margin: float       # soft walls push within this distance of a wall [m]
    gain: float         # the push per metre inside the margin [1/s²]


class Speeds(NamedTuple):
    """Reynolds' limits on a boid's motion."""

    max_acceleration: float  # [m/s²]
    min_speed: float         # [m/s]
    max_speed: float         # [m/s]


class Turning(NamedTuple):
    """Couzin's motion: constant speed, limited turn, and what avoidance may take over."""

    max_acceleration: float  # the avoidance strength that takes over the desired direction completely [m/s²]
    speed: float             # s [m/s]
    max_turn: float          # θ·dt, the largest turn in a step [rad]


@njit
def _wall_push(x: float, low: float, high: float, margin: float) -> float:
    """Soft wall along one axis, in units of the wall gain: 0 deeper inside than ``margin``, growing linearly
    to ``margin`` at the wall (positive = back into the box)."""
    return max(low + margin - x, 0.0) - max(x - (high - margin), 0.0)


@njit
def _needed(x, i, avoidance, max_acceleration, walls):
    """What boid i needs: avoidance (bodies, predators) + soft :class:`Walls`, capped at max_acceleration."""
    bounds_min, bounds_max, wall_margin, wall_gain = walls.low, walls.high, walls.margin, walls.gain
    nx, ny, nz = avoidance[i, 0], avoidance[i, 1], avoidance[i, 2]
    if walls.mode == _SOFT and wall_gain > 0.0:
        nx += wall_gain * _wall_push(x[i, 0], bounds_min[0], bounds_max[0], wall_margin)
        ny += wall_gain * _wall_push(x[i, 1], bounds_min[1], bounds_max[1], wall_margin)
        nz += wall_gain * _wall_push(x[i, 2], bounds_min[2], bounds_max[2], wall_margin)
    return _scaled_to(nx, ny, nz, max_acceleration)


@njit
def _advance(x, v, i, dt, walls):
    """``b += b_v dt`` for boid i, then the box: soft :class:`Walls` put a boid that still reached a wall back on
    it without its outward velocity, a periodic box wraps it."""
    bounds_mode, bounds_min, bounds_max = walls.mode, walls.low, walls.high
    for a in range(3):
        x[i, a] += v[i, a] * dt
        if bounds_mode == _SOFT:
            if x[i, a] < bounds_min[a]:
                x[i, a] = bounds_min[a]
                v[i, a] = max(v[i, a], 0.0)
            elif x[i, a] > bounds_max[a]:
                x[i, a] = bounds_max[a]
                v[i, a] = min(v[i, a], 0.0)
        elif bounds_mode == _WRAP:
            size = bounds_max[a] - bounds_min[a]
            wrapped = (x[i, a] - bounds_min[a]) % size
            if wrapped >= size:  # rounding can give the size itself for a tiny negative offset: that is 0
                wrapped = 0.0
            x[i, a] = bounds_min[a] + wrapped


@njit(parallel=True)
def _move(boids, wanted, avoidance, speeds, dt, walls):
    """Stages 3-5 of the step for Reynolds' rules, per boid of ``boids`` (:class:`BoidArrays`, updated in place;
    see the module docstring): what the boid needs (soft :class:`Walls` + ``avoidance``) and what the flock
    wants (``wanted``) by prioritized allocation; ``b_v += a dt``, the speed clamp (:class:`Speeds`),
    ``b += b_v dt`` and the box."""
    x, v, heading = boids
    max_acceleration, min_speed, max_speed = speeds
    for i in prange(x.shape[0]):
        nx, ny, nz = _needed(x, i, avoidance, max_acceleration, walls)
        # the flock's wish gets what is left of max_acceleration
        left = max(max_acceleration - math.sqrt(nx * nx + ny * ny + nz * nz), 0.0)
        wx, wy, wz = _scaled_to(wanted[i, 0], wanted[i, 1], wanted[i, 2], left)
        vx = v[i, 0] + (nx + wx) * dt
        vy = v[i, 1] + (ny + wy) * dt
        vz = v[i, 2] + (nz + wz) * dt
        # min_speed <= |b_v| <= max_speed; a boid whose velocity vanished keeps its last heading
        speed = math.sqrt(vx * vx + vy * vy + vz * vz)
        if speed < 1e-9:
            vx, vy, vz = heading[i, 0] * min_speed, heading[i, 1] * min_speed, heading[i, 2] * min_speed
            speed = min_speed
        scale = min(max(speed, min_speed), max_speed) / speed
        v[i, 0], v[i, 1], v[i, 2] = vx * scale, vy * scale, vz * scale
        _advance(x, v, i, dt, walls)


@njit(parallel=True)
def _turn(boids, desired, avoidance, noise, turning, dt, walls):
    """Stages 3-5 of the step for Couzin's rules, per boid of ``boids`` (:class:`BoidArrays`, updated in place;
    ``couzin.py``): what the boid needs (soft :class:`Walls` + ``avoidance``) takes over the desired direction
    in proportion to its strength, the noise (``noise``: angle, azimuth (N,) each) rotates it, the heading turns
    towards it by at most θ·dt (:class:`Turning`), ``b_v = s v̂``, ``b += b_v dt`` and the box.  The new heading
    goes into ``v`` only: the frames (``frames.py``) turn ``heading`` after it, seeing the turn."""
    x, v, heading = boids
    noise_angle, noise_azimuth = noise
    max_acceleration, speed, max_turn = turning
    cos_max, sin_max = math.cos(max_turn), math.sin(max_turn)
    for i in prange(x.shape[0]):
        nx, ny, nz = _needed(x, i, avoidance, max_acceleration, walls)
        dx, dy, dz = couzin.blend_avoidance(desired[i, 0], desired[i, 1], desired[i, 2], nx, ny, nz,
                                            max_acceleration)
        dx, dy, dz = couzin.with_noise(dx, dy, dz, noise_angle[i], noise_azimuth[i])
        hx, hy, hz = couzin.turn_towards(heading[i, 0], heading[i, 1], heading[i, 2], dx, dy, dz, cos_max, sin_max)
        v[i, 0], v[i, 1], v[i, 2] = speed * hx, speed * hy, speed * hz
        _advance(x, v, i, dt, walls)


class Flock:
    """N boids of one :class:`FlockParams`.

    Attributes (public, shapes):
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
    The arrays are the flock's state itself (writable; a step updates them in place).
    """

    def __init__(self, params: FlockParams):
        if not isinstance(params, FlockParams):
            raise TypeError(f"Flock needs FlockParams, got {type(params).__name__}")
        self.params = params
        self._search = make_search(params.neighbor_search)
        n = params.count
        self._x = np.empty((n, 3))
        self._v = np.empty((n, 3))
        self._heading = np.empty((n, 3))
        self._dorsal = np.empty((n, 3))
        self._q = np.empty((n, 4))
        p = params
        #: (3,) box sizes of a periodic box, zeros in open space (what the neighbour search and rules take)
        self.period = (p.bounds_max - p.bounds_min) if p.bounds_mode == "wrap" else np.zeros(3)
        self._no_avoidance = np.zeros((n, 3))  # what a step without bodies avoids
        #: the last metric neighbour list, the positions (N, 3) and the radius it was built with, and how far an
        #: ordinary step has moved a boid since (max_speed · dt after a step; see :meth:`order`)
        self._searched: tuple[NeighborList, np.ndarray, float] | None = None
        self._moved_since_search = 0.0
        self.reset()

    # ---- state -----------------------------------------------------------------------------------------

    def reset(self) -> None:
        """Back to the seeded initial state: positions uniform in the spawn box, directions uniform on the
        sphere, speeds uniform in [min_speed, max_speed], level frames."""
        p = self.params
        n = p.count
        rng = np.random.default_rng(p.seed)
        # drawn component-major (as this flock always has: the seeds keep their flocks)
        self._x[:] = (p.spawn_center[:, None] + (rng.random((3, n)) - 0.5) * p.spawn_extent[:, None]).T
        direction = rng.normal(size=(3, n))
        direction /= np.maximum(np.sqrt((direction * direction).sum(axis=0)), 1e-12)
        self._v[:] = (direction * rng.uniform(p.min_speed, p.max_speed, n)).T
        self._heading[:] = unit_headings(self._v.T).T
        self._dorsal[:] = initial_dorsal(self._heading.T).T
        with threads_for(n):
            quaternions_rows(self._heading, self._dorsal, self._q)
        self._search.reset()
        self._searched = None
        # a Couzin flock's noise: its own stream (the initial state above is the same for both rule sets)
        self._noise = np.random.default_rng((p.seed, couzin.NOISE_STREAM))
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
    def noise_generator(self) -> np.random.Generator:
        """The random stream of Couzin's angular noise: part of the flock's dynamic state, so a run continued
        from another (a sweep's chain) sets it too, and the stream goes on as if the flock had never stopped."""
        return self._noise

    @noise_generator.setter
    def noise_generator(self, generator: np.random.Generator) -> None:
        self._noise = generator

    @property
    def positions(self) -> np.ndarray:
        return self._x

    @property
    def velocities(self) -> np.ndarray:
        return self._v

    @property
    def orientations(self) -> np.ndarray:
        return self._q

    @property
    def headings(self) -> np.ndarray:
        return self._heading

    @property
    def dorsals(self) -> np.ndarray:
        return self._dorsal

    def polarization(self) -> float:
        """Vicsek order parameter |Σ v̂_i| / N in [0, 1] (1: all boids fly the same way)."""
        total = _column_sums(self._heading)
        return float(math.sqrt(float(total @ total)) / self.count)

    def centroid(self) -> np.ndarray:
        """Σ b / N, (3,) [m]."""
        return _column_sums(self._x) / self.count

    def mean_velocity(self) -> np.ndarray:
        """Σ b_v / N, (3,) [m/s] (the world reports its change over a tick as the flock's acceleration)."""
        return _column_sums(self._v) / self.count

    def neighbors(self) -> NeighborList:
        """Every boid's neighbours within d at the current positions (the flock's search backend; valid until
        the next call)."""
        neighbors = self._search.neighbors(self._x, self.params.radius, self.period)
        self._searched = (neighbors, self._x.copy(), self.params.radius)
        self._moved_since_search = 0.0
        return neighbors

    def interaction_neighbors(self) -> NeighborList:
        """Whom each boid interacts with at the current positions: its neighbours within d (``neighbor_mode``
        metric) or its ``neighbor_k`` nearest (topological, ``topological.py``), in one layout."""
        neighbors = self.neighbors()
        if self.params.neighbor_mode == "topological":
            return k_nearest(neighbors, self._x, self.params.neighbor_k)
        return neighbors

    def order(self) -> FlockOrder:
        """The flock's order parameters now (``order.py``): polarization, milling, centroid, radius of gyration,
        mean nearest-neighbour distance (from the last step's neighbour lists where they decide it), speeds."""
        with threads_for(self.count):
            if self._searched is None:
                nearest = nearest_neighbor_distances(self._x, self.period)
            else:
                nearest = nearest_neighbor_distances(self._x, self.period, *self._searched, self._moved_since_search)
            return flock_order(self._x, self._v, nearest)

    # ---- step ------------------------------------------------------------------------------------------

    def step(self, dt: float, obstacles: Obstacles | None = None, predators: Predators | None = None) -> None:
        """Advance by ``dt`` seconds, avoiding ``obstacles`` (the world's bodies at this tick) and fleeing
        ``predators`` (``predators.py``) if given."""
        if not (isinstance(dt, (int, float, np.floating)) and math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"flock {self.name!r}: dt must be a finite number > 0, got {dt!r}")
        with threads_for(self.count):  # both cores for big flocks, one for small ones (jit.py)
            self._step(float(dt), obstacles, predators)

    def _step(self, dt: float, obstacles: Obstacles | None, predators: Predators | None) -> None:
        p = self.params
        x, v = self._x, self._v
        boid_radius = 0.5 * p.boid_size
        use_obstacles = obstacles is not None and obstacles.shape_count > 0
        couzin_rules = p.rules == "couzin"

        if couzin_rules:  # a direction to turn towards (couzin.py), not an acceleration
            desired = self.desired_directions()
        else:
            wanted = self.flocking_acceleration()
            if p.goal is not None and p.goal_weight > 0.0:
                to_goal = p.goal - x
                wanted += to_goal * (p.goal_weight / np.maximum(_norm(to_goal), 1e-9))[:, None]

        avoidance = self._no_avoidance
        near: ObstacleHits | None = None
        if use_obstacles:
            # one query serves steering now and the no-entry projection after the move: a boid moves at most
            # max_speed·dt, so any body it can end up inside is within this reach now
            reach = boid_radius + (p.obstacle_margin if p.avoid_bodies else 0.0) + p.max_speed * dt + 1e-6
            near = obstacles.query(x.T, reach)
            if p.avoid_bodies and p.obstacle_margin > 0.0:
                avoidance = self._avoidance_acceleration(near, boid_radius)
        if predators is not None and predators.count and p.fright_radius > 0.0:
            # fleeing is avoidance: it has priority over the flocking rules
            avoidance = avoidance.copy() if avoidance is self._no_avoidance else avoidance
            flee(x, predators, p.fright_radius, p.max_acceleration, avoidance)

        # walls + avoidance, allocation or turn, integration, the box: per boid, compiled
        margin = max(p.bounds_margin, 1e-9)
        walls = Walls({"none": _OPEN, "soft": _SOFT, "wrap": _WRAP}[p.bounds_mode], p.bounds_min, p.bounds_max,
                      margin, p.bounds_strength / margin)
        boids = BoidArrays(x, v, self._heading)
        if couzin_rules:
            noise = couzin.noise_angles(self._noise, p.count, p.couzin.noise, dt)
            turning = Turning(p.max_acceleration, p.couzin.speed, math.radians(p.couzin.turning_rate_deg) * dt)
            _turn(boids, desired, avoidance, noise, turning, float(dt), walls)
        else:
            _move(boids, wanted, avoidance, Speeds(p.max_acceleration, p.min_speed, p.max_speed), float(dt), walls)

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

        # how far the step moved a boid that was only integrated (|b_v| <= max_speed); the order parameters reuse
        # this step's neighbour list with it (order.py)
        self._moved_since_search = p.max_speed * dt * (1.0 + 1e-9)
        update_frames_rows(self._heading, self._dorsal, v, float(dt), p.bank_gain,
                           low_pass_weight(dt, p.orientation_time_constant))
        quaternions_rows(self._heading, self._dorsal, self._q)
        self.time += dt
        self.steps += 1

    # ---- stages ----------------------------------------------------------------------------------------

    def flocking_acceleration(self) -> np.ndarray:
        """w1 v1 + w2 v2 + w3 v3 for every boid at the current state, (N, 3) (stage 2 without the goal)."""
        p = self.params
        neighbors = self.interaction_neighbors()
        sums = neighbor_sums(neighbors, self._x, self._v, self._heading, p.separation_radius,
                             p.cos_half_fov if p.fov_deg < 360.0 else -1.0, self.period)
        self.mean_neighbors = neighbors.total / p.count
        self.mean_visible_neighbors = float(sums.count.mean())
        return steering(sums, self._v, p.cohesion_weight, p.separation_weight, p.alignment_weight)

    def desired_directions(self) -> np.ndarray:
        """Couzin's zonal decision for every boid at the current state, (N, 3) unit (``couzin.py``; stage 2 of a
        ``rules: couzin`` flock)."""
        neighbors = self.interaction_neighbors()
        desired, perceived = couzin.desired_directions(neighbors, self._x, self._heading, self.params, self.period)
        self.mean_neighbors = neighbors.total / self.count
        self.mean_visible_neighbors = float(perceived.mean())
        return desired

    def _avoidance_acceleration(self, near: ObstacleHits, boid_radius: float) -> np.ndarray:
        """Steer around bodies, (N, 3): for each (boid, body) closer than ``obstacle_margin`` (surface to
        boid surface), ``max_acceleration · w · (n + approach · t)`` with ``w = ((margin − clearance) /
        margin)²`` (0 at the margin, 1 at contact), n the outward normal, and — for a boid flying into the
        body (``approach = −v̂·n > 0``) — t the unit sideways direction of its velocity along the surface, so it
        turns around the body instead of only braking (a boid aimed at the centre gets a fixed perpendicular)."""
        p = self.params
        a = np.zeros((p.count, 3))
        clearance = near.distance - boid_radius
        active = clearance < p.obstacle_margin
        if not np.any(active):
            return a
        boid = near.point[active]
        normal = near.normal[:, active]
        weight = np.clip((p.obstacle_margin - clearance[active]) / p.obstacle_margin, 0.0, 1.0) ** 2
        heading = self._heading[boid].T
        along = np.einsum("ij,ij->j", heading, normal)
        approach = np.maximum(-along, 0.0)
        sideways = heading - along * normal
        length = np.sqrt((sideways * sideways).sum(axis=0))
        head_on = length < 1e-6
        if np.any(head_on):
            # any perpendicular of n will do; pick one deterministically (n × world z, or n × world x)
            n_h = normal[:, head_on]
            helper = np.zeros_like(n_h)
            use_x = np.abs(n_h[2]) > 0.9
            helper[2, ~use_x] = 1.0
            helper[0, use_x] = 1.0
            sideways[:, head_on] = np.cross(n_h.T, helper.T).T
            length[head_on] = np.sqrt((sideways[:, head_on] ** 2).sum(axis=0))
        sideways /= length
        push = (normal + approach * sideways) * (p.max_acceleration * weight)
        for axis in range(3):
            a[:, axis] = np.bincount(boid, weights=push[axis], minlength=p.count)
        return a

    def _project_out_of_bodies(self, obstacles: Obstacles, candidates: np.ndarray, boid_radius: float) -> None:
        """No-entry guarantee: a boid closer than ``boid_radius`` to a body (centre inside the inflated body)
        is moved along the outward normal to the inflated surface, and its inward velocity is removed."""
        x, v = self._x, self._v
        for _ in range(_PROJECTION_PASSES):
            hits = obstacles.query(x[candidates].T, boid_radius)
            if hits.count == 0:
                return
            boid = candidates[hits.point]
            depth = boid_radius - hits.distance + _SURFACE_CLEARANCE
            normal = hits.normal
            inward = np.minimum(np.einsum("ij,ij->j", v[boid].T, normal), 0.0)
            for axis in range(3):
                np.add.at(x[:, axis], boid, depth * normal[axis])
                np.add.at(v[:, axis], boid, -inward * normal[axis])
            candidates = np.unique(boid)

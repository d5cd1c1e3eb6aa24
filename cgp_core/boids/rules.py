"""Reynolds' three rules (the lecture's "Flocking" slides), one home each.

Notation as on the slides: ``b`` a boid's position, ``b_v`` its velocity, ``x_i`` / ``x_{v_i}`` the positions /
velocities of its n neighbours (``|b − x_i| < d``, inside its field of view).  Arrays are ``(N, 3)``, one row
per boid.

- cohesion    v1 = (Σ x_i) / n − b  = (Σ (x_i − b)) / n     (towards the neighbours' centroid)       [m]
- separation  v2 = Σ_{|b − x_i| < s} (b − x_i) · (s − |b − x_i|) / |b − x_i|                       [m]
- alignment   v3 = (Σ x_{v_i}) / n − b_v                     (towards the neighbours' mean velocity)  [m/s]

and the steering acceleration a = w1 v1 + w2 v2 + w3 v3 (:func:`steering`), which ``flock.py`` integrates as
``b_v += a · dt``, ``b += b_v · dt``.

How it is computed: :func:`neighbor_sums` loops, for every boid, over its neighbour list (``neighbors.py``) —
one compiled loop per boid that reads like the slide, run in parallel over the boids — and collects what the
rules need: n, Σ (x_i − b), Σ x_{v_i}, the separation sum v2 and whether anyone is crowding the boid.  The
rules are then formulas over those sums.  The centroid is taken as the mean *offset* Σ (x_i − b) / n, which
is the slide's (Σ x_i) / n − b without the cancellation of large absolute coordinates, and which is what a
periodic box needs (offsets are minimum images).  Another rule set (Couzin's zones, topological neighbours)
is another loop over the same neighbour lists.

Slide erratum (separation sign): the slide's pseudocode says ``v2 = v2 − (b − x_i)``, which points *towards*
the close neighbour and pulls boids together (it comes from the popular boids pseudocode where ``b`` is the
*other* boid).  Separation must push away: ``v2 += (b − x_i)``.

Departure from the slide (separation weight): the slide sums the raw offsets, whose length is the distance,
so a neighbour pushes *least* when it is closest and hardest just before it leaves the separation radius,
where the push drops to zero at once.  Each term is scaled by ``(s − r) / r`` (r = |b − x_i|): the push
is a spring of rest length s, largest at contact and vanishing continuously at s.

Departure from the slide (separation has priority over cohesion): a boid with a neighbour closer than
``COHESION_GATE · s`` does not also pull towards the group's centroid (Couzin et al. 2002: an individual with
someone in its zone of repulsion responds to repulsion only; Reynolds 1987 likewise gives collision avoidance
priority).  Without it, cohesion presses the whole flock together until every boid sits inside its
neighbours' separation radius (the flock is "jammed", pressure from its rim balanced by separation springs);
with it, boids settle just outside each other's separation radius.  The 5 % margin keeps them from chattering
on its edge.

Field of view: boid i sees neighbour j when the angle between i's heading ĥ and ``r = x_j − b`` is at most
fov/2, ``ĥ · r > cos(fov/2) |r|``.  Cohesion and alignment use only what a boid sees; separation is felt all
around (a fish's lateral line; boids do not ram each other from behind).

Slide erratum (no dt): the slide updates ``b_v = b_v + w1 v1 + …`` and ``b = b + b_v`` once per frame, which
makes the motion depend on the frame rate.  The weights here are rates (w1, w2 in 1/s², w3 in 1/s), and the
velocity and position updates are multiplied by dt (semi-implicit Euler, in ``flock.py``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit import njit, prange, threads_for
from .neighbors import BoidArrays, NeighborList, pair_offset, squared_length

COHESION_GATE = 1.05  # cohesion is suspended while a neighbour is closer than this many separation radii


class NeighborSums(NamedTuple):
    """Per-boid sums over neighbours (N boids)."""

    count: np.ndarray         # (N,) float64 — n, the number of visible neighbours (inside d and the field of view)
    offset_sum: np.ndarray    # (N, 3) — Σ (x_i − b) over visible neighbours
    velocity_sum: np.ndarray  # (N, 3) — Σ x_{v_i} over visible neighbours
    separation: np.ndarray    # (N, 3) — v2 (over all neighbours closer than s, whatever the field of view)
    crowded: np.ndarray       # (N,) bool — a neighbour is closer than ``COHESION_GATE · s`` (cohesion suspended)


@njit
def sees(heading: np.ndarray, i: int, dx: float, dy: float, dz: float, r2: float, cos_half_fov: float) -> bool:
    """Does boid i (unit heading ``heading[i]``) see a neighbour at offset d, |d|² = r2?  ĥ·d > cos(fov/2) |d|;
    a field of view of 360° (``cos_half_fov <= −1``) sees everything.  Compared without a square root per
    neighbour: with a = ĥ·d and c = cos(fov/2), a > c |d| ⇔ (a > 0 and a² > c² |d|²) for c >= 0, and
    ⇔ (a > 0 or a² < c² |d|²) for c < 0.  A coincident neighbour (d = 0) is not seen."""
    if cos_half_fov <= -1.0:
        return True
    along = (heading[i, 0] * dx + heading[i, 1] * dy) + heading[i, 2] * dz
    limit2 = cos_half_fov * cos_half_fov * r2  # (c |d|)²
    # bitwise & and | (no short cut): the processor need not guess a branch per neighbour
    if cos_half_fov >= 0.0:  # a field of view up to 180°: a must be positive and a² > (c |d|)²
        return (along > 0.0) & (along * along > limit2)
    return (along > 0.0) | (along * along < limit2)  # wider than 180°


@njit(parallel=True)
def _neighbor_sums(neighbors, boids, period, separation_radius, cos_half_fov, out):
    """The loop over every boid's neighbours (a :class:`NeighborList`).  ``boids`` (:class:`BoidArrays`) in the
    list's slot order, so that a boid's neighbours are read from nearby memory; each result is written to its
    boid's row (``order[i]``) of ``out`` (:class:`NeighborSums`)."""
    start, count, index, order = neighbors.start, neighbors.count, neighbors.index, neighbors.order
    positions, velocities, headings = boids
    out_count, out_offset, out_velocity, out_separation, out_crowded = out
    s = separation_radius
    s2 = s * s
    gate2 = (COHESION_GATE * s) ** 2
    for i in prange(positions.shape[0]):
        n = 0.0
        ox = oy = oz = 0.0  # Σ (x_j − b), visible neighbours
        vx = vy = vz = 0.0  # Σ v_j, visible neighbours
        sx = sy = sz = 0.0  # v2
        crowded = False
        for e in range(start[i], start[i] + count[i]):
            j = index[e]
            dx, dy, dz = pair_offset(positions, i, j, period)  # x_j − b
            r2 = squared_length(dx, dy, dz)
            if r2 < gate2:
                crowded = True
                if r2 < s2 and r2 > 0.0:
                    # separation: (b − x_j) (s − r) / r.  Coincident boids (r = 0) have no direction to push
                    # along: they get none here and are separated as soon as their velocities differ
                    r = math.sqrt(r2)
                    w = (s - r) / r
                    sx -= dx * w
                    sy -= dy * w
                    sz -= dz * w
            # cohesion and alignment: what the boid sees (weight 1) — multiplied in rather than branched on,
            # which runs ~1.5 times faster than an `if` the processor mispredicts for the neighbours behind
            w = 1.0 if sees(headings, i, dx, dy, dz, r2, cos_half_fov) else 0.0
            n += w
            ox += w * dx
            oy += w * dy
            oz += w * dz
            vx += w * velocities[j, 0]
            vy += w * velocities[j, 1]
            vz += w * velocities[j, 2]
        b = order[i]
        out_count[b] = n
        out_offset[b, 0], out_offset[b, 1], out_offset[b, 2] = ox, oy, oz
        out_velocity[b, 0], out_velocity[b, 1], out_velocity[b, 2] = vx, vy, vz
        out_separation[b, 0], out_separation[b, 1], out_separation[b, 2] = sx, sy, sz
        out_crowded[b] = crowded


def neighbor_sums(neighbors: NeighborList, positions: np.ndarray, velocities: np.ndarray, headings: np.ndarray,
                  separation_radius: float, cos_half_fov: float, period: np.ndarray | None = None) -> NeighborSums:
    """Sum what the rules need over every boid's neighbours.

    Args:
        neighbors:   each boid's neighbours within d (any backend of ``neighbors.py``).
        positions:   (N, 3) float64.
        velocities:  (N, 3) float64.
        headings:    (N, 3) float64 unit velocity directions (the field of view is centred on them).
        separation_radius: s [m].
        cos_half_fov: cos(fov / 2); <= −1 means no blind angle.
        period:      (3,) box sizes of a periodic box (0 = open axis); None = open space.
    """
    n = len(positions)
    sums = NeighborSums(count=np.empty(n), offset_sum=np.empty((n, 3)), velocity_sum=np.empty((n, 3)),
                        separation=np.empty((n, 3)), crowded=np.empty(n, dtype=np.bool_))
    slots = BoidArrays(neighbors.sorted(positions), neighbors.sorted(velocities), neighbors.sorted(headings))
    _neighbor_sums(neighbors, slots, np.zeros(3) if period is None else period, float(separation_radius),
                   float(cos_half_fov), sums)
    return sums


@njit
def cohesion_of(count: float, offset_sum: np.ndarray, crowded: bool, gated: bool):
    """v1 of one boid = centroid of the visible neighbours − b = their mean offset; zero with no neighbour
    and, if ``gated``, for a crowded boid (separation has priority, see the module docstring)."""
    if count > 0.0 and not (gated and crowded):
        return offset_sum[0] / count, offset_sum[1] / count, offset_sum[2] / count
    return 0.0, 0.0, 0.0


@njit
def alignment_of(count: float, velocity_sum: np.ndarray, velocity: np.ndarray):
    """v3 of one boid = mean velocity of the visible neighbours − b_v; zero with no neighbour."""
    if count > 0.0:
        return (velocity_sum[0] / count - velocity[0], velocity_sum[1] / count - velocity[1],
                velocity_sum[2] / count - velocity[2])
    return 0.0, 0.0, 0.0


@njit(parallel=True)
def _rule_rows(rule, sums, velocities, gated, weights, out):
    """Per boid, from its :class:`NeighborSums`: v1 (``rule`` 1), v3 (3), or the weighted sum
    w1 v1 + w2 v2 + w3 v3 (0) with ``weights`` (w1, w2, w3)."""
    count, offset_sum, velocity_sum, separation_sum, crowded = sums
    w1, w2, w3 = weights
    for i in prange(count.shape[0]):
        c1, c2, c3 = cohesion_of(count[i], offset_sum[i], crowded[i], gated)
        a1, a2, a3 = alignment_of(count[i], velocity_sum[i], velocities[i])
        if rule == 1:
            out[i, 0], out[i, 1], out[i, 2] = c1, c2, c3
        elif rule == 3:
            out[i, 0], out[i, 1], out[i, 2] = a1, a2, a3
        else:
            out[i, 0] = (w1 * c1 + w2 * separation_sum[i, 0]) + w3 * a1
            out[i, 1] = (w1 * c2 + w2 * separation_sum[i, 1]) + w3 * a2
            out[i, 2] = (w1 * c3 + w2 * separation_sum[i, 2]) + w3 * a3


def _rows(rule: int, sums: NeighborSums, velocities: np.ndarray, gated: bool, weights=(0.0, 0.0, 0.0)):
    out = np.empty_like(sums.offset_sum)
    with threads_for(len(out)):
        _rule_rows(rule, sums, velocities, gated, tuple(map(float, weights)), out)
    return out


def cohesion(sums: NeighborSums, gated: bool = True) -> np.ndarray:
    """v1 (N, 3) of every boid (:func:`cohesion_of`)."""
    return _rows(1, sums, sums.offset_sum, gated)


def separation(sums: NeighborSums) -> np.ndarray:
    """v2 (N, 3) = Σ_{r < s} (b − x_i) (s − r) / r, summed per neighbour in :func:`neighbor_sums`."""
    return sums.separation


def alignment(sums: NeighborSums, velocities: np.ndarray) -> np.ndarray:
    """v3 (N, 3) of every boid (:func:`alignment_of`)."""
    return _rows(3, sums, velocities, False)


def steering(sums: NeighborSums, velocities: np.ndarray, cohesion_weight: float, separation_weight: float,
             alignment_weight: float) -> np.ndarray:
    """The slides' weighted sum a = w1 v1 + w2 v2 + w3 v3, (N, 3) [m/s²] (an acceleration: see dt erratum),
    per boid in one compiled loop.  The cohesion gate applies only when there is a separation rule to give
    priority to (w2 > 0)."""
    return _rows(0, sums, velocities, separation_weight > 0.0,
                 (cohesion_weight, separation_weight, alignment_weight))

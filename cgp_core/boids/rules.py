"""Reynolds' three rules (the lecture's "Flocking" slides), one home each, vectorized over all boids.

Notation as on the slides: ``b`` a boid's position, ``b_v`` its velocity, ``x_i`` / ``x_{v_i}`` the positions /
velocities of its n neighbours (``|b − x_i| < d``, inside its field of view).  All arrays are component-major
``(3, W)`` (one contiguous row per axis) over the W work slots of a step (see ``flock.py``).

- cohesion    v1 = (Σ x_i) / n − b                      (towards the neighbours' centroid)       [m]
- separation  v2 = Σ_{|b − x_i| < s} (b − x_i) · (s − |b − x_i|) / |b − x_i|                       [m]
- alignment   v3 = (Σ x_{v_i}) / n − b_v                (towards the neighbours' mean velocity)  [m/s]

and the steering acceleration a = w1 v1 + w2 v2 + w3 v3 (``steering``), which ``flock.py`` integrates as
``b_v += a · dt``, ``b += b_v · dt``.

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

Slide erratum (no dt): the slide updates ``b_v = b_v + w1 v1 + …`` and ``b = b + b_v`` once per frame, which
makes the motion depend on the frame rate.  The weights here are rates (w1, w2 in 1/s², w3 in 1/s), and the
velocity and position updates are multiplied by dt (semi-implicit Euler, in ``flock.py``).

The sums over neighbours are computed from the neighbour pairs once per pair (i < j), scattered to both
ends: as two sparse matrix products (CSR rows = i; the transposed product scatters to j), which fuse the
gather and the segment sum in compiled code.  The field of view makes "i sees j" and "j sees i" differ, so
the two products carry different weights.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse

from .neighbors import NeighborPairs

COHESION_GATE = 1.05  # cohesion is suspended while a neighbour is closer than this many separation radii
_PAIR_BLOCK = 24_000  # pairs per block in the per-pair loops (cache-sized temporaries)


@dataclass
class NeighborSums:
    """Per-slot sums over neighbours (W slots), float32.

    Attributes (shapes):
        count:          (W,) — n, the number of visible neighbours (inside d and the field of view).
        position_sum:   (3, W) — Σ x_i over visible neighbours (work coordinates).
        velocity_sum:   (3, W) — Σ x_{v_i} over visible neighbours.
        separation:     (3, W) — v2 (over all neighbours closer than s, whatever the field of view).
        crowded:        (W,) bool — a neighbour is closer than ``COHESION_GATE · s`` (cohesion suspended).
    """

    count: np.ndarray
    position_sum: np.ndarray
    velocity_sum: np.ndarray
    separation: np.ndarray
    crowded: np.ndarray


def visibility(pairs: NeighborPairs, headings: np.ndarray, cos_half_fov: float) -> tuple[np.ndarray, np.ndarray]:
    """Field of view: does i see j, does j see i?  ``headings (W, 4)`` float32 rows ``[hx, hy, hz, 0]`` of unit
    headings, slots as in ``pairs``.

    i sees j when the angle between i's heading and ``r = x_j − x_i`` is at most fov/2:
    ``ĥ_i · r > cos(fov/2) |r|``; j sees i when ``ĥ_j · (−r) > cos(fov/2) |r|``.  Returns two ``(P,)`` float32
    arrays of 0 / 1 (the weights of the neighbour sums, written directly: no bool → float pass).  Computed
    in blocks of pairs (cache-sized temporaries allocated once), gathering 16-byte heading rows."""
    count = pairs.count
    i_sees_j = np.empty(count, dtype=np.float32)
    j_sees_i = np.empty(count, dtype=np.float32)
    cosine = np.float32(cos_half_fov)
    product = np.empty((min(count, _PAIR_BLOCK), 4), dtype=np.float32)
    along = np.empty(min(count, _PAIR_BLOCK), dtype=np.float32)
    limit = np.empty_like(along)
    for first in range(0, count, _PAIR_BLOCK):
        last = min(first + _PAIR_BLOCK, count)
        size = last - first
        rows = pairs.rows[first:last]
        block_limit = np.sqrt(rows[:, 3], out=limit[:size])
        block_limit *= cosine
        block_product = np.take(headings, pairs.i[first:last], axis=0, out=product[:size], mode="clip")
        block_product *= rows
        block_along = np.add(block_product[:, 0], block_product[:, 1], out=along[:size])
        block_along += block_product[:, 2]
        np.greater(block_along, block_limit, out=i_sees_j[first:last])
        np.take(headings, pairs.j[first:last], axis=0, out=block_product, mode="clip")
        block_product *= rows
        np.add(block_product[:, 0], block_product[:, 1], out=block_along)
        block_along += block_product[:, 2]
        np.negative(block_limit, out=block_limit)
        np.less(block_along, block_limit, out=j_sees_i[first:last])
    return i_sees_j, j_sees_i


def _row_starts(i: np.ndarray, width: int) -> np.ndarray:
    """CSR row starts (W + 1,) int32 of the sorted row indices ``i``."""
    indptr = np.zeros(width + 1, dtype=np.int32)  # int32 like pairs.j: scipy then uses them without copies
    np.cumsum(np.bincount(i, minlength=width), out=indptr[1:])
    return indptr


def neighbor_sums(pairs: NeighborPairs, positions: np.ndarray, velocities: np.ndarray, headings: np.ndarray,
                  separation_radius: float, cos_half_fov: float,
                  counts: tuple[np.ndarray, np.ndarray] | None = None) -> NeighborSums:
    """Sum what the rules need over every boid's neighbours.

    Args:
        pairs:       neighbour pairs (within d) of the W work slots.
        positions:   (3, W) float32 work coordinates, in slot order (``points[:, pairs.order]``).
        velocities:  (3, W) float32, slot order.
        headings:    (W, 4) float32 rows ``[hx, hy, hz, 0]`` of unit velocity directions, slot order.
        separation_radius: s [m].
        cos_half_fov: cos(fov / 2); <= −1 means no blind angle.
        counts:      issue 14 hook (topological neighbours, ``topological.py``): ``(forward, backward)`` (P,)
                     float32 — does i count j, does j count i — multiplied into the field-of-view weights of
                     cohesion and alignment; None = every neighbour within d counts.  Separation ignores it.
    """
    width = positions.shape[1]
    shape = (width, width)
    indptr = _row_starts(pairs.i, width)
    # rows [x, y, z, vx, vy, vz, 1, 0]: what a neighbour contributes.  The unused 8th column makes the rows
    # 32 bytes: scipy's sparse × dense product is then ~20 % faster than on 7 columns
    stacked = np.empty((width, 8), dtype=np.float32)
    stacked[:, 0:3] = positions.T
    stacked[:, 3:6] = velocities.T
    stacked[:, 6] = 1.0
    stacked[:, 7] = 0.0
    if cos_half_fov <= -1.0 and counts is None:
        sees = np.ones(pairs.count, dtype=np.float32)
        matrix = scipy.sparse.csr_array((sees, pairs.j, indptr), shape=shape)
        total = matrix @ stacked
        total += matrix.T @ stacked
    else:
        if cos_half_fov <= -1.0:
            i_sees_j, j_sees_i = np.ones(pairs.count, np.float32), np.ones(pairs.count, np.float32)
        else:
            i_sees_j, j_sees_i = visibility(pairs, headings, cos_half_fov)
        if counts is not None:  # issue 14 hook: topological neighbours
            i_sees_j *= counts[0]
            j_sees_i *= counts[1]
        forward = scipy.sparse.csr_array((i_sees_j, pairs.j, indptr), shape=shape)
        backward = scipy.sparse.csr_array((j_sees_i, pairs.j, indptr), shape=shape)
        total = forward @ stacked  # row i: Σ_j [i sees j] (x_j, v_j, 1)
        total += backward.T @ stacked  # row j: Σ_i [j sees i] (x_i, v_i, 1)
    # pairs near enough to matter for separation or the cohesion gate: few in a flock that keeps its spacing
    near = np.flatnonzero(pairs.dist2 < np.float32((COHESION_GATE * separation_radius) ** 2))
    crowded = np.zeros(width, dtype=bool)
    crowded[np.take(pairs.i, near)] = True
    crowded[np.take(pairs.j, near)] = True
    return NeighborSums(count=total[:, 6], position_sum=total[:, 0:3].T, velocity_sum=total[:, 3:6].T,
                        separation=separation(pairs, separation_radius, width, near), crowded=crowded)


def separation(pairs: NeighborPairs, separation_radius: float, width: int,
               candidates: np.ndarray | None = None) -> np.ndarray:
    """v2 (3, W) = Σ_{r < s} (b − x_i) (s − r) / r over pairs closer than s (both ends; offsets are x_j − x_i).

    ``candidates`` optionally restricts the pairs looked at (indices into ``pairs``; must include every pair
    closer than s).  Close pairs are few in a flock that keeps its spacing, so they are picked out and summed
    with one ``bincount`` (exact per-pair offsets; a matrix product on absolute positions would cancel badly).
    """
    s = np.float32(separation_radius)
    if candidates is None:
        candidates = np.arange(pairs.count)
    # gather the candidates' whole rows first (one 16-byte row gather beats fancy-indexing the strided r² column)
    rows = np.take(pairs.rows, candidates, axis=0)
    is_close = rows[:, 3] < s * s
    close = np.compress(is_close, candidates)
    if len(close) == 0:
        return np.zeros((3, width), dtype=np.float32)
    rows = np.compress(is_close, rows, axis=0)
    r = np.sqrt(rows[:, 3])
    # weight (s − r) / r; coincident boids (r = 0) have no direction to push along: they get none here
    # and are separated as soon as their velocities differ
    weight = (s - r) / np.maximum(r, np.float32(1e-12))
    weight[r == 0.0] = 0.0
    i = np.take(pairs.i, close)
    j = np.take(pairs.j, close)
    m = len(close)
    # one bincount for both ends and the three axes: bin = axis · W + slot; (x_j − x_i) w pushes j away from i
    bins = np.empty((3, 2, m), dtype=np.int64)
    bins[:, 0] = j
    bins[:, 1] = i
    bins += (np.arange(3) * width)[:, None, None]
    push = np.empty((3, 2, m), dtype=np.float32)
    push[:, 0] = rows[:, :3].T * weight
    np.negative(push[:, 0], out=push[:, 1])
    return np.bincount(bins.reshape(-1), weights=push.reshape(-1), minlength=3 * width).reshape(3, width).astype(
        np.float32)


def cohesion(sums: NeighborSums, positions: np.ndarray, gated: bool = True) -> np.ndarray:
    """v1 (3, W) = centroid of the visible neighbours − b; zero for a boid with no neighbour and, if ``gated``,
    for a crowded boid (separation has priority, see the module docstring)."""
    n = sums.count
    pulls = n > 0.0
    if gated:
        pulls &= ~sums.crowded
    v1 = np.zeros_like(positions)
    np.divide(sums.position_sum, n, out=v1, where=pulls)
    v1 -= positions
    v1 *= pulls
    return v1


def alignment(sums: NeighborSums, velocities: np.ndarray) -> np.ndarray:
    """v3 (3, W) = mean velocity of the visible neighbours − b_v; zero for a boid with no neighbour."""
    n = sums.count
    has = n > 0.0
    v3 = np.zeros_like(velocities)
    np.divide(sums.velocity_sum, n, out=v3, where=has)
    v3 -= velocities
    v3 *= has
    return v3


def steering(sums: NeighborSums, positions: np.ndarray, velocities: np.ndarray, cohesion_weight: float,
             separation_weight: float, alignment_weight: float) -> np.ndarray:
    """The slides' weighted sum a = w1 v1 + w2 v2 + w3 v3, (3, W) [m/s²] (an acceleration: see dt erratum).
    The cohesion gate applies only when there is a separation rule to give priority to (w2 > 0)."""
    a = cohesion(sums, positions, gated=separation_weight > 0.0)
    a *= np.float32(cohesion_weight)
    a += np.float32(separation_weight) * sums.separation
    a += np.float32(alignment_weight) * alignment(sums, velocities)
    return a

"""Order parameters of a flock: the numbers the collective-motion literature measures groups by.

For N boids with positions x_i, velocities u_i (headings v̂_i = u_i / |u_i|), centroid c = Σ x_i / N and
r̂_i = (x_i − c) / |x_i − c|:

- polarization   p = |Σ v̂_i| / N                in [0, 1]: 1 when all swim the same way; ≈ sqrt(8 / (3πN)) for
                                                 N random headings in 3D (√π / (2√N) in the plane, Vicsek 1995)
- milling        m = |Σ r̂_i × v̂_i| / N          in [0, 1]: 1 for a perfect mill (torus) about the centroid
- radius of gyration  R_g = sqrt(Σ |x_i − c|² / N)                                                        [m]
- mean nearest-neighbour distance  (1/N) Σ min_j≠i |x_j − x_i|                                              [m]
- mean, min, max speed |u_i|                                                                              [m/s]

Couzin et al. 2002 (p_group, m_group) and Tunstrøm et al. 2013 (O_p, O_r) use p and m; Tunstrøm's phases
(:func:`classify`): polarized p > 0.65 and m < 0.35, milling m > 0.65 and p < 0.35, swarm both < 0.35,
else transitional.

The node publishes them for every flock on every tick (``~/flocks/<flock>/stats``), so they must be cheap next
to the step (issue 12: a 15k-fish tick within 16.7 ms):

- :func:`nearest_neighbor_distances` reuses the neighbour list the step already built.  Boid i's nearest
  neighbour within the search radius d is the nearest entry of its row; since the search the boids moved, boid
  i by δ_i and every other boid by at most τ (an ordinary step: max_speed · dt), so a row minimum m_i with
  m_i + δ_i + τ < d is the true nearest neighbour now (whoever is nearer now was within d at the search, hence
  in the row).  The few boids that moved farther than τ (pushed out of a body) are compared with every boid
  directly instead of widening everyone's margin.  Only the boids this cannot decide (a straggler with nobody
  near, a flock moved as a whole) are searched again: against every boid when that is a small job, else with
  a KD-tree.  Exact either way.
- the other parameters are two compiled sequential passes over the boids (:func:`_moments`: the centroid,
  Σ v̂, the speeds and the mean nearest-neighbour distance; then Σ |x − c|² and Σ r̂ × v̂ about that
  centroid) — sequential, so the sums do not depend on a thread count.

Two kernel calls per flock and tick (:func:`_nearest_in_rows`, :func:`_moments`), both on the tick's thread:
~0.75 ms at 15,000 boids alone, ~0.9 ms inside the node's tick (``benchmarks/bench_flock_stats.py``,
``bench_tick.py``'s split) — a search from scratch costs 13 ms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..jit import njit, prange
from .neighbors import NeighborList, kd_tree, minimum_image, pair_offset, squared_length

#: Tunstrøm et al. 2013's thresholds on O_p (polarization) and O_r (milling)
ORDERED = 0.65
DISORDERED = 0.35
#: the boids the neighbour list cannot decide are searched against every boid (compiled) while their number × N
#: is at most this (~1 ms); beyond, a KD-tree over the flock is built for them (~14 ms at 15k boids)
BRUTE_FORCE_PAIRS = 1_000_000
#: boids that moved more than an ordinary step since the search are checked one by one against every row, up to
#: this many (~1 ms at 15k boids); with more, the proof assumes everyone moved the largest move
MAX_JUMPERS = 32


@dataclass
class FlockOrder:
    """Order parameters of one flock at one instant (see the module docstring)."""

    count: int
    polarization: float
    milling: float
    centroid: np.ndarray  # (3,) [m]
    radius_of_gyration: float
    mean_nearest_neighbor_distance: float  # NaN for a single boid
    mean_speed: float
    min_speed: float
    max_speed: float


def classify(p: float, m: float) -> str:
    """Tunstrøm et al. 2013: 'polarized' (p > 0.65, m < 0.35), 'milling' (m > 0.65, p < 0.35), 'swarm'
    (both < 0.35), else 'transitional'."""
    if p > ORDERED and m < DISORDERED:
        return "polarized"
    if m > ORDERED and p < DISORDERED:
        return "milling"
    if p < DISORDERED and m < DISORDERED:
        return "swarm"
    return "transitional"


# ---- nearest neighbours ---------------------------------------------------------------------------------------

@njit
def _nearest_of(i, positions, candidates, count, period, best2):
    """min(best2, squared distance from boid i to ``candidates[:count]`` (itself excluded))."""
    for c in range(count):
        j = candidates[c]
        if j != i:
            dx, dy, dz = pair_offset(positions, i, j, period)
            best2 = min(best2, squared_length(dx, dy, dz))
    return best2


class Searched(NamedTuple):
    """A metric neighbour list and what it proves about the positions now (see the module docstring)."""

    neighbors: NeighborList  # each boid's neighbours within ``radius`` at ``positions``
    positions: np.ndarray    # (N, 3) where the boids were when the list was built
    radius: float            # d [m]
    ordinary_move: float     # how far an ordinary step has moved a boid since [m]


class Budget(NamedTuple):
    """How much work :func:`_nearest_in_rows` may do besides the rows."""

    max_jumpers: int        # boids that moved more than the ordinary move, checked one by one, at most
    brute_force_pairs: int  # distances tested for the boids the rows did not decide, at most


@njit
def _nearest_in_rows(searched, positions, period, budget, out, found):
    """Each boid's nearest neighbour now from the rows of the list in ``searched`` (:class:`Searched`; see the
    module docstring), within the :class:`Budget`:

    1. the moves since the search, |x_i − x_i(search)| (minimum images); the boids that moved more than
       ``ordinary_move`` are *jumpers* (at most ``max_jumpers``; with more, every boid counts as one that moved
       the largest move and there are none);
    2. per slot, the nearest of its row and of the jumpers, provably the nearest of all (``found``) when it is
       closer than d − δ_i − ``ordinary_move`` (anyone else was farther than d at the search and moved less);
    3. the boids not found, against every boid, if that is at most ``brute_force_pairs`` distances.

    One call, on the calling thread: the work is memory-bound (0.5 ms at 15k boids, one thread as fast as two),
    and every extra kernel call or parallel region is one more chance for the bag writer's Python to hold the
    GIL, or its lz4 the other core, for milliseconds.  Returns how many are still not found (searched by the
    caller)."""
    start, count, index, order = searched.neighbors.start, searched.neighbors.count, searched.neighbors.index, \
        searched.neighbors.order
    ordinary_move, radius = searched.ordinary_move, searched.radius
    max_jumpers, brute_force_pairs = budget
    n = positions.shape[0]
    moves = np.empty(n)
    jumpers = np.empty(n, np.int64)
    jumping = 0
    largest = 0.0
    for i in range(n):
        dx = minimum_image(positions[i, 0] - searched.positions[i, 0], period[0])
        dy = minimum_image(positions[i, 1] - searched.positions[i, 1], period[1])
        dz = minimum_image(positions[i, 2] - searched.positions[i, 2], period[2])
        moves[i] = math.sqrt(squared_length(dx, dy, dz))
        largest = max(largest, moves[i])
        if moves[i] > ordinary_move:
            jumpers[jumping] = i
            jumping += 1
    if jumping > max_jumpers:  # too many to check one by one: everyone may have moved the largest move
        ordinary_move = largest
        jumping = 0
    local = np.empty((n, 3))  # positions in slot order: a row's neighbours are near in memory
    for s in range(n):
        b = order[s]
        local[s, 0], local[s, 1], local[s, 2] = positions[b, 0], positions[b, 1], positions[b, 2]
    missing = 0
    for s in range(n):
        best2 = math.inf
        for e in range(start[s], start[s] + count[s]):
            dx, dy, dz = pair_offset(local, s, index[e], period)
            best2 = min(best2, squared_length(dx, dy, dz))
        b = order[s]
        best2 = _nearest_of(b, positions, jumpers, jumping, period, best2)
        out[b] = math.sqrt(best2)
        found[b] = out[b] + moves[b] + ordinary_move < radius
        missing += not found[b]
    if 0 < missing and missing * n <= brute_force_pairs:
        everyone = np.arange(n)
        for i in range(n):
            if not found[i]:
                out[i] = math.sqrt(_nearest_of(i, positions, everyone, n, period, math.inf))
                found[i] = True
        missing = 0
    return missing


@njit(parallel=True)
def _nearest_of_all(queries, positions, period, out):
    """``out[q]`` = distance from boid ``queries[q]`` to the nearest other boid, every boid tested."""
    everyone = np.arange(positions.shape[0])
    for q in prange(queries.shape[0]):
        out[q] = math.sqrt(_nearest_of(queries[q], positions, everyone, positions.shape[0], period, math.inf))


def _nearest_by_tree(queries: np.ndarray, positions: np.ndarray, period: np.ndarray) -> np.ndarray:
    """The same as :func:`_nearest_of_all` with a KD-tree (a periodic box: ``boxsize``), for many queries."""
    tree, points = kd_tree(positions, period, "nearest_neighbor_distances")
    distance, _ = tree.query(points[queries], k=2)
    return np.asarray(distance, dtype=np.float64).reshape(len(queries), 2)[:, 1]


def nearest_neighbor_distances(positions: np.ndarray, period: np.ndarray | None = None,
                               neighbors: NeighborList | None = None, searched: np.ndarray | None = None,
                               radius: float = 0.0, ordinary_move: float = 0.0) -> np.ndarray:
    """Distance from each boid to its nearest other boid, (N,) [m] (inf for N = 1).

    Args:
        positions:     (N, 3) float64 positions now.
        period:        (3,) sizes of a periodic box (0 = open axis); None = open space.
        neighbors:     optional: a metric neighbour list within ``radius`` built at the positions ``searched``
                       ((N, 3)); rows whose nearest entry is provably the nearest boid are taken from it, only
                       the others are searched.
        ordinary_move: how far a boid moves in an ordinary step since that search [m] (the flock's max_speed · dt):
                       the few boids that moved farther (pushed out of a body, moved by hand) are checked
                       against every boid's row instead of spoiling everyone's proof.  Any value is exact; this
                       one keeps the work small.
    """
    n = len(positions)
    if n < 2:
        return np.full(n, math.inf)
    period = np.zeros(3) if period is None else np.asarray(period, dtype=np.float64)
    out = np.empty(n)
    if neighbors is not None and neighbors.boids == n:
        found = np.empty(n, np.bool_)
        if _nearest_in_rows(Searched(neighbors, searched, float(radius), float(ordinary_move)), positions, period,
                            Budget(MAX_JUMPERS, BRUTE_FORCE_PAIRS), out, found) == 0:
            return out
        queries = np.flatnonzero(~found)
    else:
        queries = np.arange(n)
    if len(queries) * n <= BRUTE_FORCE_PAIRS:
        nearest = np.empty(len(queries))
        _nearest_of_all(queries, positions, period, nearest)
    else:
        nearest = _nearest_by_tree(queries, positions, period)
    out[queries] = nearest
    return out


# ---- the moments ----------------------------------------------------------------------------------------------

class Moments(NamedTuple):
    """The order parameters :func:`_moments` computes, as numbers."""

    polarization: float   # p
    milling: float        # m
    cx: float             # centroid c [m]
    cy: float
    cz: float
    radius_of_gyration: float
    mean_nearest: float   # mean nearest-neighbour distance [m]
    mean_speed: float     # [m/s]
    min_speed: float
    max_speed: float


@njit
def _moments(x, u, nearest):
    """Two sequential passes over the boids: (Σ x, Σ v̂, Σ |u|, min |u|, max |u|, Σ nearest-neighbour distance),
    then, about the centroid c, (Σ |x − c|², Σ r̂ × v̂).  Returns the order parameters as :class:`Moments`: p, m,
    c (3), R_g, mean nearest-neighbour distance, mean / min / max speed.  A boid that does not move has no
    heading (it counts 0 in Σ v̂, as one at the centroid has no r̂)."""
    n = x.shape[0]
    nearest_sum = 0.0
    cx = cy = cz = 0.0  # Σ x
    hx = hy = hz = 0.0  # Σ v̂
    speed_sum = 0.0
    slowest, fastest = math.inf, 0.0
    for i in range(n):
        nearest_sum += nearest[i]
        cx += x[i, 0]
        cy += x[i, 1]
        cz += x[i, 2]
        speed = math.sqrt(u[i, 0] * u[i, 0] + u[i, 1] * u[i, 1] + u[i, 2] * u[i, 2])
        speed_sum += speed
        slowest = min(slowest, speed)
        fastest = max(fastest, speed)
        if speed > 0.0:
            hx += u[i, 0] / speed
            hy += u[i, 1] / speed
            hz += u[i, 2] / speed
    cx, cy, cz = cx / n, cy / n, cz / n
    spread = 0.0  # Σ |x − c|²
    mx = my = mz = 0.0  # Σ r̂ × v̂
    for i in range(n):
        ox, oy, oz = x[i, 0] - cx, x[i, 1] - cy, x[i, 2] - cz
        r2 = ox * ox + oy * oy + oz * oz
        spread += r2
        speed = math.sqrt(u[i, 0] * u[i, 0] + u[i, 1] * u[i, 1] + u[i, 2] * u[i, 2])
        if r2 > 0.0 and speed > 0.0:
            scale = 1.0 / (math.sqrt(r2) * speed)  # r̂ × v̂ = (o × u) / (|o| |u|)
            mx += (oy * u[i, 2] - oz * u[i, 1]) * scale
            my += (oz * u[i, 0] - ox * u[i, 2]) * scale
            mz += (ox * u[i, 1] - oy * u[i, 0]) * scale
    polarization = math.sqrt(hx * hx + hy * hy + hz * hz) / n
    milling = math.sqrt(mx * mx + my * my + mz * mz) / n
    return Moments(polarization, milling, cx, cy, cz, math.sqrt(spread / n), nearest_sum / n, speed_sum / n, slowest,
                   fastest)


def flock_order(positions: np.ndarray, velocities: np.ndarray, nearest: np.ndarray | None = None) -> FlockOrder:
    """Every order parameter of one flock from its ``positions`` and ``velocities`` ((N, 3) float64 each, a
    Flock's state) and the nearest-neighbour distances ``nearest`` (N,) (computed here, without a neighbour
    list, if not given: :meth:`Flock.order` passes the ones from its last neighbour search)."""
    x = np.ascontiguousarray(positions, dtype=np.float64)
    u = np.ascontiguousarray(velocities, dtype=np.float64)
    n = len(x)
    if nearest is None:
        nearest = nearest_neighbor_distances(x)
    p, m, cx, cy, cz, rg, mean_nearest, mean_speed, min_speed, max_speed = _moments(x, u, nearest)
    return FlockOrder(count=n, polarization=p, milling=m, centroid=np.array([cx, cy, cz]), radius_of_gyration=rg,
                      mean_nearest_neighbor_distance=mean_nearest if n > 1 else math.nan,
                      mean_speed=mean_speed, min_speed=min_speed, max_speed=max_speed)


__all__ = ["BRUTE_FORCE_PAIRS", "DISORDERED", "FlockOrder", "ORDERED", "classify", "flock_order",
           "nearest_neighbor_distances"]

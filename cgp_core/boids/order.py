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

:func:`flock_order` computes them all for one flock (the node publishes them every tick on
``~/flocks/<flock>/stats``).  The nearest-neighbour distances come from :func:`nearest_neighbor_distances`, a
grid search compiled with numba: O(N) for a flock of roughly even density (a KD-tree query costs ~35 ms at
15k boids, more than a whole tick; ``benchmarks/bench_order.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..jit import njit

#: Tunstrøm et al. 2013's thresholds on O_p (polarization) and O_r (milling)
ORDERED = 0.65
DISORDERED = 0.35


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


def polarization(headings: np.ndarray) -> float:
    """p = |Σ v̂_i| / N of unit headings ``(3, N)``."""
    return float(np.linalg.norm(headings.sum(axis=1)) / headings.shape[1])


def milling(positions: np.ndarray, headings: np.ndarray) -> float:
    """m = |Σ r̂_i × v̂_i| / N, r̂_i the unit vector from the centroid to boid i; ``(3, N)`` each.  A boid at the
    centroid itself contributes nothing."""
    offset = positions - positions.mean(axis=1, keepdims=True)
    length = np.sqrt(np.einsum("ij,ij->j", offset, offset))
    unit = np.divide(offset, length, out=np.zeros_like(offset), where=length > 0.0)
    ux, uy, uz = unit
    hx, hy, hz = headings
    # Σ r̂ × v̂, one component at a time on the contiguous rows of (3, N) (ufuncs, not np.dot: BLAS threads
    # contend with the node's own threads)
    angular = np.array([(uy * hz - uz * hy).sum(), (uz * hx - ux * hz).sum(), (ux * hy - uy * hx).sum()])
    return float(np.linalg.norm(angular) / positions.shape[1])


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


@njit
def _nearest_in_grid(points, order, start, dims, cell_of, cell):
    """Nearest-neighbour distance of every point, ring by ring of grid cells (see the caller)."""
    n = points.shape[1]
    out = np.empty(n)
    max_ring = max(dims[0], dims[1], dims[2])
    for a in range(n):
        ax = points[0, a]
        ay = points[1, a]
        az = points[2, a]
        cx = cell_of[0, a]
        cy = cell_of[1, a]
        cz = cell_of[2, a]
        best2 = math.inf
        for ring in range(max_ring + 1):
            # the cells at Chebyshev distance `ring` from the point's own cell, clipped to the grid
            for ix in range(max(cx - ring, 0), min(cx + ring, dims[0] - 1) + 1):
                for iy in range(max(cy - ring, 0), min(cy + ring, dims[1] - 1) + 1):
                    on_side = abs(ix - cx) == ring or abs(iy - cy) == ring
                    for iz in range(max(cz - ring, 0), min(cz + ring, dims[2] - 1) + 1):
                        if not on_side and abs(iz - cz) != ring:
                            continue  # inside the ring: searched already
                        key = (ix * dims[1] + iy) * dims[2] + iz
                        for s in range(start[key], start[key + 1]):
                            b = order[s]
                            if b != a:
                                dx = points[0, b] - ax
                                dy = points[1, b] - ay
                                dz = points[2, b] - az
                                d2 = dx * dx + dy * dy + dz * dz
                                if d2 < best2:
                                    best2 = d2
            # every point in a farther ring is at least `ring` cells away
            if best2 <= (ring * cell) ** 2:
                break
        out[a] = math.sqrt(best2)
    return out


def nearest_neighbor_distances(positions: np.ndarray) -> np.ndarray:
    """Distance from each point to its nearest other point, ``positions (3, N)`` → (N,) [m] (inf for N = 1).

    A uniform grid with about one point per cell (cell edge from the bounding box's volume per point, a dense
    table of cell starts); each point searches the rings of cells around its own, nearest first, until the
    best distance found is within the rings already searched (a point in ring r + 1 is at least r cells
    away): exact, O(N) for even densities."""
    points = np.ascontiguousarray(positions, dtype=np.float64)
    n = points.shape[1]
    if n < 2:
        return np.full(n, math.inf)
    low = points.min(axis=1)
    extent = points.max(axis=1) - low
    largest = float(extent.max())
    if largest == 0.0:
        return np.zeros(n)
    volume = float(np.prod(np.maximum(extent, 1e-3 * largest)))
    cell = (volume / n) ** (1.0 / 3.0)
    # at most ~8 cells per point in the table (a flat or stretched flock gets coarser cells)
    while np.prod(np.floor(extent / cell) + 1) > 8 * n + 64:
        cell *= 1.5
    cell_of = ((points - low[:, None]) / cell).astype(np.int64)
    dims = cell_of.max(axis=1) + 1
    keys = (cell_of[0] * dims[1] + cell_of[1]) * dims[2] + cell_of[2]
    order = np.argsort(keys, kind="stable")
    start = np.zeros(int(np.prod(dims)) + 1, dtype=np.int64)
    np.cumsum(np.bincount(keys, minlength=len(start) - 1), out=start[1:])
    return _nearest_in_grid(points, order, start, dims, cell_of, cell)


def flock_order(positions: np.ndarray, velocities: np.ndarray) -> FlockOrder:
    """Every order parameter of one flock from its ``positions`` and ``velocities``, (N, 3) each (a Flock's
    public views)."""
    x = np.ascontiguousarray(np.asarray(positions, dtype=float).T)
    u = np.ascontiguousarray(np.asarray(velocities, dtype=float).T)
    n = x.shape[1]
    speed = np.sqrt(np.einsum("ij,ij->j", u, u))
    headings = np.divide(u, speed, out=np.zeros_like(u, dtype=float), where=speed > 0.0)
    centroid = x.mean(axis=1)
    offset = x - centroid[:, None]
    nearest = nearest_neighbor_distances(x)
    return FlockOrder(
        count=n,
        polarization=polarization(headings),
        milling=milling(x, headings),
        centroid=centroid,
        radius_of_gyration=float(np.sqrt(np.einsum("ij,ij->", offset, offset) / n)),
        mean_nearest_neighbor_distance=float(nearest.mean()) if n > 1 else math.nan,
        mean_speed=float(speed.mean()),
        min_speed=float(speed.min()),
        max_speed=float(speed.max()),
    )

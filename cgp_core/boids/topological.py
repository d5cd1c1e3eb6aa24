"""Topological neighbours (Ballerini et al. 2008, PNAS 105:1232): each boid interacts with its k nearest
neighbours (starlings: 6-7), at whatever distance they are, instead of with everyone within a radius.

:func:`k_nearest` is a search in the sense of ``neighbors.py``: it returns a :class:`NeighborList` in the layout
every rule kernel reads — slot s's row is ``index[k·s : k·s + k]`` (``start = k·s``, ``count = k``) — so
Reynolds' rules (``rules.py``) and Couzin's zones (``couzin.py``) run on it unchanged.  It is built on the
flock's own metric search (grid, KD-tree or brute force), in the same slot order:

1. per slot, the k nearest of its metric neighbours (within the flock's ``radius``), nearest first, ties by
   boid index (:func:`_select_nearest`: a compiled insertion into a row of k, one slot per iteration, in
   parallel).  A boid with at least k neighbours within the radius has found its k nearest overall: anyone
   outside the radius is farther;
2. a boid with fewer than k metric neighbours (a straggler, a sparse flock) gets its k nearest from one
   KD-tree query (scipy cKDTree, only for those boids; a few spare candidates ranked again with the shared
   membership formula, :func:`~cgp_core.boids.neighbors.pair_offset`, so both paths rank alike).

Every boid then interacts with exactly k others (all N − 1 for N <= k), separation included: the nearest
neighbours are the ones a collision reflex is about.  Being among someone's k nearest is not symmetric, and
the rows say so (row s holds whom s counts).

Why k nearest and not a radius: a metric flock that spreads out (a predator scatters it, it fans out around an
obstacle) loses its neighbours once they are farther than the radius and falls apart; a topological one keeps
k neighbours at any density and pulls back together (``tests/test_topological.py`` shows both).

Not for periodic boxes (``bounds_mode: wrap``; ``FlockParams`` refuses the combination): the k nearest of a
sparse flock may lie beyond the minimum images.
"""

from __future__ import annotations

import numpy as np

from ..jit import njit, prange
from .neighbors import NeighborList, pair_offset, squared_length

#: spare candidates the KD-tree returns beyond k for a straggler (ranked again with the shared formula)
_SPARE = 4


@njit
def _insert(r2, boid, k, filled, best_r2, best_boid, row, slot, out):
    """Insert candidate ``slot`` (squared distance ``r2``, boid index ``boid``) into the sorted row of at most
    k entries (``best_r2``, ``best_boid``, slots in ``out[row:]``) that holds ``filled`` so far; returns the
    new fill.  Order: nearer first, ties by boid index."""
    if filled == k and (r2 > best_r2[k - 1] or (r2 == best_r2[k - 1] and boid > best_boid[k - 1])):
        return filled
    at = filled if filled < k else k - 1
    while at > 0 and (best_r2[at - 1] > r2 or (best_r2[at - 1] == r2 and best_boid[at - 1] > boid)):
        best_r2[at] = best_r2[at - 1]  # a full row's last entry is overwritten: it drops out
        best_boid[at] = best_boid[at - 1]
        out[row + at] = out[row + at - 1]
        at -= 1
    best_r2[at] = r2
    best_boid[at] = boid
    out[row + at] = slot
    return min(filled + 1, k)


@njit(parallel=True)
def _select_nearest(start, count, index, order, positions, k, out_index, lacking):
    """Per slot: its k nearest metric neighbours into ``out_index[k·s : k·s + k]`` (nearest first);
    ``lacking[s]`` when it has fewer than k (its row is then filled by :func:`_rank_candidates`).
    ``positions`` (N, 3) in slot order."""
    no_period = np.zeros(3)
    for s in prange(order.shape[0]):
        if count[s] < k:
            lacking[s] = True
            continue
        lacking[s] = False
        best_r2 = np.empty(k)
        best_boid = np.empty(k, np.int64)
        filled = 0
        for e in range(start[s], start[s] + count[s]):
            j = index[e]
            dx, dy, dz = pair_offset(positions, s, j, no_period)
            filled = _insert(squared_length(dx, dy, dz), order[j], k, filled, best_r2, best_boid, k * s, j,
                             out_index)


@njit(parallel=True)
def _rank_candidates(slots, candidates, order, positions, k, out_index):
    """Stragglers: slot ``slots[q]``'s k nearest among its candidate slots ``candidates[q]`` (the KD-tree's,
    itself excluded), ranked with the shared formula, into its row of ``out_index``."""
    no_period = np.zeros(3)
    for q in prange(slots.shape[0]):
        s = slots[q]
        best_r2 = np.empty(k)
        best_boid = np.empty(k, np.int64)
        filled = 0
        for c in range(candidates.shape[1]):
            j = candidates[q, c]
            if j == s or j < 0:
                continue
            dx, dy, dz = pair_offset(positions, s, j, no_period)
            filled = _insert(squared_length(dx, dy, dz), order[j], k, filled, best_r2, best_boid, k * s, j,
                             out_index)


def k_nearest(metric: NeighborList, positions: np.ndarray, k: int) -> NeighborList:
    """Every boid's k nearest neighbours, in the slot order of ``metric``.

    Args:
        metric:    the flock's metric neighbour list (any backend of ``neighbors.py``), open space.
        positions: (N, 3) float64, the positions ``metric`` was built from (boid order).
        k:         neighbours per boid (>= 1); N − 1 if the flock is smaller.

    Returns:
        A :class:`NeighborList` with ``order = metric.order``, ``start = k·s``, ``count = k`` and each row
        nearest first (ties by boid index).
    """
    n = metric.boids
    k = min(int(k), n - 1)
    if k <= 0:
        return NeighborList(metric.order, np.zeros(n, np.int64), np.zeros(n, np.int64), np.zeros(0, np.int32))
    sorted_positions = metric.sorted(positions)
    index = np.empty(k * n, np.int32)
    lacking = np.empty(n, np.bool_)
    _select_nearest(metric.start, metric.count, metric.index, metric.order, sorted_positions, k, index, lacking)
    stragglers = np.flatnonzero(lacking)
    if len(stragglers):
        from scipy.spatial import cKDTree  # here, not at import: scipy.spatial takes ~0.3 s to load

        wanted = min(k + 1 + _SPARE, n)  # + 1: the query point finds itself
        _, found = cKDTree(sorted_positions).query(sorted_positions[stragglers], k=wanted)
        found = np.asarray(found, dtype=np.int64).reshape(len(stragglers), wanted)
        _rank_candidates(stragglers.astype(np.int64), found, metric.order, sorted_positions, k, index)
    return NeighborList(metric.order, np.arange(n, dtype=np.int64) * k, np.full(n, k, np.int64), index)

"""Topological neighbours (Ballerini et al. 2008, PNAS 105:1232): each boid interacts with its k nearest
neighbours (starlings: 6-7), at whatever distance they are, instead of with everyone within a radius.

:func:`topological_pairs` turns the metric search's pairs into the same :class:`NeighborPairs` structure plus a
weight per pair end, so the rule kernels run unchanged on either mode:

1. the metric search (``neighbors.py``: grid, KD-tree or brute force) gives every pair within the flock's
   neighbourhood radius; for each boid, the k nearest of its metric neighbours are selected (ties by slot);
2. a boid with fewer than k metric neighbours (a sparse flock, a straggler) gets its k nearest from one
   KD-tree query (scipy cKDTree, only for those boids), distances recomputed with the shared membership
   formula (:func:`pair_offsets`) so both paths rank alike;
3. the result is every metric pair (separation stays metric: it is a collision reflex, not a social
   interaction) plus the extra far pairs, with ``counts_forward[p]`` = does i count j among its k nearest and
   ``counts_backward[p]`` = does j count i.  Being among someone's k nearest is not symmetric.

Why k nearest and not a radius: a metric flock that spreads out (a predator scatters it, it fans out around an
obstacle) loses its neighbours once they are farther than the radius and falls apart; a topological one keeps
k neighbours at any density and pulls back together (``tests/test_topological.py`` shows both).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .neighbors import NeighborPairs, pair_offsets


def _nearest_first(source: np.ndarray, target: np.ndarray, dist2: np.ndarray) -> np.ndarray:
    """Order of the directed edges (source → target) grouped by source, nearest target first (ties: by slot)."""
    return np.lexsort((target, dist2, source))


def topological_pairs(pairs: NeighborPairs, positions: np.ndarray, k: int
                      ) -> tuple[NeighborPairs, np.ndarray, np.ndarray]:
    """The k-nearest-neighbour relation on top of the metric pairs.

    Args:
        pairs:     the metric search's pairs of the W work slots.
        positions: (3, W) float32 work coordinates in *slot* order (``points[:, pairs.order]``).
        k:         neighbours per boid (>= 1).

    Returns:
        ``(pairs', counts_forward (P',) float32, counts_backward (P',) float32)``: pairs' holds every metric pair
        and the extra pairs to far k-nearest neighbours, sorted by (i, j) with i < j, same slot order; the
        weights are 1 where that end counts the other among its k nearest, else 0.
    """
    width = positions.shape[1]
    k = min(int(k), width - 1)
    if k <= 0 or width < 2:
        zeros = np.zeros(pairs.count, dtype=np.float32)
        return pairs, zeros, zeros.copy()
    # 1. directed edges of the metric pairs, k nearest per source
    source = np.concatenate((pairs.i, pairs.j)).astype(np.int64)
    target = np.concatenate((pairs.j, pairs.i)).astype(np.int64)
    dist2 = np.concatenate((pairs.dist2, pairs.dist2))
    order = _nearest_first(source, target, dist2)
    source, target = source[order], target[order]
    per_source = np.bincount(source, minlength=width)
    first = np.cumsum(per_source) - per_source
    rank = np.arange(len(source)) - np.repeat(first, per_source)
    chosen = rank < k
    chosen_source, chosen_target = source[chosen], target[chosen]

    # 2. boids with fewer than k metric neighbours: their k nearest from a KD-tree
    lacking = np.flatnonzero(per_source < k)
    if len(lacking):
        keep = ~np.isin(chosen_source, lacking)
        chosen_source, chosen_target = chosen_source[keep], chosen_target[keep]
        points = positions.T.astype(np.float64)
        query = min(k + 4, width)  # a few spare: re-ranked below with the shared float32 formula
        _, found = cKDTree(points).query(points[lacking], k=query)
        found = np.asarray(found, dtype=np.int64).reshape(len(lacking), query)
        extra_source = np.repeat(lacking.astype(np.int64), query)
        extra_target = found.reshape(-1)
        not_self = extra_target != extra_source
        extra_source, extra_target = extra_source[not_self], extra_target[not_self]
        rows = pair_offsets(positions, extra_source, extra_target)
        order = _nearest_first(extra_source, extra_target, rows[:, 3])
        extra_source, extra_target = extra_source[order], extra_target[order]
        per_lacking = np.bincount(extra_source, minlength=width)
        first = np.cumsum(per_lacking) - per_lacking
        rank = np.arange(len(extra_source)) - np.repeat(first, per_lacking)
        take = rank < k
        chosen_source = np.concatenate((chosen_source, extra_source[take]))
        chosen_target = np.concatenate((chosen_target, extra_target[take]))

    # 3. every metric pair plus the new far ones, unordered (i < j), with who counts whom
    low = np.minimum(chosen_source, chosen_target)
    high = np.maximum(chosen_source, chosen_target)
    chosen_key = low * width + high
    metric_key = pairs.i.astype(np.int64) * width + pairs.j.astype(np.int64)
    keys = np.union1d(metric_key, chosen_key)  # sorted: (i, j) order
    forward = np.zeros(len(keys), dtype=np.float32)
    backward = np.zeros(len(keys), dtype=np.float32)
    slot = np.searchsorted(keys, chosen_key)
    from_low = chosen_source == low
    forward[slot[from_low]] = 1.0
    backward[slot[~from_low]] = 1.0
    i = (keys // width).astype(np.int32)
    j = (keys % width).astype(np.int32)
    rows = np.empty((len(keys), 4), dtype=np.float32)
    is_metric = np.isin(keys, metric_key, assume_unique=True)
    rows[is_metric] = pairs.rows[np.argsort(metric_key, kind="stable")]
    if not np.all(is_metric):
        rows[~is_metric] = pair_offsets(positions, i[~is_metric], j[~is_metric])
    return NeighborPairs(order=pairs.order, i=i, j=j, rows=rows), forward, backward

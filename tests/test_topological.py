"""Topological neighbours (Ballerini et al. 2008; cgp_core/boids/topological.py): the selection is exactly the
k nearest (checked against a KD-tree), on top of any metric search; and a flock that suddenly spreads out
(a flash expansion: density down 64-fold) falls apart with metric neighbours but gathers again with
topological ones, for Reynolds' rules and Couzin's."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from cgp_core.boids import Flock, FlockParams, make_search
from cgp_core.boids.order import flock_order
from cgp_core.boids.topological import topological_pairs


@pytest.mark.parametrize("search", ["grid", "kdtree", "brute"])
@pytest.mark.parametrize("layout", ["dense", "sparse", "mixed"])
def test_each_boid_counts_exactly_its_k_nearest(search, layout):
    rng = np.random.default_rng(11)
    if layout == "dense":
        x = rng.random((3, 400)) * 6.0
    elif layout == "sparse":
        x = rng.random((3, 200)) * 60.0  # hardly any pair within the radius: the KD-tree path
    else:
        x = np.concatenate([rng.random((3, 300)) * 5.0, 30.0 + rng.random((3, 40)) * 40.0], axis=1)
    points = x.astype(np.float32)
    k, radius = 7, 2.0
    pairs = make_search(search).pairs(points, radius)
    slot_points = np.take(points, pairs.order, axis=1)
    result, forward, backward = topological_pairs(pairs, slot_points, k)
    counted = {s: set() for s in range(points.shape[1])}
    for a, b, f, g in zip(result.i, result.j, forward, backward):
        if f:
            counted[int(pairs.order[a])].add(int(pairs.order[b]))
        if g:
            counted[int(pairs.order[b])].add(int(pairs.order[a]))
    _, nearest = cKDTree(x.T.astype(np.float64)).query(x.T, k=k + 1)
    for point in range(points.shape[1]):
        assert counted[point] == set(nearest[point, 1:].tolist())
    # every metric pair is kept (separation stays metric), with its offsets
    metric = {tuple(p) for p in pairs.point_pairs().tolist()}
    assert metric <= {tuple(p) for p in result.point_pairs().tolist()}
    assert np.all(result.i < result.j) and np.all(np.diff(result.i) >= 0)
    expected = slot_points[:, result.j] - slot_points[:, result.i]
    np.testing.assert_allclose(result.offset, expected, rtol=0, atol=1e-6)


def cluster_fraction(positions: np.ndarray, link: float) -> float:
    """Share of the boids in the largest group when boids closer than ``link`` are linked."""
    tree = cKDTree(positions)
    graph = tree.sparse_distance_matrix(tree, link, output_type="coo_matrix")
    _, labels = connected_components(graph, directed=False)
    return np.bincount(labels).max() / len(positions)


def flash_expansion(params: FlockParams, factor: float = 2.5, after: float = 25.0, dt: float = 1 / 30):
    """A flock swims 8 s, is then spread out ``factor``-fold about its centroid (density / factor³) and left
    for ``after`` seconds.  Returns (R_g at the end / R_g right after the spread, largest group's share right
    after and at the end (boids linked within 1.5 × the mean nearest-neighbour distance right after the
    spread: a scale-free measure), polarization at the end)."""
    flock = Flock(params)
    for _ in range(round(8 / dt)):
        flock.step(dt)
    x = flock.positions
    centre = x.mean(axis=0)
    x[:] = centre + factor * (x - centre)
    spread = flock_order(flock.positions, flock.velocities)
    link = 1.5 * spread.mean_nearest_neighbor_distance
    group_before = cluster_fraction(flock.positions, link)
    for _ in range(round(after / dt)):
        flock.step(dt)
    end = flock_order(flock.positions, flock.velocities)
    return (end.radius_of_gyration / spread.radius_of_gyration, group_before,
            cluster_fraction(flock.positions, link), end.polarization)


# Reynolds' rules as the lecture tunes them (weights for the ~17 neighbours a boid has within d at the flock's
# natural spacing) and a topological k of as many, 16, so both modes start with the same neighbourhoods.  (At
# Ballerini's k = 7 those weights do not even align the undisturbed flock; Couzin's zonal model with k = 7
# fragments into small cliques of mutual nearest neighbours: see the report of issue 14.)
REYNOLDS = dict(count=150, seed=5, spawn_center=[0, 0, 0], spawn_extent=[6, 6, 6], bounds_mode="none")


def test_topological_neighbours_keep_a_flock_together_when_its_density_drops():
    metric_growth, metric_group_before, metric_group, metric_p = flash_expansion(FlockParams(**REYNOLDS))
    topo_growth, topo_group_before, topo_group, topo_p = flash_expansion(
        FlockParams(**REYNOLDS, neighbor_mode="topological", neighbor_k=16))
    # metric: spread beyond the radius d, the boids lost their neighbours: the flock disperses and falls apart
    assert metric_growth > 1.5 and metric_p < 0.75, (metric_growth, metric_p)
    assert metric_group < metric_group_before - 0.15, (metric_group_before, metric_group)
    # topological: the same 16 neighbours at any distance: it stays one aligned flock, no bigger than spread
    assert topo_growth < 1.15 and topo_p > 0.9, (topo_growth, topo_p)
    assert topo_group > metric_group + 0.15, (topo_group, metric_group)

"""Order parameters (cgp_core/boids/order.py) against closed forms: a parallel group, a perfect mill, lattices
of known spacing, random headings (the expected polarization of N random unit vectors); the nearest-neighbour
distances against scipy's KD-tree — searched from scratch, and taken from a neighbour list built before the
boids moved (the step's own list, as the node's stats use it), including stragglers, flat flocks, a flock
moved as a whole and a periodic box."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from cgp_core.boids import Flock, FlockParams, make_search
from cgp_core.boids import order as order_module
from cgp_core.boids.order import classify, flock_order, nearest_neighbor_distances


def polarization(headings: np.ndarray) -> float:
    return flock_order(np.random.default_rng(0).random(headings.shape), headings).polarization


def test_parallel_group_is_fully_polarized_and_not_milling():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(50, 3))
    v = np.tile([0.0, 2.0, 0.0], (50, 1))
    order = flock_order(x, v)
    assert order.polarization == pytest.approx(1.0, abs=1e-12)
    assert order.milling < 0.2  # r̂ × v̂ of a random cloud averages out
    assert order.mean_speed == order.min_speed == order.max_speed == pytest.approx(2.0)
    np.testing.assert_allclose(order.centroid, x.mean(axis=0))


def test_perfect_mill_has_milling_one_and_no_polarization():
    n = 64
    angle = 2 * np.pi * np.arange(n) / n
    radius = 5.0
    x = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.full(n, 3.0)], axis=1)
    v = np.stack([-np.sin(angle), np.cos(angle), np.zeros(n)], axis=1) * 1.5  # tangential: a ring swimming round
    order = flock_order(x, v)
    assert order.milling == pytest.approx(1.0, abs=1e-12)
    assert order.polarization == pytest.approx(0.0, abs=1e-12)
    assert order.radius_of_gyration == pytest.approx(radius)
    # neighbours on the ring: chord 2 r sin(π / n)
    assert order.mean_nearest_neighbor_distance == pytest.approx(2 * radius * math.sin(math.pi / n))
    assert classify(order.polarization, order.milling) == "milling"


def test_radius_of_gyration_and_nearest_neighbour_of_a_lattice():
    spacing = 0.7
    grid = np.arange(5) * spacing
    x = np.array(np.meshgrid(grid, grid, grid, indexing="ij")).reshape(3, -1).T
    order = flock_order(x, np.tile([1.0, 0, 0], (len(x), 1)))
    # per axis the variance of 5 equally spaced values is 2 spacing²
    assert order.radius_of_gyration == pytest.approx(math.sqrt(3 * 2 * spacing**2))
    assert order.mean_nearest_neighbor_distance == pytest.approx(spacing)


@pytest.mark.parametrize("dimensions, expected", [
    (3, lambda n: math.sqrt(8.0 / (3.0 * math.pi * n))),  # |Σ| of N random 3D unit vectors: Maxwell, mean 2a√(2/π)
    (2, lambda n: math.sqrt(math.pi) / (2.0 * math.sqrt(n))),  # Vicsek 1995's 2D value: Rayleigh mean
])
def test_random_headings_give_the_expected_polarization(dimensions, expected):
    n, samples = 300, 4000
    rng = np.random.default_rng(7)
    values = []
    for _ in range(samples):
        h = rng.normal(size=(n, 3))
        if dimensions == 2:
            h[:, 2] = 0.0
        values.append(polarization(h))  # headings are the velocities' directions: unit or not
    # standard error of the mean ≈ 0.42 · p / sqrt(samples): 0.0004; 5 standard errors
    assert np.mean(values) == pytest.approx(expected(n), abs=0.002)
    if dimensions == 2:
        assert expected(n) == pytest.approx(0.051, abs=0.0005)  # the literature's figure at N = 300


def test_classification_uses_tunstrom_thresholds():
    assert classify(0.9, 0.1) == "polarized"
    assert classify(0.1, 0.9) == "milling"
    assert classify(0.2, 0.2) == "swarm"
    assert classify(0.5, 0.5) == "transitional"
    assert classify(0.66, 0.34) == "polarized" and classify(0.64, 0.34) == "transitional"


def cloud(case: str) -> np.ndarray:
    rng = np.random.default_rng(3)
    if case == "uniform":
        x = rng.random((2000, 3)) * [60, 60, 30]
    elif case == "clustered":
        x = np.concatenate([rng.normal(c, 0.5, size=(300, 3)) for c in ([0, 0, 0], [20, 5, 3], [-8, 30, 1])])
    elif case == "straggler":
        x = rng.normal(size=(1500, 3))
        x[0] = [500.0, 0.0, 0.0]
    elif case == "flat":
        x = rng.random((1000, 3)) * [30, 30, 0]
    elif case == "duplicates":
        x = np.repeat(rng.random((100, 3)), 2, axis=0)
    else:
        x = rng.random((2, 3))
    return x


CASES = ["uniform", "clustered", "straggler", "flat", "duplicates", "tiny"]


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("brute_force_pairs", [order_module.BRUTE_FORCE_PAIRS, 0])  # all pairs, or the KD-tree
def test_nearest_neighbours_from_scratch_match_the_kd_tree(case, brute_force_pairs, monkeypatch):
    monkeypatch.setattr(order_module, "BRUTE_FORCE_PAIRS", brute_force_pairs)
    x = cloud(case)
    reference = cKDTree(x).query(x, k=2)[0][:, 1]
    np.testing.assert_allclose(nearest_neighbor_distances(x), reference, rtol=0, atol=1e-12)


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("search", ["grid", "kdtree", "brute"])
@pytest.mark.parametrize("move", ["small", "a few jump", "whole flock"])
def test_nearest_neighbours_from_an_older_neighbour_list_are_exact(case, search, move, monkeypatch):
    """The list was built within d before every boid moved by up to 0.05 (a step), before that and a few boids
    were thrown 1-3 m (pushed out of a body: they are checked against every row), or before the flock was moved
    3 m as a whole (every row then fails the proof and is searched again): the distances are the exact nearest
    neighbours now, whether they come from the rows or from the search."""
    x = cloud(case)
    radius = 1.5 * float(np.median(cKDTree(x).query(x, k=2)[0][:, 1])) + 0.2
    neighbors = make_search(search).neighbors(x, radius)
    rng = np.random.default_rng(8)
    now = x + (rng.uniform(-0.029, 0.029, size=x.shape) if move != "whole flock" else np.array([3.0, -1.0, 0.5]))
    if move == "a few jump":
        thrown = rng.choice(len(x), size=min(5, len(x)), replace=False)
        now[thrown] += rng.uniform(1.0, 3.0, size=(len(thrown), 3)) * rng.choice([-1.0, 1.0], size=(len(thrown), 3))
    reference = cKDTree(now).query(now, k=2)[0][:, 1]
    # the kernel's own search of the undecided (all pairs, small jobs) ...
    got = nearest_neighbor_distances(now, None, neighbors, x, radius, 0.051)
    np.testing.assert_allclose(got, reference, rtol=0, atol=1e-12)
    # ... and the KD-tree, counting whom the rows could not decide
    searched = []
    tree = order_module._nearest_by_tree
    monkeypatch.setattr(order_module, "BRUTE_FORCE_PAIRS", 0)
    monkeypatch.setattr(order_module, "_nearest_by_tree", lambda q, *a: searched.append(len(q)) or tree(q, *a))
    got = nearest_neighbor_distances(now, None, neighbors, x, radius, 0.051)
    np.testing.assert_allclose(got, reference, rtol=0, atol=1e-12)
    again = sum(searched)
    if move == "whole flock":
        assert again == len(x)
    elif case != "tiny":
        assert again < 0.5 * len(x), again  # most rows decide it, jumpers or not
        assert case not in ("straggler", "uniform") or again > 0  # the far ones are searched again


def test_nearest_neighbours_in_a_periodic_box_are_minimum_images():
    box = np.array([4.0, 5.0, 3.0])
    rng = np.random.default_rng(4)
    x = rng.random((300, 3)) * box
    x[0] = [0.01, 2.0, 1.0]
    x[1] = [3.98, 2.0, 1.0]  # 0.03 apart across the wall
    reference = cKDTree(x, boxsize=box).query(x, k=2)[0][:, 1]
    neighbors = make_search("grid").neighbors(x, 0.5, box)
    for got in (nearest_neighbor_distances(x, box), nearest_neighbor_distances(x, box, neighbors, x, 0.5)):
        np.testing.assert_allclose(got, reference, rtol=0, atol=1e-12)
    assert got[0] == pytest.approx(0.03)


def test_a_flock_reports_its_order_from_its_last_step():
    """Flock.order after a step (the rows of the step's list) equals the order parameters from scratch."""
    flock = Flock(FlockParams(count=600, seed=2))
    for _ in range(30):
        flock.step(1 / 60)
    got = flock.order()
    reference = flock_order(flock.positions.copy(), flock.velocities.copy())
    assert got.mean_nearest_neighbor_distance == pytest.approx(reference.mean_nearest_neighbor_distance, abs=1e-12)
    assert got.polarization == reference.polarization and got.milling == reference.milling
    x = flock.positions
    nearest = cKDTree(x).query(x, k=2)[0][:, 1].mean()
    assert got.mean_nearest_neighbor_distance == pytest.approx(nearest, rel=1e-12)


def test_milling_ignores_a_boid_at_the_centroid():
    x = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0.0, 0, 0]])
    v = np.array([[0, 1.0, 0], [0, -1.0, 0], [0, 0, 1.0]])
    assert flock_order(x, v).milling == pytest.approx(2.0 / 3.0)

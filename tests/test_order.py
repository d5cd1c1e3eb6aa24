"""Order parameters (cgp_core/boids/order.py) against closed forms: a parallel group, a perfect mill, lattices
of known spacing, random headings (the expected polarization of N random unit vectors), and the nearest-
neighbour grid kernel against scipy's KD-tree, including stragglers and flat flocks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from cgp_core.boids.order import classify, flock_order, milling, nearest_neighbor_distances, polarization


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
        h = rng.normal(size=(3, n))
        if dimensions == 2:
            h[2] = 0.0
        h /= np.linalg.norm(h, axis=0)
        values.append(polarization(h))
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


@pytest.mark.parametrize("case", ["uniform", "clustered", "straggler", "flat", "duplicates", "tiny"])
def test_grid_nearest_neighbours_match_the_kd_tree(case):
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
    reference = cKDTree(x).query(x, k=2)[0][:, 1]
    np.testing.assert_allclose(nearest_neighbor_distances(x.T), reference, rtol=0, atol=1e-12)


def test_milling_ignores_a_boid_at_the_centroid():
    x = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0.0, 0, 0]])
    v = np.array([[0, 1.0, 0], [0, -1.0, 0], [0, 0, 1.0]])
    assert milling(x.T, v.T) == pytest.approx(2.0 / 3.0)

"""Neighbour search: the grid and the KD-tree find exactly the pairs the brute-force reference finds, on
random and awkward point sets, across reused candidate lists, in periodic boxes; and a flock steps the same
whatever the backend."""

from __future__ import annotations

import numpy as np
import pytest

from cgp_core.boids import BruteForceSearch, Flock, FlockParams, GridSearch, KDTreeSearch, make_search
from cgp_core.boids.neighbors import pair_offsets, periodic_images


def _points(array) -> np.ndarray:
    """(3, W) float32 work coordinates from an (N, 3) array."""
    return np.ascontiguousarray(np.asarray(array, dtype=np.float32).T)


def _reference_pairs(points: np.ndarray, radius: float) -> np.ndarray:
    """All pairs (a < b) with float32 r² < radius², by a plain double loop over numpy rows (independent of
    the backends' code, same arithmetic as the shared formula)."""
    xyz = points.T
    found = []
    r2max = np.float32(radius * radius)
    for a in range(len(xyz)):
        d = xyz[a + 1:] - xyz[a]
        r2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
        for b in np.flatnonzero(r2 < r2max):
            found.append((a, a + 1 + b))
    return np.array(found, dtype=np.int64).reshape(-1, 2)


def _check_contract(pairs, points, radius):
    """i < j, i sorted, rows = shared formula, all within the radius."""
    assert np.all(pairs.i < pairs.j)
    assert np.all(np.diff(pairs.i) >= 0)
    ordered = points[:, pairs.order]
    np.testing.assert_array_equal(pairs.rows, pair_offsets(ordered, pairs.i, pairs.j))
    assert np.all(pairs.dist2 < np.float32(radius * radius))
    assert sorted(pairs.order.tolist()) == list(range(points.shape[1]))


CLOUDS = {
    "uniform": lambda rng: rng.uniform(0.0, 12.0, (700, 3)),
    "clustered": lambda rng: np.concatenate([c + rng.normal(0.0, 0.8, (150, 3))
                                             for c in rng.uniform(-20, 20, (4, 3))]),
    "plane": lambda rng: np.column_stack((rng.uniform(0, 10, (500, 2)), np.full(500, 3.0))),
    "line_along_z": lambda rng: np.column_stack((np.zeros(300), np.zeros(300), rng.uniform(-5, 5, 300))),
    # a lattice of spacing exactly 1.0 with radius 1.0: every lattice neighbour sits on the boundary
    "lattice_on_boundary": lambda rng: np.stack(np.meshgrid(*[np.arange(6.0)] * 3), axis=-1).reshape(-1, 3),
    "duplicates": lambda rng: np.repeat(rng.uniform(0, 4, (80, 3)), 3, axis=0),
    "far_apart_sparse": lambda rng: rng.uniform(-5000.0, 5000.0, (400, 3)),
}


@pytest.mark.parametrize("cloud", sorted(CLOUDS))
@pytest.mark.parametrize("radius", [1.0, 2.5])
def test_grid_kdtree_brute_find_the_same_pairs(cloud, radius):
    rng = np.random.default_rng(sorted(CLOUDS).index(cloud))  # stable across runs (str hash is not)
    points = _points(CLOUDS[cloud](rng))
    expected = _reference_pairs(points, radius)
    for search in (GridSearch(), KDTreeSearch(), BruteForceSearch(block=97)):
        pairs = search.pairs(points, radius)
        _check_contract(pairs, points, radius)
        np.testing.assert_array_equal(pairs.point_pairs(), expected, err_msg=f"{search.name} on {cloud}")


def test_far_apart_cloud_uses_the_sparse_cell_lookup_and_still_agrees():
    """A cloud spread over 10 km with d = 1 has ~10¹² cells: the grid must switch to binary search."""
    rng = np.random.default_rng(3)
    points = _points(np.concatenate([rng.uniform(-5000, 5000, (300, 3)), rng.uniform(0, 3, (200, 3))]))
    grid = GridSearch()
    pairs = grid.pairs(points, 1.0)
    np.testing.assert_array_equal(pairs.point_pairs(), _reference_pairs(points, 1.0))
    assert pairs.count > 0


def test_reused_candidate_lists_stay_exact_while_points_move():
    """The grid re-tests its cached candidates between rebuilds; after every move (small jitter, a common
    drift of the whole cloud, occasional big jumps) its pairs must equal a fresh brute-force search, and the
    cache must actually be used (fewer builds than calls)."""
    rng = np.random.default_rng(7)
    xyz = rng.uniform(0.0, 10.0, (600, 3))
    velocity = rng.normal(0.0, 1.0, (600, 3))
    grid = GridSearch(skin_fraction=0.2)
    brute = BruteForceSearch()
    calls = 0
    for step in range(60):
        xyz += 0.01 * velocity + np.array([0.3, -0.1, 0.05])  # jitter + a large common drift
        if step % 17 == 16:
            xyz[rng.integers(0, 600, 5)] += rng.normal(0.0, 3.0, (5, 3))  # a few jump far
        points = _points(xyz)
        got = grid.pairs(points, 1.5)
        calls += 1
        _check_contract(got, points, 1.5)
        np.testing.assert_array_equal(got.point_pairs(), brute.pairs(points, 1.5).point_pairs(),
                                      err_msg=f"step {step}")
    assert grid.builds < calls / 3, f"candidate list rebuilt {grid.builds} times in {calls} calls"
    assert grid.builds > 3, "the jumps must have forced rebuilds"


def test_reuse_false_forgets_the_candidate_list():
    rng = np.random.default_rng(8)
    grid = GridSearch()
    a = _points(rng.uniform(0, 8, (300, 3)))
    b = _points(rng.uniform(0, 8, (300, 3)))  # different points, same count
    grid.pairs(a, 1.5)
    got = grid.pairs(b, 1.5, reuse=False)
    np.testing.assert_array_equal(got.point_pairs(), _reference_pairs(b, 1.5))


def test_periodic_images_give_the_minimum_image_neighbourhoods():
    """Ghost images + open-space search == brute force with the minimum-image convention (pairs within 1e-5
    of the radius are left out of the comparison: ghost coordinates are rounded to float32 separately)."""
    rng = np.random.default_rng(11)
    box = np.array([9.0, 7.0, 6.0])
    radius = 2.0
    xyz = rng.uniform(0.0, 1.0, (500, 3)) * box
    xyz[:20] = box * rng.choice([0.001, 0.999], (20, 3))  # corners and edges
    points, source = periodic_images(_points(xyz), box, radius)
    n = len(xyz)
    found = GridSearch().pairs(points, radius)
    a = source[found.order[found.i]]
    b = source[found.order[found.j]]
    real_end = (found.order[found.i] < n) | (found.order[found.j] < n)
    got = {(min(p, q), max(p, q)) for p, q, keep in zip(a, b, real_end) if keep}

    d = xyz[:, None, :] - xyz[None, :, :]
    d -= box * np.round(d / box)
    dist = np.sqrt((d * d).sum(axis=-1))
    upper = np.triu(np.ones((n, n), bool), k=1)
    expected = {tuple(p) for p in np.argwhere((dist < radius) & upper)}
    ambiguous = {tuple(p) for p in np.argwhere((np.abs(dist - radius) < 1e-5) & upper)}
    assert got - ambiguous == expected - ambiguous
    assert any(abs(xyz[p, 0] - xyz[q, 0]) > box[0] / 2 for p, q in expected), "no pair wraps: weak test"


@pytest.mark.parametrize("bounds_mode", ["soft", "wrap"])
def test_flock_steps_the_same_with_every_backend(bounds_mode):
    """Same seed, same rules: the three backends give the same trajectories (to float32 summation order)."""
    common = dict(count=250, seed=5, bounds_mode=bounds_mode, spawn_center=[0, 0, 5], spawn_extent=[8, 8, 4],
                  bounds_min=[-6, -6, 0.5], bounds_max=[6, 6, 10])
    flocks = {name: Flock(FlockParams(neighbor_search=name, **common)) for name in ("grid", "kdtree", "brute")}
    for _ in range(40):
        for flock in flocks.values():
            flock.step(1.0 / 60.0)
    reference = flocks["brute"]
    for name in ("grid", "kdtree"):
        np.testing.assert_allclose(flocks[name].positions, reference.positions, rtol=0, atol=1e-4, err_msg=name)
        np.testing.assert_allclose(flocks[name].velocities, reference.velocities, rtol=0, atol=1e-3, err_msg=name)
    assert reference.mean_neighbors > 3.0, "the flock must actually interact"


def test_bad_input_is_rejected_with_a_clear_error():
    grid = GridSearch()
    with pytest.raises(ValueError, match="shape"):
        grid.pairs(np.zeros((5, 3), np.float32), 1.0)
    with pytest.raises(ValueError, match="float32"):
        grid.pairs(np.zeros((3, 5)), 1.0)
    with pytest.raises(ValueError, match="radius"):
        grid.pairs(np.zeros((3, 5), np.float32), 0.0)
    with pytest.raises(ValueError, match="neighbor_search"):
        make_search("octree")


def test_tiny_inputs():
    for search in (GridSearch(), KDTreeSearch(), BruteForceSearch()):
        assert search.pairs(np.zeros((3, 0), np.float32), 1.0).count == 0
        assert search.pairs(np.zeros((3, 1), np.float32), 1.0).count == 0
        two = search.pairs(_points([[0, 0, 0], [0.5, 0, 0]]), 1.0)
        assert two.point_pairs().tolist() == [[0, 1]]
        np.testing.assert_allclose(np.abs(two.offset[:, 0]), [0.5, 0, 0])

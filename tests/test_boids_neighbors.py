"""Neighbour search: the grid and the KD-tree find exactly the neighbours the brute-force reference finds, on
random and awkward point sets, in periodic boxes, while the points move and the flock gets denser than the
grid's rows have room for; and a flock steps the same whatever the backend."""

from __future__ import annotations

import numpy as np
import pytest

from cgp_core.boids import BruteForceSearch, Flock, FlockParams, GridSearch, KDTreeSearch, make_search

BACKENDS = (GridSearch, KDTreeSearch, BruteForceSearch)


def _points(array) -> np.ndarray:
    """(N, 3) float64 positions."""
    return np.ascontiguousarray(np.asarray(array, dtype=np.float64).reshape(-1, 3))


def _reference_pairs(points: np.ndarray, radius: float, period=None) -> np.ndarray:
    """All pairs (a < b) with r² = (dx² + dy²) + dz² < radius² (minimum image in a periodic box), by a plain
    loop over numpy rows — independent of the backends' code, same arithmetic as the shared formula."""
    found = []
    for a in range(len(points)):
        d = points[a + 1:] - points[a]
        if period is not None:
            period = np.asarray(period, dtype=float)
            d -= period * np.floor(d / period + 0.5)
        r2 = (d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2]
        for b in np.flatnonzero(r2 < radius * radius):
            found.append((a, a + 1 + b))
    return np.array(found, dtype=np.int64).reshape(-1, 2)


def _check_contract(neighbors, n):
    """Slots are a permutation of the boids; no boid is its own neighbour; every pair is in both rows."""
    assert sorted(neighbors.order.tolist()) == list(range(n))
    rows = {}
    for slot in range(n):
        row = neighbors.index[neighbors.start[slot]:neighbors.start[slot] + neighbors.count[slot]]
        assert slot not in row.tolist(), "a boid is its own neighbour"
        assert len(set(row.tolist())) == len(row), "a neighbour listed twice"
        rows[slot] = set(row.tolist())
    assert all(slot in rows[other] for slot in rows for other in rows[slot]), "rows are not symmetric"


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
def test_grid_kdtree_brute_find_the_same_neighbours(cloud, radius):
    rng = np.random.default_rng(sorted(CLOUDS).index(cloud))  # stable across runs (str hash is not)
    points = _points(CLOUDS[cloud](rng))
    expected = _reference_pairs(points, radius)
    for search in (GridSearch(), KDTreeSearch(), BruteForceSearch()):
        neighbors = search.neighbors(points, radius)
        _check_contract(neighbors, len(points))
        np.testing.assert_array_equal(neighbors.pairs(), expected, err_msg=f"{search.name} on {cloud}")
        assert neighbors.total == 2 * len(expected)


def test_far_apart_cloud_uses_the_sparse_cell_lookup_and_still_agrees():
    """A cloud spread over 10 km with d = 1 has ~10¹² cells: the grid must switch to binary search."""
    rng = np.random.default_rng(3)
    points = _points(np.concatenate([rng.uniform(-5000, 5000, (300, 3)), rng.uniform(0, 3, (200, 3))]))
    neighbors = GridSearch().neighbors(points, 1.0)
    np.testing.assert_array_equal(neighbors.pairs(), _reference_pairs(points, 1.0))
    assert neighbors.total > 0


def test_moving_points_and_a_flock_denser_than_the_rows_have_room_for():
    """One grid searched again and again (its buffers are kept between calls) while the points jitter, drift
    as a whole, jump, and finally collapse into a clump far denser than the rows' initial room: every call
    must equal a fresh brute-force search, and the rows must have grown."""
    rng = np.random.default_rng(7)
    xyz = rng.uniform(0.0, 10.0, (600, 3))
    velocity = rng.normal(0.0, 1.0, (600, 3))
    grid = GridSearch()
    brute = BruteForceSearch()
    room = grid._capacity
    for step in range(40):
        xyz += 0.01 * velocity + np.array([0.3, -0.1, 0.05])  # jitter + a large common drift
        if step % 17 == 16:
            xyz[rng.integers(0, 600, 5)] += rng.normal(0.0, 3.0, (5, 3))  # a few jump far
        if step >= 30:
            xyz = xyz.mean(axis=0) + 0.5 * (xyz - xyz.mean(axis=0))  # the cloud collapses
        points = _points(xyz)
        got = grid.neighbors(points, 1.5)
        _check_contract(got, len(points))
        np.testing.assert_array_equal(got.pairs(), brute.neighbors(points, 1.5).pairs(), err_msg=f"step {step}")
    assert got.count.max() > room, "the clump must have needed more room than the rows had"
    assert grid._capacity > room


def test_a_clump_gets_exactly_sized_rows():
    """Hundreds of boids within d of each other (a flock spawned in a point) would make every row that long
    in the uniform layout: past its limit the grid sizes the rows exactly, and finds the same neighbours."""
    rng = np.random.default_rng(12)
    points = _points(np.concatenate([np.zeros((300, 3)), rng.uniform(-0.2, 0.2, (200, 3)),
                                     rng.uniform(-30, 30, (2000, 3))]))
    grid = GridSearch()
    got = grid.neighbors(points, 1.0)
    _check_contract(got, len(points))
    np.testing.assert_array_equal(got.pairs(), BruteForceSearch().neighbors(points, 1.0).pairs())
    assert got.count.max() >= 499 and grid._capacity > GridSearch.MAX_UNIFORM_CAPACITY
    assert len(got.index) < 2 * got.total + len(points), "rows sized exactly, not N x the largest"
    again = grid.neighbors(points + 0.01, 1.0)  # and it stays exact while the clump lasts
    np.testing.assert_array_equal(again.pairs(), BruteForceSearch().neighbors(points + 0.01, 1.0).pairs())


def test_completed_rows_do_not_depend_on_how_many_parts_append_them():
    """The grid's last stage appends each half-shell pair to the other boid's row, split into one part per
    thread by receiving row.  Whatever the number of parts, every row must be what one sequential walk gives:
    its own forward entries, then each earlier-walked slot that listed it, in slot order — including forward
    entries that point to *earlier* slots (a periodic box wraps the last columns onto the first) — and a row
    without room must be reported for every split."""
    from cgp_core.boids.neighbors import _complete_rows

    rng = np.random.default_rng(21)
    n = 400
    forward = rng.integers(0, 9, n)
    forward_index = np.concatenate([rng.choice(np.delete(np.arange(n), s), size=k, replace=False)
                                    for s, k in enumerate(forward)]).astype(np.int32)
    forward_start = np.concatenate([[0], np.cumsum(forward)[:-1]]).astype(np.int64)
    # the reference, written from the definition
    rows = [list(forward_index[forward_start[s]:forward_start[s] + forward[s]]) for s in range(n)]
    for s in range(n):
        for t in forward_index[forward_start[s]:forward_start[s] + forward[s]]:
            rows[t].append(s)
    room = np.full(n, max(len(r) for r in rows), np.int64)
    start = np.arange(n, dtype=np.int64) * room[0]
    for parts in (1, 2, 3, 7):
        count = np.empty(n, np.int64)
        index = np.full(n * room[0], -1, np.int32)
        assert _complete_rows(forward_start, forward, forward_index, start, room, count, index, parts)
        got = [list(index[start[s]:start[s] + count[s]]) for s in range(n)]
        assert got == rows, f"{parts} parts"
        tight = room.copy()
        tight[int(np.argmax([len(r) for r in rows]))] -= 1  # one row one entry short
        assert not _complete_rows(forward_start, forward, forward_index, start, tight, np.empty(n, np.int64),
                                  np.full(n * room[0], -1, np.int32), parts), f"{parts} parts: overflow unseen"


@pytest.mark.parametrize("box", [[9.0, 7.0, 6.0], [4.5, 30.0, 5.0]])
def test_periodic_boxes_give_the_minimum_image_neighbourhoods(box):
    """Every backend in a periodic box == brute force with the minimum-image convention (the second box has
    sides of 2-3 radii: one or two columns of cells along them)."""
    rng = np.random.default_rng(11)
    box = np.array(box)
    radius = 2.0
    xyz = rng.uniform(0.0, 1.0, (500, 3)) * box
    xyz[:20] = box * rng.choice([0.001, 0.999], (20, 3))  # corners and edges
    points = _points(xyz)
    expected = _reference_pairs(points, radius, box)
    for search in (GridSearch(), KDTreeSearch(), BruteForceSearch()):
        neighbors = search.neighbors(points, radius, box)
        _check_contract(neighbors, len(points))
        np.testing.assert_array_equal(neighbors.pairs(), expected, err_msg=search.name)
    assert any(abs(xyz[p, 0] - xyz[q, 0]) > box[0] / 2 for p, q in expected), "no pair wraps: weak test"


@pytest.mark.parametrize("bounds_mode", ["soft", "wrap"])
def test_flock_steps_the_same_with_every_backend(bounds_mode):
    """Same seed, same rules, the same neighbour sets: the three backends give the same trajectories (up to
    the round-off of the order the rules sum in)."""
    common = dict(count=250, seed=5, bounds_mode=bounds_mode, spawn_center=[0, 0, 5], spawn_extent=[8, 8, 4],
                  bounds_min=[-6, -6, 0.5], bounds_max=[6, 6, 10])
    flocks = {name: Flock(FlockParams(neighbor_search=name, **common)) for name in ("grid", "kdtree", "brute")}
    for _ in range(40):
        for flock in flocks.values():
            flock.step(1.0 / 60.0)
    reference = flocks["brute"]
    for name in ("grid", "kdtree"):
        np.testing.assert_allclose(flocks[name].positions, reference.positions, rtol=0, atol=1e-9, err_msg=name)
        np.testing.assert_allclose(flocks[name].velocities, reference.velocities, rtol=0, atol=1e-8, err_msg=name)
    assert reference.mean_neighbors > 3.0, "the flock must actually interact"


def test_bad_input_is_rejected_with_a_clear_error():
    grid = GridSearch()
    with pytest.raises(ValueError, match="shape"):
        grid.neighbors(np.zeros((3, 5)), 1.0)
    with pytest.raises(ValueError, match="float64"):
        grid.neighbors(np.zeros((5, 3), np.float32), 1.0)
    with pytest.raises(ValueError, match="radius"):
        grid.neighbors(np.zeros((5, 3)), 0.0)
    with pytest.raises(ValueError, match="2 \\* radius"):
        grid.neighbors(np.zeros((5, 3)), 1.0, period=[10.0, 1.5, 10.0])
    with pytest.raises(ValueError, match="neighbor_search"):
        make_search("octree")


def test_tiny_inputs():
    for search in (GridSearch(), KDTreeSearch(), BruteForceSearch()):
        assert search.neighbors(np.zeros((0, 3)), 1.0).total == 0
        assert search.neighbors(np.zeros((1, 3)), 1.0).total == 0
        two = search.neighbors(_points([[0, 0, 0], [0.5, 0, 0]]), 1.0)
        assert two.pairs().tolist() == [[0, 1]]
        assert two.of(0).tolist() == [1] and two.of(1).tolist() == [0]

"""Broad phase: the spatial structures find exactly the pairs the brute-force AABB test finds."""

import warnings

import numpy as np
import pytest

from cgp_core.collision.broadphase import (
    BROAD_PHASES,
    LARGE_FACTOR,
    brute_force_pairs,
    cell_edge,
    get_broad_phase,
    grid_pairs,
    sweep_and_prune_pairs,
)


def random_boxes(rng, n, *, world=5.0, small=(0.02, 0.3), large_fraction=0.05, large=(1.0, 4.0)):
    """Mixed sizes: mostly small boxes, a few large ones (walls), some of them flat (zero thickness)."""
    centre = rng.uniform(-world / 2, world / 2, size=(n, 3))
    half = rng.uniform(*small, size=(n, 3)) / 2
    big = rng.random(n) < large_fraction
    half[big] = rng.uniform(*large, size=(int(big.sum()), 3)) / 2
    flat = rng.random(n) < 0.05
    half[flat, 2] = 0.0
    return centre - half, centre + half


def as_set(pairs):
    i, j = pairs
    assert np.all(i < j), "pairs must be reported as i < j"
    return set(zip(i.tolist(), j.tolist()))


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("n", [2, 37, 400])
def test_structures_find_the_brute_force_pairs(seed, n):
    rng = np.random.default_rng(seed)
    lo, hi = random_boxes(rng, n)
    reference = brute_force_pairs(lo, hi)
    assert len(as_set(reference)) == len(reference[0])  # each pair once
    for name in ("grid", "sweep_and_prune"):
        found = BROAD_PHASES[name](lo, hi)
        assert as_set(found) == as_set(reference), name
        # canonical order too: sorted by (i, j)
        assert np.array_equal(found[0], reference[0]) and np.array_equal(found[1], reference[1]), name


def test_dense_pile_and_explicit_cell_sizes():
    """A dense pile of equal spheres' boxes (the benchmark's case) and cell sizes smaller than the boxes
    (everything takes the 'large' path) or much larger (few cells) all agree with brute force."""
    rng = np.random.default_rng(7)
    centre = rng.uniform([-1, -1, 0], [1, 1, 0.5], size=(500, 3))
    lo, hi = centre - 0.1, centre + 0.1
    reference = as_set(brute_force_pairs(lo, hi))
    assert len(reference) > 1000
    for cell in (None, 0.05, 0.2, 1.3, 10.0):
        assert as_set(grid_pairs(lo, hi, cell_size=cell)) == reference, cell


def test_touching_boxes_overlap_and_a_gap_does_not():
    lo = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0 + 1e-9, 0, 0], [0.0, 1.0, 1.0]])
    hi = lo + 1.0
    # 0-1 touch along x (lo1 == hi0); 1-2 separated by 1e-9; 0-3 touch along the edge y = z = 1
    expected = {(0, 1), (0, 3), (1, 3)}
    for name, fn in BROAD_PHASES.items():
        assert as_set(fn(lo, hi)) == expected, name


def test_exactly_one_cell_apart_lower_corners():
    """Two boxes of extent = cell size whose lower corners are exactly one cell apart touch: found."""
    lo = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.6000001, 0.0, 0.0]])
    hi = lo + 0.3
    assert as_set(grid_pairs(lo, hi, cell_size=0.3)) == {(0, 1)}


def test_degenerate_inputs():
    for fn in BROAD_PHASES.values():
        for p in (0, 1):
            i, j = fn(np.zeros((p, 3)), np.ones((p, 3)))
            assert i.size == 0 and j.size == 0
        # identical boxes all overlap
        assert as_set(fn(np.zeros((4, 3)), np.ones((4, 3)))) == {(a, b) for a in range(4) for b in range(a + 1, 4)}


def test_bad_input_is_named():
    with pytest.raises(ValueError, match=r"\(p, 3\)"):
        grid_pairs(np.zeros((3, 2)), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="finite"):
        sweep_and_prune_pairs(np.array([[0.0, np.nan, 0]]), np.ones((1, 3)))
    with pytest.raises(ValueError, match="cell size"):
        grid_pairs(np.zeros((3, 3)), np.ones((3, 3)), cell_size=-1.0)
    with pytest.raises(ValueError, match="unknown broad phase 'octree'; valid: brute_force, grid, sweep_and_prune"):
        get_broad_phase("octree")


def test_structures_agree_on_a_random_scene_of_mixed_shapes():
    """Spheres, boxes, capsules and particle bodies of mixed sizes, randomly placed and turned: the
    primitives' AABBs give the same overlapping pairs with every method."""
    from _bodies import box, capsule, make_bodies, particles, sphere

    from cgp_core.collision.primitives import build_collision_model, primitive_aabbs
    from cgp_core.rotation import quat_from_rotvec

    rng = np.random.default_rng(21)
    specs = []
    for i in range(300):
        position = rng.uniform(-2, 2, size=3)
        q = quat_from_rotvec(rng.normal(size=3))
        kind = i % 5
        if kind == 0:
            specs.append(sphere(rng.uniform(0.03, 0.3), position=position))
        elif kind == 1:
            specs.append(box(rng.uniform(0.02, 0.4, size=3), position=position, orientation=q))
        elif kind == 2:
            specs.append(capsule(rng.uniform(0.02, 0.1), rng.uniform(0.05, 0.5), position=position, orientation=q))
        elif kind == 3:
            pts = np.column_stack((rng.normal(size=(5, 3)) * 0.2, np.ones(5)))
            specs.append(particles(pts, radius=0.05, position=position, orientation=q))
        else:  # a few wall-sized slabs
            specs.append(box((rng.uniform(1, 2), 0.05, rng.uniform(0.5, 1)), fixed=True, position=position,
                             orientation=q))
    model, state = make_bodies(specs)
    cm = build_collision_model(model)
    lo, hi = primitive_aabbs(cm, state.position, state.rotation_matrices())
    assert cm.count > 300  # the particle bodies add primitives
    reference = as_set(brute_force_pairs(lo, hi))
    assert len(reference) > 100
    assert as_set(grid_pairs(lo, hi)) == reference
    assert as_set(sweep_and_prune_pairs(lo, hi)) == reference
    # grouped by body (as the collision detector calls them): exactly the pairs of two different bodies
    between_bodies = {(i, j) for i, j in reference if cm.body[i] != cm.body[j]}
    assert len(between_bodies) < len(reference)  # the particle bodies' own particles overlap
    for name, pairs in BROAD_PHASES.items():
        assert as_set(pairs(lo, hi, group=cm.body)) == between_bodies, name
    with pytest.raises(ValueError, match="group must be"):
        grid_pairs(lo, hi, group=cm.body[:-1])


@pytest.mark.parametrize("broad_phase", sorted(BROAD_PHASES))
def test_every_broad_phase_keeps_a_particle_bodys_own_particles_apart(broad_phase):
    """A pile of particle bodies whose particles overlap each other (the lecture's discrete bodies): whichever
    broad phase the detector is given, it hands over no pair of one body's own particles (the grid and brute
    force used to: candidates the narrow phase then threw away, O(k²) of them for a body of k particles under
    brute force), and the contacts are the default's."""
    from _bodies import make_bodies, particles

    from cgp_core.collision.detector import SMALL_SCENE, CollisionDetector
    from cgp_core.world import Ground

    rng = np.random.default_rng(3)
    offsets = np.array([(x, y, z) for x in range(3) for y in range(3) for z in range(2)], float) * 0.06
    grains = np.column_stack((offsets, np.ones(len(offsets))))  # 18 particles of r 0.05, 6 cm apart
    specs = [particles(grains, radius=0.05, position=(rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), 0.05 + 0.1 * k))
             for k in range(8)]
    model, state = make_bodies(specs)
    assert 18 * 8 > SMALL_SCENE  # the configured broad phase runs, not the small-scene path
    detector = CollisionDetector(broad_phase)
    handed_over = []

    def recorded(lo, hi, **kw):
        pairs = BROAD_PHASES[broad_phase](lo, hi, **kw)
        handed_over.append(pairs)
        return pairs

    if broad_phase != "sweep_and_prune":  # (the default is called as its compiled kernel, tested above)
        detector.broad_phase = recorded
    found = detector.detect(model, state, 1.0 / 240.0, ground=Ground())
    body = detector.collision_model(model).body
    for i, j in handed_over:
        assert len(i) > 0 and np.all(body[i] != body[j])
    reference = CollisionDetector("sweep_and_prune").detect(model, state, 1.0 / 240.0, ground=Ground())
    assert found.count > 8 and np.all(found.body_a != found.body_b)
    assert set(found.key.tolist()) == set(reference.key.tolist())


def test_primitive_aabbs_are_tight_bounds():
    """A turned box's AABB is the min / max of its corners; a capsule's that of its end spheres."""
    from _bodies import box, capsule, make_bodies

    from cgp_core.collision.primitives import build_collision_model, primitive_aabbs
    from cgp_core.rotation import quat_from_rotvec, quat_to_matrix

    rng = np.random.default_rng(5)
    q = quat_from_rotvec(rng.normal(size=3))
    model, state = make_bodies([box((0.3, 0.2, 0.1), position=(1, 2, 3), orientation=q),
                                capsule(0.05, 0.4, position=(-1, 0, 1), orientation=q)])
    cm = build_collision_model(model)
    lo, hi = primitive_aabbs(cm, state.position, state.rotation_matrices())
    Rq = quat_to_matrix(q)
    signs = np.array([(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    corners = np.array([1.0, 2, 3]) + (signs * [0.3, 0.2, 0.1]) @ Rq.T
    np.testing.assert_allclose(lo[0], corners.min(0), atol=1e-12)
    np.testing.assert_allclose(hi[0], corners.max(0), atol=1e-12)
    ends = np.array([-1.0, 0, 1]) + np.outer([-0.4, 0.4], Rq[:, 2])
    np.testing.assert_allclose(lo[1], ends.min(0) - 0.05, atol=1e-12)
    np.testing.assert_allclose(hi[1], ends.max(0) + 0.05, atol=1e-12)


def test_a_body_flung_far_away_does_not_break_the_grid():
    rng = np.random.default_rng(3)
    lo, hi = random_boxes(rng, 50, large_fraction=0.0)
    lo[0] += 1e9  # a million kilometres off along x: more cells than an int64 key can count
    hi[0] += 1e9
    lo[1] -= [3e8, 2e8, 1e8]
    hi[1] -= [3e8, 2e8, 1e8]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no integer overflow in the cell keys
        assert as_set(grid_pairs(lo, hi)) == as_set(brute_force_pairs(lo, hi))


def test_a_pile_too_dense_for_the_sweep_goes_to_the_grid_with_the_same_contacts():
    """A 12³ lattice of touching spheres: along any axis a slab of it holds ~300 boxes, so the sweep would test
    ~300 candidates per box (~1,000 at 10,000 spheres: 156 ms a call, the grid 29 ms).  The default broad phase
    gives up past SWEEP_TESTS_PER_BOX and the grid finds the pairs: the contacts are brute force's, a body whose
    state went NaN takes part in none, and a sparse scene keeps the sweep."""
    from _bodies import make_bodies, sphere

    from cgp_core.collision.detector import SWEEP_TESTS_PER_BOX, CollisionDetector
    from cgp_core.world import Ground

    side = 12
    lattice = np.array([(x, y, z) for x in range(side) for y in range(side) for z in range(side)], float)
    model, state = make_bodies([sphere(0.1, position=p) for p in lattice * 0.199 + [0, 0, 0.1]])
    state.position[5] = np.nan  # a blown-up body (World resets it after the tick)
    default = CollisionDetector()
    found = default.detect(model, state, 1.0 / 240.0, ground=Ground())
    assert default.dense and side ** 2 > SWEEP_TESTS_PER_BOX
    reference = CollisionDetector("brute_force").detect(model, state, 1.0 / 240.0, ground=Ground())
    assert found.count > 2.5 * side ** 3 and set(found.key.tolist()) == set(reference.key.tolist())
    assert 5 not in found.body_a and 5 not in found.body_b
    # the same spheres in one row: the sweep tests a candidate or two per box and keeps the scene
    model, state = make_bodies([sphere(0.1, position=(0.199 * k, 0, 0.1)) for k in range(side ** 3)])
    sparse = CollisionDetector()
    sparse.detect(model, state, 1.0 / 240.0, ground=Ground())
    assert not sparse.dense


@pytest.mark.parametrize("n", [1, 2, 3, 10, 11, 1000, 1001])
def test_grid_cell_is_the_largest_extent_within_the_factor_of_numpys_median(n):
    """The grid's cell edge (its median from a merge sort, not np.median): the largest extent no larger than
    LARGE_FACTOR × numpy's median, for odd and even counts, ties, and a heavy tail of sizes."""
    rng = np.random.default_rng(n)
    for extent in (rng.uniform(0.0, 1.0, n), np.round(rng.uniform(0.0, 3.0, n), 1), rng.lognormal(0.0, 2.0, n)):
        top = LARGE_FACTOR * np.median(extent)
        expected = max((e for e in extent if 0.0 < e <= top), default=1.0)
        assert cell_edge(extent) == expected

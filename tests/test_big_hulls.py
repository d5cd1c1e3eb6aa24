"""Issue 38's last row — hulls of many vertices (300 copies of a 1,000-vertex sphere hull on the ground): the costs
follow the contact, not the vertex count, and the answers are the brute-force ones.

- the hulls' exact bounds (:func:`tighten_hull_bounds`) and their ground manifolds (:func:`plane_hull_contacts`) climb
  the hull's edges from a warm start instead of turning every vertex: same bounds, same points, from any start;
- the ground manifold keeps the lowest vertex (a round hull rested on the rim of its cap, mm into the ground);
- the manifold LCP (:func:`solve_manifold_lcp`) tries the current active set first and enumerates only the subsets
  its w allows: the same λ as the plain enumeration, and a round hull resting on one of its 4 points costs one
  pseudo-inverse, not twelve;
- copies of one hull share one entry of the shape model's hull set.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cgp_core import World, parse_scene
from cgp_core.collision.convex import HullSet, PosedHull, convex_hull
from cgp_core.collision.convex_phase import HULL, ShapePoses, tighten_hull_bounds
from cgp_core.collision.manifold import keep_deepest, plane_hull_contacts, reduce_to_four
from cgp_core.collision.narrowphase import ContactBuffer
from cgp_core.solver.manifold import SUBSETS, _subset_solves, solve_manifold_lcp


def sphere_hull(count=1000, radius=0.2, seed=7):
    p = np.random.default_rng(seed).normal(size=(count, 3))
    return convex_hull(p * (radius / np.linalg.norm(p, axis=1)[:, None]))


def posed(h, position, R):
    return PosedHull(h.vertices, h.adjacency_start, h.adjacency, h.face_plane, h.face_vertex_start, h.face_vertices,
                     np.asarray(position, float), np.asarray(R, float))


def buffer(rows=64):
    return ContactBuffer(np.empty((rows, 3)), np.empty(rows), np.empty((rows, 3)), np.empty(rows, np.int64))


def turned(v, R, position=(0.0, 0.0, 0.0)):
    """position + R v per vertex, summed in the kernels' order (so the values are the same bits)."""
    return np.stack([position[r] + R[r, 0] * v[:, 0] + R[r, 1] * v[:, 1] + R[r, 2] * v[:, 2] for r in range(3)], 1)


def brute_force_ground(hull, position, R, margin):
    """plane_hull_contacts' points by its definition: every vertex below the margin, reduced to 4 (the deepest
    kept), in index order."""
    world = turned(hull.vertices, R, position)
    valid = world[:, 2] < margin
    if not valid.any():
        return np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64)
    X, Y = world[:, 0].copy(), world[:, 1].copy()
    hu = max(0.5 * (X[valid].max() - X[valid].min()), 1e-12)
    hv = max(0.5 * (Y[valid].max() - Y[valid].min()), 1e-12)
    deepest = int(np.flatnonzero(valid)[np.argmin(world[valid, 2])])
    reduce_to_four(X, Y, hu, hv, valid)
    keep_deepest(X, Y, world[:, 2].copy(), hu, hv, valid, deepest)
    index = np.flatnonzero(valid)
    return world[index], world[index, 2], index


@pytest.mark.parametrize("which", ["sphere", "lumpy"])
def test_the_ground_manifold_of_a_big_hull_is_the_brute_force_one_from_any_start(which):
    rng = np.random.default_rng(1)
    if which == "sphere":
        hull = sphere_hull()
    else:  # an uneven polytope: points on an ellipsoid with noise
        p = rng.normal(size=(400, 3))
        p = p / np.linalg.norm(p, axis=1)[:, None] * [0.3, 0.2, 0.1] * rng.uniform(0.9, 1.0, size=(400, 1))
        hull = convex_hull(p)
    k = len(hull.vertices)
    assert k > 100
    out = buffer()
    checked = 0
    for trial in range(40):
        R = Rotation.random(random_state=trial).as_matrix()
        lowest = (hull.vertices @ R.T)[:, 2].min()
        position = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), -lowest + rng.uniform(-0.003, 0.002)])
        margin = rng.uniform(0.0, 0.02)
        point, separation, feature = brute_force_ground(hull, position, R, margin)
        for start in (0, int(rng.integers(k)), k - 1):
            m = plane_hull_contacts(posed(hull, position, R), margin, start, out, 0)
            assert m == len(feature)
            np.testing.assert_array_equal(out.feature[:m], feature)
            np.testing.assert_array_equal(out.separation[:m], separation)
            np.testing.assert_array_equal(out.point[:m, :2], point[:, :2])
            checked += m
    assert checked > 100


def test_a_round_hull_keeps_its_lowest_vertex_and_rests_on_the_ground_not_in_it():
    """The diagonal extremes of a round hull's vertices below the margin are on the rim of that cap, up to the margin
    above its lowest vertex: with those 4 points alone, the hull sank until they touched (6 mm: the 300 hulls of
    issue 38; up to 14 mm in bench_convex_pile's pile).  The lowest vertex replaces the nearest of them."""
    hull = sphere_hull()
    out = buffer()
    rng = np.random.default_rng(8)
    for trial in range(20):
        R = Rotation.random(random_state=100 + trial).as_matrix()
        z = turned(hull.vertices, R)[:, 2]
        position = np.array([0.0, 0.0, -z.min() - rng.uniform(0.0, 0.004)])
        m = plane_hull_contacts(posed(hull, position, R), 0.004, 0, out, 0)
        assert m == 4 and int(np.argmin(z)) in out.feature[:m].tolist()
    points = sphere_hull().vertices.round(6).tolist()
    world = World(parse_scene(f"bodies:\n  - {{name: ball, shape: convex, points: {points}, mass: 1, "
                              "position: [0, 0, 0.25], orientation: [0.1, 0.2, 0.3, 0.927]}\n"))
    deepest = 0.0
    for _ in range(240):
        world.step()
        R = world.body_state.rotation_matrices()[0]
        deepest = max(deepest, -((world.body_model.hulls[0].vertices @ R.T)[:, 2].min()
                                 + world.body_state.position[0, 2]))
    assert deepest < 1e-3, deepest  # (was 6 mm; the solver's penetration slop is 0.5 mm)


def test_exact_bounds_of_big_hulls_by_hill_climbing_from_stale_starts():
    hulls = [sphere_hull(), sphere_hull(300, 0.1, seed=3), convex_hull(np.random.default_rng(2).normal(size=(60, 3)))]
    hull_set = HullSet.from_hulls(hulls)
    P = 9
    kind = np.full(P, HULL, np.int64)
    hull = np.arange(P, dtype=np.int64) % 3
    rng = np.random.default_rng(4)
    poses = ShapePoses(rng.normal(size=(P, 3)), Rotation.random(P, random_state=5).as_matrix(), np.zeros((P, 3)),
                       np.zeros((P, 3)), np.full(P, 0.01))
    extreme = rng.integers(0, 300, size=(P, 6)).astype(np.int64)  # stale warm starts
    pair = np.zeros(0, np.int64)
    for _ in range(3):
        poses.lo[:, 2] = -1.0  # all near the ground (as the cheap bound would have them)
        tighten_hull_bounds(kind, hull, tuple(hull_set), np.int64(0), tuple(poses), pair, pair, True, extreme)
        for k in range(P):
            x = turned(hulls[hull[k]].vertices, poses.rotation[k])
            np.testing.assert_array_equal(poses.lo[k], poses.centre[k] + x.min(0) - poses.margin[k])
            np.testing.assert_array_equal(poses.hi[k], poses.centre[k] + x.max(0) + poses.margin[k])
            if len(x) > 32:  # the extremes found are the vertices of the bounds
                for r in range(3):
                    assert x[extreme[k, 2 * r], r] == x[:, r].min()
                    assert x[extreme[k, 2 * r + 1], r] == x[:, r].max()
        # turned a little: the next bounds start from these extremes
        turn = Rotation.from_rotvec(rng.normal(size=(P, 3)) * 0.05)
        poses.rotation[:] = (Rotation.from_matrix(poses.rotation) * turn).as_matrix()


def enumerated(A, P, b, must):
    """The plain enumeration: the first subset in SUBSETS order that solves the LCP (no guesses)."""
    cache, cached, x = np.zeros((16, 4, 4)), np.zeros(16, bool), np.zeros(4)
    tol_w = 1e-9 * (np.abs(b[:P]).max() + 1e-12)
    for s in range(1 << P):
        if getattr(_subset_solves, "py_func", _subset_solves)(A, P, b, must, cache, cached, s, tol_w, x):
            return s, np.where(must, x, np.maximum(x, 0.0))
    return -1, None


def ground_block(points, com, inv_mass, inv_inertia):
    J = np.array([np.r_[0, 0, 1.0, np.cross(p - com, [0, 0, 1.0])] for p in points])
    M = np.zeros((6, 6))
    M[:3, :3] = inv_mass * np.eye(3)
    M[3:, 3:] = inv_inertia
    A = np.zeros((4, 4))
    A[:len(points), :len(points)] = J @ M @ J.T
    return A


def test_manifold_lcp_guesses_give_the_plain_enumerations_answer():
    rng = np.random.default_rng(11)
    agree = 0
    for trial in range(300):
        P = int(rng.integers(2, 5))
        # a ground manifold (rank ≤ 3: singular at 4 points, as a face is) or a general PSD block
        if trial % 2:
            points = np.c_[rng.normal(size=(P, 2)) * rng.choice([0.01, 0.1, 0.3]), np.zeros(P)]
            A = ground_block(points, np.array([0, 0, 0.2]), 1.0, np.diag(rng.uniform(5, 80, 3)))
        else:
            G = rng.normal(size=(P, int(rng.integers(1, P + 1))))
            A = np.zeros((4, 4))
            A[:P, :P] = G @ G.T
        b = np.zeros(4)
        b[:P] = rng.normal(size=P) * rng.choice([0.01, 1.0])
        must = np.zeros(4, bool)
        if trial % 7 == 0:
            must[0] = True
        s_ref, x_ref = enumerated(A, P, b, must)
        for guess in range(1 << P):
            cache, cached, x = np.zeros((16, 4, 4)), np.zeros(16, bool), np.zeros(4)
            ok = solve_manifold_lcp(A, P, b, must, cache, cached, guess, x)
            assert ok == (s_ref >= 0), (trial, guess)
            if ok:
                np.testing.assert_array_equal(x[:P], x_ref[:P])
                agree += 1
    assert agree > 1000


def test_a_round_hull_resting_on_one_of_its_four_points_costs_one_pseudo_inverse():
    """The ground manifold of a 1,000-vertex sphere hull: 4 points a few cm apart (distinct: not near-duplicates),
    resting on one, the three others speculative (mm up).  The answer is that point alone — the 12th subset of the
    plain enumeration, which computed 12 pseudo-inverses a sub-step per hull to get there; with the active set as
    the guess, one."""
    hull = sphere_hull()
    R = Rotation.from_rotvec([0.3, -0.2, 0.1]).as_matrix()
    lowest = (hull.vertices @ R.T)[:, 2].min()
    position = np.array([0.0, 0.0, -lowest - 2e-4])
    out = buffer()
    m = plane_hull_contacts(posed(hull, position, R), 0.004, 0, out, 0)
    assert m == 4
    points = out.point[:m].copy()
    assert np.linalg.norm(points[:, None, :2] - points[None, :, :2], axis=2)[np.triu_indices(4, 1)].min() > 5e-3
    A = ground_block(points, position, 1.0, np.eye(3) * 63.0)
    assert np.linalg.matrix_rank(A, 1e-9) == 3  # singular as any 4 ground points, not worse
    # the hull settled until the first of these points touched (the others a few mm up)
    separation = out.separation[:m] - out.separation[:m].min() - 1e-4
    h = 1 / 240
    b = -9.81 * h + np.maximum(separation, 0.0) / h  # velocity minus target at λ = 0
    touching = int(np.argmin(separation))
    must = np.zeros(4, bool)
    s_ref, x_ref = enumerated(A, 4, b, must)
    assert SUBSETS[4, s_ref] == 1 << touching and s_ref >= 11
    for guess in (1 << touching, 0):  # the last update's active set; λ = 0 (the position stage's start)
        cache, cached, x = np.zeros((16, 4, 4)), np.zeros(16, bool), np.zeros(4)
        assert solve_manifold_lcp(A, 4, b, must, cache, cached, guess, x)
        np.testing.assert_array_equal(x, x_ref)
        assert cached.sum() == (1 if guess else 2)  # (λ = 0: the empty set fails, the approaching point solves)


def test_copies_of_a_hull_share_one_entry_of_the_shape_model():
    points = np.random.default_rng(5).normal(size=(50, 3)).round(4).tolist()
    other = (np.random.default_rng(6).normal(size=(40, 3)) * 0.5).round(4).tolist()
    bodies = [f"  - {{name: c{k}, shape: convex, points: {points}, position: [{k}, 0, 1]}}" for k in range(3)]
    bodies.append(f"  - {{name: d, shape: convex, points: {other}, position: [5, 0, 1]}}")
    world = World(parse_scene("bodies:\n" + "\n".join(bodies) + "\n"))
    shapes = world.solver.detector.shape_model(world.body_model)
    hulls = shapes.primitives.hull[shapes.primitives.kind == HULL]
    assert len(hulls) == 4 and len(set(hulls[:3].tolist())) == 1 and hulls[3] != hulls[0]
    assert shapes.hulls.count == 2

"""Issue 38, static meshes the hostile way: a BVH's depth is bounded by construction whatever the coordinates (row
D1: a tree 327 levels deep overflowed its 256-entry traversal stack, "double free or corruption"), its SAH bins
are in bounds for any float, the active edges of a big mesh are cheap (row D2: 55 s for 500,000 triangles) and
equal a plain per-edge reference.

The "within a bound" test guards against the slow pass coming back: its bound is ~15x what it takes (the old code
took over a minute); the figures are benchmarks/bench_mesh.py's.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cgp_core.collision import bvh
from cgp_core.collision.bvh import StaticMesh, active_edges, bvh_closest_point, bvh_overlap, bvh_raycast
from cgp_core.collision.manifold import ACTIVE_EDGE_ANGLE


def tree_depth(mesh: StaticMesh) -> int:
    """The deepest level of the tree (the root: 0), read from its arrays."""
    depth = np.zeros(len(mesh.node_count), np.int64)
    for node in range(len(mesh.node_count)):  # children always come after their parent
        if mesh.node_count[node] == 0:
            child = mesh.node_child_or_first[node]
            depth[child] = depth[child + 1] = depth[node] + 1
    return int(depth.max())


def geometric_triangles(ratio: float, count: int) -> tuple[np.ndarray, np.ndarray]:
    """``count`` triangles at x = ratio^k (k = 0 .. count − 1), each as big as its distance from 0: what makes SAH
    cut one triangle off a node per level."""
    x = ratio ** np.arange(count, dtype=float)
    vertices = np.zeros((3 * count, 3))
    vertices[0::3, 0] = x
    vertices[1::3, 0], vertices[1::3, 1] = 1.5 * x, x
    vertices[2::3, 2] = x
    return vertices, np.arange(3 * count).reshape(-1, 3)


def brute_overlap(mesh: StaticMesh, lo, hi) -> set:
    inside = (mesh.triangle_lo <= hi).all(axis=1) & (mesh.triangle_hi >= lo).all(axis=1)
    return set(np.flatnonzero(inside).tolist())


def test_a_bvh_is_shallow_enough_for_its_stacks_whatever_the_coordinates():
    """Old code: 260 levels for these 1,070 triangles (coordinates 2^-k, all within the scene's ±1e6 m), beyond
    its 256-entry traversal stacks."""
    vertices, triangles = geometric_triangles(0.5, 1070)
    mesh = StaticMesh.build(vertices, triangles)
    depth = tree_depth(mesh)
    assert depth + 1 <= bvh.STACK_DEPTH  # a traversal holds at most depth + 1 nodes
    assert depth <= bvh.SAH_DEPTH + math.ceil(math.log2(len(triangles) / bvh.LEAF_SIZE))
    # every query still equals brute force, on the tiny triangles and the big ones
    rng = np.random.default_rng(38)
    found = np.empty(len(triangles), np.int64)
    for scale in (1.0, 1e-3, 1e-30, 1e-300):
        for _ in range(20):
            centre = rng.uniform(0, 1.5, 3) * scale
            lo, hi = centre - 0.3 * scale, centre + 0.3 * scale
            count = bvh_overlap(mesh.arrays, lo, hi, found)
            assert set(found[:count].tolist()) == brute_overlap(mesh, lo, hi)
            closest = bvh_closest_point(mesh.arrays, centre, np.inf)
            corners = vertices[triangles]
            assert closest.distance <= np.linalg.norm(corners - centre, axis=2).min() + 1e-12 * scale
            hit = bvh_raycast(mesh.arrays, centre + [0, 0, scale], np.array([0.0, 0.0, -2 * scale]), 1.0)
            assert hit[0] == -1 or 0.0 <= hit[1] <= 1.0


@pytest.mark.parametrize("ratio, count", [(16.5, 250), (1.001, 3000)])
def test_geometric_meshes_build_bounded_trees(ratio, count):
    """The issue's mesh (16.5^k, k < 250: beyond the scene's coordinates, which a scene refuses; the tree must be
    bounded anyway), and a slowly growing one."""
    vertices, triangles = geometric_triangles(ratio, count)
    with np.errstate(all="ignore"):  # (16.5^249 overflows the areas: the build must not care)
        mesh = StaticMesh.build(vertices, triangles)
    assert tree_depth(mesh) + 1 <= bvh.STACK_DEPTH
    assert sorted(mesh.triangle_order) == list(range(count))


def test_sah_bins_stay_in_bounds_for_degenerate_extents():
    """Centroids 5e-324 apart (the smallest float64): SAH's bin scale is inf and (c − low) · scale a NaN, whose
    conversion to an integer is undefined (old code indexed its bins with it)."""
    tiny = 5e-324
    vertices = np.array([[0, 0, 0], [0, 1, 0], [0, 0, 1]] * 8, float)
    vertices[:, 0] = np.repeat(np.arange(8), 3) * tiny  # triangle k shifted by k ulps of 0 along x
    triangles = np.arange(len(vertices)).reshape(-1, 3)
    mesh = StaticMesh.build(vertices, triangles)
    assert sorted(mesh.triangle_order) == list(range(8))
    assert mesh.node_count.sum() == 8


def reference_active_edges(vertices, triangles, angle=ACTIVE_EDGE_ANGLE) -> np.ndarray:
    """The rule of :func:`cgp_core.collision.bvh.active_edges`, one edge at a time (the code it replaced)."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    normal = np.cross(b - a, c - a)
    length = np.linalg.norm(normal, axis=1)
    normal = normal / np.where(length > 0.0, length, 1.0)[:, None]
    flags = np.zeros(len(triangles), np.uint8)
    edges: dict = {}
    for i in range(len(triangles)):
        for e in range(3):
            u, v = int(triangles[i, e]), int(triangles[i, (e + 1) % 3])
            edges.setdefault((min(u, v), max(u, v)), []).append((i, e))
    for sharing in edges.values():
        if len(sharing) != 2:
            for i, e in sharing:
                flags[i] |= np.uint8(1 << e)
            continue
        (i, ei), (j, ej) = sharing
        direction = vertices[triangles[i, (ei + 1) % 3]] - vertices[triangles[i, ei]]
        convex = float(np.dot(np.cross(normal[i], normal[j]), direction)) > 0.0
        if convex and float(np.dot(normal[i], normal[j])) < math.cos(angle):
            flags[i] |= np.uint8(1 << ei)
            flags[j] |= np.uint8(1 << ej)
    return flags


def test_active_edges_equal_the_per_edge_rule():
    from cgp_core.collision.convex import box_hull

    rng = np.random.default_rng(5)
    hull = box_hull([0.5, 0.3, 0.2])
    meshes = [(hull.vertices, hull.triangles)]  # closed and convex: every edge between two faces is active
    side = 12
    x, y = np.meshgrid(np.arange(side, dtype=float), np.arange(side, dtype=float), indexing="ij")
    terrain = np.stack([x.ravel(), y.ravel(), rng.normal(0, 0.3, x.size)], 1)
    i = np.arange(side * side).reshape(side, side)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()
    meshes.append((terrain, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])))
    for _ in range(30):  # random soups: non-manifold edges, repeated triangles, degenerate ones
        meshes.append((rng.normal(size=(12, 3)), rng.integers(0, 12, size=(30, 3))))
    for vertices, triangles in meshes:
        np.testing.assert_array_equal(active_edges(vertices, triangles), reference_active_edges(vertices, triangles))
    box_flags = active_edges(hull.vertices, hull.triangles)
    diagonals = 6  # each face's two triangles share a flat diagonal: inactive
    assert sum(bin(f).count("1") for f in box_flags) == 3 * len(hull.triangles) - 2 * diagonals


@pytest.mark.timeout(20)
def test_a_million_triangle_mesh_builds_within_a_bound():
    """A hang guard (the bound is ~15x what it takes, a million triangles: twice what a scene may hold): old code
    spent ~55 s on the active edges of 500,000 triangles alone (a Python loop over a dict of edges)."""
    side = 708
    xs = np.arange(side + 1, dtype=float) * 0.01
    x, y = np.meshgrid(xs, xs, indexing="ij")
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    i = np.arange((side + 1) ** 2).reshape(side + 1, side + 1)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()
    mesh = StaticMesh.build(vertices, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]))
    bits = np.unpackbits(mesh.active_edges[:, None], axis=1).sum()
    assert len(mesh.triangles) == 2 * side * side and bits == 4 * side  # flat: only the boundary's edges are active
    assert tree_depth(mesh) + 1 <= bvh.STACK_DEPTH

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


# ---- D4: contacts on fine meshes cost what the contact needs ------------------------------------------------

def test_the_separation_bound_is_never_below_gjk_and_epa():
    """:func:`.manifold._separation_at_most` stands in for GJK / EPA where it decides the same: it must be an upper
    bound of their separation (apart: the distance; overlapping: minus the depth), for any triangle and hull."""
    from scipy.spatial.transform import Rotation

    from cgp_core.collision.convex import HullSet, PosedHull, box_hull, convex_hull, posed
    from cgp_core.collision.gjk import support_point
    from cgp_core.collision.manifold import _separation_at_most, core_of, signed_distance

    rng = np.random.default_rng(25)
    hulls = [HullSet.from_hulls([h]).hull(0) for h in
             (box_hull([0.5, 0.3, 0.2]), *(convex_hull(rng.normal(size=(k, 3))) for k in (6, 12, 40)))]
    bounded = 0
    for trial in range(3000):
        hull = posed(hulls[trial % len(hulls)], rng.normal(size=3) * 0.4,
                     Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix())
        triangle = rng.normal(size=(3, 3)) * rng.uniform(0.05, 2.0)
        normal = np.cross(triangle[1] - triangle[0], triangle[2] - triangle[0])
        if np.linalg.norm(normal) < 1e-6:
            continue
        normal /= np.linalg.norm(normal)
        planes = np.array([[*normal, normal @ triangle[0]], [*-normal, -normal @ triangle[0]]])
        _, sx, sy, sz = support_point(core_of(hull), *-normal, 0)
        front_sep = normal @ [sx, sy, sz] - planes[0, 3]
        bound = _separation_at_most(triangle, hull, planes[0], sx, sy, sz, front_sep)
        flat = PosedHull(triangle, np.zeros(4, np.int64), np.zeros(0, np.int64), planes, np.array([0, 3, 6]),
                         np.array([0, 1, 2, 0, 2, 1]), np.zeros(3), np.eye(3))
        separation = signed_distance(core_of(flat), core_of(hull))[0]
        if bound < np.inf:
            bounded += 1
            assert separation <= bound + 1e-12, (trial, separation, bound)
    assert bounded > 1000  # (the bound is found for most pairs: it is what spares GJK)


def test_merging_near_duplicates_equals_the_pairwise_rule():
    """The hash grid finds exactly what comparing each row with every kept row found (old code, O(n²))."""
    from cgp_core.collision.convex_phase import merge_close_rows
    from cgp_core.collision.narrowphase import ContactBuffer

    rng = np.random.default_rng(3)
    for _ in range(40):
        centres = rng.uniform(-1, 1, (int(rng.integers(1, 30)), 3)) * 10.0 ** rng.uniform(-4, 2)
        points = centres[rng.integers(0, len(centres), 200)] + rng.normal(size=(200, 3)) * 10.0 ** rng.uniform(-9, -3)
        separation = rng.uniform(-1e-3, 1e-3, 200)
        out = ContactBuffer(rng.normal(size=(200, 3)), separation.copy(), points.copy(), np.arange(200))
        m = merge_close_rows(out, 0, 200)
        span = np.ptp(points, axis=0).max()
        close = (1e-3 * span + 1e-5) ** 2
        kept, deepest = [], {}
        for s in range(200):
            twin = next((t for t in kept if ((points[s] - points[t]) ** 2).sum() <= close), None)
            if twin is None:
                kept.append(s)
                deepest[s] = s
            elif separation[s] < separation[deepest[twin]]:
                deepest[twin] = s
        assert m == len(kept)
        np.testing.assert_array_equal(out.feature[:m], [deepest[t] for t in kept])


def _box_on_grid(cells: int, tmp_path):
    from cgp_core.scene import parse_scene
    from cgp_core.world import World

    xs = (np.arange(cells + 1) - cells / 2) * 0.01
    x, y = np.meshgrid(xs, xs, indexing="ij")
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    i = np.arange((cells + 1) ** 2).reshape(cells + 1, cells + 1)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()
    triangles = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    lines = [f"v {p[0]!r} {p[1]!r} 0.0" for p in vertices.tolist()] + [f"f {p + 1} {q + 1} {r + 1}"
                                                                       for p, q, r in triangles.tolist()]
    (tmp_path / "grid.obj").write_text("\n".join(lines) + "\n")
    text = """
world: {ground: false, substeps: 4, sleep: false}
bodies:
  - {name: grid, shape: mesh, mesh: grid.obj, fixed: true}
  - {name: box, shape: box, size: [1, 1, 1], mass: 1.0, position: [0.003, 0.002, 0.5]}
"""
    (tmp_path / "s.yaml").write_text(text)
    world = World(parse_scene(text, str(tmp_path / "s.yaml")), dt=1 / 60)
    world.report_contacts = True
    return world


@pytest.mark.timeout(60)
def test_a_box_rests_on_an_80k_triangle_grid_with_one_reduced_manifold(tmp_path):
    """A hang guard besides the physics (the bound is ~30x what it takes): old code took ~6.8 s a tick here."""
    world = _box_on_grid(200, tmp_path)
    for _ in range(30):
        world.step()
    box = world.body_model.names.index("box")
    report = world.contacts
    on_box = report.body_b == box
    assert on_box.sum() == 4  # one reduced manifold of 4 points (of the ~60,000 the triangles under it give)
    # ... spanning the box's bottom face: one near each corner (the deepest point, here any, replaces the nearest
    # extreme: cgp_core.collision.convex_phase.reduce_mesh_rows)
    offsets = report.point[on_box, :2] - [0.003, 0.002]
    assert (np.abs(offsets) <= 0.5 + 1e-9).all() and (np.abs(offsets) >= 0.47).all()
    assert len({(bool(x > 0), bool(y > 0)) for x, y in offsets}) == 4
    # at rest: its weight carried (m g over the tick), no sinking beyond the solver's slop, no drift
    np.testing.assert_allclose(report.force[list(report.body).index(box)], [0, 0, 9.81], rtol=1e-6, atol=1e-6)
    assert abs(world.body_state.position[box, 2] - 0.5) < 1e-3
    np.testing.assert_allclose(world.body_state.position[box, :2], [0.003, 0.002], atol=1e-6)

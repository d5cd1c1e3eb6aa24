"""Contact manifolds of convex hulls (issue 25): a box given as an 8-point hull gets the manifold of the exact box
kernel (box_box.py) on random contact poses; a hull resting on a face gets the face's corners (at most 4) at equal
separations, on another hull and on the ground; sphere and capsule on a hull; a hull on a mesh triangle, with the
internal-edge (ghost) rule."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cgp_core.collision.box_box import box_box_contacts
from cgp_core.collision.bvh import active_edges
from cgp_core.collision.convex import PosedHull, box_hull, convex_hull
from cgp_core.collision.manifold import (
    FACE_FEATURE,
    hull_capsule_contacts,
    hull_hull_contacts,
    plane_hull_contacts,
    triangle_hull_contacts,
)
from cgp_core.collision.narrowphase import Box, ContactBuffer

EYE = np.eye(3)
CAP = 64


def buffers():
    return np.empty((CAP, 3)), np.empty(CAP), np.empty((CAP, 3)), np.empty(CAP, np.int64)


def posed(h, position, R):
    """The :class:`PosedHull` of hull ``h`` at ``position``, ``R``."""
    return PosedHull(h.vertices, h.adjacency_start, h.adjacency, h.face_plane, h.face_vertex_start, h.face_vertices,
                     np.asarray(position, float), np.asarray(R, float))


def hull_hull(a, pa, Ra, b, pb, Rb, margin):
    n, s, p, f = buffers()
    m = hull_hull_contacts(posed(a, pa, Ra), posed(b, pb, Rb), margin, ContactBuffer(n, s, p, f), 0)
    return n[:m], s[:m], p[:m], f[:m]


def prism(sides=6, radius=0.2, half_height=0.05):
    angles = np.arange(sides) * 2 * np.pi / sides
    ring = np.column_stack([radius * np.cos(angles), radius * np.sin(angles), np.zeros(sides)])
    return convex_hull(np.vstack([ring + [0, 0, -half_height], ring + [0, 0, half_height]]))


def test_box_as_hull_gives_the_box_kernels_manifold_on_random_poses():
    rng = np.random.default_rng(0)
    compared = multi = wider = 0
    for trial in range(150):
        ha, hb = rng.uniform(0.1, 0.5, 3), rng.uniform(0.1, 0.5, 3)
        Ra, Rb = Rotation.random(2, random_state=trial).as_matrix()
        pa = rng.uniform(-1, 1, 3)
        d = rng.normal(size=3)
        pb = pa + d / np.linalg.norm(d) * rng.uniform(0.2, 1.0)
        margin = 0.02
        n, s, p, f = buffers()
        m = box_box_contacts(Box(pa, Ra, ha), Box(pb, Rb, hb), margin, ContactBuffer(n, s, p, f), 0)
        box = n[:m], s[:m], p[:m]
        hull = hull_hull(box_hull(ha), pa, Ra, box_hull(hb), pb, Rb, margin)
        if len(hull[0]) != m:
            # the one departure, on purpose: where box–box's reduction (in the reference face's units) keeps only
            # 2 or 3 of more candidates, the hull kernel reduces in the contact polygon's own units and keeps 4
            assert len(hull[0]) == 4 > m >= 2, trial
            np.testing.assert_allclose(hull[0], np.tile(box[0][0], (4, 1)), atol=1e-9)
            assert hull[1].min() <= box[1].min() + 1e-9  # not shallower (box–box may drop the deepest candidate)
            wider += 1
            continue
        if m == 0:
            continue
        compared += 1
        multi += m > 1
        np.testing.assert_allclose(hull[0], box[0], atol=1e-9)  # one normal per manifold
        order_box, order_hull = np.lexsort(box[2].T), np.lexsort(hull[2].T)
        np.testing.assert_allclose(hull[2][order_hull], box[2][order_box], atol=1e-9)
        np.testing.assert_allclose(hull[1][order_hull], box[1][order_box], atol=1e-9)
    assert compared >= 80 and multi >= 30 and wider <= 5


def test_a_hull_resting_on_a_face_gets_equal_separations_at_the_face_corners():
    floor = box_hull([1.0, 1.0, 0.1])
    depth = 1e-3
    # a hexagonal prism flat on the floor, turned about z: its hexagon clipped by nothing, reduced to 4 corners
    hexagon = prism()
    for yaw in (0.0, 0.3, 1.0):
        R = Rotation.from_euler("z", yaw).as_matrix()
        n, s, p, f = hull_hull(floor, [0, 0, 0], EYE, hexagon, [0.1, -0.2, 0.1 + 0.05 - depth], R, 0.01)
        assert len(s) == 4
        np.testing.assert_allclose(s, -depth, atol=1e-12)
        np.testing.assert_allclose(n, [[0, 0, 1]] * 4, atol=1e-12)
        np.testing.assert_allclose(p[:, 2], 0.1 - depth / 2, atol=1e-12)
        # the 4 kept corners span the largest quadrilateral in the hexagon
        xy = p[:, :2] - p[:, :2].mean(axis=0)
        quad = xy[np.argsort(np.arctan2(xy[:, 1], xy[:, 0]))]
        area = 0.5 * abs(sum(quad[i, 0] * quad[(i + 1) % 4, 1] - quad[i, 1] * quad[(i + 1) % 4, 0]
                             for i in range(4)))
        assert area >= 0.666 * (3 * math.sqrt(3) / 2 * 0.2**2)  # the largest inscribed quad: 2/3
        assert (f & FACE_FEATURE).all()
    # a random hull resting on one of its faces: that face's corners, all at the same separation
    rng = np.random.default_rng(1)
    rock = convex_hull(rng.normal(size=(20, 3)) * [0.2, 0.15, 0.1])
    face = int(np.argmax([len(rock.face(k)) for k in range(rock.face_count)]))  # turned to face down
    R = Rotation.align_vectors([[0, 0, -1]], [rock.face_plane[face, :3]])[0].as_matrix()
    lowest = (rock.vertices @ R.T)[:, 2].min()
    n, s, p, f = hull_hull(floor, [0, 0, 0], EYE, rock, [0, 0, 0.1 - lowest - depth], R, 0.005)
    assert len(s) == min(4, len(rock.face(face)))
    np.testing.assert_allclose(s, -depth, atol=1e-12)
    np.testing.assert_allclose(n, [[0, 0, 1]] * len(s), atol=1e-12)


def test_features_are_stable_while_a_resting_hull_moves_a_little():
    floor = box_hull([1.0, 1.0, 0.1])
    hexagon = prism()
    _, _, _, f0 = hull_hull(floor, [0, 0, 0], EYE, hexagon, [0, 0, 0.149], EYE, 0.01)
    R = Rotation.from_rotvec([0.002, -0.001, 0.01]).as_matrix()
    _, _, _, f1 = hull_hull(floor, [0, 0, 0], EYE, hexagon, [0.003, 0.001, 0.1495], R, 0.01)
    assert sorted(f0) == sorted(f1)


def test_a_hull_on_the_ground_gets_at_most_four_equally_deep_points():
    hexagon = prism()
    n, s, p, f = buffers()
    m = plane_hull_contacts(posed(hexagon, [1.0, 2.0, 0.05 - 2e-3], Rotation.from_euler("z", 0.4).as_matrix()), 0.01,
                            0, ContactBuffer(n, s, p, f), 0)
    assert m == 4
    np.testing.assert_allclose(s[:m], -2e-3, atol=1e-14)
    np.testing.assert_allclose(p[:m, 2], -1e-3, atol=1e-14)
    # tilted: only the low corners are within the margin
    m = plane_hull_contacts(posed(hexagon, [0.0, 0.0, 0.2], Rotation.from_euler("x", 0.6).as_matrix()), 0.01,
                            0, ContactBuffer(n, s, p, f), 0)
    world_z = (hexagon.vertices @ Rotation.from_euler("x", 0.6).as_matrix().T)[:, 2] + 0.2
    assert m == np.count_nonzero(world_z < 0.01)
    np.testing.assert_allclose(np.sort(s[:m]), np.sort(world_z[world_z < 0.01]), atol=1e-14)


def capsule(hull, position, R, segment, radius, margin=0.01):
    n, s, p, f = buffers()
    m = hull_capsule_contacts(posed(hull, position, R), np.asarray(segment, float), radius, margin,
                              ContactBuffer(n, s, p, f), 0)
    return n[:m], s[:m], p[:m], f[:m]


def test_sphere_and_capsule_on_a_hull_face():
    floor = box_hull([1.0, 1.0, 0.1])
    # a sphere of radius 0.1 whose centre is 0.095 above the top face (z = 0.1): 5 mm deep
    n, s, p, f = capsule(floor, [0, 0, 0], EYE, [[0.2, 0.3, 0.195]] * 2, 0.1)
    assert len(s) == 1 and s[0] == pytest.approx(-0.005, abs=1e-12)
    np.testing.assert_allclose(n[0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(p[0], [0.2, 0.3, 0.1 - 0.0025], atol=1e-12)
    # a capsule lying along the face: its two ends, equally deep
    n, s, p, f = capsule(floor, [0, 0, 0], EYE, [[-0.3, 0, 0.195], [0.4, 0.1, 0.195]], 0.1)
    assert len(s) == 2
    np.testing.assert_allclose(s, -0.005, atol=1e-12)
    np.testing.assert_allclose(p[:, :2], [[-0.3, 0], [0.4, 0.1]], atol=1e-12)
    # ... clipped where it overhangs the face
    n, s, p, f = capsule(floor, [0, 0, 0], EYE, [[0.5, 0, 0.195], [1.5, 0, 0.195]], 0.1)
    assert len(s) == 2 and p[:, 0].max() == pytest.approx(1.0, abs=1e-12)
    # tilted: one point under the low end
    n, s, p, f = capsule(floor, [0, 0, 0], EYE, [[0, 0, 0.195], [0.5, 0, 0.4]], 0.1)
    assert len(s) == 1 and s[0] == pytest.approx(-0.005, abs=1e-12)


def triangle_contacts(triangle, flags, hull, position, R, margin=0.01, two_sided=False):
    n, s, p, f = buffers()
    m = triangle_hull_contacts(np.asarray(triangle, float), np.uint8(flags), two_sided, posed(hull, position, R),
                               margin, ContactBuffer(n, s, p, f), 0)
    return n[:m], s[:m], p[:m], f[:m]


def test_a_box_sliding_across_an_internal_edge_of_a_flat_mesh_sees_only_the_face_normal():
    # a 2 m square of two triangles; the diagonal is an internal, inactive edge
    vertices = np.array([[-1.0, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]])
    triangles = np.array([[0, 1, 2], [0, 2, 3]])
    flags = active_edges(vertices, triangles)
    assert flags[0] == 0b011 and flags[1] == 0b110  # the diagonal (edge 2 of the first, 0 of the second) inactive
    box = box_hull([0.2, 0.2, 0.2])
    for x in np.linspace(-0.4, 0.4, 9):
        R = Rotation.from_euler("xyz", [0.05, -0.03, 0.7]).as_matrix()  # tilted a little: corners first
        lowest = (box.vertices @ R.T)[:, 2].min()
        position = [x, -x + 0.05, -lowest - 0.002]
        normals, seps = [], []
        for t in range(2):
            n, s, p, f = triangle_contacts(vertices[triangles[t]], flags[t], box, position, R)
            normals += list(n)
            seps += list(s)
        assert normals, x
        np.testing.assert_allclose(normals, [[0, 0, 1]] * len(normals), atol=1e-12)
        assert min(seps) == pytest.approx(-0.002, abs=1e-9)


def test_an_active_ridge_edge_gives_a_tilted_normal():
    # a roof: two triangles meeting at 90° along the x axis; a box corner touching the ridge from above-side
    vertices = np.array([[-1.0, 0, 0], [1, 0, 0], [1, -1, -1], [-1, -1, -1], [1, 1, -1], [-1, 1, -1]])
    triangles = np.array([[0, 3, 2], [0, 2, 1], [0, 1, 4], [0, 4, 5]])
    flags = active_edges(vertices, triangles)
    assert flags[1] & 0b100 and flags[2] & 0b001  # the ridge (0, 1) is active on both sides
    box = box_hull([0.1, 0.1, 0.1])
    R = Rotation.from_euler("y", 45, degrees=True).as_matrix()  # an edge of the box across the ridge
    position = np.array([0.0, 0.0, 0.1 * math.sqrt(2) - 0.001])
    n, s, p, f = triangle_contacts(vertices[triangles[1]], flags[1], box, position, R)
    assert len(s) >= 1
    np.testing.assert_allclose(n[0], [0, 0, 1], atol=1e-9)  # edge on edge: the normal bisects the roof
    assert s.min() == pytest.approx(-0.001, abs=1e-9)


# ---- static meshes: the BVH's triangles as contact pieces --------------------------------------------------

def flat_grid(cells=4, size=2.0):
    xs = np.linspace(-size / 2, size / 2, cells + 1)
    x, y = np.meshgrid(xs, xs, indexing="ij")
    vertices = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    index = np.arange((cells + 1) ** 2).reshape(cells + 1, cells + 1)
    a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    return vertices, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


def test_hulls_and_spheres_on_a_posed_flat_mesh_feel_only_its_up_direction():
    """A flat grid mesh (32 triangles, every internal edge inactive) turned and moved in the world; a box, a
    hexagonal prism and a sphere resting on it anywhere — across edges and vertices — get contacts whose normal
    is the mesh's up direction, whose deepest separation is the depth, and whose points lie on the mesh."""
    from cgp_core.collision.bvh import StaticMesh
    from cgp_core.collision.mesh_contacts import mesh_capsule_contacts, mesh_hull_contacts

    mesh = StaticMesh.build(*flat_grid())
    assert not mesh.active_edges[np.isin(mesh.triangles, [6, 7, 8, 11, 12, 13, 16, 17, 18]).all(axis=1)].any()
    Rm = Rotation.from_euler("xyz", [0.3, -0.2, 0.9]).as_matrix()
    pm = np.array([1.0, -2.0, 0.5])
    up = Rm[:, 2]
    rng = np.random.default_rng(7)
    candidates = np.empty(64, np.int64)
    depth = 2e-3
    for hull in (box_hull([0.12, 0.08, 0.05]), prism(radius=0.15)):
        for _ in range(20):
            local_R = Rotation.from_euler("z", rng.uniform(0, 2 * np.pi)).as_matrix()
            lowest = (hull.vertices @ local_R.T)[:, 2].min()
            local_p = np.array([*rng.uniform(-0.6, 0.6, 2), -lowest - depth])
            n, s, p, f = buffers()
            m, complete = mesh_hull_contacts(mesh.arrays, pm, Rm, False, posed(hull, pm + Rm @ local_p, Rm @ local_R),
                                             0.01, candidates, ContactBuffer(n, s, p, f), 0)
            assert complete and m >= 3
            np.testing.assert_allclose(n[:m], np.tile(up, (m, 1)), atol=1e-12)
            assert s[:m].min() == pytest.approx(-depth, abs=1e-12)
            np.testing.assert_allclose((p[:m] - pm) @ up, -depth / 2, atol=1e-12)  # midway, under the mesh plane
    for _ in range(40):  # a sphere anywhere, including over edges and vertices: exactly one contact
        local_c = np.array([*rng.uniform(-0.7, 0.7, 2), 0.1 - depth])
        local_c[:2] = np.round(local_c[:2] * 2) / 2 if _ % 4 == 0 else local_c[:2]  # right over a grid vertex
        c = pm + Rm @ local_c
        n, s, p, f = buffers()
        m, complete = mesh_capsule_contacts(mesh.arrays, pm, Rm, False, np.array([c, c]), 0.1, 0.01, candidates,
                                            ContactBuffer(n, s, p, f), 0)
        assert complete and m == 1, local_c
        np.testing.assert_allclose(n[0], up, atol=1e-12)
        assert s[0] == pytest.approx(-depth, abs=1e-12)

"""Convex hulls (qhull, merged faces, adjacency, support mapping), polyhedral mass properties (divergence theorem)
and compound inertia, against closed forms, invariants and brute force (issue 25)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cgp_core.collision.convex import (
    BRUTE_FORCE_SUPPORT_VERTICES,
    MAX_HULL_VERTICES,
    HullError,
    HullSet,
    box_hull,
    centred_hull,
    convex_hull,
    support_index,
)
from cgp_core.inertia import (
    MeshMassError,
    box_inertia,
    capsule_inertia,
    compound_mass_properties,
    particle_mass_properties,
    polyhedron_mass_properties,
    solid_sphere_inertia,
)


def random_points(rng, n, axes=(0.2, 0.15, 0.25)):
    p = rng.normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=1)[:, None] * np.asarray(axes) * rng.uniform(0.7, 1.0, (n, 1))


# ---- hulls --------------------------------------------------------------------------------------------

def test_box_hull_has_six_quad_faces_with_outward_planes_and_ccw_loops():
    h = np.array([0.3, 0.2, 0.1])
    hull = box_hull(h)
    assert len(hull.vertices) == 8 and hull.face_count == 6 and hull.interior_points == 0
    normals = hull.face_plane[:, :3]
    # the six axis directions, offsets the half extents
    assert sorted(map(tuple, np.round(normals).astype(int))) == sorted(
        [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)])
    np.testing.assert_allclose(hull.face_plane[:, 3], np.abs(normals) @ h, rtol=1e-14)
    for f in range(6):
        loop = hull.vertices[hull.face(f)]
        assert len(loop) == 4
        np.testing.assert_allclose(loop @ normals[f], hull.face_plane[f, 3], atol=1e-15)  # on the plane
        centre = loop.mean(axis=0)
        for k in range(4):  # counter-clockwise seen from outside: (a − c) × (b − c) along the normal
            turn = np.cross(loop[k] - centre, loop[(k + 1) % 4] - centre)
            assert turn @ normals[f] > 0
    # every vertex has its 3 box edges as neighbours (no face diagonals)
    for v in range(8):
        nbrs = hull.adjacency[hull.adjacency_start[v]:hull.adjacency_start[v + 1]]
        assert len(nbrs) == 3
        assert all(np.count_nonzero(hull.vertices[n] != hull.vertices[v]) == 1 for n in nbrs)


def test_hull_of_a_cloud_reports_its_interior_points_and_contains_them():
    rng = np.random.default_rng(0)
    surface = random_points(rng, 30)
    inside = 0.3 * random_points(rng, 20)
    hull = convex_hull(np.vstack([surface, inside]))
    assert hull.interior_points >= 20
    # every input point is inside or on every face plane; every hull vertex is on at least 3 planes
    planes = hull.face_plane
    assert (np.vstack([surface, inside]) @ planes[:, :3].T - planes[:, 3] <= 1e-12).all()
    on = np.abs(hull.vertices @ planes[:, :3].T - planes[:, 3]) <= 1e-12
    assert (on.sum(axis=1) >= 3).all()
    # Euler: V − E + F = 2 with E from the adjacency
    assert len(hull.vertices) - len(hull.adjacency) // 2 + hull.face_count == 2


@pytest.mark.parametrize("points, reason", [
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], "at least 4 points"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0.5, 0.2, 0]], "coplanar"),
    ([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3]], "coplanar or collinear"),
    ([[0, 0, 0]] * 5, "same point"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, float("nan")]], "finite"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, 1e-13]], "coplanar"),
    ([[0, 0], [1, 0], [0, 1], [1, 1]], "[x, y, z]"),
])
def test_degenerate_points_are_refused_naming_the_input_and_reason(points, reason):
    with pytest.raises(HullError, match="bodies\\[3\\].points") as error:
        convex_hull(points, what="scene.yaml: bodies[3].points")
    assert reason in str(error.value)


def test_hull_vertex_cap():
    rng = np.random.default_rng(1)
    p = rng.normal(size=(MAX_HULL_VERTICES + 200, 3))
    with pytest.raises(HullError, match="vertices, more than"):
        convex_hull(p / np.linalg.norm(p, axis=1)[:, None])


def test_support_index_brute_force_and_hill_climbing_agree_with_argmax():
    rng = np.random.default_rng(2)
    small = convex_hull(random_points(rng, 16))
    p = rng.normal(size=(400, 3))
    big = convex_hull(p / np.linalg.norm(p, axis=1)[:, None])
    assert len(small.vertices) <= BRUTE_FORCE_SUPPORT_VERTICES < len(big.vertices)
    for hull in (small, big):
        start = 0
        for d in rng.normal(size=(300, 3)):
            i = support_index(hull.vertices, hull.adjacency_start, hull.adjacency, d[0], d[1], d[2], start)
            assert hull.vertices[i] @ d == pytest.approx((hull.vertices @ d).max(), abs=1e-15)
            start = i  # warm start from the previous answer


def test_hull_set_slices_are_each_hulls_arrays():
    rng = np.random.default_rng(3)
    hulls = [box_hull([0.1, 0.2, 0.3]), convex_hull(random_points(rng, 20)), convex_hull(random_points(rng, 9))]
    hs = HullSet.from_hulls(hulls)
    assert hs.count == 3
    for i, h in enumerate(hulls):
        vertices, adjacency_start, adjacency, face_plane, face_vertex_start, face_vertices = hs.hull(i)
        np.testing.assert_array_equal(vertices, h.vertices)
        np.testing.assert_array_equal(face_plane, h.face_plane)
        for v in range(len(vertices)):
            np.testing.assert_array_equal(adjacency[adjacency_start[v]:adjacency_start[v + 1]],
                                          h.adjacency[h.adjacency_start[v]:h.adjacency_start[v + 1]])
        for f in range(len(face_plane)):
            np.testing.assert_array_equal(face_vertices[face_vertex_start[f]:face_vertex_start[f + 1]], h.face(f))


# ---- polyhedral mass properties ------------------------------------------------------------------------

def test_box_hull_mass_properties_equal_the_closed_form():
    size = np.array([0.7, 0.3, 1.9])
    offset = np.array([2.0, -1.0, 0.5])
    hull = box_hull(size / 2)
    mass, com, inertia, volume = polyhedron_mass_properties(hull.vertices + offset, hull.triangles, density=800.0)
    assert volume == pytest.approx(np.prod(size), rel=1e-12)
    assert mass == pytest.approx(800.0 * np.prod(size), rel=1e-12)
    np.testing.assert_allclose(com, offset, rtol=1e-12, atol=1e-14)
    expected = box_inertia(mass, size)
    np.testing.assert_allclose(inertia, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())


def test_tetrahedron_mass_properties_equal_the_closed_form():
    # the unit corner tetrahedron (0, e1, e2, e3): V = 1/6, COM = 1/4 (1, 1, 1); about the origin
    # ∫x² = 1/60 and ∫xy = 1/120 (per unit density), so about the COM I_xx = 2/60 − V (2/16) ...
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]) * 0.4
    triangles = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    mass, com, inertia, volume = polyhedron_mass_properties(vertices, triangles, mass=3.0)
    a = 0.4
    V = a**3 / 6
    assert volume == pytest.approx(V, rel=1e-12)
    np.testing.assert_allclose(com, [a / 4] * 3, rtol=1e-12)
    rho = 3.0 / V
    xx, xy = rho * a**5 / 60, rho * a**5 / 120  # about the origin
    c = a / 4
    diag = 2 * xx - 3.0 * 2 * c * c
    off = -(xy - 3.0 * c * c)
    expected = np.full((3, 3), off)
    np.fill_diagonal(expected, diag)
    np.testing.assert_allclose(inertia, expected, rtol=1e-12)


def test_random_hull_matches_trimesh_and_is_invariant_under_rigid_motion():
    trimesh = pytest.importorskip("trimesh")
    rng = np.random.default_rng(4)
    hull = convex_hull(random_points(rng, 40))
    mass, com, inertia, volume = polyhedron_mass_properties(hull.vertices, hull.triangles, density=2.0)
    ref = trimesh.Trimesh(hull.vertices, hull.triangles, process=False)
    ref.density = 2.0
    assert volume == pytest.approx(ref.volume, rel=1e-10)
    np.testing.assert_allclose(com, ref.center_mass, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(inertia, ref.moment_inertia, rtol=1e-9, atol=1e-12 * np.abs(inertia).max())
    # moved: the COM moves with the body, the tensor turns as R I Rᵀ (about the COM, world axes)
    R = Rotation.random(random_state=5).as_matrix()
    shift = np.array([10.0, -20.0, 3.0])
    m2, com2, inertia2, v2 = polyhedron_mass_properties(hull.vertices @ R.T + shift, hull.triangles, density=2.0)
    assert m2 == pytest.approx(mass, rel=1e-12) and v2 == pytest.approx(volume, rel=1e-12)
    np.testing.assert_allclose(com2, R @ com + shift, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(inertia2, R @ inertia @ R.T, rtol=1e-9, atol=1e-11 * np.abs(inertia).max())


def test_open_inverted_and_degenerate_meshes_are_refused():
    hull = box_hull([0.5, 0.5, 0.5])
    with pytest.raises(MeshMassError, match="rock.stl: not a closed surface.*holes"):
        polyhedron_mass_properties(hull.vertices, hull.triangles[:-1], mass=1.0, what="rock.stl")
    with pytest.raises(MeshMassError, match="inverted"):
        polyhedron_mass_properties(hull.vertices, hull.triangles[:, ::-1], mass=1.0)
    flipped_one = hull.triangles.copy()
    flipped_one[0] = flipped_one[0, ::-1]
    with pytest.raises(MeshMassError, match="not a closed surface.*same direction"):
        polyhedron_mass_properties(hull.vertices, flipped_one, mass=1.0)
    with pytest.raises(MeshMassError, match="exactly one of mass and density"):
        polyhedron_mass_properties(hull.vertices, hull.triangles)


# ---- compound inertia ----------------------------------------------------------------------------------

def test_compound_of_small_spheres_is_the_particle_set_plus_their_own_inertia():
    rng = np.random.default_rng(6)
    centres = rng.uniform(-1, 1, (8, 3))
    masses = rng.uniform(0.5, 2.0, 8)
    radius = 0.01
    own = np.array([solid_sphere_inertia(m, radius) for m in masses])
    rotations = Rotation.random(8, random_state=7).as_matrix()  # a sphere's tensor does not turn
    M, com, J = compound_mass_properties(masses, centres, rotations, own)
    Mp, comp, Jp = particle_mass_properties(centres, masses)
    assert M == pytest.approx(Mp, rel=1e-14)
    np.testing.assert_allclose(com, comp, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(J, Jp + np.eye(3) * 0.4 * radius**2 * masses.sum(), rtol=1e-12)


def test_a_box_split_into_two_boxes_is_the_box():
    size = np.array([0.8, 0.4, 0.3])
    density = 500.0
    half = size * [0.5, 1, 1]
    m_half = density * np.prod(half)
    parts_com = np.array([[-size[0] / 4, 0, 0], [size[0] / 4, 0, 0]])
    M, com, J = compound_mass_properties([m_half, m_half], parts_com, np.stack([np.eye(3)] * 2),
                                         np.stack([box_inertia(m_half, half)] * 2))
    assert M == pytest.approx(density * np.prod(size), rel=1e-14)
    np.testing.assert_allclose(com, 0.0, atol=1e-16)
    np.testing.assert_allclose(J, box_inertia(M, size), rtol=1e-13)


def test_a_turned_part_contributes_its_turned_tensor():
    # a capsule lying along x (its axis is body z: turned 90° about y) at the origin: J = R J_capsule Rᵀ
    R = Rotation.from_euler("y", 90, degrees=True).as_matrix()
    Jc = capsule_inertia(2.0, 0.1, 0.5)
    M, com, J = compound_mass_properties([2.0], [[0.3, 0.0, 0.0]], [R], [Jc])
    np.testing.assert_allclose(com, [0.3, 0, 0])
    np.testing.assert_allclose(J, np.diag([Jc[2, 2], Jc[0, 0], Jc[0, 0]]), atol=1e-15)


def test_centred_hull_is_about_its_centre_of_mass():
    rng = np.random.default_rng(8)
    hull = convex_hull(random_points(rng, 30) + [1.0, 2.0, 3.0])
    centred, mass, com, inertia = centred_hull(hull, density=1000.0)
    np.testing.assert_allclose(centred.vertices + com, hull.vertices, atol=1e-15)
    # about the new origin: the first moments vanish, the tensor is the same
    m2, com2, inertia2, _ = polyhedron_mass_properties(centred.vertices, centred.triangles, density=1000.0)
    assert m2 == pytest.approx(mass, rel=1e-12)
    np.testing.assert_allclose(com2, 0.0, atol=1e-14)
    np.testing.assert_allclose(inertia2, inertia, rtol=1e-10, atol=1e-14)
    # the planes moved with the vertices
    on = np.abs(centred.vertices @ centred.face_plane[:, :3].T - centred.face_plane[:, 3]) <= 1e-12
    assert (on.sum(axis=1) >= 3).all()

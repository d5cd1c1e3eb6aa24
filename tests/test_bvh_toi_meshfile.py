"""The static mesh's BVH (every query equals brute force over all triangles on thousands of random queries), time of
impact by conservative advancement (closed form; a spinning plank a start-of-step contact misses; no hit), and
the mesh files (the shipped ones read back; bad files refused naming the file and the reason) — issue 25."""

from __future__ import annotations

import math
import os
import struct

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cgp_core.collision.bvh import (
    LEAF_SIZE,
    StaticMesh,
    bvh_closest_point,
    bvh_overlap,
    bvh_raycast,
    closest_point_on_triangle,
    ray_triangle,
)
from cgp_core.collision.convex import box_hull, convex_hull
from cgp_core.collision.epa import penetration
from cgp_core.collision.gjk import NO_ADJACENCY, Core, box_core, no_adjacency, point_core
from cgp_core.collision.meshfile import MAX_FILE_BYTES, MeshFileError, load_mesh
from cgp_core.collision.toi import MovingCore, rotated, time_of_impact
from cgp_core.inertia import polyhedron_mass_properties
from msgs_config import __file__ as msgs_config_init

MESHES = os.path.join(os.path.dirname(msgs_config_init), "meshes")
EYE = np.eye(3)


@pytest.fixture(scope="module")
def terrain():
    vertices, triangles = load_mesh(os.path.join(MESHES, "terrain.obj"))
    return StaticMesh.build(vertices, triangles)


# ---- BVH ------------------------------------------------------------------------------------------------

def test_tree_invariants(terrain):
    t = len(terrain.triangles)
    leaves = terrain.node_count > 0
    assert sorted(terrain.triangle_order) == list(range(t))  # every triangle in exactly one leaf
    assert terrain.node_count[leaves].sum() == t and terrain.node_count.max() <= LEAF_SIZE
    for node in np.flatnonzero(~leaves):  # children inside their parent
        for child in (terrain.node_child_or_first[node], terrain.node_child_or_first[node] + 1):
            assert (terrain.node_lo[child] >= terrain.node_lo[node]).all()
            assert (terrain.node_hi[child] <= terrain.node_hi[node]).all()
    for node in np.flatnonzero(leaves):  # leaves contain their triangles
        first, count = terrain.node_child_or_first[node], terrain.node_count[node]
        tris = terrain.triangle_order[first:first + count]
        assert (terrain.triangle_lo[tris] >= terrain.node_lo[node]).all()
        assert (terrain.triangle_hi[tris] <= terrain.node_hi[node]).all()


def test_box_queries_equal_brute_force(terrain):
    rng = np.random.default_rng(0)
    out = np.empty(len(terrain.triangles), np.int64)
    for _ in range(2000):
        centre = rng.uniform([-6, -6, -1], [6, 6, 1])
        half = rng.uniform(0.01, 1.0, 3)
        lo, hi = centre - half, centre + half
        n = bvh_overlap(terrain.arrays, lo, hi, out)
        brute = np.flatnonzero(((terrain.triangle_lo <= hi) & (terrain.triangle_hi >= lo)).all(axis=1))
        assert sorted(out[:n]) == list(brute)
    # a too-small buffer: the count is still right
    small = np.empty(3, np.int64)
    assert bvh_overlap(terrain.arrays, np.array([-6.0, -6, -2]), np.array([6.0, 6, 2]), small) \
        == len(terrain.triangles)


def brute_closest(mesh, p):
    best = (np.inf, -1, None)
    for i in range(len(mesh.triangles)):
        q = np.array(closest_point_on_triangle(mesh.vertices, mesh.triangles, i, *p))
        d = np.linalg.norm(q - p)
        if d < best[0]:
            best = (d, i, q)
    return best


def test_closest_point_queries_equal_brute_force(terrain):
    rng = np.random.default_rng(1)
    # brute force with numpy over all triangles: the candidate closest points of the three regions
    for _ in range(300):
        p = rng.uniform([-6, -6, -1.5], [6, 6, 1.5])
        tri, dist, x, y, z = bvh_closest_point(terrain.arrays, p, np.inf)
        d_brute, i_brute, q_brute = brute_closest(terrain, p)
        assert dist == pytest.approx(d_brute, abs=1e-12)
        np.testing.assert_allclose([x, y, z], q_brute, atol=1e-9)
        # within a max distance: nothing beyond it
        tri, dist, *_ = bvh_closest_point(terrain.arrays, p, 0.5 * d_brute)
        assert tri == -1


def ray_all_triangles(mesh, o, d):
    """Brute force, numpy: the ray parameter of every triangle (Cramer's rule on o + t d = a + u e1 + v e2)."""
    a, b, c = (mesh.vertices[mesh.triangles[:, k]] for k in range(3))
    e1, e2 = b - a, c - a
    matrix = np.stack([-np.broadcast_to(d, e1.shape), e1, e2], axis=2)  # [−d e1 e2] (t u v)ᵀ = o − a
    det = np.linalg.det(matrix)
    ok = np.abs(det) > 1e-300
    tuv = np.full((len(a), 3), np.nan)
    tuv[ok] = np.linalg.solve(matrix[ok], (o - a)[ok][:, :, None])[:, :, 0]
    t, u, v = tuv.T
    inside = ok & (u >= -1e-12) & (v >= -1e-12) & (u + v <= 1 + 1e-12)
    return np.where(inside, t, np.inf)


def test_raycasts_equal_brute_force(terrain):
    rng = np.random.default_rng(2)
    hits = 0
    for k in range(2000):
        origin = rng.uniform([-6, -6, -1], [6, 6, 2])
        direction = rng.normal(size=3)
        if k % 4 == 0:
            direction = np.array([0.0, 0.0, -1.0])  # straight down: axis-parallel slabs
        length = rng.uniform(0.5, 5.0)
        tri, t, u, v = bvh_raycast(terrain.arrays, origin, direction, length)
        brute = ray_all_triangles(terrain, origin, direction)
        brute[(brute < 0) | (brute > length)] = np.inf
        if np.isinf(brute.min()):
            assert tri == -1
        else:
            hits += 1
            assert t == pytest.approx(brute.min(), abs=1e-9)
            assert ray_triangle(terrain.vertices, terrain.triangles, tri, *origin, *direction)[0] == t
    assert hits > 300


# ---- time of impact -------------------------------------------------------------------------------------

def core(v):
    v = np.ascontiguousarray(v, dtype=float)
    return v, no_adjacency(v), NO_ADJACENCY


def toi(a, pa, Ra, va, wa, ra, b, pb, Rb, vb, wb, rb, duration, target=1e-3, tolerance=1e-5):
    f = lambda x: np.asarray(x, dtype=float)  # noqa: E731
    return time_of_impact(MovingCore(*a, f(pa), f(Ra), f(va), f(wa), ra),
                          MovingCore(*b, f(pb), f(Rb), f(vb), f(wb), rb), duration, target, tolerance)


def test_sphere_falling_onto_a_box_meets_it_at_the_closed_form_time():
    box = core(box_core([1.0, 1.0, 0.5]))
    sphere = core(point_core())
    target = 1e-3
    # centre at z = 1.0, radius 0.1, box top at z = 0: contact (at the target distance) when z = 0.1 + target
    t, sep, n, hit, iterations = toi(box, [0, 0, -0.5], EYE, [0, 0, 0], [0, 0, 0], 0.0,
                                     sphere, [0.2, 0.1, 1.0], EYE, [0, 0, -10.0], [0, 0, 0], 0.1, 0.2, target)
    assert hit and t == pytest.approx((1.0 - 0.1 - target) / 2.0, abs=1e-5 / 2.0)
    assert target - 1e-12 <= sep <= target + 1e-5
    np.testing.assert_allclose(n, [0, 0, 1], atol=1e-12)
    # too slow to get there within the step: no hit, t = 1
    t, sep, n, hit, _ = toi(box, [0, 0, -0.5], EYE, [0, 0, 0], [0, 0, 0], 0.0,
                            sphere, [0.2, 0.1, 1.0], EYE, [0, 0, -4.0], [0, 0, 0], 0.1, 0.2, target)
    assert not hit and t == 1.0
    # moving away: no hit
    t, sep, n, hit, _ = toi(box, [0, 0, -0.5], EYE, [0, 0, 0], [0, 0, 0], 0.0,
                            sphere, [0.2, 0.1, 1.0], EYE, [3.0, 0, 10.0], [0, 0, 0], 0.1, 0.2, target)
    assert not hit and t == 1.0


def test_a_spinning_plank_is_caught_where_a_start_of_step_contact_misses_it():
    """A 2 m plank along x spins half a turn about z in one step next to a thin wall 0.8 m off its centre
    along y: at the start and the end it lies parallel to the wall, 0.79 m away, and its closest point to the wall
    (its middle) does not move — a speculative contact made at the step's start predicts no approach.  Mid-step
    its end sweeps through the wall; conservative advancement finds the first touch, which dense sampling of the
    motion confirms."""
    plank = core(box_core([1.0, 0.02, 0.05]))
    wall = core(box_core([0.2, 0.01, 0.5]))
    duration = 1 / 60
    spin = np.array([0.0, 0.0, math.pi / duration])  # half a turn per step
    wall_at = np.array([0.0, 0.8, 0.0])
    args = (plank, [0, 0, 0], EYE, [0, 0, 0], spin, 0.0, wall, wall_at, EYE, [0, 0, 0], [0, 0, 0], 0.0, duration)
    # the start-of-step picture: the gap and the closest points' approach speed along the normal
    sep0, n0, pa0, pb0 = penetration(Core(*plank, np.zeros(3), EYE), 0.0, Core(*wall, wall_at, EYE), 0.0)
    approach = np.cross(spin, pa0) @ n0  # the plank point's velocity along the normal (the wall is still)
    assert sep0 == pytest.approx(0.79 - 0.02, abs=1e-12) and sep0 - duration * approach >= sep0 - 1e-12
    t, sep, n, hit, iterations = toi(*args, target=1e-3, tolerance=1e-4)
    assert hit and 0.3 < t < 0.5
    # dense sampling: apart before t, touching (within target + tolerance) at t, overlapping a little later

    def gap(s):
        R = rotated(EYE, *spin, duration * s)
        return penetration(Core(*plank, np.zeros(3), R), 0.0, Core(*wall, wall_at, EYE), 0.0)[0]
    assert min(gap(s) for s in np.linspace(0.0, t, 400)) >= 1e-3 - 1e-9
    assert gap(t) <= 1e-3 + 1e-4
    assert min(gap(s) for s in np.linspace(t, 1.0, 400)) < 0.0  # it would have gone through


def test_a_fast_hull_against_a_thin_wall_hits_at_the_closed_form_time():
    rock = convex_hull(np.random.default_rng(3).normal(size=(20, 3)) * 0.1)
    wall = box_hull([0.0025, 1.0, 1.0])
    reach_x = rock.vertices[:, 0].max()
    # 300 m/s along x from 1 m before the wall, at 60 Hz: 5 m per step
    t, sep, n, hit, _ = toi((rock.vertices, rock.adjacency_start, rock.adjacency), [-1.0, 0, 0], EYE, [300.0, 0, 0],
                            np.zeros(3), 0.0, (wall.vertices, wall.adjacency_start, wall.adjacency), np.zeros(3), EYE,
                            np.zeros(3), np.zeros(3), 0.0, 1 / 60, 1e-3, 1e-5)
    assert hit and t == pytest.approx((1.0 - 0.0025 - reach_x - 1e-3) / 5.0, abs=1e-5 / 5.0)


def test_a_fast_hull_meets_a_single_triangle_wall():
    """The bullet scene's one-triangle mesh wall: a hull at 300 m/s (5 m per 60 Hz step) starting 1 m before a
    triangle across its path meets it at the closed-form time (the triangle is a 3-vertex core)."""
    rock = convex_hull(np.random.default_rng(4).normal(size=(20, 3)) * 0.1)
    triangle = np.array([[0.0, -2.0, -2.0], [0.0, 2.0, -2.0], [0.0, 0.0, 2.0]])
    t, sep, n, hit, _ = toi((rock.vertices, rock.adjacency_start, rock.adjacency), [-1.0, 0, 0], EYE, [300.0, 0, 0],
                            np.zeros(3), 0.0, core(triangle), np.zeros(3), EYE, np.zeros(3), np.zeros(3), 0.0, 1 / 60,
                            1e-3, 1e-5)
    reach_x = rock.vertices[:, 0].max()
    assert hit and t == pytest.approx((1.0 - reach_x - 1e-3) / 5.0, abs=1e-5 / 5.0)
    np.testing.assert_allclose(n, [1, 0, 0], atol=1e-9)


# ---- mesh files -----------------------------------------------------------------------------------------

def test_shipped_meshes_read_back():
    rock_v, rock_t = load_mesh(os.path.join(MESHES, "rock.stl"), closed=True)
    assert 20 <= len(rock_v) and len(rock_t) <= 400
    hull = convex_hull(rock_v)
    assert hull.interior_points == 0  # the rock is its own hull
    mass, com, inertia, volume = polyhedron_mass_properties(rock_v, rock_t, density=2600.0, what="rock.stl")
    assert volume == pytest.approx(polyhedron_mass_properties(hull.vertices, hull.triangles, density=1.0)[3],
                                   rel=1e-9)
    terrain_v, terrain_t = load_mesh(os.path.join(MESHES, "terrain.obj"))
    assert 1000 <= len(terrain_t) <= 2000
    with pytest.raises(MeshFileError, match="terrain.obj: not closed.*holes"):
        load_mesh(os.path.join(MESHES, "terrain.obj"), closed=True)
    mug_v, mug_t = load_mesh(os.path.join(MESHES, "mug.obj"), closed=True)
    mass, com, inertia, volume = polyhedron_mass_properties(mug_v, mug_t, density=1.0)
    hull_volume = convex_hull(mug_v).triangles  # concave: its hull holds more than the mug's material
    assert volume < 0.5 * polyhedron_mass_properties(convex_hull(mug_v).vertices, hull_volume, density=1.0)[3]


def test_ascii_and_binary_stl_give_the_same_mesh(tmp_path):
    hull = box_hull([0.5, 0.25, 0.125])
    tri = hull.vertices[hull.triangles]
    ascii_lines = ["solid box"]
    for a, b, c in tri:
        ascii_lines += ["facet normal 0 0 0", "outer loop"]
        ascii_lines += [f"vertex {x:.17g} {y:.17g} {z:.17g}" for x, y, z in (a, b, c)]
        ascii_lines += ["endloop", "endfacet"]
    (tmp_path / "box_ascii.stl").write_text("\n".join(ascii_lines + ["endsolid box"]) + "\n")
    with open(tmp_path / "box_binary.stl", "wb") as out:
        out.write(b"\0" * 80 + struct.pack("<I", len(tri)))
        for a, b, c in tri:
            out.write(struct.pack("<12fH", 0, 0, 0, *a, *b, *c, 0))
    va, ta = load_mesh(tmp_path / "box_ascii.stl", closed=True)
    vb, tb = load_mesh(tmp_path / "box_binary.stl", closed=True)
    assert len(va) == len(vb) == 8 and len(ta) == len(tb) == 12
    np.testing.assert_allclose(va[ta], vb[tb], atol=1e-7)
    assert polyhedron_mass_properties(va, ta, mass=1.0)[3] == pytest.approx(1.0 * 0.5 * 0.25, rel=1e-12)


def test_bad_mesh_files_are_refused_naming_the_file_and_reason(tmp_path):
    with pytest.raises(MeshFileError, match="nothere.stl: cannot read: no such file"):
        load_mesh(tmp_path / "nothere.stl")
    (tmp_path / "dir.obj").mkdir()
    with pytest.raises(MeshFileError, match="dir.obj: cannot read: is a directory, not a regular file"):
        load_mesh(tmp_path / "dir.obj")
    (tmp_path / "empty.stl").write_bytes(b"")
    with pytest.raises(MeshFileError, match="empty.stl: empty"):
        load_mesh(tmp_path / "empty.stl")
    (tmp_path / "noise.stl").write_bytes(bytes(range(256)) * 3)
    with pytest.raises(MeshFileError, match="noise.stl: (not a mesh|empty)"):
        load_mesh(tmp_path / "noise.stl")
    (tmp_path / "text.obj").write_text("this is not\na mesh\n")
    with pytest.raises(MeshFileError, match="text.obj: (not a mesh|empty)"):
        load_mesh(tmp_path / "text.obj")
    (tmp_path / "shape.ply").write_text("ply\n")
    with pytest.raises(MeshFileError, match="shape.ply: unknown file type"):
        load_mesh(tmp_path / "shape.ply")
    big = tmp_path / "big.stl"
    with open(big, "wb") as out:
        out.truncate(MAX_FILE_BYTES + 1)  # sparse: the size is refused before a byte is read
    with pytest.raises(MeshFileError, match="big.stl: too big"):
        load_mesh(big)
    # a link to a shipped file is followed; a dangling link is not
    (tmp_path / "rock_link.stl").symlink_to(os.path.join(MESHES, "rock.stl"))
    assert len(load_mesh(tmp_path / "rock_link.stl")[1]) > 0
    (tmp_path / "dangling.stl").symlink_to(tmp_path / "gone.stl")
    with pytest.raises(MeshFileError, match="dangling.stl: cannot read"):
        load_mesh(tmp_path / "dangling.stl")
    # an open box (one triangle missing): readable, but not closed where closure is asked for
    hull = box_hull([1, 1, 1])
    lines = [f"v {x} {y} {z}" for x, y, z in hull.vertices] + [f"f {a + 1} {b + 1} {c + 1}"
                                                                for a, b, c in hull.triangles[:-1]]
    (tmp_path / "open.obj").write_text("\n".join(lines) + "\n")
    assert len(load_mesh(tmp_path / "open.obj")[1]) == 11
    with pytest.raises(MeshFileError, match="open.obj: not closed"):
        load_mesh(tmp_path / "open.obj", closed=True)


def test_rotated_is_rodrigues():
    w = np.array([0.3, -0.2, 0.5])
    R0 = Rotation.random(random_state=4).as_matrix()
    np.testing.assert_allclose(rotated(R0, *w, 0.7), Rotation.from_rotvec(w * 0.7).as_matrix() @ R0, atol=1e-15)

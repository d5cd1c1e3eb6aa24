"""Issue 25's shapes as bodies (in-process): convex hulls, compound bodies and static meshes from scene files —
their mass properties, the errors for bad input, and how they move: a box given as an 8-point hull moves like the
box primitive, a stack of hulls stands, a hull on a ramp sticks or slides by μ as the closed form says, a sphere
on the terrain gets from the BVH exactly the contacts of all triangles, compound bodies rest on their parts, the
fish avoid hulls and meshes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cgp_core import World, parse_scene
from cgp_core.bodies import Shape
from cgp_core.collision.bvh import StaticMesh
from cgp_core.collision.convex_phase import pack_meshes
from cgp_core.collision.mesh_contacts import mesh_capsule_contacts
from cgp_core.collision.narrowphase import ContactBuffer
from cgp_core.inertia import box_inertia, compound_mass_properties, parallel_axis, solid_sphere_inertia
from cgp_core.rotation import quat_from_rotvec, quat_rotate, quat_to_matrix
from cgp_core.scene import SceneError

CORNERS = [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]


def world(text: str, **kwargs) -> World:
    return World(parse_scene(text, "test.yaml"), **kwargs)


def box_points(half) -> str:
    return "[" + ", ".join(str([c[0] * half[0], c[1] * half[1], c[2] * half[2]]) for c in CORNERS) + "]"


# ---- the model: mass properties, messages -------------------------------------------------------------------

def test_a_convex_body_is_its_points_hull_with_exact_mass_properties_and_says_when_they_were_not_convex():
    half = (0.3, 0.2, 0.1)
    points = box_points(half)[:-1] + ", [0.05, 0.02, -0.01]]"  # the box's corners and one point inside
    w = world(f"""
bodies:
  - {{name: brick, shape: convex, points: {points}, mass: 2.0, position: [1, 2, 3]}}
""")
    model = w.body_model
    assert model.shape[0] == Shape.CONVEX and len(model.hulls[0].vertices) == 8
    np.testing.assert_allclose(model.inertia_body[0], box_inertia(2.0, 2 * np.array(half)), atol=1e-12)
    np.testing.assert_allclose(w.body_state.position[0], [1, 2, 3], atol=1e-12)  # the points' COM is 0
    np.testing.assert_allclose(model.half_extents[0], half, atol=1e-12)
    events = w.take_events()
    assert [e.level for e in events] == ["warn"]
    assert "brick" in events[0].text and "1 of the 9 points" in events[0].text


def test_a_convex_body_from_a_mesh_file_has_the_mass_properties_of_its_hull_and_its_com_as_origin():
    w = world("""
bodies:
  - {name: rock, shape: convex, mesh: rock.stl, scale: 2.0, density: 2600, position: [0, 0, 1]}
""")
    from cgp_core.collision.meshfile import load_mesh
    from cgp_core.inertia import polyhedron_mass_properties
    from cgp_core.scene import builtin_mesh_dir

    vertices, triangles = load_mesh(builtin_mesh_dir() / "rock.stl")
    mass, com, inertia, _ = polyhedron_mass_properties(2.0 * vertices, triangles, density=2600.0)
    assert w.body_model.mass[0] == pytest.approx(mass, rel=1e-12)
    np.testing.assert_allclose(w.body_model.inertia_body[0], inertia, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(w.body_state.position[0], [0, 0, 1] + com, atol=1e-12)
    assert not [e for e in w.take_events() if e.level != "info"]  # the rock is its own hull


def test_a_compound_body_sums_its_parts_by_the_parallel_axis_theorem():
    """J = Σ (Rᵢ Jᵢ Rᵢᵀ + mᵢ (|dᵢ|² 1 − dᵢ dᵢᵀ)) with the mass spread by volume; the body frame's origin is the
    COM and the parts keep their poses relative to it."""
    turn = quat_from_rotvec(np.array([0.0, 0.0, math.pi / 4]))
    w = world(f"""
bodies:
  - name: dumbbell
    shape: compound
    density: 1000
    position: [0, 0, 2]
    parts:
      - {{shape: sphere, radius: 0.1, position: [-0.3, 0, 0]}}
      - {{shape: sphere, radius: 0.15, position: [0.3, 0, 0]}}
      - {{shape: box, size: [0.6, 0.04, 0.04], orientation: {turn.tolist()}}}
""")
    model = w.body_model
    v1, v2, v3 = 4 / 3 * math.pi * 0.1**3, 4 / 3 * math.pi * 0.15**3, 0.6 * 0.04 * 0.04
    masses = 1000 * np.array([v1, v2, v3])
    R = quat_to_matrix(np.array([[0, 0, 0, 1.0], [0, 0, 0, 1.0], turn]))
    inertias = np.stack([solid_sphere_inertia(masses[0], 0.1), solid_sphere_inertia(masses[1], 0.15),
                         box_inertia(masses[2], [0.6, 0.04, 0.04])])
    total, com, inertia = compound_mass_properties(masses, np.array([[-0.3, 0, 0], [0.3, 0, 0], [0, 0, 0]]), R,
                                                   inertias)
    assert model.mass[0] == pytest.approx(total, rel=1e-12)
    np.testing.assert_allclose(model.inertia_body[0], inertia, rtol=1e-12)
    # by hand for the two spheres about the COM along x: the parallel-axis terms
    d1, d2, d3 = -0.3 - com[0], 0.3 - com[0], -com[0]
    by_hand = (parallel_axis(inertias[0], masses[0], np.array([d1, 0, 0]))
               + parallel_axis(inertias[1], masses[1], np.array([d2, 0, 0]))
               + parallel_axis(R[2] @ inertias[2] @ R[2].T, masses[2], np.array([d3, 0, 0])))
    np.testing.assert_allclose(model.inertia_body[0], by_hand, rtol=1e-12)
    np.testing.assert_allclose(w.body_state.position[0], [com[0], 0, 2], atol=1e-12)
    np.testing.assert_allclose(model.parts[0].position[:, 0], [-0.3 - com[0], 0.3 - com[0], -com[0]], atol=1e-12)


@pytest.mark.parametrize("body, key, reason", [
    ("{name: b, shape: convex, points: [[0, 0, 0], [1, 0, 0], [0, 1, 0]]}", "bodies[0] (b).points",
     "at least 4 points"),
    ("{name: b, shape: convex, points: [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0.5, 0.5, 0]]}",
     "bodies[0] (b).points", "coplanar"),
    ("{name: b, shape: convex, points: [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, .nan]]}", "bodies[0] (b).points[3][2]",
     "finite"),
    ("{name: b, shape: convex, points: [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], mesh: rock.stl}", "bodies[0] (b)",
     "exactly one"),
    ("{name: b, shape: convex, mesh: no_such_rock.stl}", "bodies[0] (b).mesh", "no_such_rock.stl: cannot read"),
    ("{name: b, shape: convex, mesh: rock.stl, scale: 0}", "bodies[0] (b).scale", "must be > 0"),
    ("{name: b, shape: mesh, mesh: terrain.obj}", "bodies[0] (b).fixed", "must be fixed"),
    ("{name: b, shape: mesh, mesh: terrain.obj, fixed: true, mass: 3}", "bodies[0] (b).mass", "no mass"),
    ("{name: b, shape: compound, parts: []}", "bodies[0] (b).parts", "non-empty list"),
    ("{name: b, shape: compound, parts: [{shape: cone, radius: 1}]}", "bodies[0] (b).parts[0].shape",
     "one of sphere, box, capsule, convex"),
    ("{name: b, shape: compound, parts: [{shape: box, radius: 1}]}", "bodies[0] (b).parts[0].radius",
     "does not apply to shape box"),
    ("{name: b, shape: compound, parts: [{shape: convex, points: [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]}]}",
     "bodies[0] (b).parts[0].points", "coplanar"),
    ("{name: b, shape: sphere, radius: 1, points: [[0, 0, 0]]}", "bodies[0] (b).points",
     "does not apply to shape sphere"),
])
def test_bad_shapes_are_refused_naming_the_file_the_key_and_the_reason(body, key, reason):
    with pytest.raises(SceneError) as error:
        parse_scene(f"bodies:\n  - {body}\n", "bad.yaml")
    text = str(error.value)
    assert f"bad.yaml: {key}" in text and reason in text, text


def test_too_many_points_and_a_file_that_is_no_mesh_are_refused(tmp_path, monkeypatch):
    from cgp_core.collision import convex

    monkeypatch.setattr(convex, "MAX_INPUT_POINTS", 5)
    with pytest.raises(SceneError, match=r"bodies\[0\] \(b\).points: 9 points; at most 5"):
        parse_scene("bodies:\n  - {name: b, shape: convex, points: " + box_points((1, 1, 1))[:-1] + ", [0, 0, 0]]}",
                    "many.yaml")
    scene = tmp_path / "scene.yaml"
    (tmp_path / "junk.stl").write_bytes(b"solid junk\nthis is not an stl file\n")
    scene.write_text("bodies:\n  - {name: b, shape: convex, mesh: junk.stl}\n")  # next to the scene file
    from cgp_core import load_scene

    with pytest.raises(SceneError) as error:
        load_scene(scene)
    assert "bodies[0] (b).mesh: mesh file" in str(error.value) and "junk.stl" in str(error.value)


def test_a_static_mesh_reports_its_bvh_and_is_found_next_to_the_scene_file(tmp_path):
    import shutil

    from cgp_core import load_scene
    from cgp_core.scene import builtin_mesh_dir

    shutil.copy(builtin_mesh_dir() / "terrain.obj", tmp_path / "hills.obj")
    (tmp_path / "scene.yaml").write_text("bodies:\n  - {name: land, shape: mesh, mesh: hills.obj, fixed: true, "
                                         "scale: [2, 2, 1]}\n")
    w = World(load_scene(tmp_path / "scene.yaml"))
    mesh = w.body_model.meshes[0]
    assert len(mesh.triangles) == 1152 and mesh.vertices[:, 0].max() == pytest.approx(10.0)
    (event,) = w.take_events()
    assert event.level == "info" and "land: hills.obj, 1152 triangles" in event.text and "BVH" in event.text \
        and "ms" in event.text and "MB" in event.text


# ---- motion ------------------------------------------------------------------------------------------------

def test_a_box_given_as_an_8_point_hull_moves_like_the_box_primitive():
    """The same scene twice — a box thrown tumbling onto the ground and against a fixed box — once as
    ``shape: box``, once as ``shape: convex`` with its 8 corners: the same mass properties (exactly), and
    trajectories within 2 mm and 0.02 rad over 2 s of bouncing, sliding and coming to rest."""
    half = (0.2, 0.15, 0.1)

    def run(shape: str):
        body = (f"shape: box, size: {[2 * h for h in half]}" if shape == "box" else
                f"shape: convex, points: {box_points(half)}")
        w = world(f"""
world: {{substeps: 4, sleep: false}}
bodies:
  - {{name: wall, shape: box, size: [0.2, 2, 1], position: [1.2, 0, 0.5], fixed: true}}
  - {{name: thrown, {body}, mass: 3.0, position: [0, 0, 0.6], orientation: [0.1, 0.2, 0.05, 1],
     linear_velocity: [2.5, 0.3, 0], angular_velocity: [1, -2, 3], friction: 0.5, restitution: 0.2}}
""")
        poses = []
        for _ in range(120):
            w.step()
            poses.append(np.concatenate([w.body_state.position[1], w.body_state.orientation[1]]))
        return np.array(poses)

    as_box, as_hull = run("box"), run("convex")
    assert np.abs(as_box[:, :3] - as_hull[:, :3]).max() < 2e-3
    dots = np.abs(np.einsum("ij,ij->i", as_box[:, 3:], as_hull[:, 3:]))
    assert (2 * np.arccos(np.minimum(dots, 1.0))).max() < 0.02
    assert abs(as_box[-1, 0] - as_box[0, 0]) > 0.5  # it did travel (to the wall)


def prism_points(sides: int, radius: float, half_height: float) -> str:
    angles = np.arange(sides) * 2 * np.pi / sides
    ring = [[radius * math.cos(a), radius * math.sin(a)] for a in angles]
    return "[" + ", ".join(f"[{x:.6f}, {y:.6f}, {z}]" for z in (-half_height, half_height) for x, y in ring) + "]"


def test_a_stack_of_ten_hulls_stands_for_ten_seconds():
    """Ten hexagonal prisms (0.4 m across, 0.2 m high), each turned a little and shifted a few mm: after 10 s
    (sleeping off, so they are solved every step) none has moved by more than 1 % of its size."""
    rng = np.random.default_rng(5)
    bodies = []
    for k in range(10):
        q = quat_from_rotvec(np.array([0, 0, rng.uniform(-0.03, 0.03)]))
        x, y = rng.uniform(-0.004, 0.004, 2)
        bodies.append(f"  - {{name: p{k}, shape: convex, points: {prism_points(6, 0.2, 0.1)}, mass: 2.0, "
                      f"position: [{x}, {y}, {0.1 + 0.2 * k}], orientation: {q.tolist()}, friction: 0.6}}")
    w = world("world: {substeps: 4, sleep: false}\nbodies:\n" + "\n".join(bodies) + "\n")
    start = w.body_state.position.copy()
    for _ in range(600):
        w.step()
    drift = np.linalg.norm(w.body_state.position - start, axis=1)
    assert drift.max() <= 0.01 * 0.4, drift


@pytest.mark.parametrize("detection", ["every_substep", "once_per_tick"])
@pytest.mark.parametrize("mu, sticks", [(0.5, True), (0.2, False)])
def test_a_hull_on_a_25_degree_ramp_sticks_or_slides_by_mu(mu, sticks, detection):
    """tan 25° = 0.466: with μ = 0.5 a hexagonal prism resting on a fixed ramp (a box) stays put; with μ = 0.2
    it slides with a = g (sin θ − μ cos θ) (within 1 %), as the box does in tests/test_contacts.py — with its
    contacts found every sub-step and once per tick (``world.contact_detection``, cgp_core/collision/carry.py)."""
    theta = math.radians(25.0)
    q = quat_from_rotvec(np.array([0.0, -theta, 0.0]))
    normal = quat_rotate(q, np.array([0.0, 0.0, 1.0]))
    downhill = -quat_rotate(q, np.array([1.0, 0.0, 0.0]))
    start = np.array([0.0, 0.0, 1.0]) + normal * (0.1 + 0.05)
    w = world(f"""
world: {{substeps: 4, sleep: false, ground: false, contact_detection: {detection}}}
bodies:
  - {{name: ramp, shape: box, size: [6, 2, 0.2], position: [0, 0, 1], orientation: {q.tolist()}, fixed: true,
     friction: {mu}}}
  - {{name: puck, shape: convex, points: {prism_points(8, 0.1, 0.05)}, mass: 1.0, position: {start.tolist()},
     orientation: {q.tolist()}, friction: {mu}}}
""", dt=1 / 60)
    speeds = []
    for _ in range(60):
        w.step()
        speeds.append(w.body_state.linear_velocity(w.body_model)[1] @ downhill)
    if sticks:
        settled = w.body_state.position[1].copy()
        for _ in range(120):
            w.step()
        assert abs((w.body_state.position[1] - settled) @ downhill) < 1e-6
        assert np.linalg.norm(w.body_state.linear_velocity(w.body_model)[1]) < 1e-6
    else:
        t = np.arange(1, 61) / 60
        acceleration = np.polyfit(t[6:], np.array(speeds)[6:], 1)[0]
        assert acceleration == pytest.approx(9.81 * (math.sin(theta) - mu * math.cos(theta)), rel=0.01)
        assert np.linalg.norm(w.body_state.angular_velocity(w.body_model)[1]) < 1e-6  # no tumbling


def test_a_sphere_on_the_terrain_gets_from_the_bvh_the_contacts_of_all_its_triangles():
    """Spheres resting (2 mm deep) on terrain.obj at random places, the mesh turned and moved: the contacts
    through the BVH (the convex stage's mesh–sphere pair) equal those of the same kernel over every triangle (a
    one-leaf "tree" holding them all), row for row."""
    from cgp_core.collision.bvh import bvh_closest_point
    from cgp_core.scene import builtin_mesh_dir

    w = world("bodies:\n  - {name: land, shape: mesh, mesh: terrain.obj, fixed: true}\n")
    mesh = w.body_model.meshes[0]
    everything = StaticMesh(mesh.vertices, mesh.triangles, mesh.active_edges,
                            mesh.vertices.min(0)[None], mesh.vertices.max(0)[None], np.zeros(1, np.int64),
                            np.array([len(mesh.triangles)]), np.arange(len(mesh.triangles)), mesh.triangle_lo,
                            mesh.triangle_hi, 0.0)
    assert builtin_mesh_dir().is_dir()
    rng = np.random.default_rng(11)
    R = quat_to_matrix(quat_from_rotvec(np.array([0.1, -0.2, 0.7])))
    p = np.array([0.5, -1.0, 0.3])
    radius = 0.15
    found = 0
    for _ in range(40):
        xy = rng.uniform(-4.5, 4.5, 2)
        _, distance, cx, cy, cz = bvh_closest_point(mesh.arrays, np.array([*xy, 5.0]), np.inf)
        local = np.array([cx, cy, cz])
        # the closest point straight below, then the sphere 2 mm into the surface along the local up
        local = local + np.array([0, 0, radius - 0.002])
        centre = p + R @ local
        rows = []
        for m in (mesh, everything):
            n, s, q, f = np.empty((64, 3)), np.empty(64), np.empty((64, 3)), np.empty(64, np.int64)
            count, complete = mesh_capsule_contacts(m.arrays, p, R, False, np.array([centre, centre]), radius, 0.01,
                                                    np.empty(2048, np.int64), ContactBuffer(n, s, q, f), 0)
            assert complete
            order = np.lexsort(np.round(q[:count], 12).T)
            rows.append((n[:count][order], s[:count][order], q[:count][order]))
        (n1, s1, q1), (n2, s2, q2) = rows
        assert len(s1) == len(s2) >= 1
        np.testing.assert_allclose(n1, n2, atol=1e-12)
        np.testing.assert_allclose(s1, s2, atol=1e-12)
        np.testing.assert_allclose(q1, q2, atol=1e-12)
        found += len(s1)
    assert found >= 40
    assert pack_meshes([mesh], [False]).triangles.shape == mesh.triangles.shape


def test_a_compound_table_rests_on_its_legs():
    """A table of 5 parts (a top, three capsule legs and a hull foot) dropped on the ground comes to rest level,
    on the ends of its legs and its foot, and sleeps."""
    w = world("""
world: {substeps: 4}
bodies:
  - name: table
    shape: compound
    mass: 4.0
    position: [0, 0, 0.02]
    parts:
      - {shape: box, size: [0.6, 0.6, 0.04], position: [0, 0, 0.42]}
      - {shape: capsule, radius: 0.02, length: 0.36, position: [0.25, 0.25, 0.2]}
      - {shape: capsule, radius: 0.02, length: 0.36, position: [-0.25, 0.25, 0.2]}
      - {shape: capsule, radius: 0.02, length: 0.36, position: [0.25, -0.25, 0.2]}
      - {shape: convex, points: [[-0.27, -0.27, 0], [-0.23, -0.27, 0], [-0.27, -0.23, 0], [-0.23, -0.23, 0],
                                 [-0.25, -0.25, 0.4]]}
""")
    for _ in range(240):
        w.step()
    R = quat_to_matrix(w.body_state.orientation)[0]
    assert R[2, 2] > 1 - 1e-6  # level
    legs_bottom = w.body_state.position[0, 2] + (w.body_model.parts[0].position[1:4, 2] - 0.2)[0]
    assert legs_bottom == pytest.approx(0.0, abs=2e-3)
    assert w.bodies_asleep


def test_fish_avoid_hulls_by_their_face_planes_and_stay_above_a_terrain():
    from cgp_core.boids import Obstacles

    w = world(f"""
bodies:
  - {{name: brick, shape: convex, points: {box_points((0.5, 0.5, 0.5))}, fixed: true, position: [0, 0, 2]}}
  - {{name: land, shape: mesh, mesh: terrain.obj, fixed: true, position: [10, 0, 0]}}
  - {{name: table, shape: compound, fixed: true, position: [0, 5, 1], parts: [{{shape: box, size: [1, 1, 0.1]}}]}}
""")
    obstacles = Obstacles.from_bodies(w.body_model, w.body_state)
    points = np.array([[0.2, 0.1, 2.3],    # inside the brick: 0.2 below its top face
                       [0.0, 0.0, 2.8],    # 0.3 above it
                       [10.0, 0.0, -0.05],  # below the terrain (one-sided: inside)
                       [10.0, 0.0, 0.6],   # above it
                       [0.0, 5.0, 1.2]])   # above the table's top part: 0.15 away
    hits = obstacles.query(points.T, 1.0)
    by_point = {int(i): (d, n) for i, d, n in zip(hits.point, hits.distance, hits.normal.T)}
    assert by_point[0][0] == pytest.approx(-0.2) and np.allclose(by_point[0][1], [0, 0, 1])
    assert by_point[1][0] == pytest.approx(0.3) and np.allclose(by_point[1][1], [0, 0, 1])
    assert by_point[2][0] < 0 and by_point[2][1][2] > 0.9
    assert by_point[3][0] > 0 and by_point[3][1][2] > 0.9
    assert by_point[4][0] == pytest.approx(0.15) and np.allclose(by_point[4][1], [0, 0, 1])

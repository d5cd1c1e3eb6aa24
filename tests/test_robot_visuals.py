"""Issue 36 (markers): a robot's URDF ``<visual>`` geometry on ``~/markers``, in process (the node's serializer,
decoded by our CDR reader, which tests/test_cdr.py proves against rclpy's).

- The arm at a set joint state: one marker per visual (ns ``robots/arm``), its pose = Pinocchio's placement of
  that visual geometry (forward kinematics composed with the visual's ``<origin>``: the oracle is Pinocchio's URDF
  reader, not our model) to 1e-9, its type and scale the URDF's shape, its colour the URDF's material (read from
  the file here).  The link bodies are not drawn as well.
- A mesh visual: a TRIANGLE_LIST of the file's triangles with the URDF's scale (a mirroring scale reversing the
  winding), at the visual's pose; a material named inside another link's visual is used by name; a visual without
  material is grey; a COLLADA mesh is a MESH_RESOURCE with its file:// URI; an unreadable mesh is not drawn and
  says why; a robot without visuals keeps its link bodies' markers.
- ``cgp-sim-render``'s primitives draw every marker type the arm's visuals use (nothing skipped), where they are.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from cgp_core import World
from cgp_core.robots.links import LINK_COLOR
from cgp_core.rotation import quat_to_matrix
from cgp_sim_ros.drawing.robots import VISUAL_MESH_TRIANGLES, visual_drawing
from cgp_sim_ros.render.primitives import primitives
from cgp_sim_ros.ros.messages import TickMessages
from cgp_sim_ros.wire import cdr

REPO = Path(__file__).resolve().parents[1]
ARM_URDF = REPO / "msgs_config" / "robots" / "arm.urdf"
SHAPE_TYPES = {"box": cdr.CUBE, "sphere": cdr.SPHERE, "cylinder": cdr.CYLINDER}
#: the set joint state (URDF joint names): away from zero in every joint, inside the limits
JOINTS = {"shoulder_pan": 0.7, "shoulder_lift": -0.4, "elbow": 1.1, "wrist": -0.8, "finger_left_joint": 0.015}


def markers_of(world, ns_prefix: str = "") -> list[cdr.MarkerData]:
    data = TickMessages(world).markers(world.time_ns, delete_all_first=False, tick=0)
    return [m for m in cdr.read_marker_array(data) if m.ns.startswith(ns_prefix)]


def set_joints(world, robot: str, joints: dict[str, float]) -> np.ndarray:
    """Put ``robot``'s joints at ``joints`` (mimic followers follow), the link bodies there too; returns the
    robot's q (n_q,)."""
    robots = world.robots
    r = robots.robot(robot)
    m = r.model
    q = robots.q[r.q_slice]
    for joint, value in joints.items():
        q[m.q_start[m.joint_names.index(joint)]] = value
    for f, lead, mult, off in zip(m.mimic_follower, m.mimic_leader, m.mimic_multiplier, m.mimic_offset):
        q[m.q_start[np.searchsorted(m.dof_start, f, side="right") - 1]] = \
            mult * q[m.q_start[np.searchsorted(m.dof_start, lead, side="right") - 1]] + off
    robots.prepare()  # the kinematics at the new q
    robots.write_bodies(world.body_model, world.body_state)
    return q.copy()


def pinocchio_visuals(urdf: Path, q_by_joint: dict[str, float]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{link: (R (3, 3), p (3,))} of each link's (first) visual geometry by Pinocchio: oMg at q."""
    pin = pytest.importorskip("pinocchio")
    model, _, visual = pin.buildModelsFromUrdf(str(urdf))
    data, vdata = model.createData(), pin.GeometryData(visual)
    q = pin.neutral(model)
    for j in range(1, model.njoints):
        q[model.joints[j].idx_q] = q_by_joint[model.names[j]]
    pin.updateGeometryPlacements(model, data, visual, vdata, q)
    out = {}
    for g, placement in zip(visual.geometryObjects, vdata.oMg):
        link = g.name.rsplit("_", 1)[0]
        out.setdefault(link, (np.array(placement.rotation), np.array(placement.translation)))
    return out


def urdf_colors(urdf: Path) -> dict[str, np.ndarray]:
    """{link: rgba} of each link's visual, from the file's top-level materials (by name) or its own colour."""
    root = ET.parse(urdf).getroot()
    named = {m.get("name"): np.array(m.find("color").get("rgba").split(), float)
             for m in root.findall("material") if m.find("color") is not None}
    out = {}
    for link in root.findall("link"):
        material = link.find("visual/material")
        if material is not None:
            color = material.find("color")
            out[link.get("name")] = (np.array(color.get("rgba").split(), float) if color is not None
                                     else named[material.get("name")])
    return out


def test_arm_visual_markers_are_fk_composed_with_the_visual_origins_in_the_urdf_colours():
    world = World.from_scene("arm_teleop")
    world.step()
    q = set_joints(world, "arm", JOINTS)
    robots = world.robots
    names, position, _, _ = robots.joint_state("arm")
    q_by_joint = dict(zip(names, position))
    assert q_by_joint["finger_right_joint"] == pytest.approx(JOINTS["finger_left_joint"])
    expected = pinocchio_visuals(ARM_URDF, q_by_joint)
    colors = urdf_colors(ARM_URDF)
    visuals = robots.visuals("arm")
    markers = markers_of(world, "robots/")
    assert [(m.ns, m.id) for m in markers] == [("robots/arm", k) for k in range(len(visuals))]
    assert {g.link for g in visuals} == set(expected) == set(colors)  # every URDF visual, once
    for m, g in zip(markers, visuals):
        R, p = expected[g.link]
        assert np.abs(m.position - p).max() <= 1e-9, (g.link, m.position, p)
        assert np.abs(quat_to_matrix(m.orientation) - R).max() <= 1e-9, g.link
        assert m.type == SHAPE_TYPES[g.kind]
        np.testing.assert_allclose(m.color, colors[g.link], atol=1e-7)  # (float32 in the message)
        size = np.asarray(g.size)
        scale = {"box": size, "sphere": np.full(3, 2 * size[0]),
                 "cylinder": np.array([2 * size[0], 2 * size[0], size[1]])}[g.kind]
        np.testing.assert_allclose(m.scale, scale, rtol=0, atol=1e-15)
    # the same poses as Robots.visual_poses at this q, and the joint state really moved the arm
    R, p = robots.visual_poses("arm")
    np.testing.assert_allclose(np.array([m.position for m in markers]), p, atol=1e-12)
    assert np.abs(q).max() > 0.5
    # one picture of each link: the link bodies (their collision shapes) are not drawn too
    all_markers = markers_of(world)
    messages = TickMessages(world)
    framed = cdr.read_marker_array(messages.static_markers(world.time_ns))  # the free bodies: drawn once
    assert not [m for m in all_markers + framed if m.ns.startswith("bodies/arm/")]
    assert {m.ns for m in all_markers} >= {"robots/arm"}
    assert {m.ns for m in framed} >= {"bodies/crate", "bodies/block", "bodies/ball"}
    assert TickMessages(world).marker_ids()["robots/arm"] == set(range(len(visuals)))


def test_the_7dof_arms_visuals_several_per_link_are_pinocchios_while_it_follows_its_trajectory():
    """The `arm` scene's arm7.urdf (14 visuals on 11 links: a link's column and its joint housing, the y-axis
    housings turned by their <origin rpy>): after 2.5 s on its trajectory, each marker is Pinocchio's placement of
    the same visual (its k-th of the link: Pinocchio's ``<link>_<k>``) to 1e-9, in the URDF's colour."""
    pin = pytest.importorskip("pinocchio")
    urdf = REPO / "msgs_config" / "robots" / "arm7.urdf"
    world = World.from_scene("arm")
    for _ in range(150):
        world.step()
    names, position, _, _ = world.robots.joint_state("arm")
    model, _, geometry = pin.buildModelsFromUrdf(str(urdf))
    data, gdata = model.createData(), pin.GeometryData(geometry)
    q = pin.neutral(model)
    for j in range(1, model.njoints):
        q[model.joints[j].idx_q] = position[list(names).index(model.names[j])]
    pin.updateGeometryPlacements(model, data, geometry, gdata, q)
    placements = {g.name: (np.array(m.rotation), np.array(m.translation))
                  for g, m in zip(geometry.geometryObjects, gdata.oMg)}
    base = np.array([0.0, 0.0, 0.2])  # the scene puts the base on its pedestal
    visuals = world.robots.visuals("arm")
    markers = markers_of(world, "robots/")
    colors = urdf_colors(urdf)
    assert len(visuals) == len(markers) == len(placements) == 14
    seen: dict[str, int] = {}
    for m, g in zip(markers, visuals):
        k = seen[g.link] = seen.get(g.link, -1) + 1
        R, p = placements[f"{g.link}_{k}"]
        assert np.abs(m.position - (p + base)).max() <= 1e-9, (g.link, k)
        assert np.abs(quat_to_matrix(m.orientation) - R).max() <= 1e-9, (g.link, k)
        assert m.type == SHAPE_TYPES[g.kind]
        np.testing.assert_allclose(m.color, colors[g.link], atol=1e-7)
    assert np.abs(position[:7]).max() > 0.5  # on its way: not the zero pose


def test_the_renderer_draws_every_arm_visual():
    world = World.from_scene("arm_teleop")
    world.step()
    markers = markers_of(world, "robots/")
    drawn = primitives(markers)
    assert drawn.skipped == set()
    # every visual drawn as triangles where its marker is: the cylinders and boxes' triangles' centres
    assert len(drawn.triangles) >= 12 * 5 + 2 * 24
    centre = drawn.triangles.reshape(-1, 3).mean(axis=0)
    _, p = world.robots.visual_poses("arm")
    lo, hi = p.min(axis=0) - 0.1, p.max(axis=0) + 0.1
    assert np.all(centre >= lo) and np.all(centre <= hi)
    colors = {tuple(np.round(c, 3)) for c in drawn.triangle_colors}
    assert (0.95, 0.5, 0.1) in colors and (0.2, 0.2, 0.22) in colors  # orange and dark, from the URDF


# ---- a robot with a mesh visual ---------------------------------------------------------------------------

TETRAHEDRON = """# four triangles, counter-clockwise seen from outside
v 0 0 0
v 0.1 0 0
v 0 0.1 0
v 0 0 0.1
f 1 3 2
f 1 2 4
f 1 4 3
f 2 3 4
"""


def mesh_robot(tmp_path: Path, scale: str = "2 1 0.5", mesh: str = "tetra.obj") -> Path:
    (tmp_path / "tetra.obj").write_text(TETRAHEDRON)
    urdf = tmp_path / "meshy.urdf"
    urdf.write_text(f"""<robot name="meshy">
  <link name="base">
    <visual><origin xyz="0.1 0.2 0.3" rpy="0.3 -0.2 0.9"/>
      <geometry><mesh filename="{mesh}" scale="{scale}"/></geometry>
      <material name="teal"><color rgba="0.1 0.6 0.55 1"/></material></visual>
    <collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision>
  </link>
  <joint name="hinge" type="revolute"><parent link="base"/><child link="arm1"/>
    <origin xyz="0 0 0.2"/><axis xyz="1 0 0"/><limit lower="-2" upper="2" effort="50" velocity="2"/></joint>
  <link name="arm1">
    <inertial><origin xyz="0 0 0.1"/><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0"
      iyz="0"/></inertial>
    <visual><origin xyz="0 0 0.1" rpy="0 0.5 0"/><geometry><sphere radius="0.05"/></geometry></visual>
    <visual><origin xyz="0 0 0.2"/><geometry><cylinder radius="0.02" length="0.1"/></geometry>
      <material name="teal"/></visual>
    <collision><origin xyz="0 0 0.1"/><geometry><box size="0.04 0.04 0.2"/></geometry></collision>
  </link>
</robot>""")
    return urdf


def obj_triangles(scale) -> np.ndarray:
    """(3t, 3) the tetrahedron's triangles as TRIANGLE_LIST points, read here from the text, scaled."""
    lines = [line.split() for line in TETRAHEDRON.splitlines()]
    v = np.array([[float(x) for x in line[1:]] for line in lines if line and line[0] == "v"])
    f = np.array([[int(i) - 1 for i in line[1:]] for line in lines if line and line[0] == "f"])
    return (v * np.asarray(scale, float))[f].reshape(-1, 3)


def test_a_mesh_visual_is_the_files_triangles_at_the_visual_pose(tmp_path):
    world = World.from_scene("arm_teleop")
    world.spawn({"robot": {"urdf": str(mesh_robot(tmp_path))}}, name="meshy", position=(1.0, -1.0, 0.0))
    world.step()
    set_joints(world, "meshy", {"hinge": 0.6})
    markers = markers_of(world, "robots/meshy")
    assert [m.id for m in markers] == [0, 1, 2]
    mesh, sphere, cylinder = markers
    assert mesh.type == cdr.TRIANGLE_LIST
    np.testing.assert_array_equal(mesh.points, obj_triangles([2, 1, 0.5]))  # the file's triangles, scaled
    np.testing.assert_array_equal(mesh.scale, [1, 1, 1])
    # the visual's pose: the fixed base at the spawn pose, then the origin (rpy: Rz(yaw) Ry(pitch) Rx(roll))
    roll, pitch, yaw = 0.3, -0.2, 0.9
    Rx = np.array([[1, 0, 0], [0, np.cos(roll), -np.sin(roll)], [0, np.sin(roll), np.cos(roll)]])
    Ry = np.array([[np.cos(pitch), 0, np.sin(pitch)], [0, 1, 0], [-np.sin(pitch), 0, np.cos(pitch)]])
    Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    np.testing.assert_allclose(mesh.position, [1.1, -0.8, 0.3], atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(mesh.orientation), Rz @ Ry @ Rx, atol=1e-12)
    np.testing.assert_allclose(mesh.color, [0.1, 0.6, 0.55, 1], atol=1e-7)
    # the moving link's visuals: hinge about x by 0.6 rad at z = 0.2 above the base
    c, s = np.cos(0.6), np.sin(0.6)
    R_link = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    base = np.array([1.0, -1.0, 0.2])
    np.testing.assert_allclose(sphere.position, base + R_link @ [0, 0, 0.1], atol=1e-12)
    Ry5 = np.array([[np.cos(0.5), 0, np.sin(0.5)], [0, 1, 0], [-np.sin(0.5), 0, np.cos(0.5)]])
    np.testing.assert_allclose(quat_to_matrix(sphere.orientation), R_link @ Ry5, atol=1e-12)
    assert sphere.type == cdr.SPHERE and np.allclose(sphere.scale, 0.1)
    np.testing.assert_allclose(sphere.color, LINK_COLOR, atol=1e-7)  # no material: grey
    assert cylinder.type == cdr.CYLINDER and np.allclose(cylinder.scale, [0.04, 0.04, 0.1])
    np.testing.assert_allclose(cylinder.position, base + R_link @ [0, 0, 0.2], atol=1e-12)
    np.testing.assert_allclose(cylinder.color, [0.1, 0.6, 0.55, 1], atol=1e-7)  # by name, defined in 'base'
    # the arm next to it is still drawn by its visuals, and the mesh robot's links are not drawn as bodies
    names = {m.ns for m in markers_of(world)}
    assert "robots/arm" in names and not {n for n in names if n.startswith(("bodies/meshy/", "bodies/arm/"))}


def test_a_mirrored_mesh_keeps_its_front_outside(tmp_path):
    world = World.from_scene("arm_teleop")
    world.spawn({"robot": {"urdf": str(mesh_robot(tmp_path, scale="-1 1 1"))}}, name="meshy")
    world.step()
    (mesh,) = [m for m in markers_of(world, "robots/meshy") if m.id == 0]
    mirrored = obj_triangles([-1, 1, 1]).reshape(-1, 3, 3)[:, ::-1]  # each triangle wound the other way
    np.testing.assert_array_equal(mesh.points, mirrored.reshape(-1, 3))
    # counter-clockwise seen from outside: every normal points away from the centroid
    tris = mesh.points.reshape(-1, 3, 3)
    normals = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    assert np.all(np.einsum("ij,ij->i", normals, tris.mean(axis=1) - mesh.points.mean(axis=0)) > 0)


def test_other_mesh_formats_unreadable_meshes_and_robots_without_visuals(tmp_path):
    # a mesh format nobody here reads (3D Studio): a MESH_RESOURCE naming the file (RViz, Foxglove's desktop app)
    (tmp_path / "part.3ds").write_bytes(b"MM\x00\x00")
    urdf = mesh_robot(tmp_path, mesh="part.3ds")
    world = World.from_scene("arm_teleop")
    world.spawn({"robot": {"urdf": str(urdf)}}, name="meshy")
    world.step()
    (mesh,) = [m for m in markers_of(world, "robots/meshy") if m.id == 0]
    assert mesh.type == cdr.MESH_RESOURCE and mesh.mesh_resource == (tmp_path / "part.3ds").resolve().as_uri()
    np.testing.assert_array_equal(mesh.scale, [2, 1, 0.5])
    # a mesh file that cannot be read (here: malformed) is not drawn, and the drawing says why
    (tmp_path / "bad.obj").write_text("v 0 0 nonsense\n")
    geometry = world.robots.visuals("meshy")[0]
    from dataclasses import replace

    bad = visual_drawing(replace(geometry, mesh_path=str(tmp_path / "bad.obj")))
    assert bad.kind == "none" and "bad.obj" in bad.problem
    # a robot without visuals: drawn by its link bodies as before
    bare = urdf.read_text()
    for _ in range(bare.count("<visual>")):
        i = bare.index("<visual>")
        bare = bare[:i] + bare[bare.index("</visual>", i) + len("</visual>"):]
    world.spawn({"robot": {"urdf_xml": bare}}, name="bare", position=(0.0, 2.0, 0.0))
    world.step()
    names = {m.ns for m in markers_of(world)}
    assert "robots/bare" not in names and {"bodies/bare/base", "bodies/bare/arm1"} <= names


@pytest.mark.parametrize("suffix", [".dae", ".glb"])
def test_collada_and_gltf_visuals_are_drawn_as_their_triangles(tmp_path, suffix):
    """The visual meshes of most ROS robot packages are COLLADA: drawn as TRIANGLE_LIST like STL / OBJ, so that a
    browser's Foxglove, the bag and cgp-sim-render show them (not a file:// MESH_RESOURCE only RViz reads)."""
    trimesh = pytest.importorskip("trimesh")
    if suffix == ".dae":
        pytest.importorskip("collada")
    lines = [line.split() for line in TETRAHEDRON.splitlines()]
    v = np.array([[float(x) for x in line[1:]] for line in lines if line and line[0] == "v"])
    f = np.array([[int(i) - 1 for i in line[1:]] for line in lines if line and line[0] == "f"])
    trimesh.Trimesh(v, f, process=False).export(tmp_path / f"tetra{suffix}")
    world = World.from_scene("arm_teleop")
    world.spawn({"robot": {"urdf": str(mesh_robot(tmp_path, mesh=f"tetra{suffix}"))}}, name="meshy")
    world.step()
    (mesh,) = [m for m in markers_of(world, "robots/meshy") if m.id == 0]
    assert mesh.type == cdr.TRIANGLE_LIST
    np.testing.assert_array_equal(mesh.scale, [1, 1, 1])
    # the OBJ's triangles, scaled (the exporter may renumber vertices and start a triangle elsewhere: compared as
    # sets of corners, float32 in the file)
    drawn = {tuple(sorted(map(tuple, t.round(5)))) for t in mesh.points.reshape(-1, 3, 3)}
    expected = {tuple(sorted(map(tuple, t.round(5)))) for t in obj_triangles([2, 1, 0.5]).reshape(-1, 3, 3)}
    assert drawn == expected


def test_a_collada_file_with_a_doctype_is_refused_unparsed(tmp_path):
    """XXE: a COLLADA file is XML from wherever a URDF pointed; an external entity must never pull a file in."""
    secret = tmp_path / "secret.txt"
    secret.write_text("TOP-SECRET-42")
    (tmp_path / "evil.dae").write_text(
        f'<?xml version="1.0"?><!DOCTYPE c [<!ENTITY x SYSTEM "{secret.as_uri()}">]>'
        '<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1"><asset>'
        '<contributor><author>&x;</author></contributor></asset></COLLADA>')
    world = World.from_scene("arm_teleop")
    world.spawn({"robot": {"urdf": str(mesh_robot(tmp_path, mesh="evil.dae"))}}, name="meshy")
    geometry = world.robots.visuals("meshy")[0]
    drawing = visual_drawing(geometry)
    assert drawing.kind == "none" and "DOCTYPE" in drawing.problem and "evil.dae" in drawing.problem
    assert "TOP-SECRET" not in drawing.problem
    assert not [m for m in markers_of(world, "robots/meshy") if m.id == 0]


def test_a_big_visual_mesh_is_clustered_to_its_cap(tmp_path):
    # a 2 x n x n grid of triangles (a flat sheet, both sides) with more triangles than the cap
    n = int(np.ceil(np.sqrt(VISUAL_MESH_TRIANGLES))) + 2
    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1))
    vertices = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    k = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    quads = np.stack([k, k + 1, k + n + 2, k + n + 1], axis=-1).reshape(-1, 4)
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    text = "".join(f"v {a} {b} {c}\n" for a, b, c in vertices) + "".join(f"f {a + 1} {b + 1} {c + 1}\n"
                                                                           for a, b, c in faces)
    (tmp_path / "sheet.obj").write_text(text)
    urdf = mesh_robot(tmp_path, mesh="sheet.obj", scale="1 1 1")
    world = World.from_scene("arm_teleop")
    world.spawn({"robot": {"urdf": str(urdf)}}, name="meshy")
    drawing = visual_drawing(world.robots.visuals("meshy")[0])
    assert drawing.of == len(faces) > VISUAL_MESH_TRIANGLES
    assert 0 < drawing.triangles <= VISUAL_MESH_TRIANGLES and len(drawing.full) == 3 * drawing.triangles
    assert 0 < len(drawing.low) < len(drawing.full)
    # a view of the same sheet: its points stay on it
    assert np.all((drawing.full >= -1e-9) & (drawing.full <= 1 + 1e-9))


def test_visual_robots_count_in_the_level_of_detail_and_their_markers_go_with_them(tmp_path):
    world = World.from_scene("arm_teleop")
    world.spawn({"robot": {"urdf": str(mesh_robot(tmp_path))}}, name="meshy")
    world.step()
    messages = TickMessages(world)
    model = world.body_model
    full, low = messages.body_marker_bytes("full"), messages.body_marker_bytes("low")
    # one entry per body, then one per robot drawn by its visuals (arm, meshy); their link bodies count nothing
    assert len(full) == model.count + 2 and messages.visual_robots == ["arm", "meshy"]
    links = [i for i, name in enumerate(model.names) if name.startswith(("arm/", "meshy/"))]
    assert links and not full[links].any()
    # the arm: 7 primitives; meshy: a 4-triangle mesh (12 points of 24 bytes), a sphere and a cylinder
    overhead = 200  # messages.MARKER_OVERHEAD_BYTES
    assert full[model.count] == 7 * overhead
    assert full[model.count + 1] == low[model.count + 1] == 3 * overhead + 12 * 24
    # deleted: its namespace leaves the ids drawn (the node DELETEs them: TickPublisher.retire_markers)
    assert messages.marker_ids()["robots/meshy"] == {0, 1, 2}
    world.delete("meshy")
    world.step()
    after = TickMessages(world)
    assert "robots/meshy" not in after.marker_ids() and after.marker_ids()["robots/arm"] == set(range(7))
    assert not [m for m in markers_of(world) if m.ns.startswith(("robots/meshy", "bodies/meshy/"))]

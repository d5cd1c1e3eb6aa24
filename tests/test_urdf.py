"""Loading URDFs into RobotModel: what is read (inertial rpy, merges, mimic, limits, meshes, xacro) and what is
refused (missing limits, unknown meshes, bad inertias, DTDs and entities, malformed XML, cycles, two roots)."""

from __future__ import annotations

import math
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from cgp_core.robots import JOINT_FIXED_ROOT, JOINT_FLOATING, UrdfError, load_urdf
from cgp_core.robots.urdf import rpy_matrix

REPO = Path(__file__).resolve().parents[1]
ARM3 = REPO / "msgs_config" / "robots" / "arm3.urdf"

INERTIAL = ('<inertial><origin xyz="{xyz}" rpy="{rpy}"/><mass value="{mass}"/>'
            '<inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{iyy}" iyz="0" izz="{izz}"/></inertial>')


def _link(name, mass=1.0, xyz="0 0 0", rpy="0 0 0", ixx=0.01, iyy=0.02, izz=0.025, extra=""):
    return f'<link name="{name}">{INERTIAL.format(**locals())}{extra}</link>'


def _joint(name, parent, child, kind="revolute", extra='<limit lower="-1" upper="1" effort="1" velocity="1"/>',
           origin='<origin xyz="0 0 0.1"/>'):
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>{origin}'
            f'<axis xyz="0 0 1"/>{extra}</joint>')


def _robot(*parts):
    return '<?xml version="1.0"?><robot name="t">' + "".join(parts) + "</robot>"


def _refused(text_or_path, match, **kwargs):
    with pytest.raises(UrdfError, match=match) as info:
        load_urdf(text_or_path, **kwargs)
    return str(info.value)


# ---- what is read ----------------------------------------------------------------------------------------------

def test_inertial_rpy_turns_the_tensor_r_i_rt():
    """A link whose inertial frame is turned 90° about z: its tensor in the link frame is R I Rᵀ (ixx and iyy
    swap), not R I (the classic importer bug), and equals Pinocchio's."""
    text = _robot(_link("base"), _link("arm", mass=2.0, xyz="0.1 0 0", rpy=f"0 0 {math.pi / 2}", ixx=0.01, iyy=0.04,
                                       izz=0.03),
                  _joint("j", "base", "arm"))
    model = load_urdf(text)
    np.testing.assert_allclose(model.inertia[1], np.diag([0.04, 0.01, 0.03]), atol=1e-15)
    np.testing.assert_allclose(model.com[1], [0.1, 0, 0])
    # a general rpy
    R = rpy_matrix(np.array([0.3, -0.2, 0.5]))
    arm3 = load_urdf(ARM3)
    I = np.array([[0.012, 0.001, -0.0005], [0.001, 0.010, 0.0002], [-0.0005, 0.0002, 0.004]])
    np.testing.assert_allclose(arm3.inertia[1], R @ I @ R.T, atol=1e-15)
    pin = pytest.importorskip("pinocchio")
    pm = pin.buildModelFromUrdf(str(ARM3))
    np.testing.assert_allclose(arm3.inertia[1], pm.inertias[pm.getJointId("yaw")].inertia, atol=1e-15)


def test_rpy_is_urdfs_fixed_axis_convention():
    """rpy = (r, p, y) is Rz(y) Ry(p) Rx(r): a quarter turn in roll then a quarter in yaw sends x to y and y to z."""
    R = rpy_matrix(np.array([math.pi / 2, 0.0, math.pi / 2]))
    np.testing.assert_allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(R @ [0, 1, 0], [0, 0, 1], atol=1e-15)


def test_fixed_joint_merges_into_the_parent_and_keeps_the_frame():
    """arm3's tool hangs from link3 by a fixed joint: one body whose mass, COM and inertia are the parallel-axis sum
    of the two links (computed here by hand), the tool still a frame at its joint's pose, its visual moved."""
    model = load_urdf(ARM3)
    assert model.body_names == ("base_link", "link1", "link2", "link3")
    assert model.frame_names == ("base_link", "link1", "link2", "link3", "tool")
    k = model.frame_names.index("tool")
    assert model.frame_body[k] == 3
    Rt = rpy_matrix(np.array([0.0, 0.3, 0.0]))
    np.testing.assert_allclose(model.frame_rotation[k], Rt, atol=1e-15)
    np.testing.assert_allclose(model.frame_position[k], [0.25, 0, 0])

    R3 = rpy_matrix(np.array([0.1, 0.2, 0.3]))
    I3 = R3 @ np.array([[0.0006, 0.00001, 0], [0.00001, 0.003, 0], [0, 0, 0.0031]]) @ R3.T
    c3 = np.array([0.12, 0.01, 0.0])
    Ri = Rt @ rpy_matrix(np.array([0.4, 0.0, 0.2]))
    It = Ri @ np.diag([0.0002, 0.0003, 0.00025]) @ Ri.T
    ct = np.array([0.25, 0, 0]) + Rt @ [0.02, 0, 0.01]
    m = 0.6 + 0.25
    com = (0.6 * c3 + 0.25 * ct) / m
    expected = np.zeros((3, 3))
    for mi, ci, Ii in ((0.6, c3, I3), (0.25, ct, It)):
        d = ci - com
        expected += Ii + mi * (d @ d * np.eye(3) - np.outer(d, d))
    assert model.mass[3] == pytest.approx(m, abs=1e-15)
    np.testing.assert_allclose(model.com[3], com, atol=1e-15)
    np.testing.assert_allclose(model.inertia[3], expected, atol=1e-15)
    (tool_visual,) = [g for g in model.visuals[3] if g.link == "tool"]
    np.testing.assert_allclose(tool_visual.position, [0.25, 0, 0])
    assert tool_visual.kind == "sphere" and tool_visual.size.tolist() == [0.02]


def test_limits_dynamics_and_materials_are_read():
    model = load_urdf(ARM3)
    assert model.dof_names == ("yaw", "shoulder", "elbow")
    assert model.lower.tolist() == [-math.inf, -2.0, -2.5]  # continuous: unlimited
    assert model.upper.tolist() == [math.inf, 2.0, 2.5]
    assert model.effort_limit.tolist() == [math.inf, 40.0, math.inf]  # none given; 40; 0 means none
    assert model.velocity_limit.tolist() == [math.inf, 3.0, 4.0]
    assert model.damping.tolist() == [0.1, 0.0, 0.0]
    assert model.friction.tolist() == [0.05, 0.0, 0.0]
    np.testing.assert_allclose(model.joint_axis[3], [0, 0.6, 0.8])
    assert model.visuals[0][0].rgba.tolist() == [0.6, 0.6, 0.6, 1.0]  # a named material
    assert model.visuals[1][0].rgba.tolist() == [1.0, 0.0, 0.0, 1.0]  # an inline colour
    assert model.joint_type[0] == JOINT_FIXED_ROOT and model.n_q == model.n_dofs == 3
    assert "<robot" in model.source


def test_mimic_is_read():
    text = _robot(_link("base"), _link("a"), _link("b"),
                  _joint("lead", "base", "a", kind="prismatic"),
                  _joint("follow", "base", "b", kind="revolute",
                         extra='<limit lower="-1" upper="1" effort="1" velocity="1"/>'
                               '<mimic joint="lead" multiplier="-2" offset="0.1"/>'))
    model = load_urdf(text)
    assert model.mimic_follower.tolist() == [model.dof_index("follow")]
    assert model.mimic_leader.tolist() == [model.dof_index("lead")]
    assert model.mimic_multiplier.tolist() == [-2.0] and model.mimic_offset.tolist() == [0.1]
    msg = _refused(text.replace('joint="lead"', 'joint="nothing"'), "follow")
    assert "nothing" in msg


def test_pandas_mimic_finger(tmp_path):
    import sysconfig
    share = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share"
    panda = share / "example-robot-data" / "robots" / "panda_description" / "urdf" / "panda.urdf"
    if not panda.is_file():
        pytest.skip("example-robot-data is not installed")
    model = load_urdf(panda, package_paths={"example-robot-data": share / "example-robot-data"})
    assert model.mimic_follower.tolist() == [model.dof_index("panda_finger_joint2")]
    assert model.mimic_leader.tolist() == [model.dof_index("panda_finger_joint1")]
    assert model.mimic_multiplier.tolist() == [1.0] and model.mimic_offset.tolist() == [0.0]
    meshes = [g.mesh_path for body in model.collisions for g in body if g.kind == "mesh"]
    assert len(meshes) >= 8 and all(Path(p).is_file() for p in meshes)


def test_mesh_paths_relative_file_package_and_ament(tmp_path, monkeypatch):
    mesh = tmp_path / "src" / "mypkg" / "meshes" / "part.stl"
    mesh.parent.mkdir(parents=True)
    mesh.write_bytes(b"solid x\nendsolid x\n")
    prefix = tmp_path / "install"
    (prefix / "share" / "otherpkg" / "meshes").mkdir(parents=True)
    ament_mesh = prefix / "share" / "otherpkg" / "meshes" / "part.stl"
    ament_mesh.write_bytes(b"solid x\nendsolid x\n")
    urdf_dir = tmp_path / "src" / "mypkg" / "urdf"
    urdf_dir.mkdir()
    uris = ["../meshes/part.stl", f"file://{mesh}", "package://mypkg/meshes/part.stl",
            "package://otherpkg/meshes/part.stl"]
    visuals = "".join(f'<visual><geometry><mesh filename="{u}" scale="1 2 3"/></geometry></visual>' for u in uris)
    path = urdf_dir / "r.urdf"
    path.write_text(_robot(_link("base", extra=visuals)))
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    for package_paths in ({"mypkg": tmp_path / "src" / "mypkg"}, [tmp_path / "src"]):
        model = load_urdf(path, package_paths=package_paths)
        got = [g.mesh_path for g in model.visuals[0]]
        assert got == [str(mesh.resolve())] * 3 + [str(ament_mesh.resolve())]
        assert model.visuals[0][0].mesh_scale.tolist() == [1, 2, 3]
    # without package_paths, mypkg is not found: the error names the link and the URI
    msg = _refused(path, "not found")
    assert "link 'base'" in msg and "package://mypkg/meshes/part.stl" in msg
    # ROS_PACKAGE_PATH finds it too
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path / "src"))
    assert load_urdf(path).visuals[0][2].mesh_path == str(mesh.resolve())


def test_unknown_mesh_is_an_error_naming_link_and_uri(tmp_path):
    path = tmp_path / "r.urdf"
    path.write_text(_robot(_link("base", extra='<collision><geometry><mesh filename="meshes/gone.stl"/></geometry>'
                                               '</collision>')))
    msg = _refused(path, "not found")
    assert "link 'base'" in msg and "meshes/gone.stl" in msg


def test_xacro_with_an_arg(tmp_path):
    path = tmp_path / "r.urdf.xacro"
    path.write_text("""<?xml version="1.0"?>
<robot name="x" xmlns:xacro="http://www.ros.org/wiki/xacro">
  <xacro:arg name="reach" default="0.3"/>
  <xacro:property name="reach" value="$(arg reach)"/>
  <xacro:macro name="arm_link" params="name">
    <link name="${name}"><inertial><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0"
      izz="0.01"/></inertial></link>
  </xacro:macro>
  <xacro:arm_link name="base"/>
  <xacro:arm_link name="arm"/>
  <joint name="j" type="continuous"><parent link="base"/><child link="arm"/>
    <origin xyz="${reach * 2} 0 0"/></joint>
</robot>""")
    path = path.rename(tmp_path / "r.xacro")
    assert load_urdf(path).joint_position[1].tolist() == [0.6, 0, 0]
    model = load_urdf(path, xacro_args={"reach": 0.5})
    assert model.joint_position[1].tolist() == [1.0, 0, 0]
    assert "xacro:" not in model.source and "<robot" in model.source


def test_world_root_is_a_fixed_base_and_floating_roots_take_seven_coordinates():
    text = _robot('<link name="world"/>', _link("base"), _link("arm"),
                  _joint("weld", "world", "base", kind="fixed", extra=""), _joint("j", "base", "arm"))
    model = load_urdf(text, fixed_base=False)
    assert model.joint_type[0] == JOINT_FIXED_ROOT and model.body_names == ("world", "arm")
    assert model.frame_names == ("world", "base", "arm")
    floating = load_urdf(ARM3, fixed_base=False)
    assert floating.joint_type[0] == JOINT_FLOATING
    assert (floating.n_q, floating.n_dofs) == (10, 9)
    assert floating.dof_names[:6] == ("base_link/x", "base_link/y", "base_link/z", "base_link/wx", "base_link/wy",
                                      "base_link/wz")


# ---- what is refused -------------------------------------------------------------------------------------------

def test_revolute_without_limit_is_refused():
    msg = _refused(_robot(_link("base"), _link("arm"), _joint("elbow", "base", "arm", extra="")), "limit")
    assert "joint 'elbow'" in msg and "revolute" in msg
    msg = _refused(_robot(_link("base"), _link("arm"), _joint("slide", "base", "arm", kind="prismatic", extra="")),
                   "limit")
    assert "joint 'slide'" in msg


def test_triangle_inequality_is_repaired_with_a_warning():
    text = _robot(_link("base"), _link("arm", ixx=0.01, iyy=0.01, izz=0.05), _joint("j", "base", "arm"))
    with pytest.warns(UserWarning, match="link 'arm'.*triangle inequality") as record:
        model = load_urdf(text)
    assert "0.025, 0.025, 0.05" in str(record[0].message)
    np.testing.assert_allclose(np.linalg.eigvalsh(model.inertia[1]), [0.025, 0.025, 0.05], atol=1e-15)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_urdf(ARM3)  # a valid file: no warning


def test_bad_inertias_and_masses_are_refused():
    msg = _refused(_robot(_link("base"), _link("arm", ixx=-0.01), _joint("j", "base", "arm")),
                   "positive semi-definite")
    assert "link 'arm'" in msg
    msg = _refused(_robot(_link("base"), _link("arm", mass=-1.0), _joint("j", "base", "arm")), "mass")
    assert "link 'arm'" in msg
    _refused(_robot(_link("base"), _link("arm", mass="nan"), _joint("j", "base", "arm")), "finite")


def test_a_massless_subtree_is_refused():
    text = _robot(_link("base"), '<link name="a"/>', '<link name="b"/>',
                  _joint("j1", "base", "a"), _joint("j2", "a", "b"))
    msg = _refused(text, "no mass")
    assert "link 'a'" in msg and "joint 'j1'" in msg and "singular" in msg


def test_xxe_never_reads_the_file(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("TOPSECRET-BYTES")
    text = (f'<?xml version="1.0"?><!DOCTYPE robot [<!ENTITY x SYSTEM "file://{secret}">]>'
            f'<robot name="&x;"><link name="base"><visual><geometry><mesh filename="&x;"/></geometry></visual>'
            f'</link></robot>')
    msg = _refused(text, "DTD")
    assert "TOPSECRET" not in msg
    path = tmp_path / "xxe.urdf"
    path.write_text(text)
    msg = _refused(path, "DTD")
    assert "TOPSECRET" not in msg and str(path) in msg
    # an entity used without a declaration is not read either: malformed
    _refused(text.split("]>", 1)[1], "malformed XML")


def test_entity_bomb_is_refused_quickly():
    lol = '<!ENTITY a0 "lol">' + "".join(f'<!ENTITY a{i} "{f"&a{i - 1};" * 10}">' for i in range(1, 10))
    text = f'<?xml version="1.0"?><!DOCTYPE robot [{lol}]><robot name="&a9;"><link name="base"/></robot>'
    start = time.perf_counter()
    _refused(text, "DTD")
    assert time.perf_counter() - start < 0.5


def test_malformed_xml_is_refused_with_a_position_and_no_content():
    msg = _refused('<robot name="t"><link name="SECRET-NAME"></robot>', "malformed XML at line 1")
    assert "SECRET" not in msg
    _refused('<robo name="t"/>', "root element must be <robot>")
    _refused("<robot name='t'/>", "no <link>")


def test_cycles_and_two_roots_are_refused():
    msg = _refused(_robot(_link("a"), _link("b"), _joint("j1", "a", "b"), _joint("j2", "b", "a")), "cycle")
    assert "no root" in msg
    msg = _refused(_robot(_link("r"), _link("a"), _link("b"), _joint("j0", "r", "a"), _joint("j1", "a", "b"),
                          _joint("j2", "b", "a")), "child of two joints")
    assert "link 'a'" in msg
    msg = _refused(_robot(_link("a"), _link("b")), "2 root links")
    assert "'a'" in msg and "'b'" in msg
    _refused(_robot(_link("a"), _link("a")), "link 'a' is defined twice")
    _refused(_robot(_link("a"), _joint("j", "a", "a")), "same link")
    _refused(_robot(_link("a"), _joint("j", "a", "ghost")), "child link 'ghost' is not defined")


def test_other_refusals_name_the_joint():
    _refused(_robot(_link("a"), _link("b"), _joint("f", "a", "b", kind="floating", extra="")),
             "joint 'f': a floating joint is allowed only at the root")
    _refused(_robot(_link("a"), _link("b"), _joint("s", "a", "b", kind="spherical", extra="")),
             "joint 's': unknown type 'spherical'")
    _refused(_robot(_link("a"), _link("b"), _joint("j", "a", "b", extra='<limit lower="1" upper="-1"/>')),
             "joint 'j': limit lower 1 > upper -1")
    _refused(_robot(_link("a"), _link("b"), _joint("j", "a", "b", origin='<origin xyz="0 zero 0"/>')),
             "joint 'j' origin xyz: not a list of numbers")
    _refused(_robot(_link("a", extra='<visual><geometry><capsule radius="1" length="1"/></geometry></visual>')),
             "link 'a' visual 0: unknown geometry <capsule>")


def test_files_are_read_bounded(tmp_path):
    _refused(tmp_path / "none.urdf", "no such file")
    _refused(tmp_path, "directory")


def test_bytes_and_caps():
    """UTF-8 bytes are URDF text too; a file of too many shapes or links is refused before it is built."""
    from cgp_core.robots.urdf import MAX_URDF_LINKS, MAX_URDF_SHAPES
    assert load_urdf(ARM3.read_bytes()).n_dofs == 3
    _refused(b"<robot name='\xff'/>", "not UTF-8")
    many = "<visual><geometry><sphere radius='1'/></geometry></visual>" * (MAX_URDF_SHAPES + 1)
    _refused(_robot(_link("a", extra=many)), "more than 20000 collision and visual shapes")
    _refused(_robot(*(f'<link name="l{i}"/>' for i in range(MAX_URDF_LINKS + 1))), "more than 2000 links")


def test_mangled_files_give_urdf_errors_only():
    """400 random edits of arm3.urdf (characters deleted, inserted, swapped): each loads or is a UrdfError —
    never another exception from the parser or numpy."""
    import random
    text = ARM3.read_text()
    rng = random.Random(36)
    alphabet = '<>/"= abcxyz0123456789.-e&;!'
    outcomes = {"loaded": 0, "refused": 0}
    for _ in range(400):
        t = list(text)
        for _ in range(rng.randint(1, 6)):
            i = rng.randrange(len(t))
            op = rng.random()
            if op < 0.4:
                del t[i:i + rng.randint(1, 20)]
            elif op < 0.7:
                t.insert(i, rng.choice(alphabet))
            else:
                j = rng.randrange(len(t))
                t[i], t[j] = t[j], t[i]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                load_urdf("".join(t))
                outcomes["loaded"] += 1
            except UrdfError:
                outcomes["refused"] += 1
    assert outcomes["refused"] > 100 and outcomes["loaded"] > 10, outcomes


def test_numbers_are_bounded():
    _refused(_robot(_link("a", mass=1e300)), "within")


def test_arm7_is_its_generator_output_with_inertias_of_its_collision_primitives():
    """msgs_config/robots/arm7.urdf (the ``arm`` scene's 7-DoF arm) is what tools/arm7_urdf.py writes, and every
    link's <inertial> is that of its <collision> primitives at uniform density, recomputed here from the file's
    own elements (cylinder: m (3 r² + L²) / 12 across, m r² / 2 along; box: m (b² + c²) / 12; the parts' masses by
    volume, moved to the COM by the parallel-axis theorem) to the 6 digits printed; 7 revolute joints with
    limits, effort, velocity and damping; the right finger mimics the left.  (Its dynamics against Pinocchio's:
    tests/test_robot_model.py.)"""
    import importlib.util
    import xml.etree.ElementTree as ET

    path = REPO / "msgs_config" / "robots" / "arm7.urdf"
    spec = importlib.util.spec_from_file_location("arm7_urdf", REPO / "tools" / "arm7_urdf.py")
    generator = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(generator)
    assert generator.urdf() == path.read_text(), "arm7.urdf differs from tools/arm7_urdf.py's output: run it"

    root = ET.parse(path).getroot()
    for link in root.findall("link"):
        inertial = link.find("inertial")
        parts = link.findall("collision")
        if inertial is None:
            assert not parts, link.get("name")
            continue
        mass = float(inertial.find("mass").get("value"))
        pieces = []
        for c in parts:
            origin = c.find("origin")
            centre = np.array([float(v) for v in origin.get("xyz").split()])
            R = rpy_matrix(np.array([float(v) for v in (origin.get("rpy") or "0 0 0").split()]))
            shape = c.find("geometry")[0]
            if shape.tag == "cylinder":
                r, length = float(shape.get("radius")), float(shape.get("length"))
                volume = math.pi * r * r * length
                unit = np.diag([(3 * r * r + length * length) / 12] * 2 + [r * r / 2])
            else:
                a, b, cc = (float(v) for v in shape.get("size").split())
                volume = a * b * cc
                unit = np.diag([b * b + cc * cc, a * a + cc * cc, a * a + b * b]) / 12
            pieces.append((volume, centre, R @ unit @ R.T))
        total = sum(v for v, _, _ in pieces)
        com = sum(v * c for v, c, _ in pieces) / total
        inertia = np.zeros((3, 3))
        for v, c, unit in pieces:
            m, d = mass * v / total, c - com
            inertia += m * unit + m * (d @ d * np.eye(3) - np.outer(d, d))
        tensor = inertial.find("inertia")
        given = np.array([[float(tensor.get(f"i{a}{b}" if f"i{a}{b}" in tensor.attrib else f"i{b}{a}"))
                           for b in "xyz"] for a in "xyz"])
        np.testing.assert_allclose(given, inertia, rtol=1e-5, atol=1e-12, err_msg=link.get("name"))
        np.testing.assert_allclose([float(v) for v in inertial.find("origin").get("xyz").split()], com, atol=1e-5)
    model = load_urdf(path)
    revolute = [j for j in root.findall("joint") if j.get("type") == "revolute"]
    assert len(revolute) == 7 and model.n_dofs == 9  # 7 arm joints and the two fingers (the right one a mimic)
    for j in revolute:
        limit, dynamics = j.find("limit"), j.find("dynamics")
        assert float(limit.get("lower")) < 0 < float(limit.get("upper")), j.get("name")
        assert float(limit.get("effort")) > 0 and float(limit.get("velocity")) > 0
        assert float(dynamics.get("damping")) > 0
    mimic = root.find("joint[@name='finger_right_joint']/mimic")
    assert mimic is not None and mimic.get("joint") == "finger_left_joint"

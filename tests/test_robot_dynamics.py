"""Robots in a World against Pinocchio (the oracle) and the contact report (issue 35's proof).

- gravity compensation: effort drives set to Pinocchio's g(q) hold example-robot-data's UR5 still (≤ 1e-4 rad over
  10 s);
- a released UR5 (no drives, no contacts, its URDF's damping is zero, its velocity limits raised) follows
  Pinocchio's own integration (``pinocchio.aba`` and the same semi-implicit Euler at 1/240 s) to ≤ 1e-4 rad over
  0.5 s;
- robots solved one by one: two arms far apart step exactly as each alone; two arms whose links touch are one
  island and push each other apart equally and oppositely;
- the link contacts (solved in the robot stage) are in the world's contact report: a crate resting on a link
  reports m g up, the link m g down.
"""

from __future__ import annotations

import sysconfig
from pathlib import Path

import numpy as np
import pytest

from cgp_core import World
from cgp_core.scene import scene_from_dict

pin = pytest.importorskip("pinocchio")

H = 1.0 / 240.0


def _share() -> Path:
    share = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share"
    if not (share / "example-robot-data").is_dir():
        pytest.skip("example-robot-data is not installed")
    return share


def _ur5() -> Path:
    return _share() / "example-robot-data" / "robots" / "ur_description" / "urdf" / "ur5_robot.urdf"


POSE = {"shoulder_pan_joint": 0.3, "shoulder_lift_joint": -0.9, "elbow_joint": 1.1, "wrist_1_joint": -0.7,
        "wrist_2_joint": 0.5, "wrist_3_joint": 0.2}


def _ur5_world(path: Path, *, hold: bool) -> World:
    """The UR5 on a fixed base 1 m above a world without ground: no link touches anything."""
    entry = {"name": "ur5", "urdf": str(path), "position": [0, 0, 1.0], "joints": POSE, "hold": hold,
             "package_paths": {"example-robot-data": str(_share() / "example-robot-data")}}
    return scene_from_dict({"world": {"gravity": [0, 0, -9.81], "ground": False, "substeps": 4},
                            "robots": [entry]}, "<test>")


def _pin_model(path: Path):
    model = pin.buildModelFromUrdf(str(path))
    q = pin.neutral(model)
    for name, value in POSE.items():
        q[model.joints[model.getJointId(name)].idx_q] = value
    return model, q


def _ours_in_pin_order(world: World, model) -> np.ndarray:
    names, q, _, _ = world.robots.joint_state("ur5")
    by_name = dict(zip(names, q))
    return np.array([by_name[model.names[j]] for j in range(1, model.njoints)])


def test_effort_drives_at_pinocchios_gravity_torques_hold_the_arm_still():
    path = _ur5()
    world = World(_ur5_world(path, hold=False))  # the URDF's own damping (UR5: 0) is all that acts besides g
    model, q = _pin_model(path)
    g = pin.computeGeneralizedGravity(model, model.createData(), q)
    names = [model.names[j] for j in range(1, model.njoints)]
    assert world.robots.command("ur5", names, effort=g.tolist()) == []
    start = _ours_in_pin_order(world, model)
    worst = 0.0
    for _ in range(600):  # 10 s
        world.step()
        worst = max(worst, float(np.abs(_ours_in_pin_order(world, model) - start).max()))
    assert worst <= 1e-4, worst


def test_a_released_arm_follows_pinocchios_integration(tmp_path):
    # the UR5's velocity limits (3.15 rad/s, rows of our solver; Pinocchio's ABA has none) raised to 1000 rad/s in a
    # copy of its URDF: the arm falls faster than 3.15 rad/s within 0.5 s
    import re

    path = tmp_path / "ur5_robot.urdf"
    path.write_text(re.sub(r'velocity="[0-9.]+"', 'velocity="1000"', _ur5().read_text()))
    world = World(_ur5_world(path, hold=False))
    model, q = _pin_model(path)
    assert np.all(model.damping == 0.0) and np.all(model.friction == 0.0)  # the UR5's URDF: undamped joints
    data = model.createData()
    v = np.zeros(model.nv)
    worst = 0.0
    for _ in range(30):  # 0.5 s of ticks, 4 sub-steps each
        for _ in range(4):
            a = pin.aba(model, data, q, v, np.zeros(model.nv))
            v = v + H * a  # semi-implicit Euler, as ours: q̇ first, then q with the new q̇
            q = pin.integrate(model, q, H * v)
        world.step()
        worst = max(worst, float(np.abs(_ours_in_pin_order(world, model) - q).max()))
    assert float(np.abs(q - _pin_model(path)[1]).max()) > 0.1  # it did fall
    assert worst <= 1e-4, worst


ARM_POSE = {"shoulder_lift": np.pi / 2, "elbow": 0.0, "wrist": 0.0}


def _arms(*placed):
    """arm.urdf robots ``(name, x, yaw)``: their upper arms level, pointing along the yaw."""
    robots = [{"name": name, "urdf": "arm.urdf", "position": [x, 0, 0],
               "orientation": [0, 0, float(np.sin(yaw / 2)), float(np.cos(yaw / 2))], "joints": ARM_POSE,
               "hold": True} for name, x, yaw in placed]
    return World(scene_from_dict({"world": {"gravity": [0, 0, -9.81], "ground": True, "substeps": 4},
                                  "robots": robots}, "<test>"))


def test_robots_far_apart_step_exactly_as_each_alone():
    both, alone = _arms(("left", 0.0, 0.0), ("right", 5.0, np.pi)), _arms(("left", 0.0, 0.0))
    for world in (both, alone):
        world.robots.command("left", ["shoulder_pan"], velocity=[0.5])
    for _ in range(60):
        both.step()
        alone.step()
    assert np.array_equal(both.robots.joint_state("left")[1], alone.robots.joint_state("left")[1])
    assert both.robots.islands == [[0], [1]]


def test_arms_whose_links_touch_are_solved_as_one_island():
    """Two arms facing each other (their tools 0.84 m out), the right one turned away and swinging into line: its
    hand sweeps into the left one's; the two are one island while they touch, and neither sinks into the
    other."""
    world = _arms(("left", 0.0, 0.0), ("right", 1.6, np.pi + 0.5))
    assert world.robots.islands == [[0], [1]]
    world.robots.command("right", ["shoulder_pan"], position=[-0.5])
    joined, deepest = False, 0.0
    world.report_contacts = True
    for _ in range(60):
        world.step()
        joined |= any(len(island) == 2 for island in world.robots.islands)
        if world.contacts.separation.size:
            deepest = min(deepest, float(world.contacts.separation.min()))
    assert joined
    assert deepest > -0.01, deepest
    for name in ("left", "right"):
        assert np.all(np.isfinite(world.robots.joint_state(name)[1]))


def test_a_crate_resting_on_a_link_is_in_the_contact_report_with_its_weight():
    joints = {"shoulder_lift": np.pi / 2, "elbow": -np.pi / 2, "wrist": 0.0}
    m = 0.4
    crate = {"name": "crate", "shape": "box", "size": [0.06, 0.06, 0.04], "mass": m, "friction": 1.0,
             "position": [0.25, 0.0, 0.225 + 0.022]}
    world = World(scene_from_dict({"world": {"gravity": [0, 0, -9.81], "ground": True, "substeps": 4},
                                   "robots": [{"name": "arm", "urdf": "arm.urdf", "joints": joints, "hold": True}],
                                   "bodies": [crate]}, "<test>"))
    for _ in range(60):
        world.step()
    world.report_contacts = True
    world.step()
    report = world.contacts
    crate_row = world.body_model.index("crate")
    upper = world.body_model.index("arm/upper_arm")
    body = list(report.body)
    assert crate_row in body and upper in body, body
    force = dict(zip(body, report.force))
    np.testing.assert_allclose(force[crate_row], [0, 0, m * 9.81], atol=0.01 * m * 9.81)
    np.testing.assert_allclose(force[upper], [0, 0, -m * 9.81], atol=0.01 * m * 9.81)
    between = [(a, b) for a, b in zip(report.body_a, report.body_b) if {a, b} == {crate_row, upper}]
    assert between, "the link-crate contact points are listed"

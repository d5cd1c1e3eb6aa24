"""Issue 36 (spawning, core): robots spawned into a running World from a scene's robot entry (``{robot: {...}}``:
``urdf`` a file, or ``urdf_xml`` URDF text), deleted, listed, queried, teleported (a floating base) and reset —
the robots already there keep their joint state, drives and commands.  Refusals name the key and the reason."""

from __future__ import annotations

import numpy as np
import pytest

from cgp_core import World
from cgp_core.editing import EditError
from cgp_core.scene import SceneError
from cgp_core.scene.robots import builtin_robot_dir as robot_dir

JOINTS = {"shoulder_lift": 0.6, "elbow": 1.2, "wrist": 0.6}
ENTRY = {"urdf": "arm.urdf", "joints": JOINTS}
BESIDE = (0.0, 1.0, 0.0)  # a metre to the side of the scene's arm: they never touch


def run(world: World, seconds: float, each=None) -> None:
    for _ in range(round(seconds / world.dt)):
        world.step()
        if each is not None:
            each(world)


def positions(world: World, robot: str) -> dict[str, float]:
    names, q, _, _ = world.robots.joint_state(robot)
    return dict(zip(names, q))


def arm_xml() -> str:
    return (robot_dir() / "arm.urdf").read_text()


@pytest.mark.parametrize("source", ["file", "xml"])
def test_a_spawned_arm_holds_its_pose_next_to_the_scene_arm(source):
    world = World.from_scene("arm_teleop")
    run(world, 0.5)
    before = positions(world, "arm")
    q_arm = world.robots.q.copy()
    entry = ENTRY if source == "file" else {"urdf_xml": arm_xml(), "joints": JOINTS}
    assert world.spawn({"robot": entry}, name="arm2", position=BESIDE) == "robot"
    # the scene's arm is untouched by the spawn: the same bits, its coordinates first
    assert np.array_equal(world.robots.q[:q_arm.size], q_arm)
    assert positions(world, "arm") == before
    assert world.entity_kind("arm2") == "robot"
    names = world.entity_names()
    assert "arm2" in names and "arm2/base_link" in names and "arm" in names
    assert world.spawned == ["arm2"]
    state = world.entity_state("arm2")
    assert state.kind == "robot"
    assert np.allclose(state.position, BESIDE) and np.allclose(state.orientation, [0, 0, 0, 1])
    start = positions(world, "arm2")
    worst = {"arm": 0.0, "arm2": 0.0}

    def check(w):
        for robot, reference in (("arm", before), ("arm2", start)):
            now = positions(w, robot)
            worst[robot] = max(worst[robot], max(abs(now[j] - reference[j]) for j in JOINTS))

    run(world, 2.0, check)
    assert worst["arm"] <= 1e-3 and worst["arm2"] <= 1e-3, worst
    for joint, value in JOINTS.items():
        assert abs(positions(world, "arm2")[joint] - value) <= 1e-3
    # its links are where its joints put them: the tool a metre to the side of the scene arm's
    names, _, p = world.robots.frame_poses("arm2")
    names1, _, p1 = world.robots.frame_poses("arm")
    tool = list(names).index("tool")
    assert np.allclose(p[tool] - p1[list(names1).index("tool")], BESIDE, atol=2e-3)


def test_spawning_keeps_the_other_robots_commands_and_deleting_keeps_their_state_continuous():
    world = World.from_scene("arm_teleop")
    assert world.robots.command("arm", ["shoulder_pan"], position=[0.4]) == []
    run(world, 0.3)
    world.spawn({"robot": ENTRY}, name="arm2", position=BESIDE)
    # the scene arm goes on to its commanded target (the command survived the spawn)
    run(world, 2.0)
    assert abs(positions(world, "arm")["shoulder_pan"] - 0.4) <= 1e-3
    # a command to the spawned one, then the scene's arm deleted: arm2 goes on, its coordinates shifted to 0
    assert world.robots.command("arm2", ["elbow"], position=[0.9]) == []
    run(world, 0.2)
    q2 = world.robots.q[world.robots.robot("arm2").q_slice].copy()
    qd2 = world.robots.qd[world.robots.robot("arm2").dof_slice].copy()
    assert world.delete("arm") == "robot"
    assert "arm" not in world.entity_names() and not any(n.startswith("arm/") for n in world.entity_names())
    r = world.robots.robot("arm2")
    assert r.q_slice.start == 0
    assert np.array_equal(world.robots.q[r.q_slice], q2) and np.array_equal(world.robots.qd[r.dof_slice], qd2)
    previous = world.robots.q.copy()
    biggest = 0.0

    def smooth(w):
        nonlocal previous, biggest
        biggest = max(biggest, float(np.abs(w.robots.q - previous).max()))
        previous = w.robots.q.copy()

    run(world, 2.0, smooth)
    assert biggest < 0.05, biggest  # no jump: at most a tick's worth of motion
    assert abs(positions(world, "arm2")["elbow"] - 0.9) <= 1e-3


def test_deleting_a_spawned_robot_leaves_the_other_as_if_it_had_never_been_there():
    alone = World.from_scene("arm_teleop")
    both = World.from_scene("arm_teleop")
    both.spawn({"robot": ENTRY}, name="arm2", position=BESIDE)
    run(alone, 0.5)
    run(both, 0.5)
    both.delete("arm2")
    run(alone, 0.5)
    run(both, 0.5)
    # the two robots never touch: the one left has the same bits as in a world that never held the other
    assert np.array_equal(alone.robots.q, both.robots.q) and np.array_equal(alone.robots.qd, both.robots.qd)
    assert both.entity_names() == alone.entity_names()


def test_reset_removes_spawned_robots_and_restores_joint_states():
    world = World.from_scene("arm_teleop")
    scene_names = world.entity_names()
    world.spawn({"robot": ENTRY}, name="arm2", position=BESIDE)
    world.robots.command("arm2", ["elbow"], position=[0.5])
    world.robots.command("arm", ["elbow"], position=[0.5])
    run(world, 1.0)
    world.reset(state=True, spawned=False)  # the spawned robot stays, at its spawn state
    assert "arm2" in world.entity_names()
    assert abs(positions(world, "arm2")["elbow"] - 1.2) <= 1e-12
    assert abs(positions(world, "arm")["elbow"] - 1.2) <= 1e-12
    run(world, 0.5)
    assert abs(positions(world, "arm2")["elbow"] - 1.2) <= 1e-3  # its drives hold the spawn state again
    world.reset(state=False, spawned=True)
    assert world.entity_names() == scene_names and world.spawned == []
    world.spawn({"robot": ENTRY}, name="arm3", position=BESIDE)
    world.delete("arm")  # a scene robot deleted comes back with a full reset
    world.reset()
    assert world.entity_names() == scene_names
    assert [r.name for r in world.robots.robots] == ["arm"]
    run(world, 0.2)


def test_a_robot_spawned_into_a_world_without_robots_and_deleted_again():
    world = World.from_scene("default")
    assert world.robots is None
    run(world, 0.1)
    world.spawn({"robot": {"urdf": "pendulum.urdf"}}, name="pendulum", position=(3.0, 3.0, 2.0))
    # the robot's links are one sleep island (cgp_core.sleep): the world still sleeps
    assert world.robot_names() == ["pendulum"] and world.sleep_enabled == bool(world.scene.world.sleep)
    run(world, 0.3)
    world.delete("pendulum")
    assert world.robots is None and world.sleep_enabled == bool(world.scene.world.sleep)
    assert not any(n.startswith("pendulum") for n in world.entity_names())
    run(world, 0.1)


def test_a_floating_base_robot_is_teleported_and_a_fixed_base_is_refused():
    world = World.from_scene("arm_teleop")
    world.spawn({"robot": dict(ENTRY, fixed_base=False)}, name="free", position=(0.0, 2.0, 1.0))
    world.set_body_state("free", (1.0, 2.0, 3.0), (0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 1.0))
    state = world.entity_state("free")
    assert np.allclose(state.position, (1.0, 2.0, 3.0)) and np.allclose(state.linear_velocity, (0.0, 0.0, 1.0))
    assert np.allclose(world.body_state.position[world.body_model.index("free/base_link")][:2], (1.0, 2.0),
                       atol=0.2)
    with pytest.raises(EditError, match="fixed base") as refused:
        world.set_body_state("arm", (1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    assert refused.value.kind == "not_possible"
    with pytest.raises(EditError, match="link of robot arm"):
        world.delete("arm/hand")


@pytest.mark.parametrize("entry, where", [
    ({"urdf": "arm.urdf", "colour": 1}, "colour"),
    ({"urdf": "arm.urdf", "position": [0, 0, 0]}, "robot.position"),
    ({"urdf": "arm.urdf", "name": "x"}, "robot.name"),
    ({"urdf": "nothing_here.urdf"}, "robot.urdf"),
    ({}, "robot.urdf"),
    ({"urdf": "arm.urdf", "urdf_xml": "<robot/>"}, "robot.urdf_xml"),
    ({"urdf_xml": 42}, "robot.urdf_xml"),
    ({"urdf_xml": "<robot name='r'><link name='a'/><joint name='j' type='spinning'><parent link='a'/>"
                  "<child link='b'/></joint><link name='b'/></robot>"}, "joint 'j'"),
    ({"urdf_xml": "<robot name='r'><link name='a'>"}, "malformed XML"),
    ({"urdf_xml": "<robot name='r'><link name='a'/></robot>", "xacro_args": {"x": "1"}}, "xacro"),
    ({"urdf": "arm.urdf", "joints": {"no_such_joint": 0.1}}, "no_such_joint"),
])
def test_bad_robot_entries_are_refused_naming_the_key(entry, where):
    world = World.from_scene("arm_teleop")
    with pytest.raises(SceneError, match=where):
        world.spawn({"robot": entry}, name="arm2", position=BESIDE)
    assert world.entity_names() == World.from_scene("arm_teleop").entity_names()


def test_xml_entities_are_refused_and_never_read(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("TOP-SECRET-BYTES")
    world = World.from_scene("arm_teleop")
    for xml in (f'<?xml version="1.0"?><!DOCTYPE r [<!ENTITY x SYSTEM "file://{secret}">]>'
                '<robot name="r"><link name="a&x;"/></robot>',
                '<!DOCTYPE r [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">]>'
                '<robot name="r"><link name="&b;"/></robot>'):
        with pytest.raises(SceneError) as refused:
            world.spawn({"robot": {"urdf_xml": xml}}, name="evil", position=BESIDE)
        text = str(refused.value)
        assert "DOCTYPE" in text and "robot.urdf_xml" in text
        assert "TOP-SECRET" not in text and "aaaa" not in text
    assert "evil" not in world.entity_names()


def test_a_taken_name_is_refused():
    world = World.from_scene("arm_teleop")
    for name in ("arm", "crate"):
        with pytest.raises(EditError) as refused:
            world.spawn({"robot": ENTRY}, name=name, position=BESIDE)
        assert refused.value.kind == "name_taken"
    world.spawn({"robot": ENTRY}, name="arm2", position=BESIDE)
    with pytest.raises(EditError) as refused:
        world.spawn({"body": {"shape": "sphere", "radius": 0.1}}, name="arm2")
    assert refused.value.kind == "name_taken"


def test_prepared_robot_spawns_pickle():
    """The node prepares spawns in a worker process: a prepared robot travels back by pickle."""
    import pickle

    world = World.from_scene("arm_teleop")
    prepared = world.prepare_spawn({"robot": ENTRY}, name="arm2", taken=set(world.entity_names()), position=BESIDE)
    world.add_spawned(pickle.loads(pickle.dumps(prepared)))
    run(world, 0.5)
    assert abs(positions(world, "arm2")["elbow"] - 1.2) <= 1e-3

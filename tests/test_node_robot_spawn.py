"""Issue 36 (spawning robots), as another node sees it: the real node runs the ``default`` scene (no robots) as its
own process; this process spawns robots through ``~/spawn_entity`` — a URDF file as ``uri``, URDF XML as
``resource_string`` — reads their ``~/robots/<robot>/joint_states`` over DDS, asks ``get_entities`` /
``get_entity_state``, deletes one (its publishers go from the graph) and resets (the spawned robots go).  Hostile
XML in a request (a DOCTYPE with an external entity naming a file) is refused, and neither the reply nor
``~/events`` ever carries the file's bytes."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from sensor_msgs.msg import JointState
from sim_client import OK, SimClient
from simulation_interfaces.msg import Result
from simulation_interfaces.srv import GetSimulatorFeatures, ResetSimulation, SpawnEntity
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

REPO = Path(__file__).resolve().parents[1]
ARM_URDF = REPO / "msgs_config" / "robots" / "arm.urdf"
ARM_JOINTS = {"shoulder_pan", "shoulder_lift", "elbow", "wrist", "finger_left_joint", "finger_right_joint"}
#: a spawn's first request starts the spawn worker (imports, compiled kernels loaded): allow for it
SPAWN_CALL_TIMEOUT = 120.0


def topic(robot: str, name: str) -> str:
    return f"/cgp_sim/robots/{robot}/{name}"


def start(start_node, probe):
    """The node on the default scene, running, importing this checkout (PYTHONPATH), the probe matched."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])))
    node = start_node("--scene", "default", env=env)
    probe.client(GetSimulatorFeatures, "/cgp_sim/get_simulator_features", timeout=30)
    return node, SimClient(probe)


def spawn(sim: SimClient, name: str, *, uri: str = "", resource: str = "", position=(0.0, 0.0, 0.0)):
    request = SpawnEntity.Request(name=name, uri=uri, resource_string=resource)
    p = request.initial_pose.pose.position
    p.x, p.y, p.z = map(float, position)
    request.initial_pose.pose.orientation.w = 1.0
    return sim.call(SpawnEntity, request, timeout=SPAWN_CALL_TIMEOUT)


def wait_gone(probe, name: str, timeout: float = 20.0) -> None:
    probe.spin_until(lambda: probe.node.count_publishers(name) == 0, timeout, f"no publisher left on {name}")


def tf_children(messages) -> set[str]:
    return {t.child_frame_id for m in messages for t in m.transforms}


def test_robots_spawned_from_a_file_and_from_urdf_text_publish_and_go_when_deleted(start_node, probe):
    tf = probe.subscribe("/tf", TFMessage)
    node, sim = start(start_node, probe)
    assert "urdf" in sim.call(GetSimulatorFeatures).features.spawn_formats

    answer = spawn(sim, "arm_file", uri=f"file://{ARM_URDF}", position=(-8.0, -8.0, 0.0))
    assert answer.result.result == OK, answer.result.error_message
    assert answer.entity_name == "arm_file"
    answer = spawn(sim, "arm_text", resource=ARM_URDF.read_text(), position=(-8.0, 8.0, 0.0))
    assert answer.result.result == OK, answer.result.error_message

    names = sim.names()
    assert {"arm_file", "arm_text", "arm_file/base_link", "arm_text/hand"} <= set(names)
    state = sim.state("arm_text")
    assert state.result.result == OK
    p = state.state.pose.position
    assert abs(p.x + 8.0) < 1e-9 and abs(p.y - 8.0) < 1e-9 and abs(p.z) < 1e-9

    # joint_states of both, read here over DDS; the arms hold their (zero) pose under their drives
    for robot in ("arm_file", "arm_text"):
        probe.wait_for_publisher(topic(robot, "joint_states"), timeout=20)
        box = probe.subscribe(topic(robot, "joint_states"), JointState)
        messages = probe.wait_for_messages(topic(robot, "joint_states"), 30, timeout=30)
        last = messages[-1]
        assert set(last.name) == ARM_JOINTS
        assert max(abs(x) for x in last.position) < 1e-2, dict(zip(last.name, last.position))
        assert box.messages
        assert probe.node.count_publishers(topic(robot, "robot_description")) == 1
        assert probe.node.count_subscribers(topic(robot, "joint_commands")) == 1

    # a fixed base takes no teleport: refused, saying why
    moved = sim.set_state("arm_file", position=(-7.0, -8.0, 0.0))
    assert moved.result.result == Result.RESULT_OPERATION_FAILED and "fixed base" in moved.result.error_message
    assert abs(sim.state("arm_file").state.pose.position.x + 8.0) < 1e-9

    # their moving links on /tf, named <robot>/<link> (frame_prefix empty by default)
    def both_on_tf() -> bool:
        children = tf_children(tf.messages)
        return all(any(c.endswith(link) for c in children) for link in ("arm_file/shoulder", "arm_text/forearm"))

    probe.spin_until(both_on_tf, 20, "the spawned robots' links on /tf")

    answer = sim.delete("arm_file")
    assert answer.result.result == OK, answer.result.error_message
    wait_gone(probe, topic("arm_file", "joint_states"))
    probe.spin_for(0.3)  # what was on the way
    seen = len(tf.messages)
    probe.spin_for(0.5)
    later = tf_children(tf.messages[seen:])
    assert any("arm_text/" in c for c in later) and not any("arm_file/" in c for c in later), later
    wait_gone(probe, topic("arm_file", "robot_description"))
    probe.spin_until(lambda: probe.node.count_subscribers(topic("arm_file", "joint_commands")) == 0, 20,
                     "the joint_commands subscription of the deleted robot to go")
    assert not any(n == "arm_file" or n.startswith("arm_file/") for n in sim.names())
    assert sim.state("arm_file").result.result == Result.RESULT_NOT_FOUND
    # the other one goes on publishing
    count = len(probe.received[topic("arm_text", "joint_states")].messages)
    probe.wait_for_messages(topic("arm_text", "joint_states"), count + 10, timeout=20)

    # spawned again under another name from the same file: its topics appear
    answer = spawn(sim, "arm_again", uri=str(ARM_URDF), position=(8.0, -8.0, 0.0))
    assert answer.result.result == OK, answer.result.error_message
    probe.wait_for_publisher(topic("arm_again", "joint_states"), timeout=20)

    # a reset (all) removes the spawned robots and their topics
    reset = sim.reset(ResetSimulation.Request.SCOPE_ALL)
    assert reset.result.result == OK, reset.result.error_message
    for robot in ("arm_text", "arm_again"):
        wait_gone(probe, topic(robot, "joint_states"))
    assert not any(n.startswith("arm_") for n in sim.names())
    assert node.alive()


def test_hostile_urdf_xml_is_refused_without_reading_the_file(start_node, probe, tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("CGP-SECRET-7f3a")
    events = probe.subscribe("/cgp_sim/events", String)
    node, sim = start(start_node, probe)
    probe.wait_until_matched("/cgp_sim/events")
    hostile = {
        "xxe": f'<!DOCTYPE r [<!ENTITY x SYSTEM "file://{secret}">]><robot name="r"><link name="a&x;"/></robot>',
        "bomb": '<!DOCTYPE r [<!ENTITY a "CGP-SECRET-lol"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">'
                '<!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;">]><robot name="r"><link name="&c;"/></robot>',
        "malformed": f'<robot name="r"><link name="a"><!-- {secret} -->',
    }
    for label, xml in hostile.items():
        answer = spawn(sim, f"evil_{label}", resource=xml)
        assert answer.result.result == SpawnEntity.Response.RESOURCE_PARSE_ERROR, (label, answer.result)
        message = answer.result.error_message
        assert "CGP-SECRET" not in message, message
        assert ("DOCTYPE" in message) if label != "malformed" else ("malformed XML" in message), message
    # a YAML robot entry whose urdf_xml is hostile: the same
    answer = spawn(sim, "evil_yaml", resource=json.dumps({"robot": {"urdf_xml": hostile["xxe"]}}))
    assert answer.result.result == SpawnEntity.Response.RESOURCE_PARSE_ERROR, answer.result
    assert "robot.urdf_xml" in answer.result.error_message and "CGP-SECRET" not in answer.result.error_message
    # a file that is no URDF named by a robot entry, as a uri, or a FIFO as a uri: refused, never quoted
    not_xml = tmp_path / "notes.urdf"
    not_xml.write_text(f"root:{secret.read_text()}:0:0\n")
    fifo = tmp_path / "pipe.urdf"
    os.mkfifo(fifo)
    for label, kwargs, text in (("yaml_file", dict(resource=json.dumps({"robot": {"urdf": str(not_xml)}})),
                                 "malformed XML"),
                                ("uri_file", dict(uri=str(not_xml)), "malformed XML"),
                                ("fifo", dict(uri=f"file://{fifo}"), "not a regular file")):
        answer = spawn(sim, f"evil_{label}", **kwargs)
        assert answer.result.result == SpawnEntity.Response.RESOURCE_PARSE_ERROR, (label, answer.result)
        assert text in answer.result.error_message and "CGP-SECRET" not in answer.result.error_message, \
            answer.result.error_message
    deadline = time.monotonic() + 10
    probe.spin_until(lambda: sum("evil_" in m.data for m in events.messages) >= 7 or time.monotonic() > deadline,
                     15, "the refusals on ~/events")
    spawn_events = [m.data for m in events.messages if "spawn_entity" in m.data]
    assert len(spawn_events) >= 7
    assert all("CGP-SECRET" not in e for e in spawn_events)
    assert not any(n.startswith("evil") for n in sim.names())
    assert node.alive()


def test_the_bag_records_a_spawned_robot_from_its_spawn_to_its_delete(start_node, probe, tmp_path):
    from mcap_ros2.reader import read_ros2_messages

    bag = tmp_path / "bag"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])))
    node = start_node("--scene", "default", "--bag", str(bag), env=env)
    probe.client(GetSimulatorFeatures, "/cgp_sim/get_simulator_features", timeout=30)
    sim = SimClient(probe)
    answer = spawn(sim, "arm_text", resource=ARM_URDF.read_text(), position=(-8.0, 8.0, 0.0))
    assert answer.result.result == OK, answer.result.error_message
    states = topic("arm_text", "joint_states")
    probe.wait_for_publisher(states, timeout=20)
    probe.subscribe(states, JointState)
    probe.wait_for_messages(states, 20, timeout=30)
    assert sim.delete("arm_text").result.result == OK
    wait_gone(probe, states)
    assert node.stop() == 0, node.log()[-3000:]
    recorded, descriptions = [], []
    for mcap_file in sorted(bag.glob("*.mcap")):
        for m in read_ros2_messages(str(mcap_file), topics=[states, topic("arm_text", "robot_description")]):
            (recorded if m.channel.topic == states else descriptions).append(m)
    assert len(recorded) >= 20 and all(set(m.ros_msg.name) == ARM_JOINTS for m in recorded)
    assert [m.ros_msg.data for m in descriptions] == [ARM_URDF.read_text()]

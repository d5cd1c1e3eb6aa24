"""The bag of a run whose world was edited, read back by independent readers: a body spawned mid-recording gets
its channels from then on (counted in metadata.yaml), its messages stop when it is deleted, the calls are on
``~/events`` in the bag, TF is recorded, and ``set_simulation_state QUITTING`` ends the run cleanly (finished
file)."""

from __future__ import annotations

import json

import yaml
from geometry_msgs.msg import WrenchStamped
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from sim_client import OK
from simulation_interfaces.msg import SimulationState
from test_node_sim_services import start_paused

BOX1_TOPICS = {"/cgp_sim/bodies/box1/odom": "nav_msgs/msg/Odometry",
               "/cgp_sim/bodies/box1/wrench": "geometry_msgs/msg/WrenchStamped"}


def test_spawned_topics_are_recorded_and_counted(start_node, probe, tmp_path):
    bag = tmp_path / "bag"
    node, sim = start_paused(start_node, probe, "zero_g", "--bag", str(bag))
    assert sim.step(3).result.result == OK
    assert sim.spawn("box1", "body: {shape: box, size: [0.4, 0.4, 0.4], mass: 2.0}",
                     position=(0, -4, 2)).result.result == OK
    pub = probe.publisher("/cgp_sim/bodies/box1/wrench", WrenchStamped)
    probe.wait_for_subscriber(pub)
    command = WrenchStamped()
    command.wrench.force.y = 1.0
    pub.publish(command)
    probe.spin_for(0.3)
    assert sim.step(5).result.result == OK
    assert sim.delete("box1").result.result == OK
    assert sim.step(2).result.result == OK
    quit_reply = sim.set_simulation_state(SimulationState.STATE_QUITTING)
    assert quit_reply.result.result == OK
    assert node.wait(30) == 0, node.log()
    assert "bag in" in node.log()

    with AnyReader([bag]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        messages: dict[str, list] = {}
        for connection, t, raw in reader.messages():
            messages.setdefault(connection.topic, []).append((t, reader.deserialize(raw, connection.msgtype)))
    assert BOX1_TOPICS.items() <= types.items()
    assert types["/tf"] == types["/tf_static"] == "tf2_msgs/msg/TFMessage"
    # box1's odometry: one per tick while it existed (5 ticks), stamped within them
    odom = messages["/cgp_sim/bodies/box1/odom"]
    assert len(odom) == 5 and all(m.child_frame_id == "box1" for _, m in odom)
    (_, command_recorded), = messages["/cgp_sim/bodies/box1/wrench"]
    assert command_recorded.wrench.force.y == 1.0
    in_tf = [sum(t.child_frame_id == "box1" for t in m.transforms) for _, m in messages["/tf"]]
    assert in_tf == [0] * 3 + [1] * 5 + [0] * 2
    assert len(messages["/clock"]) == 10

    # metadata.yaml counts every topic, the ones added mid-recording included, as the files hold them
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    assert counts == {topic: len(messages.get(topic, [])) for topic in counts}
    assert counts["/cgp_sim/bodies/box1/odom"] == 5 and counts["/cgp_sim/bodies/box1/wrench"] == 1
    assert meta["message_count"] == sum(len(v) for v in messages.values())

    # the calls, in order, with their results
    events = [json.loads(m.data) for _, m in messages["/cgp_sim/events"]]
    calls = [(e["name"], e["result"]) for e in events if e.get("event") == "service" and e.get("result") == "OK"]
    assert [c for c in calls if c[0] in ("spawn_entity", "delete_entity", "set_simulation_state")] == [
        ("spawn_entity", "OK"), ("delete_entity", "OK"), ("set_simulation_state", "OK")]
    assert {"entity": "box1", "entity_name": "box1"}.items() <= next(
        e for e in events if e.get("name") == "spawn_entity" and e.get("result") == "OK").items()
    # the bodies' shapes are recorded once per change of the set (issue 37): with box1 after the spawn, without it
    # (after a DELETEALL) after the delete; none on ~/markers
    sets = [{m.ns for m in a.markers} for _, a in messages["/cgp_sim/static_markers"]]
    assert any("bodies/box1" in s for s in sets) and "bodies/box1" not in sets[-1] and "bodies/box" in sets[-1]
    assert not [m for _, a in messages["/cgp_sim/markers"] for m in a.markers if m.ns.startswith("bodies/")]

    (mcap_file,) = sorted(bag.glob("*.mcap"))
    with open(mcap_file, "rb") as f:
        assert make_reader(f).get_summary() is not None  # QUITTING finished the file

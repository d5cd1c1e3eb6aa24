"""Issue 6 through the node: the bag a `cgp-sim --bag DIR` run leaves is what a live subscriber saw, reads
back with rosbags (AnyReader over the directory) and with mcap_ros2, holds the commands it received and the
service calls, and survives SIGINT / SIGTERM (finished file) and SIGKILL (every committed chunk readable).
BagWriter-level behaviour (schemas, splitting, disk full, queue policies) is in tests/test_bag.py."""

from __future__ import annotations

import json
import signal

import numpy as np
import pytest
import yaml
from geometry_msgs.msg import PoseArray
from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from mcap_ros2.reader import read_ros2_messages
from ros_probe import pause
from rosbags.highlevel import AnyReader
from rosgraph_msgs.msg import Clock

PUBLISHED = {
    "/clock": "rosgraph_msgs/msg/Clock",
    "/cgp_sim/bodies/poses": "geometry_msgs/msg/PoseArray",
    "/cgp_sim/bodies/box/odom": "nav_msgs/msg/Odometry",
    "/cgp_sim/bodies/spinner/odom": "nav_msgs/msg/Odometry",
    "/cgp_sim/flocks/birds/poses": "geometry_msgs/msg/PoseArray",
    "/cgp_sim/flocks/birds/stats": "cgp_sim_msgs/msg/FlockStats",
    "/cgp_sim/contacts": "cgp_sim_msgs/msg/Contacts",
    "/cgp_sim/markers": "visualization_msgs/msg/MarkerArray",
    "/cgp_sim/static_markers": "visualization_msgs/msg/MarkerArray",  # the bodies' shapes, once (issue 37)
    "/cgp_sim/events": "std_msgs/msg/String",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
}
RECEIVED = {
    "/cgp_sim/apply_wrench": "cgp_sim_msgs/msg/ApplyWrench",
    "/cgp_sim/bodies/box/wrench": "geometry_msgs/msg/WrenchStamped",
    "/cgp_sim/bodies/spinner/wrench": "geometry_msgs/msg/WrenchStamped",
}


def read_bag(bag_dir):
    """{topic: [(log_time_ns, message)]} via rosbags (which checks every schema against its type hash)."""
    out = {}
    with AnyReader([bag_dir]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    return types, out


def stamp_ns(t) -> int:
    return t.sec * 1_000_000_000 + t.nanosec


def test_bag_of_a_run_is_what_a_live_subscriber_saw(start_node, probe, tmp_path):
    from cgp_sim_msgs.msg import ApplyWrench

    bag = tmp_path / "run"
    live = probe.subscribe("/cgp_sim/bodies/poses", PoseArray)
    # started paused, and resumed once the probe is matched: it sees every one of the 120 ticks
    node = start_node("--scene", "zero_g", "--duration", "2.0", "--bag", str(bag), "--start-paused", "true")
    probe.wait_until_matched("/cgp_sim/bodies/poses")
    command = ApplyWrench(body="box")
    command.wrench.force.x = 3.0
    command.point.z = 2.0
    pub = probe.publisher("/cgp_sim/apply_wrench", ApplyWrench)
    probe.wait_for_subscriber(pub)
    probe.publish_acked(pub, command)  # received (and so recorded) before the first tick
    pause(probe, False)
    probe.spin_until(lambda: not node.alive(), 60, "the node to end after its 2 s")
    assert node.wait(10) == 0, node.log()
    probe.spin_for(0.2)

    types, messages = read_bag(bag)
    assert types == {**PUBLISHED, **RECEIVED}
    # every tick of 2 s at 60 Hz, once per topic
    for topic in ("/clock", "/cgp_sim/bodies/poses", "/cgp_sim/bodies/box/odom", "/cgp_sim/markers",
                  "/cgp_sim/flocks/birds/poses", "/cgp_sim/flocks/birds/stats", "/tf"):
        assert len(messages[topic]) == 120, topic
    clocks = [stamp_ns(m.clock) for _, m in messages["/clock"]]
    assert clocks == [t for t, _ in messages["/clock"]]  # log time = the sim time /clock carries
    assert clocks == sorted(clocks) and clocks[-1] == 120 * round(1e9 / 60)

    # what the live subscriber saw is in the bag, message for message, pose for pose
    recorded = {stamp_ns(m.header.stamp): m for _, m in messages["/cgp_sim/bodies/poses"]}
    assert len(live.messages) > 60  # (the last ones may still be in flight when the node exits)
    for seen in live.messages:
        kept = recorded[stamp_ns(seen.header.stamp)]
        a = np.array([[p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y,
                       p.orientation.z, p.orientation.w] for p in seen.poses])
        b = np.array([[p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y,
                       p.orientation.z, p.orientation.w] for p in kept.poses])
        assert np.array_equal(a, b)

    # the command it received and the service call it served are there too
    (t_cmd, cmd), = messages["/cgp_sim/apply_wrench"]
    assert cmd.body == "box" and cmd.wrench.force.x == 3.0
    events = [json.loads(m.data) for _, m in messages["/cgp_sim/events"]]
    assert events[0]["event"] == "level_of_detail"  # the node's first event: what it draws and records how often
    services = [e for e in events if e["event"] == "service"]
    assert {"event": "service", "name": "pause", "data": False}.items() <= services[0].items()

    # mcap_ros2 decodes every message too, and the file is finished (summary with statistics)
    (mcap_file,) = sorted(bag.glob("*.mcap"))
    decoded = list(read_ros2_messages(str(mcap_file)))
    assert len(decoded) == sum(len(v) for v in messages.values())
    with open(mcap_file, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == len(decoded)
        assert reader.get_header().profile == "ros2"
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["storage_identifier"] == "mcap"
    assert meta["message_count"] == len(decoded)
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    assert counts["/cgp_sim/bodies/poses"] == 120


def committed_clock_messages(bag) -> int:
    """/clock messages in the bag's (first) MCAP file so far, read sequentially as a recovering reader would,
    up to the first incomplete record of a file still being written."""
    files = sorted(bag.glob("*.mcap"))
    if not files:
        return 0
    count, clock_channels = 0, set()
    with open(files[0], "rb") as f:
        try:
            for record in StreamReader(f, validate_crcs=True).records:
                if isinstance(record, Channel) and record.topic == "/clock":
                    clock_channels.add(record.id)
                elif isinstance(record, Message) and record.channel_id in clock_channels:
                    count += 1
        except Exception:  # the record being written: the end of what is committed
            pass
    return count


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_signal_finishes_the_bag(start_node, probe, tmp_path, signum):
    bag = tmp_path / "bag"
    clock = probe.subscribe("/clock", Clock)
    node = start_node("--scene", "default", "--bag", str(bag))
    probe.wait_for_messages("/clock", 30, timeout=30)
    node.send(signum)
    assert node.wait(20) == 0, node.log()
    assert "bag in" in node.log()
    (mcap_file,) = sorted(bag.glob("*.mcap"))
    with open(mcap_file, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None, "no summary: the file was not finished"
    _, messages = read_bag(bag)
    recorded = [stamp_ns(m.clock) for _, m in messages["/clock"]]
    # everything the node published before it stopped is in the bag (the live view is a subset)
    assert {stamp_ns(m.clock) for m in clock.messages} <= set(recorded)
    assert recorded == sorted(recorded)


def test_sigkill_leaves_every_committed_chunk_readable(start_node, probe, tmp_path):
    bag = tmp_path / "bag"
    probe.subscribe("/clock", Clock)
    node = start_node("--scene", "default", "--bag", str(bag))
    # run until the file holds at least a second of committed ticks (a chunk closes after 0.5 s at the latest),
    # whatever the machine's speed, then kill
    probe.wait_for_messages("/clock", 30, timeout=60)
    probe.spin_until(lambda: committed_clock_messages(bag) >= 60, 60, "60 committed /clock messages")
    node.send(signal.SIGKILL)
    node.wait(10)
    (mcap_file,) = sorted(bag.glob("*.mcap"))
    # mcap's reader in recovery mode: read records sequentially up to the end of what was committed
    with open(mcap_file, "rb") as f:
        recovered = [r for r in StreamReader(f, validate_crcs=True).records if isinstance(r, Message)]
    assert len(recovered) > 0
    _, messages = read_bag(bag)  # rosbags reads the killed directory as it is
    assert sum(len(v) for v in messages.values()) == len(recovered)
    stamps = [stamp_ns(m.clock) for _, m in messages["/clock"]]
    # no gaps: every tick from the first up to the last committed one
    assert stamps == [round(1e9 / 60) * (i + 1) for i in range(len(stamps))]
    assert len(stamps) >= 60  # at least what had been committed when it was killed

"""~/flocks/<flock>/stats (issue 14): the FlockStats CDR bytes equal rclpy's serialization; over DDS, from the
node in its own process, each tick's stats agree with the same tick's PoseArray (polarization from the fish
frames' x axes, which are the velocity directions; centroid, radius of gyration and nearest-neighbour distance
from the positions); the bag holds the stats with their schema, one per tick, readable by rosbags; and a flock
spawned while the node runs gets its stats topic (published and recorded) until it is deleted."""

from __future__ import annotations

import math

import numpy as np
import pytest
from geometry_msgs.msg import PoseArray
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.highlevel import AnyReader
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from sim_client import OK
from test_cdr import reference_bytes
from test_node_sim_services import start_paused

from cgp_core.boids.order import FlockOrder
from cgp_sim_ros.wire.cdr import FlockStatsSerializer


def serialize(stamp_ns: int, frame_id: str, order: FlockOrder) -> bytes:
    o = order
    return FlockStatsSerializer(frame_id).serialize(stamp_ns, o.count, (
        o.polarization, o.milling, *o.centroid, o.radius_of_gyration, o.mean_nearest_neighbor_distance, o.mean_speed,
        o.min_speed, o.max_speed))


def stats_message(stamp_ns: int, frame_id: str, order: FlockOrder):
    from cgp_sim_msgs.msg import FlockStats

    msg = FlockStats(count=order.count, polarization=order.polarization, milling=order.milling,
                     radius_of_gyration=order.radius_of_gyration,
                     mean_nearest_neighbor_distance=order.mean_nearest_neighbor_distance,
                     mean_speed=order.mean_speed, min_speed=order.min_speed, max_speed=order.max_speed)
    msg.header.frame_id = frame_id
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    msg.centroid.x, msg.centroid.y, msg.centroid.z = map(float, order.centroid)
    return msg


@pytest.mark.parametrize("frame_id", ["world", "", "w", "ab", "abc", "map_frame_7"])  # every string padding
@pytest.mark.parametrize("count, nearest", [(150, 0.93), (1, math.nan)])
def test_cdr_bytes_equal_rclpy_serialization(frame_id, count, nearest):
    order = FlockOrder(count=count, polarization=0.97, milling=0.01, centroid=np.array([1.5, -2.25, 15.0]),
                       radius_of_gyration=3.3, mean_nearest_neighbor_distance=nearest, mean_speed=3.0,
                       min_speed=2.5, max_speed=3.5)
    stamp = 12_345_678_901
    data = serialize(stamp, frame_id, order)
    message = stats_message(stamp, frame_id, order)
    # test_cdr's reference serializer (zero padding), and rclpy's bytes outside the padding it leaves
    # uninitialised
    reference, padding = reference_bytes(message)
    assert data == reference
    rclpy_bytes = np.frombuffer(serialize_message(message), dtype=np.uint8)
    ours = np.frombuffer(data, dtype=np.uint8)
    assert len(ours) == len(rclpy_bytes) and np.array_equal(ours[~padding], rclpy_bytes[~padding])
    back = deserialize_message(data, type(message))
    assert back.count == count and back.polarization == 0.97 and back.header.frame_id == frame_id
    assert back.centroid.y == -2.25 and back.max_speed == 3.5
    assert back.mean_nearest_neighbor_distance == nearest or math.isnan(nearest)


def headings_of(poses: PoseArray) -> np.ndarray:
    q = np.array([[p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w] for p in poses.poses])
    return Rotation.from_quat(q).apply([1.0, 0.0, 0.0])


def positions_of(poses: PoseArray) -> np.ndarray:
    return np.array([[p.position.x, p.position.y, p.position.z] for p in poses.poses])


def stamp_ns(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def test_stats_over_dds_match_the_poses_and_are_recorded(start_node, probe, tmp_path):
    from cgp_sim_msgs.msg import FlockStats

    bag = tmp_path / "run"
    stats = probe.subscribe("/cgp_sim/flocks/school/stats", FlockStats)
    poses = probe.subscribe("/cgp_sim/flocks/school/poses", PoseArray)
    node, sim = start_paused(start_node, probe, "predator", "--bag", str(bag))
    probe.wait_until_matched("/cgp_sim/flocks/school/stats", "/cgp_sim/flocks/school/poses")
    # 1 s in steps of 10 ticks, each delivered before the next: the state topics keep the last 10 samples
    # (KEEP_LAST 10), so 60 ticks in one burst (realtime: false) outran a subscriber slowed by a parallel test run
    # (32 of 60 stats seen)
    for k in range(1, 7):
        assert sim.step(10).result.result == OK
        probe.spin_until(lambda k=k: len(stats.messages) == len(poses.messages) == 10 * k, 20,
                         f"the stats and poses of {10 * k} ticks")
    assert node.stop() == 0, node.log()  # (the bag closed)

    by_stamp = {stamp_ns(m.header): m for m in poses.messages}
    assert len(stats.messages) == 60 and len(by_stamp) == 60
    for message in stats.messages:
        pose_array = by_stamp[stamp_ns(message.header)]
        x, h = positions_of(pose_array), headings_of(pose_array)
        assert message.count == 150 and message.header.frame_id == "world"
        assert message.polarization == pytest.approx(np.linalg.norm(h.sum(axis=0)) / 150, abs=1e-9)
        np.testing.assert_allclose([message.centroid.x, message.centroid.y, message.centroid.z], x.mean(axis=0),
                                   atol=1e-9)
        assert message.radius_of_gyration == pytest.approx(
            math.sqrt(((x - x.mean(axis=0)) ** 2).sum(axis=1).mean()), abs=1e-9)
        assert message.mean_nearest_neighbor_distance == pytest.approx(
            cKDTree(x).query(x, k=2)[0][:, 1].mean(), abs=1e-9)
        assert message.min_speed == pytest.approx(3.0) and message.max_speed == pytest.approx(3.0)  # Couzin: s
        assert 0.0 <= message.milling <= 1.0

    with AnyReader([bag]) as reader:
        connections = [c for c in reader.connections if c.topic == "/cgp_sim/flocks/school/stats"]
        assert [c.msgtype for c in connections] == ["cgp_sim_msgs/msg/FlockStats"]
        recorded = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=connections)]
    assert len(recorded) == 60
    live = {stamp_ns(m.header): m.polarization for m in stats.messages}
    assert {stamp_ns(m.header): m.polarization for m in recorded} == live


def test_a_spawned_flock_gets_its_stats_until_it_is_deleted(start_node, probe, tmp_path):
    from cgp_sim_msgs.msg import FlockStats

    bag = tmp_path / "bag"
    node, sim = start_paused(start_node, probe, "zero_g", "--bag", str(bag))
    stats = probe.subscribe("/cgp_sim/flocks/school/stats", FlockStats)
    assert sim.step(2).result.result == OK
    assert sim.spawn("school", "flock: {count: 40, rules: couzin, couzin: {speed: 2.0}, bounds: {mode: none}}",
                     position=(0, 0, 12)).result.result == OK
    probe.wait_until_matched("/cgp_sim/flocks/school/stats")
    assert sim.step(4).result.result == OK
    probe.spin_until(lambda: len(stats.messages) == 4, 20, "4 stats of the spawned school")
    assert [m.count for m in stats.messages] == [40] * 4
    assert all(m.min_speed == pytest.approx(2.0) == m.max_speed for m in stats.messages)  # its Couzin speed s
    assert math.dist([stats.messages[-1].centroid.x, stats.messages[-1].centroid.y,
                      stats.messages[-1].centroid.z], [0, 0, 12]) < 2.0
    assert sim.delete("school").result.result == OK
    probe.spin_until(lambda: probe.node.count_publishers("/cgp_sim/flocks/school/stats") == 0, 20,
                     "the stats publisher to go with the flock")
    assert sim.step(2).result.result == OK
    probe.spin_for(0.3)
    assert len(stats.messages) == 4
    assert node.stop() == 0, node.log()

    with AnyReader([bag]) as reader:
        connections = [c for c in reader.connections if c.topic == "/cgp_sim/flocks/school/stats"]
        assert [c.msgtype for c in connections] == ["cgp_sim_msgs/msg/FlockStats"]
        recorded = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=connections)]
    assert [(m.header.stamp.sec, m.header.stamp.nanosec, m.polarization) for m in recorded] == [
        (m.header.stamp.sec, m.header.stamp.nanosec, m.polarization) for m in stats.messages]

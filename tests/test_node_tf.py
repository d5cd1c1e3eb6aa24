"""TF as a tf2 listener sees it, over DDS from another process: ``/tf`` each tick with ``world`` → ``<body>`` for
the movable bodies (the pose ``~/bodies/<body>/odom`` carries, same ``child_frame_id``, same stamp), and
``/tf_static`` (transient local, as tf2_ros' static listener subscribes) with the fixed ones, delivered to a
subscriber that joins late.  Spawned bodies appear, deleted ones stop.  (The numpy-built ``/tf`` bytes are
checked against rclpy's own serialization in tests/test_cdr.py.)"""

from __future__ import annotations

import numpy as np
from nav_msgs.msg import Odometry
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sim_client import OK
from test_node_sim_services import start_paused
from tf2_msgs.msg import TFMessage

# what tf2_ros' TransformListener subscribes with (tf2_ros::DynamicListenerQoS / StaticListenerQoS)
TF_LISTENER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)
TF_STATIC_LISTENER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                                    reliability=ReliabilityPolicy.RELIABLE,
                                    durability=DurabilityPolicy.TRANSIENT_LOCAL)
MOVABLE = ["ball", "crate", "capsule", "tetromino"]


def stamp_ns(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def pose_of(transform) -> list[float]:
    t, q = transform.transform.translation, transform.transform.rotation
    return [t.x, t.y, t.z, q.x, q.y, q.z, q.w]


def test_tf_follows_the_bodies(start_node, probe):
    tf = probe.subscribe("/tf", TFMessage, TF_LISTENER_QOS, raw=True)
    odoms = {name: probe.subscribe(f"/cgp_sim/bodies/{name}/odom", Odometry) for name in MOVABLE}
    node, sim = start_paused(start_node, probe, "default")
    probe.wait_for_publisher("/tf")
    for name in MOVABLE:
        probe.wait_for_publisher(f"/cgp_sim/bodies/{name}/odom")
    assert sim.step(3).result.result == OK
    probe.spin_until(lambda: len(tf.messages) >= 3 and all(len(o.messages) >= 3 for o in odoms.values()), 20,
                     "3 ticks of /tf and odometry")

    for raw in tf.messages:
        msg = deserialize_message(raw, TFMessage)
        assert [t.child_frame_id for t in msg.transforms] == MOVABLE  # the fixed pillar is not on /tf
        assert {t.header.frame_id for t in msg.transforms} == {"world"}
        assert len({stamp_ns(t.header) for t in msg.transforms}) == 1
        for t in msg.transforms:
            odom = next(o for o in odoms[t.child_frame_id].messages if stamp_ns(o.header) == stamp_ns(t.header))
            assert odom.child_frame_id == t.child_frame_id and odom.header.frame_id == t.header.frame_id
            p, q = odom.pose.pose.position, odom.pose.pose.orientation
            assert pose_of(t) == [p.x, p.y, p.z, q.x, q.y, q.z, q.w]

    # a spawned movable body appears on /tf, a deleted one stops
    assert sim.spawn("box1", "body: {shape: box, size: [0.4, 0.4, 0.4], mass: 2.0}",
                     position=(0, 3, 5)).result.result == OK
    assert sim.delete("ball").result.result == OK
    assert sim.step(1).result.result == OK

    def of_the_step() -> TFMessage | None:
        """The newest /tf with box1 on it: not simply the newest /tf received, which may be a late one of the
        3-tick burst above (a reader waits for 3 messages, not for the burst's last)."""
        spawned = [m for m in map(lambda raw: deserialize_message(raw, TFMessage), tf.messages)
                   if "box1" in [t.child_frame_id for t in m.transforms]]
        return max(spawned, key=lambda m: stamp_ns(m.transforms[0].header), default=None)

    probe.spin_until(lambda: of_the_step() is not None, 10, "the /tf of the step after the spawn")
    msg = of_the_step()
    assert [t.child_frame_id for t in msg.transforms] == ["crate", "capsule", "tetromino", "box1"]
    box1 = msg.transforms[-1]
    assert pose_of(box1)[:2] == [0.0, 3.0] and pose_of(box1)[2] < 5.0


def test_tf_static_reaches_late_subscribers_and_follows_fixed_bodies(start_node, probe):
    node, sim = start_paused(start_node, probe, "default")
    assert sim.step(2).result.result == OK  # the node has been up a while before anyone listens to /tf_static

    def latest_static(timeout: float = 20.0) -> TFMessage:
        """What a tf2 static listener that joins now receives (a new subscription each time)."""
        box = probe.subscribe("/tf_static", TFMessage, TF_STATIC_LISTENER_QOS)
        probe.spin_until(lambda: box.messages, timeout, "/tf_static (transient local)")
        probe.spin_for(0.2)
        return box.messages[-1]

    static = latest_static()
    (pillar,) = static.transforms
    assert pillar.child_frame_id == "pillar" and pillar.header.frame_id == "world"
    assert pose_of(pillar) == [6.0, 0.0, 4.0, 0.0, 0.0, 0.0, 1.0]

    # a spawned fixed body joins the static set; a teleported one is sent with its new pose
    assert sim.spawn("wall", "body: {shape: box, size: [0.2, 4.0, 2.0], fixed: true}",
                     position=(-6, 0, 1)).result.result == OK
    assert sim.set_state("pillar", (7.0, 0.0, 4.0)).result.result == OK
    static = latest_static()
    assert {t.child_frame_id: pose_of(t)[:3] for t in static.transforms} == {"pillar": [7.0, 0.0, 4.0],
                                                                             "wall": [-6.0, 0.0, 1.0]}
    # a deleted one is no longer sent to listeners that join later
    assert sim.delete("pillar").result.result == OK
    assert [t.child_frame_id for t in latest_static().transforms] == ["wall"]
    np.testing.assert_equal(sim.names(), ["ball", "crate", "capsule", "tetromino", "wall", "fish"])

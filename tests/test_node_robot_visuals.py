"""Issue 36 (markers) through the node: another process subscribes to ``~/markers`` and ``~/robots/arm/joint_states``
of the ``arm_teleop`` scene (the 4-joint arm.urdf, one visual per link; the node its own process, started paused
so that both readers see it from its first tick) and sees one marker per URDF visual (ns ``robots/arm``) with the
shape's marker type, the URDF's colour and the pose Pinocchio gives that visual at the joint positions of the
joint_states message of the same tick (same stamp), to 1e-6 m — while the arm moves under a position command, so
a marker a tick late would be off by far more.  The bag of a run holds the same markers (read back with
mcap_ros2, not our reader)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap_ros2.reader import read_ros2_messages
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from ros_probe import pause
from sensor_msgs.msg import JointState
from test_robot_visuals import SHAPE_TYPES, pinocchio_visuals, urdf_colors
from visualization_msgs.msg import Marker, MarkerArray

from cgp_core.rotation import quat_to_matrix

REPO = Path(__file__).resolve().parents[1]
ARM_URDF = REPO / "msgs_config" / "robots" / "arm.urdf"
MARKERS = "/cgp_sim/markers"
JOINT_STATES = "/cgp_sim/robots/arm/joint_states"
JOINT_COMMANDS = "/cgp_sim/robots/arm/joint_commands"
NS = "robots/arm"
#: the arm's URDF visuals: (link, shape) in the URDF's tree order (depth first, children in file order), the
#: order of the node's marker ids and of Pinocchio's visual geometries
ARM_VISUALS = [("base_link", "cylinder"), ("shoulder", "cylinder"), ("upper_arm", "box"), ("forearm", "box"),
               ("hand", "box"), ("finger_left", "box"), ("finger_right", "box")]
KEEP_ALL = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def stamp_ns(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def check_visual_markers(markers: list, state: JointState, colors: dict) -> float:
    """The ``robots/arm`` markers of one tick against Pinocchio at that tick's joint positions; returns the
    largest position error [m]."""
    expected = pinocchio_visuals(ARM_URDF, dict(zip(state.name, state.position)))
    assert [m.id for m in markers] == list(range(len(ARM_VISUALS)))
    worst = 0.0
    for m, (link, shape) in zip(markers, ARM_VISUALS):
        assert m.action == Marker.ADD and m.type == SHAPE_TYPES[shape], (link, m.type)
        assert m.header.frame_id == "world"
        R, p = expected[link]
        position = np.array([m.pose.position.x, m.pose.position.y, m.pose.position.z])
        q = np.array([m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w])
        worst = max(worst, float(np.abs(position - p).max()))
        assert np.abs(position - p).max() <= 1e-6, (link, position, p)
        assert np.abs(quat_to_matrix(q) - R).max() <= 1e-6, link
        np.testing.assert_allclose([m.color.r, m.color.g, m.color.b, m.color.a], colors[link], atol=1e-6)
    return worst


def test_markers_carry_every_visual_at_the_joint_states_of_the_same_tick(start_node, probe):
    markers = probe.subscribe(MARKERS, MarkerArray, KEEP_ALL)
    states = probe.subscribe(JOINT_STATES, JointState, KEEP_ALL)
    start_node("--scene", "arm_teleop", "--start-paused", "true")
    probe.wait_until_matched(MARKERS, JOINT_STATES, timeout=60)
    commands = probe.publisher(JOINT_COMMANDS, JointState)
    probe.wait_for_subscriber(commands, timeout=30)
    pause(probe, False)
    probe.spin_until(lambda: len(states.messages) >= 3, 60, "the first joint_states")
    # move the arm: the poses then change from tick to tick
    probe.publish_acked(commands, JointState(name=["shoulder_pan", "shoulder_lift", "elbow", "wrist"],
                                             position=[1.2, -0.3, 0.4, 1.0]))
    first = len(states.messages)
    probe.spin_until(lambda: len(states.messages) >= first + 40 and len(markers.messages) >= first + 40, 60,
                     "40 more ticks of joint_states and markers")
    colors = urdf_colors(ARM_URDF)
    by_stamp = {stamp_ns(s.header): s for s in states.messages}
    checked, moved = 0, []
    for array in markers.messages:
        ours = [m for m in array.markers if m.ns == NS]
        assert not [m for m in array.markers if m.ns.startswith("bodies/arm/")]  # not drawn twice
        if not ours:
            continue
        stamp = stamp_ns(ours[0].header)
        assert all(stamp_ns(m.header) == stamp for m in ours)
        state = by_stamp.get(stamp)
        if state is None:  # (a tick whose joint_states this reader missed: none expected, reliable keep-1000)
            continue
        check_visual_markers(ours, state, colors)
        moved.append(np.array([ours[-1].pose.position.x, ours[-1].pose.position.y, ours[-1].pose.position.z]))
        checked += 1
    assert checked >= 40
    # the arm moved while these were taken: consecutive ticks differ far more than the tolerance
    steps = np.linalg.norm(np.diff(np.array(moved), axis=0), axis=1)
    assert steps.max() > 1e-3


def test_the_bag_holds_the_visual_markers(start_node, tmp_path):
    bag = tmp_path / "bag"
    node = start_node("--scene", "arm_teleop", "--bag", str(bag), "--duration", "0.5", "--realtime", "false")
    assert node.wait(120) == 0, node.log()[-3000:]
    arrays, states = [], {}
    for mcap_file in sorted(bag.glob("*.mcap")):
        for m in read_ros2_messages(str(mcap_file), topics=[MARKERS, JOINT_STATES]):
            if m.channel.topic == MARKERS:
                assert m.schema.name == "visualization_msgs/msg/MarkerArray"
                arrays.append(m.ros_msg)
            else:
                states[stamp_ns(m.ros_msg.header)] = m.ros_msg
    assert len(arrays) == 30 == len(states)  # every tick of 0.5 s at 60 Hz
    colors = urdf_colors(ARM_URDF)
    for array in arrays:
        ours = [m for m in array.markers if m.ns == NS]
        check_visual_markers(ours, states[stamp_ns(ours[0].header)], colors)


@pytest.fixture(autouse=True)
def _pinocchio():
    pytest.importorskip("pinocchio")

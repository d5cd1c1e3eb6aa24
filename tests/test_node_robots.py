"""Issue 36 (topics): a robot on the ROS graph as another node sees it — the node runs the built-in ``arm_teleop``
scene (the 4-joint arm holding its pose until commanded) as its own process and this process subscribes and
commands over DDS, as robot_state_publisher, topic_based_ros2_control, RViz and a recorder would.

- ``~/robots/arm/joint_states`` (sensor_msgs/JointState) every tick, stamped in simulation time (the tick's
  ``/clock``), the URDF's movable joints in URDF order, finite values; it reaches a SensorDataQoS (best-effort)
  reader, as robot_state_publisher and topic_based_ros2_control subscribe, and a reliable one.
- ``~/robots/arm/robot_description`` (std_msgs/String, transient local): the URDF file as loaded, to a late reader.
- TF: every URDF link as ``arm/<link>``; the root link's parent ``world``, every other link's its URDF parent;
  fixed-joint children (and the fixed base's root) on ``/tf_static``, the rest on ``/tf``; the links are not
  also published as bodies.
- ``~/robots/arm/joint_commands`` as topic_based_ros2_control publishes it: a position command for all joints is
  reached (≤ 1e-3 rad, read back on joint_states), an effort-only and a velocity-only command are accepted (no
  rejection), a bad one (unknown joint, NaN) is rejected with a line on ``~/events`` naming it, and the node
  keeps ticking.
- ``~/robots/arm/joint_trajectory``: a JointTrajectory is followed to its end point (≤ 1e-3 rad); one naming an
  unknown joint is refused on ``~/events``.
- Two robots from one URDF stay apart: topics by robot name, frames ``<frame_prefix><robot>/<link>``.
- The bag holds JointState and the robot_description, decoded by mcap_ros2 (not our reader).
- The ``arm`` scene (the 7-DoF arm following its scene trajectory): it moves on its own, and a ``joint_commands``
  or a ``joint_trajectory`` message wins — the arm goes where the ROS command says (≤ 1e-3 rad) and stays there
  for 2 s of simulated time, which its looping trajectory would not.
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap_ros2.reader import read_ros2_messages
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from ros_probe import pause
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from cgp_core.rotation import quat_to_matrix

REPO = Path(__file__).resolve().parents[1]
SCENE = REPO / "msgs_config" / "scenes" / "arm_teleop.yaml"  # the 4-joint arm holding its pose
ROBOT = "arm"
JOINT_STATES = f"/cgp_sim/robots/{ROBOT}/joint_states"
JOINT_COMMANDS = f"/cgp_sim/robots/{ROBOT}/joint_commands"
JOINT_TRAJECTORY = f"/cgp_sim/robots/{ROBOT}/joint_trajectory"
DESCRIPTION = f"/cgp_sim/robots/{ROBOT}/robot_description"
EVENTS = "/cgp_sim/events"
MOVABLE_TYPES = ("revolute", "prismatic", "continuous")
#: what robot_state_publisher's robot_description subscribers (RViz) and tf2's static listener ask for
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
TF_STATIC_LISTENER = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                                durability=DurabilityPolicy.TRANSIENT_LOCAL)
EVENTS_READER = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)

pytestmark = pytest.mark.skipif(not SCENE.exists(), reason="the arm scene (issue 35's robots) is not there yet")


# ---- the URDF, read here on its own (the oracle is the file, not the node's model) ----------------------------

def robot_file() -> Path:
    """The URDF (or xacro) file of the arm scene's robot: the string value of its entry that names one."""
    scene = yaml.safe_load(SCENE.read_text())
    (entry,) = [r for r in scene["robots"] if r.get("name", ROBOT) == ROBOT]
    for value in entry.values():
        if isinstance(value, str) and value.endswith((".urdf", ".xacro", ".urdf.xacro")):
            for base in (SCENE.parent, REPO / "msgs_config" / "robots", REPO / "msgs_config"):
                if (base / value).is_file():
                    return (base / value).resolve()
            if Path(value).is_file():
                return Path(value)
    raise AssertionError(f"no URDF file named in the arm scene's robot entry {entry}")


class Urdf:
    def __init__(self, text: str):
        root = ET.fromstring(text)
        self.links = [link.get("name") for link in root.findall("link")]
        self.joints = [(j.get("name"), j.get("type"), j.find("parent").get("link"), j.find("child").get("link"),
                        j.find("limit")) for j in root.findall("joint")]
        children = {child for _, _, _, child, _ in self.joints}
        (self.root,) = [link for link in self.links if link not in children]
        self.movable = [name for name, kind, _, _, _ in self.joints if kind in MOVABLE_TYPES]
        self.parent = {child: parent for _, _, parent, child, _ in self.joints}
        self.fixed_children = {child for _, kind, _, child, _ in self.joints if kind == "fixed"}
        self.limits = {name: (float(limit.get("lower", -math.pi)), float(limit.get("upper", math.pi)))
                       if limit is not None and kind != "continuous" else (-math.pi, math.pi)
                       for name, kind, _, _, limit in self.joints if kind in MOVABLE_TYPES}
        #: mimic followers (commanded through their leader: ros2_control refuses command interfaces on them)
        self.mimic = {j.get("name") for j in root.findall("joint") if j.find("mimic") is not None}
        #: the joints a controller commands: the movable ones but the mimic followers, in URDF order
        self.commanded = [name for name in self.movable if name not in self.mimic]

    def targets(self, q: np.ndarray, step: float) -> np.ndarray:
        """Targets for the commanded joints (``q``: their positions) ``step`` away (at most a fifth of a joint's
        range), inside the limits with a margin."""
        lower, upper = np.array([self.limits[j] for j in self.commanded]).T
        span = upper - lower
        moved = q + np.sign(step) * np.minimum(abs(step), 0.2 * span)
        return np.clip(moved, lower + 0.1 * span, upper - 0.1 * span)

    def of(self, msg, joints) -> np.ndarray:
        """The positions of ``joints`` in a JointState."""
        index = {name: i for i, name in enumerate(msg.name)}
        return np.array([msg.position[index[j]] for j in joints])


@pytest.fixture(scope="module")
def urdf() -> Urdf:
    text = robot_file().read_text()
    if robot_file().suffix == ".xacro":
        pytest.skip("the arm's robot is a xacro file: the comparison needs its expansion")
    return Urdf(text)


def stamp_ns(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def events_of(box) -> list[dict]:
    return [json.loads(m.data) for m in box.messages]


def rejections(box) -> list[dict]:
    return [e for e in events_of(box) if e.get("event") == "rejected"
            and e.get("source") == f"robots/{ROBOT}/joint_commands"]


@pytest.fixture
def arm(start_node, probe):
    """The node on the arm scene, started paused; the probe's readers matched, then the node unpaused (the probe
    sees it from its first tick)."""
    subs = {
        "sensor": probe.subscribe(JOINT_STATES, JointState, qos_profile_sensor_data),
        "clock": probe.subscribe("/clock", Clock),
        "tf": probe.subscribe("/tf", TFMessage),
        "events": probe.subscribe(EVENTS, String, EVENTS_READER),
    }
    node = start_node("--scene", "arm_teleop", "--start-paused", "true")
    probe.wait_until_matched(JOINT_STATES, "/clock", "/tf", EVENTS, timeout=60)
    # a reliable reader too (RViz's default); the probe keeps one subscription per topic, so a second probe node
    from ros_probe import Probe

    reliable = Probe(f"{probe.node.get_name()}_reliable")
    subs["reliable"] = reliable.subscribe(JOINT_STATES, JointState)
    reliable.wait_until_matched(JOINT_STATES, timeout=60)
    pause(probe, False)
    yield node, subs, reliable
    reliable.close()


def latest_state(probe, box, count: int = 1, timeout: float = 30.0) -> JointState:
    n = len(box.messages)
    probe.spin_until(lambda: len(box.messages) >= n + count, timeout, f"{count} more joint_states")
    return box.messages[-1]


# ---- joint_states, robot_description, TF -----------------------------------------------------------------------

def test_joint_states_every_tick_in_sim_time_to_sensor_data_and_reliable_readers(arm, probe, urdf):
    node, subs, reliable = arm
    probe.wait_for_messages(JOINT_STATES, 10, timeout=30)
    reliable.wait_for_messages(JOINT_STATES, 10, timeout=30)
    probe.spin_until(lambda: len(subs["clock"].messages) >= 10, 30, "10 ticks of /clock")
    for box in (subs["sensor"], subs["reliable"]):
        for msg in box.messages:
            assert list(msg.name) == urdf.movable  # the URDF's movable joints, in URDF order
            for values in (msg.position, msg.velocity, msg.effort):
                assert len(values) == len(urdf.movable) and np.all(np.isfinite(values))
    # stamped in simulation time: every stamp is a tick's /clock, one message per tick, in order
    clock = {c.clock.sec * 1_000_000_000 + c.clock.nanosec for c in subs["clock"].messages}
    stamps = [stamp_ns(m.header) for m in subs["reliable"].messages]
    assert stamps == sorted(set(stamps))
    assert set(stamps[:5]) <= clock, (stamps[:5], sorted(clock)[:5])
    # the initial pose is held (position drives): within the limits, nothing has run away
    q = np.array(subs["reliable"].messages[-1].position)
    lower, upper = np.array([urdf.limits[j] for j in urdf.movable]).T
    assert np.all(q >= lower - 1e-3) and np.all(q <= upper + 1e-3)


def test_robot_description_is_the_urdf_as_loaded_for_a_late_reader(arm, probe, urdf):
    node, subs, _ = arm
    probe.wait_for_messages(JOINT_STATES, 3, timeout=30)  # the node has ticked before this reader joins
    box = probe.subscribe(DESCRIPTION, String, LATCHED)
    probe.spin_until(lambda: box.messages, 30, "robot_description (transient local)")
    assert box.messages[-1].data == robot_file().read_text()
    assert probe.topic_types()[DESCRIPTION] == ["std_msgs/msg/String"]


def test_tf_has_every_link_with_fixed_frames_on_tf_static(arm, probe, urdf):
    node, subs, _ = arm
    probe.wait_for_messages("/tf", 5, timeout=30)
    static = probe.subscribe("/tf_static", TFMessage, TF_STATIC_LISTENER)
    probe.spin_until(lambda: static.messages, 30, "/tf_static (transient local)")
    probe.spin_for(0.2)

    def edges(messages) -> dict[str, str]:
        return {t.child_frame_id: t.header.frame_id for m in messages for t in m.transforms}

    moving, fixed = edges(subs["tf"].messages[-3:]), edges(static.messages[-1:])
    prefix = f"{ROBOT}/"
    robot_moving = {c: p for c, p in moving.items() if c.startswith(prefix)}
    robot_fixed = {c: p for c, p in fixed.items() if c.startswith(prefix)}
    # every URDF link, once, with its URDF parent (the root: world)
    assert set(robot_moving) | set(robot_fixed) == {prefix + link for link in urdf.links}
    assert not set(robot_moving) & set(robot_fixed)
    for child, parent in {**robot_moving, **robot_fixed}.items():
        link = child[len(prefix):]
        assert parent == ("world" if link == urdf.root else prefix + urdf.parent[link]), (child, parent)
    # fixed joints' frames are static; moving joints' are on /tf
    for link in urdf.fixed_children:
        assert prefix + link in robot_fixed, link
    for name, kind, _, child, _ in urdf.joints:
        if kind in MOVABLE_TYPES:
            assert prefix + child in robot_moving, (name, child)
    # one message per tick carries the robot with the bodies, all with the tick's stamp
    last = subs["tf"].messages[-1]
    assert len({stamp_ns(t.header) for t in last.transforms}) == 1
    assert all(np.isfinite([t.transform.translation.x, t.transform.rotation.w]).all() for t in last.transforms)


def test_tf_of_every_link_is_pinocchios_forward_kinematics_at_the_published_joint_positions(arm, probe, urdf):
    """Issue 36: each link's world pose, composed from ``/tf`` and ``/tf_static`` as a TF listener composes it, is
    Pinocchio's forward kinematics (its own URDF parser) at the positions ``joint_states`` published for the same
    tick, to <= 1e-6 m and rad."""
    pin = pytest.importorskip("pinocchio")
    node, subs, _ = arm
    static = probe.subscribe("/tf_static", TFMessage, TF_STATIC_LISTENER)
    probe.spin_until(lambda: static.messages, 30, "/tf_static (transient local)")
    # the arm moving (a position step on every commanded joint), so that the check is not of the initial pose
    latest = latest_state(probe, subs["sensor"])
    targets = urdf.targets(urdf.of(latest, urdf.commanded), 0.4)
    commands = probe.node.create_publisher(JointState, JOINT_COMMANDS, 10)
    probe.spin_until(lambda: commands.get_subscription_count() > 0, 30, "the node's joint_commands reader")
    commands.publish(JointState(name=urdf.commanded, position=targets.tolist()))
    latest_state(probe, subs["sensor"], count=20)
    # a tick whose joint_states and /tf both arrived
    tf_by_stamp = {stamp_ns(m.transforms[0].header): m for m in subs["tf"].messages if m.transforms}
    state = next(m for m in reversed(subs["sensor"].messages) if stamp_ns(m.header) in tf_by_stamp)
    edges = {t.child_frame_id: t for m in (*static.messages, tf_by_stamp[stamp_ns(state.header)])
             for t in m.transforms}

    def world_pose(frame: str) -> tuple[np.ndarray, np.ndarray]:
        if frame == "world":
            return np.eye(3), np.zeros(3)
        t = edges[frame]
        R_parent, p_parent = world_pose(t.header.frame_id)
        r, x = t.transform.rotation, t.transform.translation
        return (R_parent @ quat_to_matrix(np.array([r.x, r.y, r.z, r.w])),
                p_parent + R_parent @ np.array([x.x, x.y, x.z]))

    model = pin.buildModelFromUrdf(str(robot_file()))
    data = model.createData()
    q = pin.neutral(model)
    published = dict(zip(state.name, state.position))
    for j in range(1, model.njoints):
        q[model.joints[j].idx_q] = published[model.names[j]]
    pin.framesForwardKinematics(model, data, q)
    prefix = f"{ROBOT}/"
    R_root, p_root = world_pose(prefix + urdf.root)  # where the scene put the root link
    for link in urdf.links:
        frame = model.getFrameId(link, pin.BODY)
        placement = data.oMf[frame]
        R_expected = R_root @ np.array(placement.rotation)
        p_expected = p_root + R_root @ np.array(placement.translation)
        R, p = world_pose(prefix + link)
        assert np.abs(p - p_expected).max() <= 1e-6, (link, p, p_expected)
        assert np.abs(R - R_expected).max() <= 1e-6, link
    moved = np.abs(np.array([published[j] for j in urdf.commanded]) - urdf.of(latest, urdf.commanded)).max()
    assert moved > 0.05, moved  # the check was at a pose the drive moved to, not the initial one


# ---- joint_commands --------------------------------------------------------------------------------------------

def test_position_effort_velocity_commands_and_a_bad_one(arm, probe, urdf):
    node, subs, _ = arm
    states, events = subs["sensor"], subs["events"]
    joints = urdf.commanded
    q0 = urdf.of(latest_state(probe, states, 3), joints)
    # topic_based_ros2_control's publisher: reliable, volatile, keep last 1 (rclcpp::QoS(1))
    commands = probe.publisher(JOINT_COMMANDS, JointState,
                               QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                                          reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE))
    probe.wait_for_subscriber(commands, timeout=30)

    # position for all (commanded) joints: reached and held within 1e-3 rad
    target = urdf.targets(q0, 0.25)
    probe.publish_acked(commands, JointState(name=joints, position=target.tolist()))
    probe.spin_until(lambda: np.max(np.abs(urdf.of(states.messages[-1], joints) - target)) <= 1e-3, 60,
                     f"the joints at {target} (last: {list(states.messages[-1].position)})")
    for _ in range(30):  # and they stay there
        assert np.max(np.abs(urdf.of(latest_state(probe, states), joints) - target)) <= 1e-3

    # effort only (all joints, 0 N m / N: the arm is let go), then velocity only (the first joint turning at
    # 0.3 rad/s, the others held still): accepted, and the first joint reaches its velocity
    probe.publish_acked(commands, JointState(name=joints, effort=[0.0] * len(joints)))
    latest_state(probe, states, 5)
    velocity = [0.3] + [0.0] * (len(joints) - 1)
    probe.publish_acked(commands, JointState(name=joints, velocity=velocity))
    index = list(states.messages[-1].name).index(joints[0])
    probe.spin_until(lambda: abs(states.messages[-1].velocity[index] - 0.3) <= 1e-2, 30,
                     f"{joints[0]} turning at 0.3 rad/s (last: {states.messages[-1].velocity[index]})")

    # a bad command: an unknown joint and a NaN; the rejections are named on ~/events, the node ticks on
    first = joints[0]
    probe.publish_acked(commands, JointState(name=["no_such_joint", first], position=[0.0, float("nan")]))
    probe.spin_until(lambda: {e["field"] for e in rejections(events)} >= {"name", first}, 30,
                     f"~/events naming the rejected joints (got {rejections(events)})")
    named = {e["field"]: e for e in rejections(events)}
    assert "no_such_joint" in named["name"]["reason"] and named["name"]["kind"] == "unknown"
    assert first in named[first]["reason"] and "nan" in named[first]["reason"].lower()
    # only the bad command was rejected: the position, effort and velocity commands before it were accepted
    assert {e["field"] for e in rejections(events)} == {"name", first}, rejections(events)
    # a message larger than any joint command (64 kB) is dropped unread, and said so
    probe.publish_acked(commands, JointState(name=["x" * 70_000], position=[0.0]))
    probe.spin_until(lambda: any(e["field"] == "message" and e["kind"] == "too large" for e in rejections(events)),
                     30, "the oversized command's rejection")
    before = stamp_ns(states.messages[-1].header)
    assert stamp_ns(latest_state(probe, states, 10).header) > before
    assert node.alive()


def test_joint_command_topic_takes_joint_state_as_topic_based_ros2_control_sends_it(arm, probe, urdf):
    """Arrays shorter than ``name`` (the plugin sends only its configured interfaces): a position for the first
    joint only moves that joint; the others hold their pose."""
    node, subs, _ = arm
    states = subs["sensor"]
    joints = urdf.commanded
    q0 = urdf.of(latest_state(probe, states, 3), joints)
    commands = probe.publisher(JOINT_COMMANDS, JointState)
    probe.wait_for_subscriber(commands, timeout=30)
    target = float(urdf.targets(q0, -0.2)[0])
    probe.publish_acked(commands, JointState(name=[joints[0]], position=[target]))
    probe.spin_until(lambda: abs(urdf.of(states.messages[-1], joints[:1])[0] - target) <= 1e-3, 60,
                     "the first joint at target")
    q = urdf.of(latest_state(probe, states, 10), joints)
    assert np.max(np.abs(q[1:] - q0[1:])) <= 1e-3, (q, q0)
    assert not rejections(subs["events"])


def test_joint_trajectory_is_followed_to_its_end_point(arm, probe, urdf):
    """A JointTrajectory as joint_trajectory_controller takes it (stamp 0: start now; two points, positions only:
    linear): the joints pass the first point's side and end at the last point (≤ 1e-3 rad, 0.5 s after its time);
    a trajectory naming an unknown joint is refused on ~/events."""
    node, subs, _ = arm
    states, events = subs["sensor"], subs["events"]
    joints = urdf.commanded
    q0 = urdf.of(latest_state(probe, states, 3), joints)
    publisher = probe.publisher(JOINT_TRAJECTORY, JointTrajectory)
    probe.wait_for_subscriber(publisher, timeout=30)
    end = urdf.targets(q0, -0.3)
    middle = 0.5 * (q0 + end)
    msg = JointTrajectory(joint_names=joints)
    for seconds, q in ((0.5, middle), (1.0, end)):
        point = JointTrajectoryPoint(positions=q.tolist())
        point.time_from_start.sec, point.time_from_start.nanosec = 0, int(seconds * 1e9)
        msg.points.append(point)
    sent_at = stamp_ns(states.messages[-1].header)
    probe.publish_acked(publisher, msg)
    done_ns = sent_at + 1_500_000_000  # the end point's time (≤ 1 s after the message was taken) + 0.5 s
    probe.spin_until(lambda: stamp_ns(states.messages[-1].header) >= done_ns, 60, "1.5 s of simulated time")
    reached = next(m for m in states.messages if stamp_ns(m.header) >= done_ns)
    assert np.max(np.abs(urdf.of(reached, joints) - end)) <= 1e-3, (list(reached.position), end)

    bad = JointTrajectory(joint_names=["no_such_joint"], points=[JointTrajectoryPoint(positions=[0.0])])
    probe.publish_acked(publisher, bad)
    source = f"robots/{ROBOT}/joint_trajectory"
    probe.spin_until(lambda: any(e.get("source") == source and "no_such_joint" in e["reason"]
                                 for e in events_of(events)), 30, "the trajectory's rejection on ~/events")
    assert node.alive()


def test_two_robots_from_one_urdf_stay_apart_with_a_frame_prefix(start_node, probe, tmp_path, urdf):
    """Two robots loaded from the same URDF: their topics by robot name, their frames ``<prefix><robot>/<link>``
    under ``<prefix>world`` (``frame_prefix:=sim1/``), so one /tf holds both."""
    scene = tmp_path / "two_arms.yaml"
    scene.write_text(f"world: {{gravity: [0, 0, -9.81], ground: true}}\n"
                     f"robots:\n"
                     f"  - {{name: left, urdf: {robot_file()}, position: [0, 0.5, 0]}}\n"
                     f"  - {{name: right, urdf: {robot_file()}, position: [0, -0.5, 0]}}\n")
    tf = probe.subscribe("/tf", TFMessage)
    states = {name: probe.subscribe(f"/cgp_sim/robots/{name}/joint_states", JointState) for name in ("left", "right")}
    start_node("--scene", str(scene), "--frame-prefix", "sim1/", "--start-paused", "true")
    probe.wait_until_matched("/tf", *(f"/cgp_sim/robots/{name}/joint_states" for name in states), timeout=60)
    pause(probe, False)
    for name, box in states.items():
        probe.spin_until(lambda box=box: len(box.messages) >= 3, 30, f"{name}'s joint_states")
        assert list(box.messages[-1].name) == urdf.movable  # the same joint names: the topic tells them apart
    static = probe.subscribe("/tf_static", TFMessage, TF_STATIC_LISTENER)
    probe.spin_until(lambda: static.messages and tf.messages, 30, "/tf and /tf_static")
    probe.spin_for(0.2)
    edges = {t.child_frame_id: t.header.frame_id
             for m in [*tf.messages[-3:], static.messages[-1]] for t in m.transforms}
    for name in ("left", "right"):
        prefix = f"sim1/{name}/"
        assert {c for c in edges if c.startswith(prefix)} == {prefix + link for link in urdf.links}
        assert edges[prefix + urdf.root] == "sim1/world"
        for link, parent in urdf.parent.items():
            assert edges[prefix + link] == prefix + parent


# ---- the bag ---------------------------------------------------------------------------------------------------

def test_bag_holds_joint_states_and_the_description(start_node, tmp_path, urdf):
    bag = tmp_path / "bag"
    node = start_node("--scene", "arm_teleop", "--bag", str(bag), "--duration", "0.5", "--realtime", "false")
    assert node.wait(120) == 0, node.log()[-3000:]
    states, descriptions = [], []
    for mcap_file in sorted(bag.glob("*.mcap")):
        for m in read_ros2_messages(str(mcap_file), topics=[JOINT_STATES, DESCRIPTION]):
            assert m.schema.name == {JOINT_STATES: "sensor_msgs/msg/JointState",
                                     DESCRIPTION: "std_msgs/msg/String"}[m.channel.topic]
            (states if m.channel.topic == JOINT_STATES else descriptions).append(m)
    assert len(states) == 30  # every tick of 0.5 s at 60 Hz
    for m in states:
        assert list(m.ros_msg.name) == urdf.movable and np.all(np.isfinite(m.ros_msg.position))
        assert m.log_time_ns == stamp_ns(m.ros_msg.header)
    assert [m.ros_msg.data for m in descriptions] == [robot_file().read_text()]


# ---- the `arm` scene: its own trajectory until a ROS command comes -----------------------------------------------

#: the `arm` scene's initial pose (msgs_config/scenes/arm.yaml): the arm up over its pedestal, clear of the table
ARM_HOME = {"shoulder_pan": 0.0, "shoulder_lift": 0.3, "upper_arm_roll": 0.0, "elbow": 0.6, "forearm_roll": 0.0,
            "wrist": 0.6, "wrist_roll": 0.0}


@pytest.mark.parametrize("how", ["joint_commands", "joint_trajectory"])
def test_the_arm_scene_follows_its_trajectory_until_a_ros_command_wins(start_node, probe, how):
    states = probe.subscribe(JOINT_STATES, JointState)
    node = start_node("--scene", "arm", "--start-paused", "true")
    probe.wait_until_matched(JOINT_STATES, timeout=60)
    topic, msg_type = (JOINT_COMMANDS, JointState) if how == "joint_commands" else (JOINT_TRAJECTORY, JointTrajectory)
    publisher = probe.publisher(topic, msg_type)
    probe.wait_for_subscriber(publisher, timeout=30)
    pause(probe, False)
    joints = list(ARM_HOME)
    target = np.array(list(ARM_HOME.values()))

    def q_of(msg) -> np.ndarray:
        index = {name: i for i, name in enumerate(msg.name)}
        return np.array([msg.position[index[j]] for j in joints])

    # on its own, the arm moves: its joints change by more than 0.3 rad within 1.5 s of simulated time
    first = latest_state(probe, states, 3)
    probe.spin_until(lambda: stamp_ns(states.messages[-1].header) >= stamp_ns(first.header) + 1_500_000_000, 60,
                     "1.5 s of simulated time")
    moved = np.abs(q_of(states.messages[-1]) - q_of(first)).max()
    assert moved > 0.3, moved

    if how == "joint_commands":
        message = JointState(name=joints, position=target.tolist())
    else:
        point = JointTrajectoryPoint(positions=target.tolist())
        point.time_from_start.sec, point.time_from_start.nanosec = 1, 500_000_000
        message = JointTrajectory(joint_names=joints, points=[point])
    sent_at = stamp_ns(states.messages[-1].header)
    probe.publish_acked(publisher, message)
    # reached within 3 s of simulated time, then held for 2 s: the scene's trajectory does not come back
    probe.spin_until(lambda: stamp_ns(states.messages[-1].header) >= sent_at + 5_000_000_000, 120,
                     "5 s of simulated time after the command")
    after = [m for m in states.messages if sent_at + 3_000_000_000 <= stamp_ns(m.header) <= sent_at + 5_000_000_000]
    assert len(after) >= 100, len(after)  # 2 s at 60 Hz (a reliable reader: none missed)
    worst = max(np.abs(q_of(m) - target).max() for m in after)
    assert worst <= 1e-3, worst
    assert node.alive()

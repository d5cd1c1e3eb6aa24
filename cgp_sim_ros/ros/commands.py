"""The wrench commands the node takes, from the moment they arrive to the tick that applies them.

Every command input — ``~/apply_wrench``, every movable body's ``~/bodies/<body>/wrench`` and every robot's
``joint_commands`` and ``joint_trajectory``, over DDS or from a Foxglove client (:attr:`CommandInputs.inputs`:
topic → message type and handler of its CDR bytes) — goes the same path, in this module, on the executor's thread
(the DDS subscriptions are waited on by a thread of their own, which only takes their bytes:
cgp_sim_ros/ros/inbox.py):

1. size: a message larger than any valid command (:data:`~cgp_sim_ros.interface.MAX_COMMAND_BYTES`) is
   dropped before it is decoded or recorded;
2. recorded (the bag, the live view) as received;
3. decoded, and validated by :func:`cgp_core.wrenches.make_command` (the node's ``max_force`` /
   ``max_torque``);
4. queued for the next tick: a bounded queue (:data:`~cgp_sim_ros.interface.MAX_PENDING_COMMANDS`, the oldest
   dropped and reported); the tick hands it to the world, whose active wrenches are bounded too
   (``WrenchSchedule.max_active``).

A rejected command (at any step, or a Foxglove client's bad input: :meth:`CommandInputs.reject`) is logged at
once the first time its (source, field, kind of problem) occurs, then summarized every
:data:`~cgp_sim_ros.interface.REPORT_PERIOD_S` seconds with a count (log and ``~/events``), so a flood cannot
flood the log.
"""

from __future__ import annotations

import collections
import re
from dataclasses import dataclass, replace

import numpy as np
from cgp_sim_msgs.msg import ApplyWrench
from geometry_msgs.msg import WrenchStamped
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from cgp_core.wrenches import MAX_NAME_LENGTH, CommandLimits, WrenchError, make_command

from .. import interface as itf
from ..trajectory import Trajectory, TrajectoryError, check_trajectory, sample

#: The per-body command subscriptions are made without rclpy's default QoS-event handlers (the "incompatible
#: QoS / type" warnings): each handler is a waitable that the inbox's thread adds to its wait set, in Python, every
#: time a command arrives (see cgp_sim_ros/ros/publishing.py, which does the same for the per-entity publishers).
_NO_EVENT_HANDLERS = SubscriptionEventCallbacks(use_default_callbacks=False)
#: a joint command's rejection as reported (log, ~/events) is cut to this many characters (a name may be long)
MAX_REASON_LENGTH = 300


class CommandInputs:
    """The command subscriptions of ``node`` (a :class:`~cgp_sim_ros.ros.node.SimNode`), the queue of validated
    commands waiting for the next tick, and the count of rejected ones (see the module docstring)."""

    def __init__(self, node):
        self._node = node
        #: every command input: topic -> (message type, handler of its serialized bytes), for other transports
        self.inputs: dict[str, tuple[type, object]] = {}
        self._pending: collections.deque = collections.deque()  # validated commands, for the next tick
        self._dropped = 0  # pending commands dropped (the oldest) since the last report
        self._rejections: collections.Counter = collections.Counter()
        self._last_rejection: dict[tuple[str, str, str], str] = {}  # (source, field, kind) -> last reason
        #: the subscriptions' own waiting thread (the node's), which hands their raw bytes to the executor's
        self.inbox = node.inbox
        self._apply_wrench = self._subscription(ApplyWrench, itf.TOPIC_APPLY_WRENCH, self._on_apply_wrench)
        self._body_wrench: dict = {}  # body name -> its ~/bodies/<body>/wrench subscription
        self._body_names: list[str] = []  # the body set the pending commands' indices refer to
        self._joint_commands: dict = {}  # robot name -> its ~/robots/<robot>/joint_commands subscription
        self._joint_trajectory: dict = {}  # robot name -> its ~/robots/<robot>/joint_trajectory subscription
        #: JointCommand and RobotTrajectory, in the order they came, for the next tick
        self._joint_pending: collections.deque = collections.deque()
        #: robot name -> the trajectory it follows (FollowedTrajectory), until its end or a joint command
        self.following: dict = {}

    # ---- the per-body subscriptions ------------------------------------------------------------------------

    def follow_bodies(self, names: list[str], movable: set[str]) -> list:
        """After the body set changed: a ``~/bodies/<body>/wrench`` subscription for every movable body (made
        for new ones, destroyed for gone ones, kept for the others); pending commands follow their body (its
        new index), those on deleted bodies are dropped.  Returns the subscriptions made."""
        for name in [n for n in self._body_wrench if n not in movable]:
            subscription = self._body_wrench.pop(name)
            self.inputs.pop(subscription.topic_name, None)
            self.inbox.destroy(subscription)
        added = []
        for name in names:
            if name in movable and name not in self._body_wrench:
                self._body_wrench[name] = self._subscription(
                    WrenchStamped, itf.TOPIC_BODY_WRENCH.format(body=name),
                    lambda data, body=name: self._on_body_wrench(body, data), per_entity=True)
                added.append(self._body_wrench[name])
        # pending commands hold body indices of the model they were validated against
        new_index = {name: i for i, name in enumerate(names)}
        old_names = self._body_names
        self._pending = collections.deque(
            replace(c, body=new_index[old_names[c.body]]) for c in self._pending
            if c.body < len(old_names) and old_names[c.body] in new_index)
        self._body_names = list(names)
        return added

    def follow_robots(self, robots: list[str]) -> list:
        """After the robot set changed: ``~/robots/<robot>/joint_commands`` and ``joint_trajectory``
        subscriptions for every robot (made for new ones, destroyed for gone ones); pending joint commands and
        trajectories of gone robots are dropped.  Returns the subscriptions made."""
        added = []
        for subscriptions, topic, msg_type, handle in (
                (self._joint_commands, itf.TOPIC_ROBOT_JOINT_COMMANDS, JointState, self._on_joint_command),
                (self._joint_trajectory, itf.TOPIC_ROBOT_JOINT_TRAJECTORY, JointTrajectory, self._on_trajectory)):
            for name in [n for n in subscriptions if n not in robots]:
                subscription = subscriptions.pop(name)
                self.inputs.pop(subscription.topic_name, None)
                self.inbox.destroy(subscription)
            for name in robots:
                if name not in subscriptions:
                    subscriptions[name] = self._subscription(
                        msg_type, topic.format(robot=name),
                        lambda data, robot=name, handle=handle: handle(robot, data), per_entity=True)
                    added.append(subscriptions[name])
        self._joint_pending = collections.deque(c for c in self._joint_pending if c.robot in self._joint_commands)
        self.following = {robot: f for robot, f in self.following.items() if robot in self._joint_commands}
        return added

    def _subscription(self, msg_type, topic: str, handle, per_entity: bool = False):
        """A raw command subscription, waited on by the inbox's thread (cgp_sim_ros/ros/inbox.py); its messages
        reach ``handle`` on the executor's thread."""
        subscription = self.inbox.subscribe(msg_type, topic, handle,
                                            event_callbacks=_NO_EVENT_HANDLERS if per_entity else None)
        self.inputs[subscription.topic_name] = (msg_type, handle)
        return subscription

    def take_arrived(self) -> None:
        """Before a paused node's step: every command its readers have is taken and queued now
        (:meth:`~cgp_sim_ros.ros.inbox.CommandInbox.flush`)."""
        self.inbox.flush()

    # ---- arrival: size, record, decode, validate, queue ----------------------------------------------------

    def _on_apply_wrench(self, data: bytes) -> None:
        if self._oversized("apply_wrench", data):
            return
        self._record_received(self._apply_wrench.topic_name, data)
        try:
            command = apply_wrench_command(data, self._node.world, self._node.params,
                                           self._node.frames)
        except WrenchError as exc:
            self.reject("apply_wrench", exc)
            return
        self._enqueue(command)

    def _on_body_wrench(self, body: str, data: bytes) -> None:
        source = f"bodies/{body}/wrench"
        if self._oversized(source, data):
            return
        self._record_received(self._body_wrench[body].topic_name, data)
        try:
            command = body_wrench_command(body, data, self._node.world, self._node.params, self._node.frames)
        except WrenchError as exc:
            self.reject(source, exc)
            return
        self._enqueue(command)

    def _on_joint_command(self, robot: str, data: bytes) -> None:
        source = f"robots/{robot}/joint_commands"
        if len(data) > itf.MAX_JOINT_COMMAND_BYTES:
            self.reject(source, WrenchError(
                "message", f"{len(data)} bytes, more than a joint command may have "
                f"({itf.MAX_JOINT_COMMAND_BYTES} bytes); dropped unread", "too large"))
            return
        self._record_received(self._joint_commands[robot].topic_name, data)
        try:
            command = joint_command(robot, data)
        except WrenchError as exc:
            self.reject(source, exc)
            return
        self._enqueue_joint(command)

    def _on_trajectory(self, robot: str, data: bytes) -> None:
        source = f"robots/{robot}/joint_trajectory"
        if len(data) > itf.MAX_TRAJECTORY_BYTES:
            self.reject(source, WrenchError(
                "message", f"{len(data)} bytes, more than a trajectory may have ({itf.MAX_TRAJECTORY_BYTES} bytes); "
                "dropped unread", "too large"))
            return
        self._record_received(self._joint_trajectory[robot].topic_name, data)
        try:
            msg = _decode(data, JointTrajectory)
            trajectory = check_trajectory(
                msg.joint_names, msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec,
                [p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec for p in msg.points],
                [list(p.positions) for p in msg.points], [list(p.velocities) for p in msg.points])
        except TrajectoryError as exc:
            self.reject(source, _as_wrench_error(exc))
            return
        except WrenchError as exc:
            self.reject(source, exc)
            return
        self._enqueue_joint(RobotTrajectory(robot, trajectory))

    def _enqueue_joint(self, command) -> None:
        if len(self._joint_pending) >= itf.MAX_PENDING_COMMANDS:
            self._joint_pending.popleft()
            self._dropped += 1
        self._joint_pending.append(command)

    def _oversized(self, source: str, data: bytes) -> bool:
        """Drop a message larger than any valid command, cheaply (no decoding, no recording)."""
        if len(data) <= itf.MAX_COMMAND_BYTES:
            return False
        self.reject(source, WrenchError(
            "message", f"{len(data)} bytes, more than any valid command ({itf.MAX_COMMAND_BYTES} bytes: body and "
            f"header.frame_id are names of at most {MAX_NAME_LENGTH} characters); dropped unread", "too large"))
        return True

    def _record_received(self, topic: str, data: bytes) -> None:
        node = self._node
        if node.recorder is not None:
            node.recorder.write(topic, data, node.world.time_ns)
        if node.foxglove is not None:
            node.foxglove.received(topic, data, node.world.time_ns)

    def _enqueue(self, command) -> None:
        if len(self._pending) >= itf.MAX_PENDING_COMMANDS:
            self._pending.popleft()
            self._dropped += 1
        self._pending.append(command)

    # ---- the tick, and the services that clear ------------------------------------------------------------

    def apply_pending(self, world) -> None:
        """Hand the waiting commands to ``world`` (the tick, before its step): the joint commands to its robots
        in the order they came (each holds until the next: :meth:`apply_joint_commands`), the wrenches to its
        wrench schedule, where those over the limit of active wrenches are rejected."""
        if self._joint_pending:
            self.apply_joint_commands(world)
        if self.following:
            self.follow_trajectories(world)
        if not self._pending:
            return
        commands = list(self._pending)
        self._pending.clear()
        accepted = world.add_commands(commands)
        if accepted < len(commands):
            self.reject("apply_wrench", WrenchError(
                "wrenches", f"{len(commands) - accepted} wrench(es) over the limit of "
                f"{world.wrenches.max_active} active wrenches (clear some with ~/clear_wrenches)", "too many"),
                count=len(commands) - accepted)

    def apply_joint_commands(self, world) -> None:
        """The waiting joint commands, in order, through ``Robots.command``; what it refuses (or clamps) is
        reported per robot, joint and kind (:meth:`reject`)."""
        commands = list(self._joint_pending)
        self._joint_pending.clear()
        robots = world.robots
        if robots is None:
            return
        known = {name: None for name in robots.names()}
        for c in commands:
            if c.robot not in known:
                continue
            if known[c.robot] is None:
                known[c.robot] = set(robots.joint_state(c.robot)[0])
            if isinstance(c, RobotTrajectory):
                self._take_trajectory(world, c, known[c.robot])
                continue
            self.following.pop(c.robot, None)  # a joint command stops the robot's trajectory
            if any(name in known[c.robot] for name in c.names):
                world.stop_trajectory(c.robot)  # and its scene trajectory: the ROS command wins
            problems = robots.command(c.robot, c.names, c.position, c.velocity, c.effort)
            for text in problems:
                self.reject(f"robots/{c.robot}/joint_commands", joint_rejection(text, c.names, known[c.robot]))

    def _take_trajectory(self, world, command, joints: set) -> None:
        """A new trajectory for a robot (replacing the one it follows, and its scene trajectory): its joints must
        be the robot's; it starts at its stamp, or now (a zero stamp), from the joints' current positions."""
        trajectory = command.trajectory
        unknown = [j for j in trajectory.joints if j not in joints]
        if unknown:
            self.reject(f"robots/{command.robot}/joint_trajectory", WrenchError(
                "joint_names", f"{command.robot} has no movable joint {unknown[0]!r} (joints: "
                f"{', '.join(sorted(joints))}); trajectory ignored"[:300], "unknown"))
            return
        names, position, _, _ = world.robots.joint_state(command.robot)
        index = {name: i for i, name in enumerate(names)}
        start = np.array([position[index[j]] for j in trajectory.joints])
        start_ns = trajectory.start_ns if trajectory.start_ns is not None else world.time_ns
        self.following[command.robot] = FollowedTrajectory(trajectory, start_ns, start)
        world.stop_trajectory(command.robot)  # it replaces the robot's scene trajectory (robots[].trajectory)

    def follow_trajectories(self, world) -> None:
        """Every followed trajectory's position targets for the end of this tick (through ``Robots.command``);
        a trajectory past its last point is commanded its last positions once more and let go (the position
        drives hold them)."""
        robots = world.robots
        t_end = world.time_ns + round(world.dt * 1e9)
        for robot, f in list(self.following.items()):
            t = (t_end - f.start_ns) * 1e-9
            if t < 0.0:  # starts later: the drives hold what they held
                continue
            targets = sample(f.trajectory, t, f.start_positions)
            problems = robots.command(robot, list(f.trajectory.joints), targets.tolist(), [], [])
            for text in problems:
                self.reject(f"robots/{robot}/joint_trajectory",
                            joint_rejection(text, f.trajectory.joints, set(f.trajectory.joints)))
            if t >= f.trajectory.duration:
                del self.following[robot]

    def clear_pending(self) -> int:
        """Drop the waiting wrench commands (a reset, ~/clear_wrenches); returns how many there were."""
        count = len(self._pending)
        self._pending.clear()
        return count

    def clear_joint_commands(self) -> int:
        """Drop the waiting joint commands and trajectories and stop the followed ones (a reset of the state);
        returns how many were waiting."""
        count = len(self._joint_pending)
        self._joint_pending.clear()
        self.following.clear()
        return count

    # ---- rejections -----------------------------------------------------------------------------------------

    def reject(self, source: str, error: WrenchError, count: int = 1) -> None:
        """Count rejected commands; the first of each (source, field, kind) is logged at once, the rest are
        summarized every REPORT_PERIOD_S (see :meth:`report`)."""
        key = (source, error.field, error.kind)
        if key not in self._last_rejection:
            self._node.get_logger().warn(f"rejected {source} command: {error}")
        self._rejections[key] += count
        self._last_rejection[key] = str(error)

    def report(self) -> None:
        """The summary of the last REPORT_PERIOD_S: dropped and rejected commands (log and ``~/events``)."""
        node = self._node
        if self._dropped:
            node.get_logger().warn(f"command flood: dropped the {self._dropped} oldest pending wrench "
                                   f"commands (more than {itf.MAX_PENDING_COMMANDS} arrived within one tick)")
            node.emit_event({"event": "dropped_commands", "count": self._dropped})
            self._dropped = 0
        for (source, field, kind), count in self._rejections.items():
            reason = self._last_rejection[(source, field, kind)]
            node.get_logger().warn(f"rejected {count} {source} command(s) with {kind} {field} in the last "
                                   f"{itf.REPORT_PERIOD_S:g} s; last reason: {reason}")
            node.emit_event({"event": "rejected", "source": source, "field": field, "kind": kind, "count": count,
                             "reason": reason})
        self._rejections.clear()


def apply_wrench_command(data: bytes, world, params, frames: itf.Frames = itf.UNPREFIXED):
    """The validated command of a ``~/apply_wrench`` message's CDR bytes (``world``: the :class:`World` it is for;
    ``params``: the node's ``max_force`` / ``max_torque``; ``frames``: the node's frame ids, whose prefix a
    ``header.frame_id`` may carry); :class:`WrenchError` naming the field otherwise."""
    msg = _decode(data, ApplyWrench)
    if msg.duration.nanosec >= 1_000_000_000:
        raise WrenchError("duration.nanosec", f"must be < 1e9, got {msg.duration.nanosec}", "malformed")
    return make_command(
        world.body_model.names, msg.body,
        force=(msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z),
        torque=(msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z),
        point=(msg.point.x, msg.point.y, msg.point.z), frame=frames.to_core(msg.header.frame_id),
        duration=msg.duration.sec + 1e-9 * msg.duration.nanosec,
        limits=CommandLimits(max_force=params["max_force"], max_torque=params["max_torque"]),
        fixed=world.body_model.fixed, positions=world.body_state.position)


def body_wrench_command(body: str, data: bytes, world, params, frames: itf.Frames = itf.UNPREFIXED):
    """The validated command of a ``~/bodies/<body>/wrench`` WrenchStamped's CDR bytes (as above)."""
    msg = _decode(data, WrenchStamped)
    return make_command(
        world.body_model.names, body,
        force=(msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z),
        torque=(msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z),
        point=None, frame=frames.to_core(msg.header.frame_id), duration=0.0,
        limits=CommandLimits(max_force=params["max_force"], max_torque=params["max_torque"]))


@dataclass(frozen=True)
class JointCommand:
    """A decoded ``~/robots/<robot>/joint_commands`` message, for ``Robots.command`` at the next tick."""

    robot: str
    names: list
    position: list
    velocity: list
    effort: list


@dataclass(frozen=True)
class RobotTrajectory:
    """A checked ``~/robots/<robot>/joint_trajectory`` message, for the next tick."""

    robot: str
    trajectory: Trajectory


@dataclass(frozen=True)
class FollowedTrajectory:
    """A trajectory a robot follows: its start in simulation time (ns) and the joints' positions then."""

    trajectory: Trajectory
    start_ns: int
    start_positions: np.ndarray


def _as_wrench_error(exc: TrajectoryError) -> WrenchError:
    return WrenchError(exc.field, exc.reason, exc.kind)


def joint_command(robot: str, data: bytes) -> JointCommand:
    """The command of a ``sensor_msgs/JointState``'s CDR bytes, as topic_based_ros2_control sends it (checked by
    ``Robots.command`` at the tick: which joints, which arrays, finite values, limits)."""
    msg = _decode(data, JointState)
    return JointCommand(robot, list(msg.name), list(msg.position), list(msg.velocity), list(msg.effort))


def joint_rejection(text: str, names, joints: set) -> WrenchError:
    """A ``Robots.command`` rejection (a sentence naming the joint and the reason) as a reportable error: ``field``
    the robot's joint it is about (``joint <name>`` in the sentence), ``name`` for a name the robot does not have
    (kind ``unknown``: one report key for every unknown name, however many are sent), else ``command``; ``kind``
    ``clamped`` for a value clamped to the URDF's limits (applied), ``invalid`` otherwise.  The sentence is kept
    as it is, cut to :data:`MAX_REASON_LENGTH` characters."""
    field, kind = "command", "invalid"
    for joint in names:
        if not isinstance(joint, str):
            continue
        if joint not in joints and (repr(joint) in text or f"joint {joint}" in text):
            field, kind = "name", "unknown"
            break
        if joint in joints and re.search(rf"\bjoint {re.escape(joint)}(?![\w/.-])", text):
            field = joint
            break
    if kind != "unknown" and "clamp" in text:
        kind = "clamped"
    if len(text) > MAX_REASON_LENGTH:
        text = text[:MAX_REASON_LENGTH] + f"... ({len(text)} characters)"
    error = WrenchError(field, text, kind)
    error.args = (text,)  # the sentence as it is (it names the joint already)
    return error


def _decode(data: bytes, msg_type):
    try:
        return deserialize_message(data, msg_type)
    except Exception as exc:  # undecodable bytes: a peer with a mismatched definition
        raise WrenchError("message", f"cannot decode: {exc}", "undecodable") from None

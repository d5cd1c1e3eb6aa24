"""TF for the bodies and the robots: what a tf2 listener (RViz, ``tf2_echo``, your node's ``tf2_ros.Buffer``) needs.

Frame ids carry the node's ``frame_prefix`` (:class:`cgp_sim_ros.interface.Frames`): ``sim1/world`` →
``sim1/<body>`` with ``frame_prefix:=sim1/``, so several simulators share one ``/tf``.

- ``/tf`` (:data:`~cgp_sim_ros.ros.qos.TF_QOS`), every tick: ``world`` → ``<body>`` for every *movable* body,
  stamped with the simulation time of the tick, in one ``tf2_msgs/TFMessage`` (numpy-built CDR,
  :class:`cgp_sim_ros.wire.cdr.TFMessageSerializer`).  The transform is the body frame: origin at the centre of
  mass, the body's axes — the pose ``~/bodies/<body>/odom`` carries, whose ``child_frame_id`` is the same name.
- ``/tf_static`` (:data:`~cgp_sim_ros.ros.qos.TF_STATIC_QOS`, transient local): the *fixed* bodies, all in
  one message, as tf2_ros' static broadcaster sends them; sent with the first tick and again whenever that set
  or a fixed body's pose changes (spawn, delete, reset, teleport), so a late subscriber gets the current set.
  A deleted fixed body's frame stays in the buffers of listeners that already had it (static transforms
  never expire in tf2); listeners that join later do not get it.

Robots (``World.robots``: :meth:`cgp_core.robots.world.Robots.transforms`): every URDF link frame, named
``<robot>/<link>`` (:meth:`~cgp_sim_ros.interface.Frames.link`) — the root link relative to ``world``, every other
link relative to its URDF parent link, as robot_state_publisher names them with ``frame_prefix: <robot>/``.  The
transforms that move (a joint's) are in the same ``/tf`` message as the bodies', after them; the static ones (fixed
joints, the root of a fixed base) are in the one ``/tf_static`` message with the fixed bodies (transient local,
depth 1: a late subscriber gets only the last message, so it must hold every static frame).  A robot's links are
bodies of the world too (``<robot>/<link>``, for contacts and markers); they are *not* published as bodies here:
their body frame (at the COM) would be a second parent for the link frame of the same name.

Spawned bodies appear in the next message; deleted ones are no longer sent.  Both topics are published
through :meth:`cgp_sim_ros.ros.publishing.TickPublisher.publish` (recorded in the bag like every topic).
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import TransformStamped
from rclpy.serialization import serialize_message
from tf2_msgs.msg import TFMessage

from .. import interface as itf
from ..wire.cdr import TFMessageSerializer, split_stamp
from .messages import robot_link_rows, robot_names


class BodyTransforms:
    """The TF of one world's bodies and robots; :meth:`rebuild` after every change of the body or robot set."""

    TFMessage = TFMessage

    def __init__(self, world, frames: itf.Frames = itf.UNPREFIXED):
        self.world = world
        self.frames = frames
        self.frame_id = frames.world
        self._static_sent = None  # (names, poses) of the last /tf_static message
        self.rebuild()

    def rebuild(self) -> None:
        model = self.world.body_model
        links = robot_link_rows(self.world)
        fixed = np.asarray(model.fixed, dtype=bool)
        self._movable = np.flatnonzero(~fixed & ~links)
        self._fixed = np.flatnonzero(fixed & ~links)
        self._robots = robot_names(self.world)
        # each robot's moving transforms, in the order Robots.transforms gives them (URDF order: fixed per robot)
        parents = [self.frame_id] * len(self._movable)
        children = [self.frames.body(model.names[i]) for i in self._movable]
        self._robot_moving = []  # per robot: the indices of its moving transforms in Robots.transforms
        for robot in self._robots:
            moving = []
            for k, (parent, child, _, _, static) in enumerate(self.world.robots.transforms(robot)):
                if not static:
                    moving.append(k)
                    parents.append(self._robot_frame(robot, parent))
                    children.append(self.frames.link(robot, child))
            self._robot_moving.append(moving)
        self._count = len(children)
        self._serializer = TFMessageSerializer(parents, children)

    def _robot_frame(self, robot: str, frame: str) -> str:
        """A frame ``Robots.transforms`` names: ``world`` (the root link's parent) or a link of ``robot``."""
        return self.frame_id if frame == itf.WORLD_FRAME else self.frames.link(robot, frame)

    def dynamic(self, stamp_ns: int) -> bytes | None:
        """``/tf`` for this tick (None when nothing moves: no movable body, no moving robot link)."""
        if self._count == 0:
            return None
        state = self.world.body_state
        translations = [state.position[self._movable]]
        rotations = [state.orientation[self._movable]]
        for robot, moving in zip(self._robots, self._robot_moving):
            if not moving:
                continue
            transforms = self.world.robots.transforms(robot)
            translations.append(np.array([transforms[k][3] for k in moving], dtype=float).reshape(-1, 3))
            rotations.append(np.array([transforms[k][2] for k in moving], dtype=float).reshape(-1, 4))
        return self._serializer.serialize(stamp_ns, np.concatenate(translations), np.concatenate(rotations))

    def _static_content(self) -> list[tuple[str, str, list[float], list[float]]]:
        """Every static transform now: ``(parent id, child id, translation, rotation xyzw)``, the fixed bodies
        first, then each robot's fixed-joint frames (and a fixed base's root)."""
        model, state = self.world.body_model, self.world.body_state
        content = [(self.frame_id, self.frames.body(model.names[i]), state.position[i].tolist(),
                    state.orientation[i].tolist()) for i in self._fixed]
        for robot in self._robots:
            for parent, child, quaternion, translation, static in self.world.robots.transforms(robot):
                if static:
                    content.append((self._robot_frame(robot, parent), self.frames.link(robot, child),
                                    np.asarray(translation, dtype=float).tolist(),
                                    np.asarray(quaternion, dtype=float).tolist()))
        return content

    def static_if_changed(self, stamp_ns: int) -> bytes | None:
        """``/tf_static`` if the static transforms (fixed bodies, robots' fixed frames) or their poses differ from
        the last one returned (the first call always returns it, possibly empty: a late subscriber then learns
        there are none), else None."""
        content = self._static_content()
        if content == self._static_sent:
            return None
        self._static_sent = content
        sec, nanosec = split_stamp(stamp_ns)
        msg = TFMessage()
        for parent, child, p, q in content:
            t = TransformStamped()
            t.header.stamp.sec, t.header.stamp.nanosec = sec, nanosec
            t.header.frame_id = parent
            t.child_frame_id = child
            t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = p
            t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w = q
            msg.transforms.append(t)
        return serialize_message(msg)

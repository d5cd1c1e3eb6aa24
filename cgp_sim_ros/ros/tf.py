"""TF for the bodies: what a tf2 listener (RViz, ``tf2_echo``, your node's ``tf2_ros.Buffer``) needs.

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


class BodyTransforms:
    """The TF of one world's bodies; :meth:`rebuild` after every change of the body set."""

    TFMessage = TFMessage

    def __init__(self, world, frames: itf.Frames = itf.UNPREFIXED):
        self.world = world
        self.frames = frames
        self.frame_id = frames.world
        self._static_sent = None  # (names, poses) of the last /tf_static message
        self.rebuild()

    def rebuild(self) -> None:
        model = self.world.body_model
        self._movable = np.flatnonzero(~np.asarray(model.fixed, dtype=bool))
        self._serializer = TFMessageSerializer(self.frame_id, [self.frames.body(model.names[i]) for i in self._movable])

    def dynamic(self, stamp_ns: int) -> bytes | None:
        """``/tf`` for this tick (None when there is no movable body)."""
        if len(self._movable) == 0:
            return None
        state = self.world.body_state
        return self._serializer.serialize(stamp_ns, state.position[self._movable], state.orientation[self._movable])

    def static_if_changed(self, stamp_ns: int) -> bytes | None:
        """``/tf_static`` if the fixed bodies or their poses differ from the last one returned (the first call
        always returns it, possibly empty: a late subscriber then learns there are none), else None."""
        model, state = self.world.body_model, self.world.body_state
        fixed = np.flatnonzero(np.asarray(model.fixed, dtype=bool))
        content = ([model.names[i] for i in fixed], state.position[fixed].tolist(), state.orientation[fixed].tolist())
        if content == self._static_sent:
            return None
        self._static_sent = content
        sec, nanosec = split_stamp(stamp_ns)
        msg = TFMessage()
        for name, p, q in zip(*content):
            t = TransformStamped()
            t.header.stamp.sec, t.header.stamp.nanosec = sec, nanosec
            t.header.frame_id = self.frame_id
            t.child_frame_id = self.frames.body(name)
            t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = p
            t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w = q
            msg.transforms.append(t)
        return serialize_message(msg)

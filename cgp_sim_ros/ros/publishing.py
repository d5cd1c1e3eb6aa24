"""Everything the node publishes, and the one path every message takes: published on DDS, recorded in the
bag (:class:`~cgp_sim_ros.ros.recorder.Recorder`) and shown in the Foxglove live view as the very same bytes
(:meth:`TickPublisher.publish`).

What a tick publishes, in order (:meth:`TickPublisher.tick_messages`; the bytes are built by
:class:`~cgp_sim_ros.ros.messages.TickMessages` and :class:`~cgp_sim_ros.ros.tf.BodyTransforms`): ``/clock``,
``~/bodies/poses``, every body's ``~/bodies/<body>/odom``, every flock's ``~/flocks/<flock>/poses`` (recorded
on the ticks the level-of-detail plan says) and ``~/flocks/<flock>/stats``, every robot's
``~/robots/<robot>/joint_states``, ``~/contacts`` (parameter ``contacts``), ``/tf``, the first ``/tf_static``,
``~/markers``, then the first ``~/static_markers`` (the bodies' shapes in their TF frames and the static meshes:
sent once, not every tick — issue 37, :mod:`cgp_sim_ros.ros.messages`) and every robot's first
``~/robots/<robot>/robot_description`` (latched).  Besides the ticks: ``~/events`` (:meth:`TickPublisher.event`),
``/tf_static``, ``~/static_markers`` and ``robot_description`` again when the fixed bodies / the bodies and static
meshes / the robots change, DELETE markers for what is no longer drawn on ``~/markers``.

The per-body and per-flock publishers follow the world's entities (:meth:`TickPublisher.follow_entities`).
They are made without rclpy's default QoS-event handlers (the "incompatible QoS / type" warnings).  Each
handler is a waitable the executor adds to its wait set, in Python, on every spin: with 100 spawned bodies
their ~400 handlers cost the single-threaded executor ~5 ms per tick (measured: the tick rate fell to 45 Hz
while they were spawned).  The node's fixed topics keep the warnings.
"""

from __future__ import annotations

import json
import weakref

from rclpy.event_handler import PublisherEventCallbacks
from rclpy.serialization import serialize_message
from std_msgs.msg import String

from .. import interface as itf
from ..drawing import detail as lod
from ..drawing.bodies import Drawings, model_shapes
from ..drawing.robots import robot_geometries, visual_drawing
from ..wire import cdr
from .messages import TickMessages, robot_names
from .qos import CLOCK_QOS, EVENTS_QOS, LATCHED_QOS, STATE_QOS, TF_QOS, TF_STATIC_QOS
from .tf import BodyTransforms

#: publisher -> its topic name, for the bag's records: rclpy's ``topic_name`` asks rcl every time (~1–2 µs, a call
#: per record: an odometry per body per tick); a publisher's name never changes, and a destroyed one drops out
_TOPIC_NAMES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()

_NO_EVENT_HANDLERS = PublisherEventCallbacks(use_default_callbacks=False)


class TickPublisher:
    """The publishers of ``node`` (a :class:`~cgp_sim_ros.ros.node.SimNode`) and the serializers of its world
    (see the module docstring)."""

    def __init__(self, node):
        self._node = node
        self.world = node.world
        params = node.params
        # the world sums its contact report only while someone takes it (prepare_tick); on for the throwaway
        # tick that loads the kernels
        self.world.report_contacts = bool(params["contacts"] or params["contact_markers"])
        #: metres per newton of the contact force arrows, None without contact markers
        self._force_scale = params["contact_force_scale"] if params["contact_markers"] else None
        #: the drawings of the hulls and static meshes (cgp_sim_ros/drawing/bodies.py): the scene's made here,
        #: before the first tick; a spawned body's come with it from the spawn worker (SimNode.add_spawned)
        self.drawings = Drawings()
        for kind, shape in model_shapes(self.world.body_model):
            self.drawings.hull(shape) if kind == "hull" else self.drawings.mesh(shape)
        visuals = robot_geometries(self.world.robots)  # the robots' URDF visuals (their mesh files read here)
        for geometry in visuals:
            self.report_visual_problem(self.drawings.of(geometry, visual_drawing))
        self._scene_shapes = [shape for _, shape in model_shapes(self.world.body_model)] + visuals
        #: what ~/static_markers last sent (TickMessages.static_signature), None before the first
        self._static_sent: tuple | None = None
        #: ticks whose contacts were more than ~/contacts carries since the last report, and the most of them
        self.contacts_capped = self.contacts_most = 0
        #: the per-tick serializers (rebuilt by :meth:`rebuild` after the world's entities changed)
        self.messages = TickMessages(self.world, node.frames, contact_force_scale=self._force_scale,
                                     drawings=self.drawings)
        self.tf = BodyTransforms(self.world, node.frames)
        # The publishers' QoS events (an incompatible subscriber: rclpy's warning) are waited on by the command
        # inbox's thread (cgp_sim_ros/ros/inbox.py), not by the executor, which rebuilds its wait set every spin.
        publisher = node.inbox.publisher
        self.pub_clock = publisher(TickMessages.Clock, itf.TOPIC_CLOCK, CLOCK_QOS)
        self.pub_body_poses = publisher(TickMessages.PoseArray, itf.TOPIC_BODY_POSES, STATE_QOS)
        self.pub_markers = publisher(TickMessages.MarkerArray, itf.TOPIC_MARKERS, STATE_QOS)
        self.pub_static_markers = publisher(TickMessages.MarkerArray, itf.TOPIC_STATIC_MARKERS, LATCHED_QOS)
        self.pub_contacts = (publisher(TickMessages.Contacts, itf.TOPIC_CONTACTS, STATE_QOS)
                             if params["contacts"] else None)
        self.pub_events = publisher(String, itf.TOPIC_EVENTS, EVENTS_QOS)
        self.pub_tf = publisher(BodyTransforms.TFMessage, itf.TOPIC_TF, TF_QOS)
        self.pub_tf_static = publisher(BodyTransforms.TFMessage, itf.TOPIC_TF_STATIC, TF_STATIC_QOS)
        # per body / per flock (name -> publisher), and in the world's order (see follow_entities)
        self._odom: dict = {}
        self._flock_poses: dict = {}
        self._flock_stats: dict = {}
        self._joint_states: dict = {}
        self._descriptions: dict = {}
        self.pub_odom: list = []
        self.pub_flock_poses: list = []
        self.pub_flock_stats: list = []
        self.pub_joint_states: list = []
        #: robot -> the robot_description last sent (see publish_robot_descriptions)
        self._description_sent: dict[str, str] = {}
        self._marker_ids: dict[str, set[int]] = {}  # marker namespace -> the ids drawn (see retire_markers)
        self._delete_all_markers = False  # see redraw_all_markers

    # ---- the world's entities -------------------------------------------------------------------------------

    def follow_entities(self) -> list:
        """``~/bodies/<body>/odom``, ``~/flocks/<flock>/poses``, ``~/flocks/<flock>/stats``,
        ``~/robots/<robot>/joint_states`` and ``~/robots/<robot>/robot_description`` publishers for the world's
        bodies, flocks and robots now: created for new entities, destroyed for gone ones, kept for the others
        (subscribers stay matched).  Returns the publishers made."""
        node, world = self._node, self.world
        names = list(world.body_model.names)
        flock_names = [f.params.name for f in world.flocks]
        robots = robot_names(world)
        added = []
        for publishers, wanted, topic, msg_type, key, qos in (
                (self._odom, names, itf.TOPIC_BODY_ODOM, TickMessages.Odometry, "body", STATE_QOS),
                (self._flock_poses, flock_names, itf.TOPIC_FLOCK_POSES, TickMessages.PoseArray, "flock", STATE_QOS),
                (self._flock_stats, flock_names, itf.TOPIC_FLOCK_STATS, TickMessages.FlockStats, "flock", STATE_QOS),
                (self._joint_states, robots, itf.TOPIC_ROBOT_JOINT_STATES, TickMessages.JointState, "robot",
                 STATE_QOS),
                (self._descriptions, robots, itf.TOPIC_ROBOT_DESCRIPTION, TickMessages.String, "robot",
                 LATCHED_QOS)):
            for name in [n for n in publishers if n not in wanted]:
                node.destroy_publisher(publishers.pop(name))
                if publishers is self._descriptions:
                    self._description_sent.pop(name, None)
            for name in wanted:
                if name not in publishers:
                    publishers[name] = node.create_publisher(msg_type, topic.format(**{key: name}), qos,
                                                             event_callbacks=_NO_EVENT_HANDLERS)
                    added.append(publishers[name])
        self.pub_odom = [self._odom[n] for n in names]
        self.pub_flock_poses = [self._flock_poses[n] for n in flock_names]
        self.pub_flock_stats = [self._flock_stats[n] for n in flock_names]
        self.pub_joint_states = [self._joint_states[n] for n in robots]
        return added

    def scene_changed(self, drawings=()) -> None:
        """Another scene was loaded into the world (``load_world``, ``unload_world``): its hulls' and meshes'
        drawings (``(shape, drawing)`` pairs made by the worker; the others are made on first use) are the
        scene's now, the old scene's are dropped at the next :meth:`rebuild`, and the next marker array starts
        with a DELETEALL."""
        self.drawings.add(drawings)
        self._scene_shapes = [shape for _, shape in model_shapes(self.world.body_model)]
        self.redraw_all_markers()

    def rebuild(self) -> None:
        """New per-tick serializers for the world's bodies and flocks now (the plan is set again by the
        caller: :meth:`set_plan`); the drawings of shapes neither the world nor its scene holds are dropped."""
        self.drawings.keep([*self._scene_shapes, *(shape for _, shape in model_shapes(self.world.body_model)),
                            *robot_geometries(self.world.robots)])
        self.messages = TickMessages(self.world, self._node.frames, contact_force_scale=self._force_scale,
                                     drawings=self.drawings)

    def report_visual_problem(self, drawing) -> None:
        """Log a robot visual that is not drawn (a mesh file that cannot be read; the robot itself is simulated)."""
        if drawing.problem:
            self._node.get_logger().warning(f"robot visual: {drawing.problem}")

    def set_plan(self, plan) -> None:
        """Draw as the level-of-detail ``plan`` (:class:`~cgp_sim_ros.drawing.detail.DetailPlan`) says (what is
        recorded follows ``node.detail``)."""
        self.messages.set_plan(plan)

    def redraw_all_markers(self) -> None:
        """The next marker array starts with a DELETEALL, then every marker (after a reset)."""
        self._delete_all_markers = True

    def retire_markers(self) -> None:
        """DELETE the markers no longer drawn — a deleted body's or flock's, a flock's parts beyond the ones it is
        now drawn in — so that no viewer keeps them (a marker without a lifetime never expires)."""
        drawn = self.messages.marker_ids()
        stale = [(ns, i) for ns, ids in self._marker_ids.items() for i in sorted(ids - drawn.get(ns, set()))]
        if stale and not self._delete_all_markers:  # a pending DELETEALL (after a reset) removes them anyway
            t = self.world.time_ns
            deletes = [cdr.marker(cdr.MarkerFields(marker_type=cdr.ARROW, action=cdr.DELETE, stamp_ns=t,
                                                   frame_id=self._node.frames.world, ns=ns, id=i))
                       for ns, i in stale]
            self.publish(self.pub_markers, cdr.marker_array(deletes), t)
        self._marker_ids = drawn

    def publish_static_markers(self) -> None:
        """``~/static_markers`` if what it shows changed since it was last sent — static meshes spawned, deleted or
        moved; bodies spawned or deleted; another hull detail (:meth:`TickMessages.static_signature`) — the first
        time on the first tick, if there is anything to show.  Not before the first tick, as ``/tf_static``: the
        bodies' markers are in their TF frames, which ``/tf`` and ``/tf_static`` carry from the first tick."""
        if self.world.ticks == 0:
            return
        signature = self.messages.static_signature()
        if signature == self._static_sent or (self._static_sent is None and not signature):
            return
        self._static_sent = signature
        t = self.world.time_ns
        self.publish(self.pub_static_markers, self.messages.static_markers(t), t)

    def publish_robot_descriptions(self) -> None:
        """``~/robots/<robot>/robot_description`` (latched) of every robot whose URDF was not sent yet or changed
        since.  Not before the first tick, as ``/tf_static``: the robot is drawn from it and TF together."""
        if self.world.ticks == 0:
            return
        robots = self.world.robots
        for name in robot_names(self.world):
            text = robots.description(name)
            if self._description_sent.get(name) == text:
                continue
            self._description_sent[name] = text
            self.publish(self._descriptions[name], serialize_message(String(data=text)), self.world.time_ns)

    def publish_static_tf(self) -> None:
        """``/tf_static`` again if the fixed bodies changed.  Not before the first tick: a node publishes nothing
        before it (a paused node is silent; a bag starts with the first tick, at its time)."""
        if self.world.ticks == 0:
            return
        data = self.tf.static_if_changed(self.world.time_ns)
        if data is not None:
            self.publish(self.pub_tf_static, data, self.world.time_ns)

    # ---- publishing ---------------------------------------------------------------------------------------

    def publish(self, publisher, data: bytes, stamp_ns: int, record: bool = True) -> None:
        """Publish serialized bytes, and record (unless the level-of-detail plan records this topic on fewer
        ticks: ``record`` False) and show in Foxglove the very same bytes."""
        publisher.publish(data)
        recorder, foxglove = self._node.recorder, self._node.foxglove
        if record and recorder is not None:
            topic = _TOPIC_NAMES.get(publisher)
            if topic is None:
                topic = _TOPIC_NAMES[publisher] = publisher.topic_name
            recorder.write(topic, data, stamp_ns)
        if foxglove is not None:
            foxglove.publish(publisher, data, stamp_ns)

    def event(self, payload: dict) -> None:
        """Publish (and so record) one line on ~/events: the audit trail of what was done to the world."""
        payload = {"time": round(self.world.time, 9), **payload}
        msg = String(data=json.dumps(payload, separators=(",", ":")))
        self.publish(self.pub_events, serialize_message(msg), self.world.time_ns)

    def prepare_tick(self) -> None:
        """Before the world's step: whether it sums its contact report this tick — only while someone takes it
        (the contact markers; the bag; a subscriber of ``~/contacts``, in DDS or in the live view), so that
        ``contacts:=true`` costs nothing while nobody listens.  (A body asleep when the report starts is
        reported from when it wakes: its contacts were not summed while it slept.)"""
        pub, node = self.pub_contacts, self._node
        self.world.report_contacts = self._force_scale is not None or (pub is not None and (
            node.recorder is not None or pub.get_subscription_count() > 0
            or (node.foxglove is not None and node.foxglove.listening(pub))))

    def publish_tick(self) -> None:
        """Everything one tick publishes (after the world's step)."""
        t = self.world.time_ns
        for publisher, data, record in self.tick_messages(self.world, self.messages, self.tf,
                                                          self._delete_all_markers):
            self.publish(publisher, data, t, record=record)
        self._delete_all_markers = False
        if self.world.ticks == 1:
            self.publish_static_markers()
            self.publish_robot_descriptions()
        if self.messages.contacts_of > self.messages.contacts_sent:
            self.contacts_capped += 1
            self.contacts_most = max(self.contacts_most, self.messages.contacts_of)
            self.messages.contacts_of = self.messages.contacts_sent = 0

    def report_contacts_capped(self) -> str | None:
        """A line about the ticks whose contacts ~/contacts did not all carry since the last call (None if none)."""
        if not self.contacts_capped:
            return None
        text = (f"~/contacts: {self.contacts_capped} tick(s) had more contacts than a message carries (at most "
                f"{self.contacts_most:,}); each sent the {itf.MAX_CONTACTS_PER_MESSAGE:,} with the largest impulse, "
                "and every body's full contact wrench")
        self.contacts_capped = self.contacts_most = 0
        return text

    def tick_messages(self, world, messages: TickMessages, tf: BodyTransforms, delete_all_markers: bool):
        """What a tick publishes, in publishing order, as ``(publisher, CDR bytes, recorded?)``, each built as
        the caller takes it, from ``world`` by ``messages`` and ``tf``: the node's own every tick
        (:meth:`publish_tick`), a throwaway copy's once before the first (:meth:`build_throwaway`)."""
        t = world.time_ns
        yield self.pub_clock, messages.clock(t), True
        yield self.pub_body_poses, messages.body_poses(t), True
        for pub, data in zip(self.pub_odom, messages.body_odometry(t)):
            yield pub, data, True
        record_poses = world.ticks % self._node.detail.flock_poses_every == 0  # the data: published every tick
        for pub, data in zip(self.pub_flock_poses, messages.flock_poses(t)):
            yield pub, data, record_poses
        for pub, data in zip(self.pub_flock_stats, messages.flock_stats(t)):  # tiny: recorded on every tick
            yield pub, data, True
        for pub, data in zip(self.pub_joint_states, messages.joint_states(t)):
            yield pub, data, True
        if self.pub_contacts is not None and world.report_contacts:  # (nobody listens otherwise)
            yield self.pub_contacts, messages.contacts(t), True
        dynamic = tf.dynamic(t)
        if dynamic is not None:
            yield self.pub_tf, dynamic, True
        if world.ticks == 1:  # the first /tf_static (later ones: publish_static_tf): what changed before it
            static = tf.static_if_changed(t)
            if static is not None:
                yield self.pub_tf_static, static, True
        # every tick: ground, bodies and one part of each flock's marker (a flock is redrawn every
        # markers_every ticks, part by part: cgp_sim_ros/ros/messages.py)
        yield self.pub_markers, messages.markers(t, delete_all_first=delete_all_markers, tick=world.ticks), True

    def build_for_another(self, world) -> None:
        """Build (and drop) what a tick of ``world`` — a copy of a world about to replace the node's
        (``load_world``), stepped on a helper thread — publishes, with drawings and a level-of-detail plan of
        its own: the serializers' and the fish drawing's kernels are loaded before its first real tick, and
        nothing of the node's (its drawings, plan, publishers) is touched from that thread."""
        params, frames = self._node.params, self._node.frames
        messages = TickMessages(world, frames, contact_force_scale=self._force_scale, drawings=Drawings())
        messages.set_plan(lod.plan([f.params for f in world.flocks], params["rate_hz"],
                                   fish_detail=params["fish_detail"], markers_every=params["markers_every"],
                                   flock_poses_every=params["bag_flock_poses_every"], body_bytes=messages.body_bytes()))
        t = world.time_ns
        for build in (messages.clock, messages.body_poses, messages.body_odometry, messages.flock_poses,
                      messages.flock_stats, messages.joint_states):
            build(t)
        if world.report_contacts:
            messages.contacts(t)
        tf = BodyTransforms(world, frames)
        tf.dynamic(t)
        tf.static_if_changed(t)
        messages.markers(t, delete_all_first=True, tick=world.ticks)
        messages.static_markers(t)

    def build_throwaway(self, world) -> None:
        """Build (and drop: nothing is published) everything a tick of ``world`` — a copy of the node's —
        publishes, every marker part included: what the first real tick will run, run once before it."""
        frames = self._node.frames
        messages = TickMessages(world, frames, self._node.detail, self._force_scale, drawings=self.drawings)
        for _ in self.tick_messages(world, messages, BodyTransforms(world, frames), delete_all_markers=True):
            pass
        messages.static_markers(world.time_ns)

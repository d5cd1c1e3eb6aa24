"""The cgp_sim node: a thin, timer-driven adapter between ``cgp_core.World`` and the ROS graph.

Per tick (one timer callback): drain the validated wrench commands into the world → ``World.step()`` →
serialize the state once per message (numpy-built CDR, :mod:`cgp_sim_ros.messages`) → publish those bytes and
hand the same bytes to the recorder.  No physics here: every equation lives in ``cgp_core``.

Threading: one single-threaded executor runs the timer, the subscriptions and the services, so they never
interleave with a step and need no locks.  The bag is written on its own thread (:mod:`cgp_sim_ros.bag`).
With ``foxglove:=true`` a Foxglove WebSocket server (:mod:`cgp_sim_ros.foxglove_server`) gets the same bytes in
:meth:`SimNode._out`; what its clients send reaches the node through the same executor (a guard condition).
While a flock big enough for numba's thread pool runs (``pin_threads``), the executor's thread — the tick's —
has a CPU of its own and every other thread the others (:meth:`SimNode._place_threads`).
The interface (topics, QoS, parameters) is defined and documented in :mod:`cgp_sim_ros.interface`.

Bad input (what a node on a shared graph must expect):

- commands: a message larger than any valid command (:data:`MAX_COMMAND_BYTES`) is dropped before it is
  decoded or recorded; every other one is validated by :func:`cgp_core.wrenches.make_command`.  A rejected
  command is logged at once the first time its (topic, field, kind of problem) occurs, then summarized every
  :data:`REPORT_PERIOD_S` seconds with a count (log and ``~/events``), so a flood cannot flood the log.
  Pending commands are a bounded queue (:data:`MAX_PENDING_COMMANDS`, the oldest dropped and reported) and
  active wrenches are bounded (``WrenchSchedule.max_active``).
- parameters: checked at start-up (a :class:`ConfigError`: ``cgp-sim`` exits with status 2 and the reason)
  and at run time (the parameter callback refuses the change with the reason); an override of a parameter
  the node does not have is warned about (a typo), not fatal (parameter files may address many nodes).
- recording: the bag path is resolved once (``~``, symlinks, ``..``) and nothing is written outside that
  directory; an existing, non-empty bag directory is a :class:`ConfigError`; a location that cannot be
  written (beneath a regular file, a name too long, disk full...) is logged once with the path and the reason,
  and the simulation and publishing go on without recording.
"""

from __future__ import annotations

import collections
import copy
import gc
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import rclpy
from rcl_interfaces.msg import ParameterDescriptor, ParameterType, SetParametersResult
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.exceptions import InvalidParameterTypeException
from rclpy.node import Node
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger

from cgp_core.jit import ThreadPlacement, runs_on_pool
from cgp_core.scene import SceneError
from cgp_core.world import World
from cgp_core.wrenches import MAX_NAME_LENGTH, WrenchError, make_command

from . import cdr
from . import detail as lod
from . import interface as itf
from .messages import TickMessages
from .progress import BatchProgress, ProgressLine
from .sim_services import SimulationInterfaces
from .tf import BodyTransforms

#: commands waiting for the next tick; beyond this, the oldest are dropped (and counted, and reported)
MAX_PENDING_COMMANDS = 2000
#: how often (wall seconds) rejected-command reports and rate checks are summarized in the log
REPORT_PERIOD_S = 2.0
#: larger than any valid ApplyWrench / WrenchStamped: their only unbounded fields are the strings `body` and
#: `header.frame_id`, names of at most MAX_NAME_LENGTH (255) characters (≈ 620 serialized bytes in all).
#: Anything larger is dropped on arrival, before it is decoded or recorded.
MAX_COMMAND_BYTES = 1024
#: a command callback goes on taking waiting commands for at most this long (wall seconds)
COMMAND_BATCH_S = 0.002
#: parameters rclpy itself declares or reads; an override of these is not "unknown"
_ROS_OWN_PARAMETERS = ("use_sim_time", "start_type_description_service")
#: The endpoints made per body and per flock (odometry, flock poses and stats, per-body wrench commands) are made
#: without rclpy's default QoS-event handlers (the "incompatible QoS / type" warnings).  Each handler is a waitable
#: the executor adds to its wait set, in Python, on every spin: with 100 spawned bodies their ~400 handlers cost
#: the single-threaded executor ~5 ms per tick (measured: the tick rate fell to 45 Hz while they were spawned).
#: The node's fixed topics keep the warnings.
_NO_EVENT_HANDLERS_PUB = PublisherEventCallbacks(use_default_callbacks=False)
_NO_EVENT_HANDLERS_SUB = SubscriptionEventCallbacks(use_default_callbacks=False)


class ConfigError(ValueError):
    """A parameter value or scene the node cannot start with."""


class SimNode(Node):
    def __init__(self, *, parameter_overrides=None, node_name: str = "cgp_sim"):
        super().__init__(node_name, parameter_overrides=parameter_overrides)
        problems = self._declare_parameters()
        self.params = {p.name: self.get_parameter(p.name).value for p in itf.PARAMETERS
                       if self.has_parameter(p.name)}
        problems += [msg for p in itf.PARAMETERS if p.name in self.params
                     and (msg := _check_parameter(p, self.params[p.name]))]
        if problems:
            raise ConfigError("invalid parameters: " + "; ".join(problems))
        self.params = {p.name: _coerce(p, v) for p, v in zip(itf.PARAMETERS, self.params.values())}
        unknown = sorted(name for name in self._parameter_overrides
                         if name not in itf.PARAMETER_BY_NAME and name not in _ROS_OWN_PARAMETERS
                         and not name.startswith("qos_overrides."))
        if unknown:
            self.get_logger().warn(f"ignoring unknown parameter(s) {', '.join(unknown)}; cgp_sim's parameters "
                                   f"are {', '.join(p.name for p in itf.PARAMETERS)}")
        #: the bag directory, resolved once (``~``, symlinks and ``..`` as the OS resolves them): the recording
        #: writes inside it and nowhere else (a lexical ``a/new/../bag`` would make ``mkdir -p`` create ``a/new``)
        self.bag_path = _resolve_bag_path(self.params["bag"]) if self.params["bag"] else None
        if self.bag_path is not None:
            # Checked before anything is built or published: recording into an old bag would mix two runs.
            # A path that cannot even be examined (a name longer than NAME_MAX...) is not a configuration error
            # here: the recorder reports it as it reports any unwritable location, and the simulation goes on.
            from .bag import bag_path_occupied

            try:
                occupied = bag_path_occupied(self.bag_path)
            except OSError:
                occupied = False
            if occupied:
                raise ConfigError(f"bag: {str(self.bag_path)!r} already exists and is "
                                  f"{'not empty' if self.bag_path.is_dir() else 'not a directory'}; choose a new "
                                  "directory (a bag is never overwritten)")

        seed = self.params["seed"]
        try:
            self.world = World.from_scene(self.params["scene"], dt=1.0 / self.params["rate_hz"],
                                          substeps=self.params["substeps"] or None,
                                          seed=None if seed < 0 else seed)
        except SceneError as exc:
            raise ConfigError(f"scene: {exc}") from None

        self.messages = TickMessages(self.world, itf.WORLD_FRAME)
        self.tf = BodyTransforms(self.world, itf.WORLD_FRAME)
        #: what is drawn and recorded at what rate (cgp_sim_ros/detail.py); set by _plan_detail
        self.detail: lod.DetailPlan | None = None
        self.paused = bool(self.params["start_paused"])
        self._pending: collections.deque = collections.deque()
        self._dropped_commands = 0
        self._rejections: collections.Counter = collections.Counter()
        self._last_rejection: dict[tuple[str, str, str], str] = {}  # (source, field, kind) -> last reason
        self._delete_all_markers = False
        #: set when `duration` is reached; the main loop then shuts the node down
        self.finished = False

        self.recorder = None
        #: the live view (parameter `foxglove`): a Foxglove WebSocket server fed in _out(), or None
        self.foxglove = None
        #: every command input: topic -> (message type, handler of its serialized bytes), for other transports
        self.command_inputs: dict[str, tuple[type, object]] = {}
        self._make_publishers()
        self._make_subscriptions()
        self._make_services()
        # Per body / per flock endpoints (odometry, wrench commands, flock poses): made here and again after
        # every spawn, delete or reset (see _sync_entities).
        self._odom_publishers: dict = {}
        self._flock_publishers: dict = {}
        self._flock_stats_publishers: dict = {}
        self.sub_body_wrench: dict = {}
        self._marker_ids: dict[str, set[int]] = {}
        self._synced_names: list[str] = []
        self._synced_version = None
        self._sync_entities()
        # ROS 2's simulation_interfaces services and action (cgp_sim_ros.sim_services)
        self.sim = SimulationInterfaces(self)

        if self.params["foxglove"]:
            self._start_foxglove()  # after the per-entity endpoints exist: it makes a channel for each

        self._plan_detail()
        if self.bag_path is not None:
            self._start_recording(self.bag_path)
        self._event(self.detail.event())  # after the recorder: the plan is the bag's first event

        self._tick_wall_times: collections.deque = collections.deque(maxlen=512)
        #: the rate check's window: starts at the first tick after start-up or a pause (see _periodic_reports)
        self._window_start: float | None = None
        self._window_ticks = 0
        self._timer = self.create_timer(self._timer_period(), self._on_timer)
        #: batch runs (realtime:=false) show their progress: one updating line on a terminal, log lines otherwise
        self._progress = None
        if not self.params["realtime"]:
            self._progress = (ProgressLine(sys.stderr, log=lambda text: self.get_logger().info(f"progress: {text}")),
                              BatchProgress(self.params["duration"]))
        # Reports on their own wall-clock timer, so rejected commands are summarized while paused too.
        self._report_timer = self.create_timer(REPORT_PERIOD_S, self._report)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        counts = f"{self.world.body_model.count} bodies, " + ", ".join(
            f"flock {f.params.name} ({len(f.positions)} boids)" for f in self.world.flocks) if self.world.flocks \
            else f"{self.world.body_model.count} bodies"
        self.get_logger().info(
            f"scene {self.world.scene.source}: {counts}; {self.params['rate_hz']:g} Hz × {self.world.substeps} "
            f"substeps, integrator {self.world.scene.world.integrator}, "
            f"{'real time' if self.params['realtime'] else 'as fast as possible'}"
            + ("" if self.recorder is None else f", recording to {self.recorder.directory}"
               if self.recorder.recording else f", NOT recording (the bag {str(self.bag_path)!r} cannot be "
               "written: see the error above)"))
        self.get_logger().info("level of detail: " + " ".join(self.detail.lines))
        self._load_kernels()
        self._freeze_startup_objects()
        self._share_the_gil_finely()
        self._thread_placement = ThreadPlacement()
        self._thread_placement_said: str | None = None
        self._place_threads()

    # ---- set-up -----------------------------------------------------------------------------------------

    def _declare_parameters(self) -> list[str]:
        """Declare every parameter; returns the problems with start-up values rclpy itself refuses, worded like
        :func:`_check_parameter` (none expected: see below)."""
        problems = []
        for p in itf.PARAMETERS:
            # Declared with dynamic typing, and checked by _check_parameter (at start-up and in the parameter
            # callback), so that a value of the wrong type gets a reason naming the parameter and the expected
            # type ("realtime must be bool, got str 'yes'") rather than rclpy's "Wrong parameter type, expected
            # '1' got '4'"; and `-p rate_hz:=60` (an integer to the ROS parser) is accepted and converted.
            # The type and range are stated in the descriptor for `ros2 param describe`.
            descriptor = ParameterDescriptor(
                name=p.name, type=ParameterType.PARAMETER_NOT_SET, description=p.description,
                additional_constraints=_constraints(p), read_only=p.read_only, dynamic_typing=True)
            try:
                self.declare_parameter(p.name, p.default, descriptor)
            except InvalidParameterTypeException:
                value = self._parameter_overrides[p.name].value
                problems.append(f"{p.name} must be {type(p.default).__name__}, got {type(value).__name__} "
                                f"{_brief(value)}")
        return problems

    def _make_publishers(self) -> None:
        self.pub_clock = self.create_publisher(self.messages.Clock, itf.TOPIC_CLOCK, itf.CLOCK_QOS)
        self.pub_body_poses = self.create_publisher(self.messages.PoseArray, itf.TOPIC_BODY_POSES, itf.STATE_QOS)
        self.pub_markers = self.create_publisher(self.messages.MarkerArray, itf.TOPIC_MARKERS, itf.STATE_QOS)
        self.pub_events = self.create_publisher(String, itf.TOPIC_EVENTS, itf.COMMAND_QOS)
        self.pub_tf = self.create_publisher(self.tf.TFMessage, itf.TOPIC_TF, itf.TF_QOS)
        self.pub_tf_static = self.create_publisher(self.tf.TFMessage, itf.TOPIC_TF_STATIC, itf.TF_STATIC_QOS)

    def _make_subscriptions(self) -> None:
        from cgp_sim_msgs.msg import ApplyWrench
        from geometry_msgs.msg import WrenchStamped

        self._apply_wrench_type = ApplyWrench
        self._wrench_stamped_type = WrenchStamped
        self.sub_apply_wrench = self._command_subscription(ApplyWrench, itf.TOPIC_APPLY_WRENCH,
                                                           self._on_apply_wrench)

    def _sync_entities(self) -> None:
        """Make everything per body and per flock follow the world's current bodies and flocks (after start-up,
        a spawn, a delete or a reset; a no-op when ``world.model_version`` did not change):

        - ``~/bodies/<body>/odom`` publishers, ``~/bodies/<body>/wrench`` subscriptions (movable bodies),
          ``~/flocks/<flock>/poses`` and ``~/flocks/<flock>/stats`` publishers: created for new entities,
          destroyed for gone ones, kept for the others (subscribers stay matched);
        - the new topics are added to the recording (new channels mid-recording, counted in metadata.yaml) and
          to the Foxglove live view, if on (new channels; the command inputs follow ``command_inputs``);
        - the per-tick serializers (:class:`TickMessages`, TF) are rebuilt for the new body set;
        - pending wrench commands follow their body (index), those on deleted bodies are dropped;
        - the markers of gone entities are deleted (a MarkerArray of DELETE actions, published at once) and
          ``/tf_static`` is sent again if the fixed bodies changed."""
        world = self.world
        if world.model_version == self._synced_version:
            return
        names = list(world.body_model.names)
        movable = {n for n, fixed in zip(names, world.body_model.fixed) if not fixed}
        flock_names = [f.params.name for f in world.flocks]
        added = []
        for publishers, wanted, topic, msg_type in (
                (self._odom_publishers, names, itf.TOPIC_BODY_ODOM, self.messages.Odometry),
                (self._flock_publishers, flock_names, itf.TOPIC_FLOCK_POSES, self.messages.PoseArray),
                (self._flock_stats_publishers, flock_names, itf.TOPIC_FLOCK_STATS, self.messages.FlockStats)):
            for name in [n for n in publishers if n not in wanted]:
                self.destroy_publisher(publishers.pop(name))
            for name in wanted:
                if name not in publishers:
                    key = "body" if publishers is self._odom_publishers else "flock"
                    publishers[name] = self.create_publisher(msg_type, topic.format(**{key: name}), itf.STATE_QOS,
                                                             event_callbacks=_NO_EVENT_HANDLERS_PUB)
                    added.append(publishers[name])
        for name in [n for n in self.sub_body_wrench if n not in movable]:
            subscription = self.sub_body_wrench.pop(name)
            self.command_inputs.pop(subscription.topic_name, None)
            self.destroy_subscription(subscription)
        for name in names:
            if name in movable and name not in self.sub_body_wrench:
                self.sub_body_wrench[name] = self._command_subscription(
                    self._wrench_stamped_type, itf.TOPIC_BODY_WRENCH.format(body=name),
                    lambda data, body=name: self._on_body_wrench(body, data), per_entity=True)
                added.append(self.sub_body_wrench[name])
        self.pub_odom = [self._odom_publishers[n] for n in names]
        self.pub_flock_poses = [self._flock_publishers[n] for n in flock_names]
        self.pub_flock_stats = [self._flock_stats_publishers[n] for n in flock_names]
        if self.recorder is not None and added:
            self.recorder.add_endpoints(added)
        if self.foxglove is not None:
            self.foxglove.follow_endpoints(added)

        # pending commands hold body indices of the model they were validated against
        new_index = {name: i for i, name in enumerate(names)}
        old_names = self._synced_names
        self._pending = collections.deque(
            replace(c, body=new_index[old_names[c.body]]) for c in self._pending
            if c.body < len(old_names) and old_names[c.body] in new_index)

        self.messages = TickMessages(world, itf.WORLD_FRAME)
        if self.detail is not None:  # after start-up: a flock spawned or deleted may change the plan (logged if so)
            self._replan_detail()
        self.tf.rebuild()
        self._retire_markers()
        if self._synced_version is not None:
            self._publish_static_tf()
        self._synced_names = names
        self._synced_version = world.model_version

    def _retire_markers(self) -> None:
        """DELETE the markers no longer drawn — a deleted body's or flock's, a flock's parts beyond the ones it is
        now drawn in — so that no viewer keeps them (a marker without a lifetime never expires)."""
        drawn = self.messages.marker_ids()
        stale = [(ns, i) for ns, ids in self._marker_ids.items() for i in sorted(ids - drawn.get(ns, set()))]
        if stale and not self._delete_all_markers:  # a pending DELETEALL (after a reset) removes them anyway
            t = self.world.time_ns
            deletes = [cdr.marker(marker_type=cdr.ARROW, action=cdr.DELETE, stamp_ns=t, frame_id=itf.WORLD_FRAME,
                                  ns=ns, id=i) for ns, i in stale]
            self._out(self.pub_markers, cdr.marker_array(deletes), t)
        self._marker_ids = drawn

    def _publish_static_tf(self) -> None:
        """``/tf_static`` again if the fixed bodies changed.  Not before the first tick: a node publishes nothing
        before it (a paused node is silent; a bag starts with the first tick, at its time)."""
        if self.world.ticks == 0:
            return
        data = self.tf.static_if_changed(self.world.time_ns)
        if data is not None:
            self._out(self.pub_tf_static, data, self.world.time_ns)

    def _command_subscription(self, msg_type, topic: str, handle, per_entity: bool = False):
        """A raw command subscription whose callback also takes the messages already waiting behind the first.

        rclpy's executor takes one message per subscription per wait, and a wait costs a fraction of a
        millisecond of Python, so a flood would be read at a few hundred messages per tick at best and the rest
        overwritten in the DDS reader's bounded history.  Taking what is waiting in one go (bounded by
        COMMAND_BATCH_S of wall time, so a tick is never held up for long) reads thousands per second."""
        subscription = None

        def take_all(data: bytes) -> None:
            handle(data)
            deadline = time.perf_counter() + COMMAND_BATCH_S
            while time.perf_counter() < deadline:
                with subscription.handle:
                    taken = subscription.handle.take_message(msg_type, True)
                if taken is None:
                    return
                handle(taken[0])

        subscription = self.create_subscription(msg_type, topic, take_all, itf.COMMAND_QOS, raw=True,
                                                event_callbacks=_NO_EVENT_HANDLERS_SUB if per_entity else None)
        self.command_inputs[subscription.topic_name] = (msg_type, handle)
        return subscription

    def _make_services(self) -> None:
        self.create_service(Trigger, itf.SERVICE_RESET, self._on_reset)
        self.create_service(SetBool, itf.SERVICE_PAUSE, self._on_pause)
        self.create_service(Trigger, itf.SERVICE_STEP, self._on_step)
        self.create_service(Trigger, itf.SERVICE_CLEAR_WRENCHES, self._on_clear_wrenches)

    def _start_foxglove(self) -> None:
        from .foxglove_server import FoxgloveServer, FoxgloveServerError

        try:
            self.foxglove = FoxgloveServer(self, host=self.params["foxglove_host"], port=self.params["foxglove_port"])
        except FoxgloveServerError as exc:
            raise ConfigError(f"foxglove: {exc}") from None

    def _start_recording(self, directory: Path) -> None:
        from .bag import BagExistsError
        from .recorder import Recorder

        try:
            self.recorder = Recorder(self, directory,
                                     max_bytes=self.params["bag_max_size"],
                                     max_duration_s=self.params["bag_max_duration"],
                                     custom_data=self._detail_custom_data())
        except BagExistsError as exc:  # created between the check in __init__ and now
            raise ConfigError(f"bag: {exc}") from None

    def _load_kernels(self) -> None:
        """Have the compiled kernels the first tick runs loaded before it.  numba loads a kernel from its
        on-disk cache at the kernel's first call, ~9 ms each: the default scene's first tick took ~170 ms
        (24 kernels), ten 60 Hz periods of a real-time run lost at its start.  A throwaway copy of the world
        takes one tick here and its messages are built (every marker part) and dropped: nothing is published,
        the world itself is untouched.  Whatever fails here fails again, and is reported, in the real tick.

        That tick runs the kernels of the scene's first instant only: the contact kernels of shapes that touch
        later were loaded when they first touched — the default scene's ball lands 0.7 s in, and that tick
        took ~16 ms (the penetration recovery's kernel loading).  So the core's warm-up scenario (its own
        world: bodies of every shape placed in contact, no flock) takes one tick here too: every rigid-body
        kernel is loaded before the first tick, also for bodies spawned later (~0.1 s more start-up)."""
        from cgp_core.warmup import warm_up

        world = copy.deepcopy(self.world)
        try:
            warm_up(ticks=1, complete=False, flocks=False)
            world.step()
            for _ in self._tick_messages(world, TickMessages(world, itf.WORLD_FRAME, self.detail),
                                         BodyTransforms(world, itf.WORLD_FRAME), delete_all_markers=True):
                pass  # built, not published
        except Exception as exc:  # noqa: BLE001 - the real first tick reports it
            self.get_logger().debug(f"loading the kernels before the first tick: {exc!r}")

    @staticmethod
    def _freeze_startup_objects() -> None:
        """Everything built so far — the imported modules (rclpy, numpy, scipy, numba and its compiled kernels),
        the scene, the world — lives as long as the node: move it out of the cyclic garbage collector's sight
        (``gc.freeze``).  Python's full collections, which it runs now and then between ticks, then scan only
        what the ticks create: about a millisecond instead of the ~200 ms pause measured at 15k fish, which
        alone would break the tick's 16.7 ms."""
        gc.collect()
        gc.freeze()

    #: how long a thread that wants the GIL waits before the holder must let go [s] (Python's default: 5 ms)
    GIL_SWITCH_INTERVAL_S = 0.001

    @classmethod
    def _share_the_gil_finely(cls) -> None:
        """The tick releases the GIL in every compiled kernel (``nogil``), and the bag writer's thread takes it
        for its Python (MCAP framing, chunk buffers).  When a kernel returns while the writer is busy, the
        tick waits for the GIL until the writer blocks or the switch interval forces a hand-over — up to 5 ms
        by Python's default, a third of a 60 Hz tick, on any of the ~15 kernel calls of a flock step.  At 1 ms
        the wait is bounded by 1 ms; both threads still get their share (measured on the 15k-fish tick, three
        alternating runs each: p99 14.6-21.8 ms against 18.3-28.7 ms at 5 ms — an indication: this machine's
        speed varied between the runs almost as much)."""
        sys.setswitchinterval(min(sys.getswitchinterval(), cls.GIL_SWITCH_INTERVAL_S))

    def _place_threads(self) -> None:
        """The tick's thread on a CPU of its own, every other thread on the others (``cgp_core.jit.ThreadPlacement``:
        why, and what it measured), while ``pin_threads`` is on and a flock runs on numba's thread pool; else every
        thread on every CPU.  Called at start-up and every REPORT_PERIOD_S from the tick (threads started since
        are moved too; a flock spawned or deleted changes the answer); each change of the answer is logged."""
        on_pool = any(runs_on_pool(f.count) for f in self.world.flocks)
        placement = self._thread_placement
        if on_pool and self.params["pin_threads"] and placement.place():
            others = placement.others
            said = (f"threads: the tick on CPU {placement.cpu} alone; numba's pool workers, the bag writer and DDS "
                    f"on CPU{'s' if len(others) > 1 else ''} {', '.join(map(str, others))} (pin_threads; a flock runs "
                    "on numba's pool)")
        else:
            placement.release()
            if not on_pool:  # said only after a placement: a small flock's node has nothing to say about it
                said = "threads: not pinned (no flock runs on numba's pool now)" if self._thread_placement_said \
                    else None
            elif not self.params["pin_threads"]:
                said = "threads: not pinned (pin_threads false)"
            else:
                said = f"threads: not pinned ({placement.unavailable})"
        if said is not None and said != self._thread_placement_said:
            self.get_logger().info(said)
            self._thread_placement_said = said

    def _plan_detail(self) -> None:
        """(Re)make the level-of-detail plan from the flocks and the parameters (cgp_sim_ros/detail.py)."""
        self.detail = lod.plan([f.params for f in self.world.flocks], self.params["rate_hz"],
                               fish_detail=self.params["fish_detail"], markers_every=self.params["markers_every"],
                               flock_poses_every=self.params["bag_flock_poses_every"])
        self.messages.set_plan(self.detail)

    def _detail_custom_data(self) -> dict:
        return self.detail.custom_data({f.params.name: pub.topic_name for f, pub in
                                        zip(self.world.flocks, self.pub_flock_poses)}, self.pub_markers.topic_name)

    def _timer_period(self) -> float:
        # realtime=false: a zero-period timer is always ready, so the executor runs ticks back to back while
        # still serving subscriptions and services in between.
        return 1.0 / self.params["rate_hz"] if self.params["realtime"] else 0.0

    # ---- the tick -----------------------------------------------------------------------------------------

    def _on_timer(self) -> None:
        if self.finished:
            return
        if self.sim.quit_due():
            self.finished = True
            return
        if self.paused:
            # a stepping request (~/step_simulation, ~/simulate_steps) ticks a paused world at the timer's pace
            if self.sim.stepping:
                self.tick()
                self.sim.stepped()
            return
        self.tick()

    def tick(self) -> None:
        """One simulation tick: commands in, step, everything out."""
        start = time.perf_counter()
        if self.recorder is not None and self.params["realtime"]:
            # the bag writer works between real-time ticks, not in them (back to back there is no "between":
            # it works beside the ticks)
            self.recorder.begin_tick()
        self._apply_pending_commands()
        self.world.step()
        for event in self.world.take_events():
            (self.get_logger().error if event.level == "error" else self.get_logger().warn)(event.text)
            self._event({"event": "world", "level": event.level, "text": event.text})
        self._publish_state()
        if self.recorder is not None:
            self.recorder.end_tick()  # the bag writer works while this thread waits for the next tick
        self._tick_wall_times.append(time.perf_counter() - start)
        self._window_ticks += 1
        self._periodic_reports()
        if self._progress is not None and self._progress[0].due():
            self._show_progress()
        duration = self.params["duration"]
        if duration > 0.0 and self.world.time_ns >= round(duration * 1e9) and not self.finished:
            self.finished = True
            if self._progress is not None:
                self._show_progress(final=True)
            self.get_logger().info(f"duration {duration:g} s of simulated time reached after {self.world.ticks} "
                                   "ticks; shutting down")

    def _publish_state(self) -> None:
        t = self.world.time_ns
        for publisher, data, record in self._tick_messages(self.world, self.messages, self.tf,
                                                           self._delete_all_markers):
            self._out(publisher, data, t, record=record)
        self._delete_all_markers = False

    def _tick_messages(self, world, messages: TickMessages, tf: BodyTransforms, delete_all_markers: bool):
        """What a tick publishes, in publishing order, as ``(publisher, CDR bytes, recorded?)``, each built as
        the caller takes it, from ``world`` by ``messages`` and ``tf``: the node's own every tick
        (:meth:`_publish_state`), a throwaway copy's once before the first (:meth:`_load_kernels`)."""
        t = world.time_ns
        yield self.pub_clock, messages.clock(t), True
        yield self.pub_body_poses, messages.body_poses(t), True
        for pub, data in zip(self.pub_odom, messages.body_odometry(t)):
            yield pub, data, True
        record_poses = world.ticks % self.detail.flock_poses_every == 0  # the data: published every tick
        for pub, data in zip(self.pub_flock_poses, messages.flock_poses(t)):
            yield pub, data, record_poses
        for pub, data in zip(self.pub_flock_stats, messages.flock_stats(t)):  # tiny: recorded on every tick
            yield pub, data, True
        dynamic = tf.dynamic(t)
        if dynamic is not None:
            yield self.pub_tf, dynamic, True
        if world.ticks == 1:  # the first /tf_static (later ones: _publish_static_tf): what changed before it
            static = tf.static_if_changed(t)
            if static is not None:
                yield self.pub_tf_static, static, True
        # every tick: ground, bodies and one part of each flock's marker (a flock is redrawn every
        # markers_every ticks, part by part: cgp_sim_ros/messages.py)
        yield self.pub_markers, messages.markers(t, delete_all_first=delete_all_markers, tick=world.ticks), True

    def _show_progress(self, final: bool = False) -> None:
        line, status = self._progress
        text = status.status(self.world.time, self.world.ticks,
                             self.recorder.size_bytes() if self.recorder is not None else None, final=final)
        if final:
            line.finish(text)
        else:
            line.update(text)

    def _out(self, publisher, data: bytes, stamp_ns: int, record: bool = True) -> None:
        """Publish serialized bytes, and record (unless the level-of-detail plan records this topic on fewer
        ticks: ``record`` False) and show in Foxglove the very same bytes."""
        publisher.publish(data)
        if record and self.recorder is not None:
            self.recorder.write(publisher.topic_name, data, stamp_ns)
        if self.foxglove is not None:
            self.foxglove.publish(publisher, data, stamp_ns)

    def _periodic_reports(self) -> None:
        now = time.monotonic()
        if self._window_start is None:  # the first tick since start-up or a pause: the window opens here
            self._window_start, self._window_ticks = now, 0
            return
        elapsed = now - self._window_start
        if elapsed < REPORT_PERIOD_S:
            return
        achieved = self._window_ticks / elapsed
        target = self.params["rate_hz"]
        if self.params["realtime"] and not self.paused and achieved < 0.95 * target:
            median_ms = 1e3 * float(np.median(self._tick_wall_times)) if self._tick_wall_times else float("nan")
            self.get_logger().warn(
                f"falling behind real time: {achieved:.1f} Hz achieved of {target:g} Hz (median tick "
                f"{median_ms:.1f} ms); dt stays {self.world.dt * 1e3:.3f} ms, so simulated time runs slower "
                "than the wall clock")
        self._window_start, self._window_ticks = now, 0
        self._place_threads()

    def _report(self) -> None:
        """Every REPORT_PERIOD_S of wall time: rejected / dropped commands, recording errors."""
        self._report_rejections()
        if self.recorder is not None:
            self.recorder.report_errors()

    # ---- commands -----------------------------------------------------------------------------------------

    def _on_apply_wrench(self, data: bytes) -> None:
        if self._oversized("apply_wrench", data):
            return
        self._record_received(self.sub_apply_wrench.topic_name, data)
        try:
            msg = self._decode(data, self._apply_wrench_type)
            if msg.duration.nanosec >= 1_000_000_000:
                raise WrenchError("duration.nanosec", f"must be < 1e9, got {msg.duration.nanosec}", "malformed")
            command = make_command(
                self.world.body_model.names, msg.body,
                force=(msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z),
                torque=(msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z),
                point=(msg.point.x, msg.point.y, msg.point.z), frame=msg.header.frame_id,
                duration=msg.duration.sec + 1e-9 * msg.duration.nanosec,
                max_force=self.params["max_force"], max_torque=self.params["max_torque"],
                fixed=self.world.body_model.fixed, positions=self.world.body_state.position)
        except WrenchError as exc:
            self._reject("apply_wrench", exc)
            return
        self._enqueue(command)

    def _on_body_wrench(self, body: str, data: bytes) -> None:
        source = f"bodies/{body}/wrench"
        if self._oversized(source, data):
            return
        self._record_received(self.sub_body_wrench[body].topic_name, data)
        try:
            msg = self._decode(data, self._wrench_stamped_type)
            command = make_command(
                self.world.body_model.names, body,
                force=(msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z),
                torque=(msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z),
                point=None, frame=msg.header.frame_id, duration=0.0,
                max_force=self.params["max_force"], max_torque=self.params["max_torque"])
        except WrenchError as exc:
            self._reject(source, exc)
            return
        self._enqueue(command)

    def _oversized(self, source: str, data: bytes) -> bool:
        """Drop a message larger than any valid command, cheaply (no decoding, no recording)."""
        if len(data) <= MAX_COMMAND_BYTES:
            return False
        self._reject(source, WrenchError(
            "message", f"{len(data)} bytes, more than any valid command ({MAX_COMMAND_BYTES} bytes: body and "
            f"header.frame_id are names of at most {MAX_NAME_LENGTH} characters); dropped unread", "too large"))
        return True

    @staticmethod
    def _decode(data: bytes, msg_type):
        try:
            return deserialize_message(data, msg_type)
        except Exception as exc:  # undecodable bytes: a peer with a mismatched definition
            raise WrenchError("message", f"cannot decode: {exc}", "undecodable") from None

    def _enqueue(self, command) -> None:
        if len(self._pending) >= MAX_PENDING_COMMANDS:
            self._pending.popleft()
            self._dropped_commands += 1
        self._pending.append(command)

    def _apply_pending_commands(self) -> None:
        if not self._pending:
            return
        commands = list(self._pending)
        self._pending.clear()
        accepted = self.world.add_commands(commands)
        if accepted < len(commands):
            self._reject("apply_wrench", WrenchError(
                "wrenches", f"{len(commands) - accepted} wrench(es) over the limit of "
                f"{self.world.wrenches.max_active} active wrenches (clear some with ~/clear_wrenches)", "too many"),
                count=len(commands) - accepted)

    def _reject(self, source: str, error: WrenchError, count: int = 1) -> None:
        """Count rejected commands; the first of each (source, field, kind) is logged at once, the rest are
        summarized every REPORT_PERIOD_S (see :meth:`_report_rejections`)."""
        key = (source, error.field, error.kind)
        if key not in self._last_rejection:
            self.get_logger().warn(f"rejected {source} command: {error}")
        self._rejections[key] += count
        self._last_rejection[key] = str(error)

    def _report_rejections(self) -> None:
        if self._dropped_commands:
            self.get_logger().warn(f"command flood: dropped the {self._dropped_commands} oldest pending wrench "
                                   f"commands (more than {MAX_PENDING_COMMANDS} arrived within one tick)")
            self._event({"event": "dropped_commands", "count": self._dropped_commands})
            self._dropped_commands = 0
        for (source, field, kind), count in self._rejections.items():
            reason = self._last_rejection[(source, field, kind)]
            self.get_logger().warn(f"rejected {count} {source} command(s) with {kind} {field} in the last "
                                   f"{REPORT_PERIOD_S:g} s; last reason: {reason}")
            self._event({"event": "rejected", "source": source, "field": field, "kind": kind, "count": count,
                         "reason": reason})
        self._rejections.clear()

    def _record_received(self, topic: str, data: bytes) -> None:
        if self.recorder is not None:
            self.recorder.write(topic, data, self.world.time_ns)
        if self.foxglove is not None:
            self.foxglove.received(topic, data, self.world.time_ns)

    def _event(self, payload: dict) -> None:
        """Publish (and so record) one line on ~/events: the audit trail of what was done to the world."""
        payload = {"time": round(self.world.time, 9), **payload}
        msg = String(data=json.dumps(payload, separators=(",", ":")))
        self._out(self.pub_events, serialize_message(msg), self.world.time_ns)

    # ---- services ----------------------------------------------------------------------------------------

    def _on_reset(self, request, response):
        self.world.reset()
        self._pending.clear()
        self._delete_all_markers = True
        self._sync_entities()
        self._publish_static_tf()
        self._event({"event": "service", "name": "reset"})
        response.success = True
        response.message = f"reset to the initial state of {self.world.scene.source} at t = {self.world.time:.9f} s"
        return response

    def _on_pause(self, request, response):
        self.sim.set_paused(bool(request.data))
        self._window_start = None  # time spent paused is not "falling behind"
        self._event({"event": "service", "name": "pause", "data": self.paused})
        response.success = True
        response.message = f"{'paused' if self.paused else 'running'} at t = {self.world.time:.9f} s"
        return response

    def _on_step(self, request, response):
        self._event({"event": "service", "name": "step"})
        if not self.paused:
            response.success = False
            response.message = "not paused: call ~/pause with data: true first"
            return response
        if self.sim.stepping:
            response.success = False
            response.message = "a stepping request (~/step_simulation or ~/simulate_steps) is running"
            return response
        self.sim.stopped = False
        self.tick()
        response.success = True
        response.message = f"stepped to t = {self.world.time:.9f} s (tick {self.world.ticks})"
        return response

    def _on_clear_wrenches(self, request, response):
        active, pending = self.world.wrenches.active, len(self._pending)
        self.world.clear_wrenches()
        self._pending.clear()
        self._event({"event": "service", "name": "clear_wrenches", "cleared": active + pending})
        response.success = True
        response.message = f"cleared {active} active wrench(es) and {pending} pending command(s)"
        return response

    # ---- parameters at run time --------------------------------------------------------------------------

    def _on_set_parameters(self, parameters) -> SetParametersResult:
        for param in parameters:
            spec = itf.PARAMETER_BY_NAME.get(param.name)
            if spec is None:
                continue
            problem = _check_parameter(spec, param.value)
            if problem:
                return SetParametersResult(successful=False, reason=problem)
        for param in parameters:
            if param.name not in itf.PARAMETER_BY_NAME:
                continue
            self.params[param.name] = _coerce(itf.PARAMETER_BY_NAME[param.name], param.value)
            if param.name == "rate_hz":
                self.world.set_dt(1.0 / param.value)
            if param.name in ("rate_hz", "realtime"):
                self._timer.cancel()
                self.destroy_timer(self._timer)
                self._timer = self.create_timer(self._timer_period(), self._on_timer)
                self._window_start = None  # the rate check starts over at the new rate
        if any(param.name in ("rate_hz", "markers_every", "fish_detail") for param in parameters):
            self._replan_detail()
        if any(param.name == "pin_threads" for param in parameters):
            self._place_threads()
        return SetParametersResult(successful=True)

    def _replan_detail(self) -> None:
        """A parameter the level of detail depends on changed: new plan, logged, on ~/events and in the bag
        (whose ``custom_data`` also holds the rate the plan is for)."""
        before = self.detail
        self._plan_detail()
        if (before.fish_detail, before.markers_every, before.flock_poses_every, before.rate_hz) == \
                (self.detail.fish_detail, self.detail.markers_every, self.detail.flock_poses_every,
                 self.detail.rate_hz):
            return
        self.get_logger().info("level of detail changed: " + " ".join(self.detail.lines))
        self._retire_markers()  # fewer parts: the flock's last ones are no longer drawn
        if self.recorder is not None:
            self.recorder.set_custom_data(self._detail_custom_data())
        self._event(self.detail.event())

    # ---- shutdown ----------------------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the Foxglove server, finish the recording (summary, metadata.yaml) and the progress line; safe to
        call twice."""
        if self.foxglove is not None:
            self.foxglove.close()
        if self._progress is not None:
            self._progress[0].finish()
        if self.recorder is not None:
            self.recorder.close()

    def destroy_node(self) -> None:
        """rclpy's ``destroy_node`` plus what it leaves behind: the ``simulate_steps`` action server.  rclpy
        destroys a node's publishers, subscriptions, services, timers and guard conditions, but not its action
        servers, and a live action server keeps the rcl node, and with it the process's DDS participant, alive
        until the process exits.  Fast DDS then deletes that participant from a static destructor while its
        threads still handle other participants leaving — seen as a node hanging at exit at full CPU, or
        aborting with "malloc_consolidate(): unaligned fastbin chunk detected", when several nodes on one
        domain stop at once."""
        self.sim.close()
        if hasattr(self, "_thread_placement"):
            self._thread_placement.release()
        super().destroy_node()


def _resolve_bag_path(text: str) -> Path:
    """The absolute bag directory ``text`` names, resolved as the OS resolves it (``~``, symlinks, ``..``)."""
    path = Path(text).expanduser()
    try:
        return path.resolve()
    except (OSError, RuntimeError):  # a symlink loop, ...: left for the recorder to report
        return path.absolute()


def _constraints(spec: itf.ParameterSpec) -> str:
    text = type(spec.default).__name__
    if spec.choices is not None:
        text += f", one of {', '.join(spec.choices)}"
    if spec.minimum is not None:
        text += f", >= {spec.minimum:g}"
    if spec.maximum is not None:
        text += f", <= {spec.maximum:g}"
    return text


def _brief(value, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


def _coerce(spec: itf.ParameterSpec, value):
    return float(value) if isinstance(spec.default, float) else value


def _check_parameter(spec: itf.ParameterSpec, value) -> str | None:
    """Why ``value`` is not acceptable for ``spec`` (None if it is)."""
    expected = type(spec.default)
    if expected is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, expected) or (expected is int and isinstance(value, bool)):
        return f"{spec.name} must be {expected.__name__}, got {type(value).__name__} {_brief(value)}"
    if isinstance(value, float) and not math.isfinite(value):
        return f"{spec.name} must be finite, got {value}"
    if spec.choices is not None and value not in spec.choices:
        return f"{spec.name} must be one of {', '.join(spec.choices)}, got {_brief(value)}"
    if spec.minimum is not None and value < spec.minimum:
        return f"{spec.name} must be >= {spec.minimum:g}, got {value}"
    if spec.maximum is not None and value > spec.maximum:
        return f"{spec.name} must be <= {spec.maximum:g}, got {value}"
    return None

"""The cgp_sim node: a thin, timer-driven adapter between ``cgp_core.World`` and the ROS graph.

Per tick (one timer callback): drain the validated wrench commands into the world → ``World.step()`` →
serialize the state once per message (numpy-built CDR, :mod:`cgp_sim_ros.messages`) → publish those bytes and
hand the same bytes to the recorder.  No physics here: every equation lives in ``cgp_core``.

Threading: one single-threaded executor runs the timer, the subscriptions and the services, so they never
interleave with a step and need no locks.  The bag is written on its own thread (:mod:`cgp_sim_ros.bag`).
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
import json
import math
import time
from pathlib import Path

import numpy as np
import rclpy
from rcl_interfaces.msg import ParameterDescriptor, ParameterType, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger

from cgp_core.scene import SceneError
from cgp_core.world import World
from cgp_core.wrenches import MAX_NAME_LENGTH, WrenchError, make_command

from . import interface as itf
from .flock_stats import FlockStatsPublishers
from .messages import TickMessages

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
        self.paused = bool(self.params["start_paused"])
        self._pending: collections.deque = collections.deque()
        self._dropped_commands = 0
        self._rejections: collections.Counter = collections.Counter()
        self._last_rejection: dict[tuple[str, str, str], str] = {}  # (source, field, kind) -> last reason
        self._delete_all_markers = False
        #: set when `duration` is reached; the main loop then shuts the node down
        self.finished = False

        self._make_publishers()
        self._make_subscriptions()
        self._make_services()

        self.recorder = None
        if self.bag_path is not None:
            self._start_recording(self.bag_path)

        self._tick_wall_times: collections.deque = collections.deque(maxlen=512)
        self._window_start = time.monotonic()
        self._window_ticks = 0
        self._timer = self.create_timer(self._timer_period(), self._on_timer)
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
        world = self.world
        self.pub_clock = self.create_publisher(self.messages.Clock, itf.TOPIC_CLOCK, itf.CLOCK_QOS)
        self.pub_body_poses = self.create_publisher(self.messages.PoseArray, itf.TOPIC_BODY_POSES, itf.STATE_QOS)
        self.pub_odom = [self.create_publisher(self.messages.Odometry, itf.TOPIC_BODY_ODOM.format(body=name),
                                               itf.STATE_QOS) for name in world.body_model.names]
        self.pub_flock_poses = [self.create_publisher(self.messages.PoseArray,
                                                      itf.TOPIC_FLOCK_POSES.format(flock=f.params.name),
                                                      itf.STATE_QOS) for f in world.flocks]
        self.pub_markers = self.create_publisher(self.messages.MarkerArray, itf.TOPIC_MARKERS, itf.STATE_QOS)
        self.flock_stats = FlockStatsPublishers(self, world)  # issue 14: ~/flocks/<flock>/stats
        self.pub_events = self.create_publisher(String, itf.TOPIC_EVENTS, itf.COMMAND_QOS)

    def _make_subscriptions(self) -> None:
        from cgp_sim_msgs.msg import ApplyWrench
        from geometry_msgs.msg import WrenchStamped

        self._apply_wrench_type = ApplyWrench
        self._wrench_stamped_type = WrenchStamped
        self.sub_apply_wrench = self._command_subscription(ApplyWrench, itf.TOPIC_APPLY_WRENCH,
                                                           self._on_apply_wrench)
        self.sub_body_wrench = {}
        for name, fixed in zip(self.world.body_model.names, self.world.body_model.fixed):
            if fixed:
                continue
            self.sub_body_wrench[name] = self._command_subscription(
                WrenchStamped, itf.TOPIC_BODY_WRENCH.format(body=name),
                lambda data, body=name: self._on_body_wrench(body, data))

    def _command_subscription(self, msg_type, topic: str, handle):
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

        subscription = self.create_subscription(msg_type, topic, take_all, itf.COMMAND_QOS, raw=True)
        return subscription

    def _make_services(self) -> None:
        self.create_service(Trigger, itf.SERVICE_RESET, self._on_reset)
        self.create_service(SetBool, itf.SERVICE_PAUSE, self._on_pause)
        self.create_service(Trigger, itf.SERVICE_STEP, self._on_step)
        self.create_service(Trigger, itf.SERVICE_CLEAR_WRENCHES, self._on_clear_wrenches)

    def _start_recording(self, directory: Path) -> None:
        from .bag import BagExistsError
        from .recorder import Recorder

        try:
            self.recorder = Recorder(self, directory,
                                     max_bytes=self.params["bag_max_size"],
                                     max_duration_s=self.params["bag_max_duration"])
        except BagExistsError as exc:  # created between the check in __init__ and now
            raise ConfigError(f"bag: {exc}") from None

    def _timer_period(self) -> float:
        # realtime=false: a zero-period timer is always ready, so the executor runs ticks back to back while
        # still serving subscriptions and services in between.
        return 1.0 / self.params["rate_hz"] if self.params["realtime"] else 0.0

    # ---- the tick -----------------------------------------------------------------------------------------

    def _on_timer(self) -> None:
        if self.paused or self.finished:
            return
        self.tick()

    def tick(self) -> None:
        """One simulation tick: commands in, step, everything out."""
        start = time.perf_counter()
        self._apply_pending_commands()
        self.world.step()
        for event in self.world.take_events():
            (self.get_logger().error if event.level == "error" else self.get_logger().warn)(event.text)
            self._event({"event": "world", "level": event.level, "text": event.text})
        self._publish_state()
        self._tick_wall_times.append(time.perf_counter() - start)
        self._window_ticks += 1
        self._periodic_reports()
        duration = self.params["duration"]
        if duration > 0.0 and self.world.time_ns >= round(duration * 1e9) and not self.finished:
            self.finished = True
            self.get_logger().info(f"duration {duration:g} s of simulated time reached after {self.world.ticks} "
                                   "ticks; shutting down")

    def _publish_state(self) -> None:
        t = self.world.time_ns
        m = self.messages
        self._out(self.pub_clock, m.clock(t), t)
        self._out(self.pub_body_poses, m.body_poses(t), t)
        for pub, data in zip(self.pub_odom, m.body_odometry(t)):
            self._out(pub, data, t)
        for pub, data in zip(self.pub_flock_poses, m.flock_poses(t)):
            self._out(pub, data, t)
        self.flock_stats.publish(t, self._out)
        if self._delete_all_markers or self.world.ticks % self.params["markers_every"] == 0:
            self._out(self.pub_markers, m.markers(t, delete_all_first=self._delete_all_markers), t)
            self._delete_all_markers = False

    def _out(self, publisher, data: bytes, stamp_ns: int) -> None:
        """Publish serialized bytes and record the very same bytes."""
        publisher.publish(data)
        if self.recorder is not None:
            self.recorder.write(publisher.topic_name, data, stamp_ns)

    def _periodic_reports(self) -> None:
        now = time.monotonic()
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

    def _event(self, payload: dict) -> None:
        """Publish (and so record) one line on ~/events: the audit trail of what was done to the world."""
        payload = {"time": round(self.world.time, 9), **payload}
        msg = String(data=json.dumps(payload, separators=(",", ":")))
        self.pub_events.publish(msg)
        if self.recorder is not None:
            from rclpy.serialization import serialize_message

            self.recorder.write(self.pub_events.topic_name, serialize_message(msg), self.world.time_ns)

    # ---- services ----------------------------------------------------------------------------------------

    def _on_reset(self, request, response):
        self.world.reset()
        self._pending.clear()
        self._delete_all_markers = True
        self._event({"event": "service", "name": "reset"})
        response.success = True
        response.message = f"reset to the initial state of {self.world.scene.source} at t = {self.world.time:.9f} s"
        return response

    def _on_pause(self, request, response):
        self.paused = bool(request.data)
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
        return SetParametersResult(successful=True)

    # ---- shutdown ----------------------------------------------------------------------------------------

    def close(self) -> None:
        """Finish the recording (summary, metadata.yaml); safe to call twice."""
        if self.recorder is not None:
            self.recorder.close()


def _resolve_bag_path(text: str) -> Path:
    """The absolute bag directory ``text`` names, resolved as the OS resolves it (``~``, symlinks, ``..``)."""
    path = Path(text).expanduser()
    try:
        return path.resolve()
    except (OSError, RuntimeError):  # a symlink loop, ...: left for the recorder to report
        return path.absolute()


def _constraints(spec: itf.ParameterSpec) -> str:
    text = type(spec.default).__name__
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
    if spec.minimum is not None and value < spec.minimum:
        return f"{spec.name} must be >= {spec.minimum:g}, got {value}"
    if spec.maximum is not None and value > spec.maximum:
        return f"{spec.name} must be <= {spec.maximum:g}, got {value}"
    return None

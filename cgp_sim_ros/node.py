"""The cgp_sim node: a thin, timer-driven adapter between ``cgp_core.World`` and the ROS graph.

Per tick (one timer callback): drain the validated wrench commands into the world → ``World.step()`` →
serialize the state once per message (numpy-built CDR, :mod:`cgp_sim_ros.messages`) → publish those bytes and
hand the same bytes to the recorder.  No physics here: every equation lives in ``cgp_core``.

Threading: one single-threaded executor runs the timer, the subscriptions and the services, so they never
interleave with a step and need no locks.  The bag is written on its own thread (:mod:`cgp_sim_ros.bag`).
The interface (topics, QoS, parameters) is defined and documented in :mod:`cgp_sim_ros.interface`.
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
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger

from cgp_core.scene import SceneError
from cgp_core.world import World
from cgp_core.wrenches import WrenchError, make_command

from . import interface as itf
from .messages import TickMessages

#: commands waiting for the next tick; beyond this, the oldest are dropped (and counted, and reported)
MAX_PENDING_COMMANDS = 2000
#: how often (wall seconds) rejected-command reports and rate checks are summarized in the log
REPORT_PERIOD_S = 2.0

_PARAM_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
                float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING}


class ConfigError(ValueError):
    """A parameter value or scene the node cannot start with."""


class SimNode(Node):
    def __init__(self, *, parameter_overrides=None, node_name: str = "cgp_sim"):
        super().__init__(node_name, parameter_overrides=parameter_overrides)
        self._declare_parameters()
        self.params = {p.name: self.get_parameter(p.name).value for p in itf.PARAMETERS}
        problems = [msg for p in itf.PARAMETERS if (msg := _check_parameter(p, self.params[p.name]))]
        if problems:
            raise ConfigError("invalid parameters: " + "; ".join(problems))
        self.params = {p.name: _coerce(p, v) for p, v in zip(itf.PARAMETERS, self.params.values())}

        seed = self.params["seed"]
        try:
            self.world = World.from_scene(self.params["scene"], dt=1.0 / self.params["rate_hz"],
                                          substeps=self.params["substeps"] or None,
                                          seed=None if seed < 0 else seed)
        except SceneError as exc:
            raise ConfigError(f"scene: {exc}") from None

        self.messages = TickMessages(self.world, itf.WORLD_FRAME)
        self.paused = False
        self._pending: collections.deque = collections.deque()
        self._dropped_commands = 0
        self._rejections: collections.Counter = collections.Counter()
        self._last_rejection: dict[str, str] = {}
        self._delete_all_markers = False
        #: set when `duration` is reached; the main loop then shuts the node down
        self.finished = False

        self._make_publishers()
        self._make_subscriptions()
        self._make_services()

        self.recorder = None
        if self.params["bag"]:
            self._start_recording(self.params["bag"])

        self._tick_wall_times: collections.deque = collections.deque(maxlen=512)
        self._window_start = time.monotonic()
        self._window_ticks = 0
        self._timer = self.create_timer(self._timer_period(), self._on_timer)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        counts = f"{self.world.body_model.count} bodies, " + ", ".join(
            f"flock {f.params.name} ({len(f.positions)} boids)" for f in self.world.flocks) if self.world.flocks \
            else f"{self.world.body_model.count} bodies"
        self.get_logger().info(
            f"scene {self.world.scene.source}: {counts}; {self.params['rate_hz']:g} Hz × {self.world.substeps} "
            f"substeps, integrator {self.world.scene.world.integrator}, "
            f"{'real time' if self.params['realtime'] else 'as fast as possible'}"
            + (f", recording to {self.recorder.directory}" if self.recorder else ""))

    # ---- set-up -----------------------------------------------------------------------------------------

    def _declare_parameters(self) -> None:
        for p in itf.PARAMETERS:
            # Floats are declared with dynamic typing so `-p rate_hz:=60` (an integer to the ROS parser) is
            # accepted and converted instead of failing with a type error.
            is_float = isinstance(p.default, float)
            descriptor = ParameterDescriptor(
                name=p.name, type=ParameterType.PARAMETER_NOT_SET if is_float else _PARAM_TYPES[type(p.default)],
                description=p.description, read_only=p.read_only, dynamic_typing=is_float)
            self.declare_parameter(p.name, p.default, descriptor)

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
        self.pub_events = self.create_publisher(String, itf.TOPIC_EVENTS, itf.COMMAND_QOS)

    def _make_subscriptions(self) -> None:
        from cgp_sim_msgs.msg import ApplyWrench
        from geometry_msgs.msg import WrenchStamped

        self._apply_wrench_type = ApplyWrench
        self.sub_apply_wrench = self.create_subscription(
            ApplyWrench, itf.TOPIC_APPLY_WRENCH, self._on_apply_wrench, itf.COMMAND_QOS, raw=True)
        self.sub_body_wrench = {}
        for name, fixed in zip(self.world.body_model.names, self.world.body_model.fixed):
            if fixed:
                continue
            self.sub_body_wrench[name] = self.create_subscription(
                WrenchStamped, itf.TOPIC_BODY_WRENCH.format(body=name),
                lambda data, body=name: self._on_body_wrench(body, data), itf.COMMAND_QOS, raw=True)
        self._wrench_stamped_type = WrenchStamped

    def _make_services(self) -> None:
        self.create_service(Trigger, itf.SERVICE_RESET, self._on_reset)
        self.create_service(SetBool, itf.SERVICE_PAUSE, self._on_pause)
        self.create_service(Trigger, itf.SERVICE_STEP, self._on_step)
        self.create_service(Trigger, itf.SERVICE_CLEAR_WRENCHES, self._on_clear_wrenches)

    def _start_recording(self, directory: str) -> None:
        from .recorder import Recorder

        self.recorder = Recorder(self, Path(directory).expanduser(),
                                 max_bytes=self.params["bag_max_size"],
                                 max_duration_s=self.params["bag_max_duration"])

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
        self._report_rejections()
        if self.recorder is not None:
            self.recorder.report_errors()
        self._window_start, self._window_ticks = now, 0

    # ---- commands -----------------------------------------------------------------------------------------

    def _on_apply_wrench(self, data: bytes) -> None:
        self._record_received(self.sub_apply_wrench.topic_name, data)
        try:
            msg = deserialize_message(data, self._apply_wrench_type)
            if msg.duration.nanosec >= 1_000_000_000:
                raise WrenchError("duration.nanosec", f"must be < 1e9, got {msg.duration.nanosec}")
            command = make_command(
                self.world.body_model.names, msg.body,
                force=(msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z),
                torque=(msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z),
                point=(msg.point.x, msg.point.y, msg.point.z), frame=msg.header.frame_id,
                duration=msg.duration.sec + 1e-9 * msg.duration.nanosec,
                max_force=self.params["max_force"], max_torque=self.params["max_torque"],
                fixed=self.world.body_model.fixed)
        except WrenchError as exc:
            self._reject("apply_wrench", str(exc))
            return
        except Exception as exc:  # undecodable bytes: a peer with a mismatched definition
            self._reject("apply_wrench", f"cannot decode message: {exc}")
            return
        self._enqueue(command)

    def _on_body_wrench(self, body: str, data: bytes) -> None:
        self._record_received(self.sub_body_wrench[body].topic_name, data)
        try:
            msg = deserialize_message(data, self._wrench_stamped_type)
            command = make_command(
                self.world.body_model.names, body,
                force=(msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z),
                torque=(msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z),
                point=None, frame=msg.header.frame_id, duration=0.0,
                max_force=self.params["max_force"], max_torque=self.params["max_torque"])
        except WrenchError as exc:
            self._reject(f"bodies/{body}/wrench", str(exc))
            return
        except Exception as exc:
            self._reject(f"bodies/{body}/wrench", f"cannot decode message: {exc}")
            return
        self._enqueue(command)

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
            self._reject("apply_wrench", f"{len(commands) - accepted} wrench(es) over the limit of "
                         f"{self.world.wrenches.max_active} active wrenches (clear some with ~/clear_wrenches)")

    def _reject(self, source: str, reason: str) -> None:
        """Count a rejected command; the first of a kind is logged at once, the rest summarized periodically."""
        key = f"{source}: {reason.split(':')[0]}"
        if self._rejections[key] == 0 and key not in self._last_rejection:
            self.get_logger().warn(f"rejected {source} command: {reason}")
        self._rejections[key] += 1
        self._last_rejection[key] = reason

    def _report_rejections(self) -> None:
        if self._dropped_commands:
            self.get_logger().warn(f"command flood: dropped the {self._dropped_commands} oldest pending wrench "
                                   f"commands (more than {MAX_PENDING_COMMANDS} arrived within one tick)")
            self._event({"event": "dropped_commands", "count": self._dropped_commands})
            self._dropped_commands = 0
        for key, count in self._rejections.items():
            if count:
                self.get_logger().warn(f"rejected {count} {key.split(':')[0]} command(s) in the last "
                                       f"{REPORT_PERIOD_S:g} s; last reason: {self._last_rejection[key]}")
                self._event({"event": "rejected", "source": key.split(":")[0], "count": count,
                             "reason": self._last_rejection[key]})
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
        response.message = f"reset to the initial state of {self.world.scene.source} at t = {self.world.time:.6f} s"
        return response

    def _on_pause(self, request, response):
        self.paused = bool(request.data)
        self._event({"event": "service", "name": "pause", "data": self.paused})
        response.success = True
        response.message = f"{'paused' if self.paused else 'running'} at t = {self.world.time:.6f} s"
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
        count = self.world.wrenches.active + len(self._pending)
        self.world.clear_wrenches()
        self._pending.clear()
        self._event({"event": "service", "name": "clear_wrenches", "cleared": count})
        response.success = True
        response.message = f"cleared {count} wrench(es)"
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


def _coerce(spec: itf.ParameterSpec, value):
    return float(value) if isinstance(spec.default, float) else value


def _check_parameter(spec: itf.ParameterSpec, value) -> str | None:
    """Why ``value`` is not acceptable for ``spec`` (None if it is)."""
    expected = type(spec.default)
    if expected is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, expected) or (expected is int and isinstance(value, bool)):
        return f"{spec.name} must be {expected.__name__}, got {type(value).__name__} {value!r}"
    if isinstance(value, float) and not math.isfinite(value):
        return f"{spec.name} must be finite, got {value}"
    if spec.minimum is not None and value < spec.minimum:
        return f"{spec.name} must be >= {spec.minimum:g}, got {value}"
    if spec.maximum is not None and value > spec.maximum:
        return f"{spec.name} must be <= {spec.maximum:g}, got {value}"
    return None

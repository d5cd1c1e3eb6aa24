"""Live view: a Foxglove WebSocket server inside the node (the Foxglove SDK, PyPI ``foxglove-sdk``).

Started by the node when the parameter ``foxglove`` is true (``foxglove_host``, ``foxglove_port``); the Foxglove
app connects with "Open connection" → Foxglove WebSocket → ``ws://localhost:8765``.  What a client gets:

- **Channels**: one per topic the node publishes or takes commands on (the topics the bag records), each with
  message encoding ``cdr`` and the schema ``pkg/msg/Type`` in ``ros2msg`` with the bag's concatenated definition
  (:func:`cgp_sim_ros.wire.schemas.message_definition`).  The messages are the very bytes the node publishes
  on DDS, handed over in :meth:`cgp_sim_ros.ros.publishing.TickPublisher.publish` (no second serialization),
  stamped with the tick's simulation time; the command topics carry every command the node received (over DDS
  or from a Foxglove client), as the bag does.
  A channel no client subscribes to costs one ``Channel.has_sinks()`` call (~50 ns) and nothing else.
- **Time** (capability ``time``): the simulation time, broadcast with the first message of each tick anyone
  subscribed to (and to a new subscriber at once, even while paused), so the app's timeline follows ``/clock``;
  never backwards (a reset keeps the clock).  The SDK queues time messages apart from message data (a
  control and a data queue per client, sent in whichever order its writer picks), so a client can get a tick's
  messages just before that tick's time: the app's receive time of a live message may be one tick off; header
  stamps and log times are exact.
- **Client publishing** (``clientPublish``, encodings ``cdr`` and ``json``) on the command topics
  (``~/apply_wrench``, ``~/bodies/<body>/wrench``), and the node's **services** (:data:`EXPOSED_SERVICES`,
  ``cdr`` requests).  Both are handed to the node's executor and run by the node's own callbacks: the same
  validation, rejection reports (log + ``~/events``) and recording as DDS commands and service calls.  The
  app's Publish panel takes the first of the server's encodings it knows (``cdr``) and writes the message from
  the definitions it has seen on channels: that the command topics are channels too is what lets it write
  ``WrenchStamped`` and ``ApplyWrench`` (the Python SDK cannot send the ``ROS_DISTRO`` metadata that would give
  it the common ROS types).

Threads: the SDK calls the listener, the service handlers and its log records on its own threads.  They only
append to a bounded inbox and trigger a guard condition; the node's single-threaded executor drains the inbox
between ticks (:meth:`FoxgloveServer._drain`), so nothing touches the world concurrently with a tick.  A service
handler then waits (at most :data:`SERVICE_TIMEOUT_S`) for the executor's answer.

Bad clients, and what they get:

- a message on a topic that takes no commands, in an encoding other than ``cdr``/``json``, with a schema other
  than the topic's type, larger than any valid command, or that does not decode: rejected through the node's
  reject path (one warning at once per kind, then a count every 2 s, also on ``~/events``); a refused channel
  also gets a status message in the app;
- protocol errors the SDK itself refuses (an unknown client channel id, an unparsable JSON or binary message):
  the SDK answers the client with an error status, and its log record goes the same reject path;
- a flood: at most :data:`MAX_INBOX` client messages wait for the executor (the oldest are dropped and
  reported), the executor spends at most ``COMMAND_BATCH_S`` per turn on them (ticks come first), and the
  node's own pending-command bound still applies.  Each message still costs a call into Python on an SDK
  thread (the GIL): 20,000 messages a second cost the default scene's tick about 1 ms;
- a slow or stalled reader: the SDK queues at most :data:`CLIENT_BACKLOG` messages per client, dropping the
  oldest; a client that stops reading stays connected (SDK 0.30.3 drops no client for time messages piling up)
  and costs the node that queue and its socket buffers.  Logging on a channel never waits for a client
  (``benchmarks/bench_foxglove.py`` measures all of this).

The SDK 0.30.3 accepts only the WebSocket subprotocol ``foxglove.sdk.v1`` (the current Foxglove app offers it);
clients that offer only ``foxglove.websocket.v1`` are refused with HTTP 400 during the handshake.
"""

from __future__ import annotations

import collections
import json
import logging
import threading
import time
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeoutError
from dataclasses import dataclass

import foxglove
from foxglove import Channel, Context, MessageSchema, Schema, Service, ServiceSchema, StatusLevel
from foxglove.websocket import Capability, ServerListener
from rclpy.qos import DurabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message

from cgp_core.wrenches import WrenchError

from .. import interface as itf
from ..interface import COMMAND_BATCH_S, MAX_COMMAND_BYTES, MAX_PENDING_COMMANDS, REPORT_PERIOD_S
from ..wire.schemas import message_definition, normalize_type_name, service_definitions
from .recorder import INFRASTRUCTURE_TOPICS, type_name

#: The node's services a Foxglove client may call, named as the node creates them: one line each (e.g. the
#: simulation_interfaces services, once the node offers them).  Request and response schemas, decoding and the
#: hand-over to the node's own callback follow from the service's type.
EXPOSED_SERVICES: tuple[str, ...] = (
    itf.SERVICE_RESET,
    itf.SERVICE_PAUSE,
    itf.SERVICE_STEP,
    itf.SERVICE_CLEAR_WRENCHES,
)
#: Encodings clients may publish in, in the order the Foxglove app picks from (it takes the first it supports):
#: ``cdr``, which the app writes from the definitions of our command channels; ``json`` for clients without them.
SUPPORTED_ENCODINGS = ["cdr", "json"]
#: Messages the SDK queues per client before it drops the oldest (its control queue of statuses and service
#: responses has the same bound, past which the SDK disconnects the client).  ~30 ticks of the default scene's
#: ~10 messages per tick; the memory a stalled client can hold is this many of the node's messages.
CLIENT_BACKLOG = 300
#: Client messages and service calls waiting for the executor; beyond it the oldest are dropped and reported.
MAX_INBOX = MAX_PENDING_COMMANDS
#: A JSON command is longer than its CDR form (field names, numbers as text): the bound for those.
MAX_JSON_COMMAND_BYTES = 4 * MAX_COMMAND_BYTES
#: Client channels remembered at once (over all clients); more advertisements are refused.
MAX_CLIENT_CHANNELS = 1000
#: How long a service call from a client waits for the node's executor.
SERVICE_TIMEOUT_S = 10.0
#: The ``source`` of rejections reported for Foxglove clients (the node's per-topic sources are kept for
#: commands that reach the node's own command handlers).
SOURCE = "foxglove"
#: SDK log records that are a client's bad input (reported as rejections); other records are logged as they are.
_BAD_INPUT_RECORDS = ("Received message for unknown channel", "Invalid message", "Failed to parse",
                      "attempted to subscribe")


class FoxgloveServerError(RuntimeError):
    """The server cannot start (address in use, unknown host...)."""


@dataclass(frozen=True)
class _Route:
    """Where an accepted client channel's messages go: a command input of the node."""

    topic: str
    encoding: str
    msg_type: type
    handle: object  # the node's command handler: serialized CDR bytes -> None


class FoxgloveServer:
    """The node's Foxglove WebSocket server (see the module docstring).  ``port`` 0 = any free port (``.port``)."""

    def __init__(self, node, host: str, port: int, name: str | None = None):
        self.node = node
        self._closed = False
        self._context = Context()  # our own: channels reach our server only, not the SDK's global sinks

        # ---- outbound: one channel per topic the node publishes or takes (what the bag records)
        self._channels: dict[str, Channel] = {}
        for endpoint in [*node.publishers, *node.subscriptions]:
            topic = endpoint.topic_name
            if topic in INFRASTRUCTURE_TOPICS or topic in self._channels:
                continue
            schema_name = type_name(endpoint.msg_type)
            schema = Schema(name=schema_name, encoding="ros2msg", data=message_definition(schema_name).encode())
            self._channels[topic] = Channel(topic, schema=schema, message_encoding="cdr", context=self._context)
        #: the node's publishers -> their channels (a dict lookup by object is ~20x cheaper than .topic_name)
        self._by_publisher = {p: self._channels[p.topic_name] for p in node.publishers
                              if p.topic_name in self._channels}
        self._time_sent = -1  # the last simulation time broadcast [ns]
        #: the latched topics' (transient local: /tf_static, ~/static_markers) last message, (data, stamp), sent
        #: again when a client subscribes to their channel, as DDS gives a late subscriber the last one
        self._latched: dict[str, tuple[bytes, int]] = {}

        # ---- inbound: client channels -> the node's command inputs; everything through one bounded inbox
        self._commands = dict(node.command_inputs)  # topic -> (msg type, handler of CDR bytes)
        self._client_channels: dict[tuple[int, int], _Route | WrenchError] = {}
        self._inbox: collections.deque = collections.deque()
        self._inbox_lock = threading.Lock()
        self._inbox_dropped = 0
        self._status_sent: dict[tuple[str, str], float] = {}
        self._wake = node.create_guard_condition(self._drain)

        # The SDK logs through Python's logging ("foxglove.*", via pyo3-log): its warnings and errors go to the
        # node (see _SdkLog).  Not INFO: the SDK logs some records while holding a lock the tick's
        # Channel.log also takes, and a record that reaches Python needs the GIL the tick holds.
        self._sdk_logger = logging.getLogger("foxglove")
        self._log_handler = _SdkLog(self)
        self._sdk_logger.addHandler(self._log_handler)
        self._sdk_logger.setLevel(logging.WARNING)
        self._sdk_logger.propagate = False

        services = self._services()
        try:
            self.server = foxglove.start_server(
                name=name or node.get_fully_qualified_name(), host=host, port=port, context=self._context,
                capabilities=[Capability.ClientPublish, Capability.Services, Capability.Time],
                supported_encodings=SUPPORTED_ENCODINGS, services=services, server_listener=_Listener(self),
                message_backlog_size=CLIENT_BACKLOG)
        except RuntimeError as exc:
            self._release()
            reason = str(exc).removeprefix("FoxgloveError: ")
            raise FoxgloveServerError(f"cannot listen on {host}:{port}: {reason} (choose another port with "
                                      "--foxglove-port, 0 = any free port)") from None
        self.port = self.server.port
        shown_host = "localhost" if host in ("127.0.0.1", "localhost", "::1") else host
        self.url = f"ws://{shown_host}:{self.port}"
        node.get_logger().info(
            f"Foxglove live view on {self.url}: in the Foxglove app, Open connection → Foxglove WebSocket → "
            f"{self.url} (or open {self.server.app_url()}); layout: msgs_config/foxglove/cgp_sim_layout.json")

    def follow_endpoints(self, added) -> None:
        """After the node's entities changed (spawn, delete, reset: :meth:`SimNode.world_edited`): a channel for
        each new publisher's or subscription's topic (a topic seen before keeps its channel), the publishers that
        are gone no longer mapped, and the command inputs as the node has them now.  The node's thread."""
        for endpoint in added:
            topic = endpoint.topic_name
            if topic not in INFRASTRUCTURE_TOPICS and topic not in self._channels:
                schema_name = type_name(endpoint.msg_type)
                schema = Schema(name=schema_name, encoding="ros2msg", data=message_definition(schema_name).encode())
                self._channels[topic] = Channel(topic, schema=schema, message_encoding="cdr", context=self._context)
        live = set(self.node.publishers)
        self._by_publisher = {p: self._channels[p.topic_name] for p in live if p.topic_name in self._channels}
        self._commands = dict(self.node.command_inputs)  # replaced whole: the SDK's threads read it

    # ---- outbound (the node's thread, per message) ------------------------------------------------------

    def listening(self, publisher) -> bool:
        """Whether a client is subscribed to ``publisher``'s channel (what the node computes only on demand)."""
        channel = self._by_publisher.get(publisher)
        return channel is not None and channel.has_sinks()

    def publish(self, publisher, data: bytes, stamp_ns: int) -> None:
        """The bytes ``publisher`` just published, to the clients subscribed to its channel (if any); a latched
        topic's are kept for the clients that subscribe later."""
        channel = self._by_publisher.get(publisher)
        if channel is not None and publisher.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL:
            self._latched[publisher.topic_name] = (data, stamp_ns)
        if channel is not None and channel.has_sinks():
            self._log(channel, data, stamp_ns)

    def received(self, topic: str, data: bytes, stamp_ns: int) -> None:
        """A command the node received on ``topic`` (as recorded), to the clients subscribed to it."""
        channel = self._channels.get(topic)
        if channel is not None and channel.has_sinks():
            self._log(channel, data, stamp_ns)

    def _log(self, channel: Channel, data: bytes, stamp_ns: int) -> None:
        if stamp_ns > self._time_sent:  # the tick's time, queued before its first message
            self._time_sent = stamp_ns
            self.server.broadcast_time(stamp_ns)
        channel.log(data, log_time=stamp_ns)  # queued per client; never waits for a client

    # ---- inbound (SDK threads: only classify, append, wake the executor) ---------------------------------

    def _advertised(self, client_id: int, channel) -> None:
        key = (client_id, channel.id)
        route = self._route(channel)
        if len(self._client_channels) >= MAX_CLIENT_CHANNELS and key not in self._client_channels:
            route = WrenchError("channel", f"client {client_id} advertised {channel.topic!r} beyond "
                                f"{MAX_CLIENT_CHANNELS} client channels; refused", "too many")
        else:
            self._client_channels[key] = route
        if isinstance(route, WrenchError):
            self._put(("refused", client_id, route))

    def _unadvertised(self, client_id: int, channel_id: int) -> None:
        self._client_channels.pop((client_id, channel_id), None)

    def _route(self, channel) -> _Route | WrenchError:
        """Where a client channel's messages go, or why they cannot go anywhere."""
        command = self._commands.get(channel.topic)
        if command is None:
            return WrenchError("topic", f"{_brief(channel.topic)} takes no commands (command topics: "
                               f"{_names(sorted(self._commands))})", "unknown")
        if channel.encoding not in SUPPORTED_ENCODINGS:
            return WrenchError("encoding", f"{_brief(channel.encoding)} on {channel.topic} (supported: "
                               f"{', '.join(SUPPORTED_ENCODINGS)})", "unsupported")
        msg_type, handle = command
        expected = type_name(msg_type)
        if not _same_type(channel.schema_name, expected):
            return WrenchError("schemaName", f"{_brief(channel.schema_name)} on {channel.topic}, which takes "
                               f"{expected}", "wrong type")
        return _Route(channel.topic, channel.encoding, msg_type, handle)

    def _message(self, client_id: int, channel_id: int, data: bytes) -> None:
        route = self._client_channels.get((client_id, channel_id))
        if not isinstance(route, _Route):
            why = "it was refused when advertised" if route is not None else "it was not accepted"
            self._put(("reject", WrenchError("channel", f"client {client_id} channel {channel_id}: {why}",
                                             "refused")))
            return
        limit = MAX_COMMAND_BYTES if route.encoding == "cdr" else MAX_JSON_COMMAND_BYTES
        if len(data) > limit:  # dropped here: the inbox never holds more than MAX_INBOX small messages
            self._put(("reject", WrenchError("message", f"{len(data)} bytes of {route.encoding} on {route.topic}, "
                                             f"more than any valid command ({limit} bytes); dropped unread",
                                             "too large")))
            return
        self._put(("command", route, data))

    def _call(self, service, request) -> bytes:
        """A client's service call (an SDK thread): decode, run the node's callback on its executor, encode."""
        try:
            request_msg = _decode_request(service.srv_type.Request, request.payload)
        except Exception as exc:  # noqa: BLE001 - undecodable bytes: tell the client, report like a bad command
            error = WrenchError("request", f"{service.service_name}: cannot decode {len(request.payload)} bytes "
                                f"as {_service_type_name(service.srv_type)} request: {exc}", "undecodable")
            self._put(("reject", error))
            raise ValueError(str(error)) from None
        future: Future = Future()
        self._put(("call", service, request_msg, future))
        try:
            response = future.result(timeout=SERVICE_TIMEOUT_S)
        except FutureTimeoutError:
            future.cancel()
            raise TimeoutError(f"{service.service_name}: the node did not answer within {SERVICE_TIMEOUT_S:g} s") \
                from None
        return serialize_message(response)

    def _put(self, item: tuple) -> None:
        if self._closed:
            if item[0] == "call":
                item[3].set_exception(RuntimeError("the node is shutting down"))
            return
        with self._inbox_lock:
            was_empty = not self._inbox
            if len(self._inbox) >= MAX_INBOX:
                dropped = self._inbox.popleft()
                self._inbox_dropped += 1
                if dropped[0] == "call" and dropped[3].set_running_or_notify_cancel():
                    dropped[3].set_exception(RuntimeError(f"dropped: more than {MAX_INBOX} client messages "
                                                          "were waiting"))
            self._inbox.append(item)
        if was_empty:
            self._wake.trigger()

    # ---- the executor's side ----------------------------------------------------------------------------

    def _drain(self) -> None:
        """Guard-condition callback (the node's executor): handle waiting client input, at most
        ``COMMAND_BATCH_S`` of it per turn (the rest on the next turn, after the timer had its chance)."""
        deadline = time.perf_counter() + COMMAND_BATCH_S
        while not self._closed:
            with self._inbox_lock:
                item = self._inbox.popleft() if self._inbox else None
                dropped, self._inbox_dropped = self._inbox_dropped, 0
            if dropped:
                self.node.report_rejection(SOURCE, WrenchError(
                    "message", f"more than {MAX_INBOX} client messages waiting for the simulation; dropped the "
                    f"{dropped} oldest", "flood"), count=dropped)
            if item is None:
                return
            self._handle(item)
            if time.perf_counter() > deadline:
                self._wake.trigger()
                return

    def _handle(self, item: tuple) -> None:
        kind = item[0]
        if kind == "command":
            _, route, data = item
            if route.encoding == "json":
                try:
                    data = serialize_message(_message_from_json(route.msg_type, data))
                except WrenchError as exc:
                    self.node.report_rejection(SOURCE, exc)
                    return
            route.handle(data)  # the node's command path: size, record, decode, validate, queue for the tick
        elif kind == "call":
            _, service, request, future = item
            if not future.set_running_or_notify_cancel():
                return  # the client's call timed out meanwhile
            try:
                future.set_result(service.callback(request, service.srv_type.Response()))
            except Exception as exc:  # noqa: BLE001 - the client gets the error, the node goes on
                future.set_exception(exc)
        elif kind == "reject":
            self.node.report_rejection(SOURCE, item[1])
        elif kind == "refused":
            _, client_id, error = item
            self.node.report_rejection(SOURCE, error)
            self._status(f"client {client_id}: refused channel: {error}", (error.field, error.kind))
        elif kind == "time":
            self._time_sent = max(self._time_sent, self.node.world.time_ns)
            self.server.broadcast_time(self._time_sent)
        elif kind == "latched":  # a client subscribed to a latched topic: its last message again
            latched, channel = self._latched.get(item[1]), self._channels.get(item[1])
            if latched is not None and channel is not None:
                self._log(channel, *latched)
        elif kind == "log":
            self.node.get_logger().warn(f"foxglove: {item[1]}")

    def _status(self, text: str, key: tuple[str, str]) -> None:
        """A warning in the clients' problem list, at most one per kind of problem every REPORT_PERIOD_S."""
        now = time.monotonic()
        if now - self._status_sent.get(key, -REPORT_PERIOD_S) >= REPORT_PERIOD_S:
            self._status_sent[key] = now
            self.server.publish_status(text, StatusLevel.Warning)

    # ---- services ---------------------------------------------------------------------------------------

    def _services(self) -> list[Service]:
        created = {service.srv_name: service for service in self.node.services}
        services = []
        for name in EXPOSED_SERVICES:
            service = created.get(name)
            if service is None:
                self.node.get_logger().warn(f"foxglove: the node has no service {name}; not offered to clients")
                continue
            srv = _service_type_name(service.srv_type)
            request_text, response_text = service_definitions(srv)
            schema = ServiceSchema(
                srv,
                request=MessageSchema(encoding="cdr", schema=Schema(
                    name=f"{srv}_Request", encoding="ros2msg", data=request_text.encode())),
                response=MessageSchema(encoding="cdr", schema=Schema(
                    name=f"{srv}_Response", encoding="ros2msg", data=response_text.encode())))
            services.append(Service(service.service_name, schema=schema,
                                    handler=lambda request, service=service: self._call(service, request)))
        return services

    # ---- shutdown ---------------------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the server (clients are disconnected); waiting service calls fail.  Safe to call twice."""
        if self._closed:
            return
        self._closed = True  # from now on _put turns calls away at once
        with self._inbox_lock:
            waiting, self._inbox = list(self._inbox), collections.deque()
        for item in waiting:  # before stopping: their handlers would otherwise hold the server's shutdown up
            if item[0] == "call" and item[3].set_running_or_notify_cancel():
                item[3].set_exception(RuntimeError("the node is shutting down"))
        self.server.stop()
        self._release()

    def _release(self) -> None:
        self._sdk_logger.removeHandler(self._log_handler)
        self._sdk_logger.propagate = True
        self.node.destroy_guard_condition(self._wake)


class _Listener(ServerListener):
    """The SDK's callbacks (its threads): hand everything to :class:`FoxgloveServer`'s inbox."""

    def __init__(self, server: FoxgloveServer):
        self._server = server

    def on_subscribe(self, client, channel) -> None:
        self._server._put(("time",))  # a new subscriber learns the time now, even while paused
        self._server._put(("latched", channel.topic))

    def on_client_advertise(self, client, channel) -> None:
        self._server._advertised(client.id, channel)

    def on_client_unadvertise(self, client, client_channel_id: int) -> None:
        self._server._unadvertised(client.id, client_channel_id)

    def on_message_data(self, client, client_channel_id: int, data: bytes) -> None:
        self._server._message(client.id, client_channel_id, data)


class _SdkLog(logging.Handler):
    """The SDK's warnings and errors (its threads): a client's bad input goes the node's reject path (throttled
    with the others), anything else to the node's log; both through the executor."""

    def __init__(self, server: FoxgloveServer):
        super().__init__(logging.WARNING)
        self._server = server

    def emit(self, record: logging.LogRecord) -> None:
        text = record.getMessage()
        if any(part in text for part in _BAD_INPUT_RECORDS):
            self._server._put(("reject", WrenchError("client message", text, "invalid")))
        else:
            self._server._put(("log", text))


# ---- decoding client input ------------------------------------------------------------------------------


def _decode_request(msg_type, payload: bytes):
    """A service request from CDR bytes.  A request without fields (``Trigger``'s) needs no bytes: clients
    send the 4-byte CDR header alone, which rclpy cannot read (it expects the placeholder byte rosidl adds)."""
    if not msg_type.get_fields_and_field_types():
        return msg_type()
    return deserialize_message(bytes(payload), msg_type)


def _message_from_json(msg_type, data: bytes):
    """The message a JSON object describes (fields left out keep their defaults; integers are accepted for
    floating-point fields); a :class:`WrenchError` naming the field otherwise."""
    try:
        value = json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise WrenchError("message", f"not JSON: {exc}", "undecodable") from None
    except RecursionError:  # [[[[...: json nests by recursion (found by tests/test_fuzz_inputs.py)
        raise WrenchError("message", "not JSON of a command: nested too deeply", "undecodable") from None
    if not isinstance(value, dict):
        raise WrenchError("message", f"must be a JSON object, got {type(value).__name__}", "undecodable")
    msg = msg_type()
    _fill(msg, value, "")
    try:
        serialize_message(msg)  # what rclpy's setters did not check (they are asserts, gone under python -O)
    except Exception as exc:  # noqa: BLE001
        raise WrenchError("message", f"cannot serialize: {exc}", "malformed") from None
    return msg


def _fill(msg, value: dict, prefix: str) -> None:
    fields = msg.get_fields_and_field_types()
    for key, item in value.items():
        field = f"{prefix}{key}"
        if key not in fields:
            raise WrenchError(field, f"{type(msg).__name__} has no field {_brief(key)} (fields: "
                              f"{', '.join(fields)})", "unknown field")
        current = getattr(msg, key)
        if hasattr(current, "get_fields_and_field_types"):
            if not isinstance(item, dict):
                raise WrenchError(field, f"must be an object, got {_brief(item)}", "malformed")
            _fill(current, item, field + ".")
            continue
        if fields[key] in ("double", "float") and isinstance(item, int) and not isinstance(item, bool):
            item = float(item)
        try:
            setattr(msg, key, item)
        except (AssertionError, TypeError, ValueError):
            raise WrenchError(field, f"{_brief(item)} is not a valid {fields[key]}", "malformed") from None


def _same_type(given: str, expected: str) -> bool:
    """``pkg/msg/Type`` and ``pkg/Type`` name the same message type."""
    try:
        return normalize_type_name(given) == normalize_type_name(expected)
    except ValueError:
        return False


def _service_type_name(srv_type) -> str:
    """``pkg/srv/Type`` of a generated rclpy service class."""
    return f"{srv_type.__module__.split('.')[0]}/srv/{srv_type.__name__}"


def _brief(value, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


def _names(names: list[str], limit: int = 4) -> str:
    return ", ".join(names[:limit]) + (f", ... ({len(names)} in all)" if len(names) > limit else "")

"""A Foxglove WebSocket client written from the protocol (foxglove/ws-protocol ``docs/spec.md``; subprotocol
``foxglove.sdk.v1``), for the tests and the benchmark: no Foxglove code, only the ``websockets`` package.

Server → client: JSON ``serverInfo``, ``advertise``, ``unadvertise``, ``status``, ``removeStatus``,
``advertiseServices``, ``unadvertiseServices``, ``serviceCallFailure``; binary, little-endian, first byte the
opcode: ``0x01`` message data (u32 subscription id, u64 log time [ns], payload), ``0x02`` time (u64 ns),
``0x03`` service call response (u32 service id, u32 call id, u32 encoding length, encoding, payload).
Client → server: JSON ``subscribe``, ``unsubscribe``, ``advertise``, ``unadvertise``; binary ``0x01`` message
data (u32 client channel id, payload), ``0x02`` service call request (u32 service id, u32 call id, u32 encoding
length, encoding, payload).

A reader thread parses everything the server sends; tests wait on it with deadlines (:meth:`wait`).

Run as a script, it is a peer process for the benchmark: ``python foxglove_client.py URL read|stall``
subscribes to every channel and then reads everything (``read``) or stops reading (``stall``; the socket
fills and the server's queues for it overflow), printing ``subscribed`` once it has subscribed;
``flood:<body>`` sends 20,000 non-finite wrenches a second on ``/cgp_sim/bodies/<body>/wrench``.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import struct
import sys
import threading
import time
from collections import defaultdict

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

SUBPROTOCOL = "foxglove.sdk.v1"


class ServiceCallFailed(Exception):
    """The server answered a service call with ``serviceCallFailure``."""


class FoxgloveClient:
    def __init__(self, url: str, *, subprotocol: str = SUBPROTOCOL, keep_messages: bool = True,
                 read: bool = True, open_timeout: float = 20.0):
        self.url = url
        self._stack = contextlib.ExitStack()  # websockets wants its connection used as a context manager
        self.ws = self._stack.enter_context(connect(url, subprotocols=[subprotocol], max_size=None,
                                                    open_timeout=open_timeout, max_queue=16 if read else 1))
        self.keep_messages = keep_messages
        self.server_info: dict | None = None
        self.channels: dict[int, dict] = {}  # channel id -> advertised channel
        self.services: dict[str, dict] = {}  # service name -> advertised service
        self.statuses: list[dict] = []
        self.times: list[int] = []
        #: subscription id -> [(log time, payload)] (when keep_messages)
        self.messages: dict[int, list[tuple[int, bytes]]] = defaultdict(list)
        self.message_count = 0
        self.message_bytes = 0
        #: time and message-data events in arrival order: ("time", t) / ("message", subscription id, log time)
        self.sequence: list[tuple] = []
        self.responses: dict[int, tuple[str, bytes] | ServiceCallFailed] = {}
        self.closed = False
        self._subscriptions: dict[int, int] = {}  # subscription id -> channel id
        self._ids = itertools.count(1)
        self._cond = threading.Condition()
        self._thread = None
        if read:
            self._thread = threading.Thread(target=self._read, daemon=True)
            self._thread.start()

    # ---- receiving ---------------------------------------------------------------------------------------

    def _read(self) -> None:
        try:
            for message in self.ws:
                with self._cond:
                    if isinstance(message, str):
                        self._on_json(json.loads(message))
                    else:
                        self._on_binary(message)
                    self._cond.notify_all()
        except ConnectionClosed:
            pass
        finally:
            with self._cond:
                self.closed = True
                self._cond.notify_all()

    def _on_json(self, msg: dict) -> None:
        op = msg["op"]
        if op == "serverInfo":
            self.server_info = msg
        elif op == "advertise":
            for channel in msg["channels"]:
                self.channels[channel["id"]] = channel
        elif op == "unadvertise":
            for channel_id in msg["channelIds"]:
                self.channels.pop(channel_id, None)
        elif op == "status":
            self.statuses.append(msg)
        elif op == "advertiseServices":
            for service in msg["services"]:
                self.services[service["name"]] = service
        elif op == "serviceCallFailure":
            self.responses[msg["callId"]] = ServiceCallFailed(msg["message"])

    def _on_binary(self, data: bytes) -> None:
        op = data[0]
        if op == 0x01:
            subscription, log_time = struct.unpack_from("<IQ", data, 1)
            self.message_count += 1
            self.message_bytes += len(data) - 13
            if self.keep_messages:
                self.messages[subscription].append((log_time, bytes(data[13:])))
                self.sequence.append(("message", subscription, log_time))
        elif op == 0x02:
            (timestamp,) = struct.unpack_from("<Q", data, 1)
            self.times.append(timestamp)
            if self.keep_messages:
                self.sequence.append(("time", timestamp))
        elif op == 0x03:
            _, call_id, length = struct.unpack_from("<III", data, 1)
            encoding = data[13:13 + length].decode()
            self.responses[call_id] = (encoding, bytes(data[13 + length:]))

    def wait(self, predicate, timeout: float, what: str):
        """Wait until ``predicate()`` (called under the reader's lock) is true; returns its value."""
        with self._cond:
            value = self._cond.wait_for(predicate, timeout)
            if not value:
                raise AssertionError(f"timed out after {timeout} s waiting for {what}")
            return value

    # ---- channels and subscriptions -----------------------------------------------------------------------

    def channel(self, topic: str, timeout: float = 20.0) -> dict:
        """The server channel advertised for ``topic`` (waits for the advertisement)."""
        def find():
            return next((c for c in self.channels.values() if c["topic"] == topic), None)
        return self.wait(find, timeout, f"a channel for {topic}")

    def subscribe(self, topic: str) -> int:
        channel = self.channel(topic)
        subscription = next(self._ids)
        with self._cond:
            self._subscriptions[subscription] = channel["id"]
        self._send_json({"op": "subscribe", "subscriptions": [{"id": subscription, "channelId": channel["id"]}]})
        return subscription

    def subscribe_all(self) -> list[int]:
        self.wait(lambda: self.channels, 20.0, "advertised channels")
        with self._cond:
            topics = [c["topic"] for c in self.channels.values()]
        return [self.subscribe(topic) for topic in topics]

    def received(self, subscription: int) -> list[tuple[int, bytes]]:
        with self._cond:
            return list(self.messages[subscription])

    # ---- publishing and services ------------------------------------------------------------------------

    def advertise(self, topic: str, encoding: str, schema_name: str, channel_id: int | None = None) -> int:
        channel_id = next(self._ids) if channel_id is None else channel_id
        self._send_json({"op": "advertise", "channels": [
            {"id": channel_id, "topic": topic, "encoding": encoding, "schemaName": schema_name}]})
        return channel_id

    def unadvertise(self, channel_id: int) -> None:
        self._send_json({"op": "unadvertise", "channelIds": [channel_id]})

    def publish(self, channel_id: int, payload: bytes) -> None:
        self.ws.send(struct.pack("<BI", 0x01, channel_id) + payload)

    def call_async(self, name: str, payload: bytes, encoding: str = "cdr") -> int:
        service = self.wait(lambda: self.services.get(name), 20.0, f"service {name}")
        call_id = next(self._ids)
        encoded = encoding.encode()
        self.ws.send(struct.pack("<BIII", 0x02, service["id"], call_id, len(encoded)) + encoded + payload)
        return call_id

    def call(self, name: str, payload: bytes, encoding: str = "cdr", timeout: float = 20.0) -> bytes:
        """Call a service; the response payload, or :class:`ServiceCallFailed` raised."""
        call_id = self.call_async(name, payload, encoding)
        response = self.wait(lambda: self.responses.get(call_id), timeout, f"the response of {name}")
        if isinstance(response, ServiceCallFailed):
            raise response
        return response[1]

    def _send_json(self, msg: dict) -> None:
        self.ws.send(json.dumps(msg))

    def close(self) -> None:
        self._stack.close()
        if self._thread is not None:
            self._thread.join(timeout=10)


def _peer(url: str, mode: str) -> None:
    import signal

    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # print the counts below when the benchmark stops us
    client = FoxgloveClient(url, keep_messages=False, read=(mode != "stall"))
    if mode == "read":
        client.subscribe_all()
    elif mode.startswith("flood:"):  # flood:<body>: 20,000 non-finite wrenches a second on its wrench topic
        from geometry_msgs.msg import WrenchStamped
        from rclpy.serialization import serialize_message

        command = WrenchStamped()
        command.wrench.force.x = float("inf")
        data = serialize_message(command)
        channel = client.advertise(f"/cgp_sim/bodies/{mode.split(':', 1)[1]}/wrench", "cdr",
                                   "geometry_msgs/msg/WrenchStamped")
        print("subscribed", flush=True)
        end = time.monotonic() + 600
        try:
            while time.monotonic() < end and not client.closed:
                batch_end = time.monotonic() + 0.01
                for _ in range(200):
                    client.publish(channel, data)
                time.sleep(max(0.0, batch_end - time.monotonic()))
        finally:
            client.close()
        return
    else:  # no reader thread: read the advertisement by hand, subscribe, then never read again
        channels = []
        while not channels:
            message = client.ws.recv(timeout=20)
            if isinstance(message, str) and json.loads(message)["op"] == "advertise":
                channels = json.loads(message)["channels"]
        client._send_json({"op": "subscribe", "subscriptions": [
            {"id": i + 1, "channelId": c["id"]} for i, c in enumerate(channels)]})
    print("subscribed", flush=True)
    end = time.monotonic() + 600  # a peer never outlives its benchmark for long
    try:
        while time.monotonic() < end and not client.closed:
            time.sleep(0.5)
    finally:
        print(f"received {client.message_count} messages, {client.message_bytes} bytes", flush=True)


if __name__ == "__main__":
    _peer(sys.argv[1], sys.argv[2])

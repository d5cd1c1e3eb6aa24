"""An observer node for tests: subscribe to what the simulator publishes, call its services, and wait for
things with deadlines (never fixed sleeps)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

RELIABLE_DEEP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.VOLATILE)


@dataclass
class Received:
    """Messages of one topic as they arrived, with the local receive time (monotonic seconds)."""

    messages: list = field(default_factory=list)
    times: list = field(default_factory=list)


class Probe:
    def __init__(self, name: str):
        self.node = Node(name)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.received: dict[str, Received] = {}
        self.subscriptions: dict = {}
        self._clients: dict = {}
        self._action_clients: list = []

    def action_client(self, action_type, name: str):
        """An rclpy ActionClient on the probe's node, destroyed by :meth:`close`."""
        from rclpy.action import ActionClient

        client = ActionClient(self.node, action_type, name)
        self._action_clients.append(client)
        return client

    def close(self) -> None:
        self.executor.remove_node(self.node)
        # rclpy's destroy_node leaves action clients alive, and with them the node and this process's DDS
        # participant, which Fast DDS would then delete at exit (see test_node_graph's participant test)
        for client in self._action_clients:
            client.destroy()
        self.node.destroy_node()

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.02, max(0.0, end - time.monotonic())))

    def spin_until(self, condition, timeout: float, what: str) -> None:
        end = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > end:
                raise AssertionError(f"timed out after {timeout} s waiting for {what}")
            self.executor.spin_once(timeout_sec=0.02)

    def subscribe(self, topic: str, msg_type, qos: QoSProfile = RELIABLE_DEEP, raw: bool = False) -> Received:
        box = Received()

        def callback(msg):
            box.messages.append(msg)
            box.times.append(time.monotonic())

        self.subscriptions[topic] = self.node.create_subscription(msg_type, topic, callback, qos, raw=raw)
        self.received[topic] = box
        return box

    def wait_until_matched(self, *topics: str, timeout: float = 30.0) -> None:
        """Wait until this probe's subscriptions to ``topics`` are *matched* with a publisher: DDS will deliver
        every sample published from now on (reliable QoS).  Seeing the publisher in the graph
        (:meth:`wait_for_publisher`) is not enough: graph discovery and reader-writer matching are separate
        protocols and either can come first.  Start the node paused, wait for this, then unpause, and the probe
        sees the run from its first tick, however long discovery took."""
        for topic in topics:
            subscription = self.subscriptions[topic]
            self.spin_until(lambda: subscription.get_publisher_count() > 0, timeout,
                            f"the subscription to {topic} to match a publisher")

    def wait_for_publisher(self, topic: str, timeout: float = 20.0) -> None:
        self.spin_until(lambda: self.node.count_publishers(topic) > 0, timeout, f"a publisher on {topic}")

    def wait_for_messages(self, topic: str, count: int, timeout: float = 20.0) -> list:
        box = self.received[topic]
        self.spin_until(lambda: len(box.messages) >= count, timeout, f"{count} messages on {topic} "
                        f"(got {len(box.messages)})")
        return box.messages

    def publisher(self, topic: str, msg_type, qos: QoSProfile = RELIABLE_DEEP):
        pub = self.node.create_publisher(msg_type, topic, qos)
        return pub

    def publish_acked(self, publisher, msg, timeout: float = 20.0) -> None:
        """Publish ``msg`` and wait until every matched reader has acknowledged it, i.e. it sits in the node's
        reader history.  A service request sent after this is handled after the message: rclpy's executor
        takes the ready subscriptions of a wait before its ready services.  (Without it, a command published
        just before a ``~/step`` may reach the node only after the step: a race, not a bug.)"""
        from rclpy.duration import Duration

        publisher.publish(msg)
        end = time.monotonic() + timeout
        while not publisher.wait_for_all_acked(Duration(seconds=0.05)):
            if time.monotonic() > end:
                raise AssertionError(f"the message on {publisher.topic_name} was not acknowledged in {timeout} s")
            self.executor.spin_once(timeout_sec=0.0)

    def wait_for_subscriber(self, publisher, timeout: float = 20.0) -> None:
        self.spin_until(lambda: publisher.get_subscription_count() > 0, timeout,
                        f"a subscriber on {publisher.topic_name}")

    def client(self, srv_type, name: str, timeout: float = 20.0):
        """One client per service for the probe's life (each new client is a new DDS discovery, see call)."""
        client = self._clients.get(name)
        if client is None:
            client = self._clients[name] = self.node.create_client(srv_type, name)
        self.spin_until(client.service_is_ready, timeout, f"service {name}")
        return client

    def call(self, srv_type, name: str, request, timeout: float = 20.0, *, idempotent: bool = True,
             attempt_timeout: float = 2.0):
        """Call a service and return its response, within ``timeout``.

        ``service_is_ready()`` can be true before the service's reply writer has matched this client's reply
        reader; a reply sent then is dropped by Fast DDS after ~100 ms ("client will not receive response",
        ros2/rmw_fastrtps#842, ros2/ros2#1253), and the future never completes.  An idempotent request is
        therefore re-sent when no reply came within ``attempt_timeout``; a late reply to an earlier attempt is
        ignored (replies are matched by sequence number).  A non-idempotent one (``~/step``) is sent once:
        warm its client up first with :meth:`warm_up`."""
        client = self.client(srv_type, name, timeout)
        end = time.monotonic() + timeout
        while True:
            future = client.call_async(request)
            attempt_end = min(end, time.monotonic() + (attempt_timeout if idempotent else timeout))
            while not future.done() and time.monotonic() < attempt_end:
                self.executor.spin_once(timeout_sec=0.02)
            if future.done():
                return future.result()
            client.remove_pending_request(future)
            if not idempotent or time.monotonic() >= end:
                raise AssertionError(f"timed out after {timeout} s waiting for a response from {name}")

    def warm_up(self, srv_type, name: str, request, timeout: float = 20.0) -> None:
        """Complete one call of a request that has no effect in the current state (e.g. ``~/step`` while the
        node runs), so that a later non-idempotent call of the same client cannot lose its reply."""
        self.call(srv_type, name, request, timeout)

    def topic_types(self) -> dict[str, list[str]]:
        return dict(self.node.get_topic_names_and_types())


def pause(probe: Probe, on: bool, node: str = "/cgp_sim") -> None:
    """Pause (or resume) the simulator.  Before pausing, the ``~/step`` client is warmed up with a step
    request while the node still runs (refused, without effect), so that the non-idempotent steps that follow
    cannot lose their replies to the discovery race described in :meth:`Probe.call`."""
    from std_srvs.srv import SetBool, Trigger

    if on:
        probe.warm_up(Trigger, f"{node}/step", Trigger.Request())
    response = probe.call(SetBool, f"{node}/pause", SetBool.Request(data=on))
    assert response.success, response.message


def step(probe: Probe, node: str = "/cgp_sim"):
    """One ``~/step`` of a paused simulator (sent once: a step is not idempotent)."""
    from std_srvs.srv import Trigger

    response = probe.call(Trigger, f"{node}/step", Trigger.Request(), idempotent=False)
    assert response.success, response.message
    return response


def odom_of_step(probe: Probe, messages: list, reply, what: str):
    """The odometry of the tick a ``~/step`` just took (``reply``: its response, "stepped to t = … s"), found by its
    stamp among ``messages`` — not the newest one received: one published just before the pause may arrive after
    the step's reply."""
    import re

    t = float(re.search(r"stepped to t = ([0-9.]+) s", reply.message).group(1))

    def of_step():
        return next((m for m in reversed(messages)
                     if abs(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 - t) < 1e-6), None)

    probe.spin_until(lambda: of_step() is not None, 10, what)
    return of_step()


class PeerProcess:
    """Another ROS process a test starts (a command flooder, a reader that stalls...): ``python -c code args``
    with its output in ``log_path``, which the test polls for the marker lines the code prints."""

    def __init__(self, code: str, args, log_path):
        import subprocess
        import sys

        self._log = open(log_path, "w+")
        self.proc = subprocess.Popen([sys.executable, "-c", code, *map(str, args)], stdout=self._log,
                                     stderr=subprocess.STDOUT)

    def output(self) -> str:
        self._log.seek(0)
        return self._log.read()

    def printed(self, marker: str) -> bool:
        return marker in self.output()

    def stop(self) -> str:
        """Kill it if it still runs (resuming it first if it was stopped); returns its output."""
        import signal

        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGCONT)
            self.proc.kill()
        self.proc.wait()
        output = self.output()
        self._log.close()
        return output

"""An observer node for tests: subscribe to what the simulator publishes, call its services, and wait for
things with deadlines (never fixed sleeps)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import rclpy
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

    def close(self) -> None:
        self.executor.remove_node(self.node)
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

        self.node.create_subscription(msg_type, topic, callback, qos, raw=raw)
        self.received[topic] = box
        return box

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

    def wait_for_subscriber(self, publisher, timeout: float = 20.0) -> None:
        self.spin_until(lambda: publisher.get_subscription_count() > 0, timeout,
                        f"a subscriber on {publisher.topic_name}")

    def call(self, srv_type, name: str, request, timeout: float = 20.0):
        client = self.node.create_client(srv_type, name)
        self.spin_until(client.service_is_ready, timeout, f"service {name}")
        future = client.call_async(request)
        self.spin_until(future.done, timeout, f"response from {name}")
        self.node.destroy_client(client)
        return future.result()

    def topic_types(self) -> dict[str, list[str]]:
        return dict(self.node.get_topic_names_and_types())

"""The node's second waiting thread: the command subscriptions (what arrives is handed to the node's executor as
raw bytes) and the publishers' QoS events.

Why: rclpy's executor rebuilds its wait set in Python on every spin, entity by entity (an ``ExitStack`` entry, a
``can_execute``, an ``add_*``, then the readiness check), and the node spins at least once per tick.  The node has
a wrench subscription per movable body (``~/bodies/<body>/wrench``) and two per robot, so with 100 bodies those
were ~100 of the wait set's ~160 entities, re-added every tick while no command arrives at all: ~1–3 ms of Python
per tick (benchmarks/README.md, "The executor's wait set").  rclpy's ``EventsExecutor`` would avoid that, but the
node's coroutine services do not answer under it (same section).  The QoS event handlers of the node's publishers
(rclpy's warnings about an incompatible subscriber: two waitables per publisher) were another 16 entities of it.

How: every command subscription (:meth:`CommandInbox.subscribe`) is in a callback group that only this module's
thread may execute (:class:`_InboxGroup`), so the node's executor leaves it out of its wait set.  The thread waits
on those subscriptions alone, with the GIL released, and rebuilds its wait set only when a command arrives or the
set changes.  It only *takes* the messages: their raw bytes go into a bounded inbox (at most
:data:`~cgp_sim_ros.interface.MAX_PENDING_COMMANDS`, the oldest dropped and reported as a flood), and a guard
condition wakes the node's executor, which hands them to their handlers — size check, recording, decoding,
validation, the pending queue (cgp_sim_ros/ros/commands.py) — at most ``COMMAND_BATCH_S`` of them per turn, so a
tick is never held up for long.  So everything that touches the world or the bag still runs on the executor's
thread, between ticks, in the order the commands were taken; the Foxglove live view hands its clients' commands
over the same way (cgp_sim_ros/ros/foxglove_server.py).  The publishers made through :meth:`CommandInbox.publisher`
have their QoS event handlers in the same group: this thread waits on them and logs rclpy's warnings.
"""

from __future__ import annotations

import collections
import threading
import time

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.exceptions import InvalidHandle
from rclpy.executors import (
    ConditionReachedException,
    ExternalShutdownException,
    ShutdownException,
    SingleThreadedExecutor,
    TimeoutException,
)

from cgp_core.wrenches import WrenchError

from .. import interface as itf
from .qos import COMMAND_QOS

#: the inbox's bound: what the node's own pending queue holds (a flood beyond it drops the oldest, reported)
MAX_INBOX = itf.MAX_PENDING_COMMANDS
#: how long the thread may take in one go the messages waiting behind the first on one subscription (then the
#: executor's thread gets the GIL back)
TAKE_BATCH_S = itf.COMMAND_BATCH_S


class _InboxGroup(ReentrantCallbackGroup):
    """The callback group of the command subscriptions: executable on the inbox's thread only.  Any other
    executor (the node's, or rclpy's global one a test spins) finds ``can_execute`` false, so it neither adds
    these subscriptions to its wait set nor takes their messages."""

    def __init__(self) -> None:
        super().__init__()
        self.thread_id: int | None = None

    def can_execute(self, entity) -> bool:
        return threading.get_ident() == self.thread_id

    def beginning_execution(self, entity) -> bool:
        return threading.get_ident() == self.thread_id


class _Waited:
    """What the inbox's executor waits on, in the shape an executor reads a node: the command subscriptions and
    the QoS event handlers of those endpoints made here, nothing else (not the node's timers, services or guard
    conditions, which its own executor runs)."""

    def __init__(self) -> None:
        # each replaced whole by the executor's thread (the inbox's thread reads a snapshot)
        self.subscriptions: tuple = ()
        self.waitables: tuple = ()
        self.timers = self.clients = self.services = self.guards = ()


class CommandInbox:
    """The command subscriptions of ``node``, its publishers' QoS events and the thread that waits on them (see
    the module docstring)."""

    def __init__(self, node) -> None:
        self._node = node
        #: the callback group only this thread executes
        self.group = _InboxGroup()
        self._waited = _Waited()
        self._executor = SingleThreadedExecutor(context=node.context)
        self._inbox: collections.deque = collections.deque()  # (subscription, handler, raw bytes), as taken
        #: the subscriptions not destroyed (the executor's thread's view): what the inbox still holds of a destroyed
        #: one (a body deleted after its command was taken) is dropped, as a deleted body's pending commands are
        self._live: set = set()
        self._lock = threading.Lock()
        self._dropped = 0  # taken and dropped (the inbox full) since the executor's last turn
        self._stopping = False
        # flush(): requests counted by the executor's thread, passes done by the inbox's thread
        self._flush_requested = 0
        self._flushed = 0
        self._flush_done = threading.Condition()
        self._wake = node.create_guard_condition(self._drain)
        self._thread = threading.Thread(target=self._wait_loop, name="cgp_sim commands", daemon=True)
        self._thread.start()

    # ---- the subscriptions (the executor's thread) ---------------------------------------------------------

    def subscribe(self, msg_type, topic: str, handle, event_callbacks=None):
        """A raw subscription to ``topic`` (COMMAND_QOS) whose messages reach ``handle(bytes)`` on the node's
        executor; returns it."""
        subscription = None

        def take_all(data: bytes) -> None:
            # the inbox's thread: this message, then those already waiting behind it (rclpy's executor takes one
            # per subscription per wait, and a wait costs a fraction of a millisecond of Python)
            self._put(subscription, handle, data)
            deadline = time.perf_counter() + TAKE_BATCH_S
            while time.perf_counter() < deadline:
                with subscription.handle:
                    taken = subscription.handle.take_message(msg_type, True)
                if taken is None:
                    return
                self._put(subscription, handle, taken[0])

        subscription = self._node.create_subscription(msg_type, topic, take_all, COMMAND_QOS, raw=True,
                                                      callback_group=self.group, event_callbacks=event_callbacks)
        self._live.add(subscription)
        self._waited.subscriptions = (*self._waited.subscriptions, subscription)
        self._waited.waitables = (*self._waited.waitables, *subscription.event_handlers)  # its QoS events, if any
        self._executor.wake()
        return subscription

    def publisher(self, msg_type, topic: str, qos):
        """``node.create_publisher`` whose QoS event handlers (rclpy's default warnings: a subscriber asking for
        an incompatible QoS or type) this thread waits on; returns it."""
        publisher = self._node.create_publisher(msg_type, topic, qos, callback_group=self.group)
        self._waited.waitables = (*self._waited.waitables, *publisher.event_handlers)
        self._executor.wake()
        return publisher

    def destroy(self, subscription) -> None:
        """Stop waiting on ``subscription`` and destroy it (rclpy defers that while the thread's wait holds it);
        what the inbox holds of it is not handed on."""
        self._live.discard(subscription)
        self._waited.subscriptions = tuple(s for s in self._waited.subscriptions if s is not subscription)
        self._waited.waitables = tuple(w for w in self._waited.waitables if w not in subscription.event_handlers)
        self._node.destroy_subscription(subscription)
        self._executor.wake()

    def flush(self, timeout_s: float = 2.0) -> None:
        """Hand every command that reached the subscriptions' readers before this call to its handler, now.

        For a paused node's step (``~/step``, a stepping request): a command sent, acknowledged by the node's
        reader, then a step requested must be applied by that step, as it was when one executor waited on the
        commands and the services together.  The inbox's thread makes one more pass over the readers (costing
        one build of its wait set) while this thread waits, at most ``timeout_s``."""
        if self._stopping:  # closed: the node is shutting down
            return
        with self._flush_done:
            self._flush_requested += 1
            target = self._flush_requested
        self._executor.wake()
        with self._flush_done:
            self._flush_done.wait_for(lambda: self._flushed >= target or not self._thread.is_alive(), timeout_s)
        self._drain(batch_s=None)

    def close(self) -> None:
        """Stop the thread (before the node is destroyed); what is still in the inbox is dropped.  Safe to call
        twice."""
        if self._stopping:
            return
        self._stopping = True
        self._executor.wake()
        self._thread.join(timeout=5.0)
        self._executor.shutdown(timeout_sec=1.0)
        with self._lock:
            self._inbox.clear()

    # ---- the inbox's thread -------------------------------------------------------------------------------

    def _wait_loop(self) -> None:
        self.group.thread_id = threading.get_ident()
        nodes = [self._waited]
        while not self._stopping:
            try:
                handler = self._next(None, nodes, self._interrupted)
            except ConditionReachedException:
                if self._stopping:
                    return
                with self._flush_done:
                    target = self._flush_requested
                self._take_ready(nodes)  # a wait begun after the request: whatever was in a reader before it
                with self._flush_done:
                    self._flushed = target
                    self._flush_done.notify_all()
                continue
            except (ShutdownException, ExternalShutdownException):
                return
            if handler is not None:
                self._run(handler)

    def _next(self, timeout_s, nodes, condition=None):
        """The next ready callback's handler, or None when a subscription the executor was reading was destroyed
        meanwhile by the executor's thread (a body deleted: rclpy raises ``InvalidHandle``; the next wait is
        without it)."""
        try:
            if condition is None:
                return self._executor.wait_for_ready_callbacks(timeout_s, nodes)[0]
            return self._executor.wait_for_ready_callbacks(timeout_s, nodes, condition)[0]
        except InvalidHandle:
            return None

    def _interrupted(self) -> bool:
        return self._stopping or self._flush_requested != self._flushed

    def _take_ready(self, nodes) -> None:
        """One pass over the readers without blocking: take what is ready."""
        while True:
            try:
                handler = self._next(0, nodes)
            except (TimeoutException, ShutdownException, ExternalShutdownException):
                return
            if handler is not None:
                self._run(handler)

    def _run(self, handler) -> None:
        handler()
        if handler.exception() is not None:  # only rclpy's own take can raise here: say so, keep waiting
            self._node.get_logger().error(f"taking a command failed: {handler.exception()!r}")

    def _put(self, subscription, handle, data: bytes) -> None:
        with self._lock:
            was_empty = not self._inbox
            if len(self._inbox) >= MAX_INBOX:
                self._inbox.popleft()
                self._dropped += 1
            self._inbox.append((subscription, handle, data))
        if was_empty:
            self._wake.trigger()

    # ---- the executor's thread ----------------------------------------------------------------------------

    def _drain(self, batch_s: float | None = itf.COMMAND_BATCH_S) -> None:
        """Guard-condition callback (the node's executor): hand the waiting commands to their handlers, at most
        ``batch_s`` of them per turn (the rest on the next turn, after the timer had its chance; all of them if
        None)."""
        deadline = None if batch_s is None else time.perf_counter() + batch_s
        while True:
            with self._lock:
                item = self._inbox.popleft() if self._inbox else None
                dropped, self._dropped = self._dropped, 0
            if dropped:
                self._node.report_rejection("commands", WrenchError(
                    "message", f"more than {MAX_INBOX} commands waiting for the simulation; dropped the {dropped} "
                    "oldest", "flood"), count=dropped)
            if item is None:
                return
            subscription, handle, data = item
            if subscription in self._live:
                handle(data)
            if deadline is not None and time.perf_counter() > deadline:
                self._wake.trigger()
                return

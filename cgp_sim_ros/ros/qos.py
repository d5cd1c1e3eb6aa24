"""The QoS profiles the node offers its topics with (which topic takes which: :mod:`cgp_sim_ros.interface`)."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# State topics: reliable so RViz / Foxglove (reliable by default) and best-effort subscribers both match;
# KEEP_LAST so a subscriber that never reads cannot make the publisher block or grow memory.
STATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
# /clock: as rclpy / rclcpp's own clock QoS expects (a reliable writer also serves best-effort readers).
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
# Commands: reliable, a deep enough queue for bursts; the node bounds its own pending queue as well.
COMMAND_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
# ~/events: reliable, and transient local with the last 100 lines, so that a subscriber that joins late (a test, a
# dashboard started after the node) still reads the start-up's lines (the level-of-detail plan); a volatile
# subscriber matches it too and gets the lines from when it joined
EVENTS_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
# TF, as tf2_ros' broadcasters offer it: /tf reliable, volatile, keep last 100; /tf_static reliable,
# transient local, keep last 1 (a late subscriber gets the latest set of static transforms).
TF_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)
TF_STATIC_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Latched state (~/static_markers): what /tf_static's profile gives a late subscriber, the last message sent.
LATCHED_QOS = TF_STATIC_QOS

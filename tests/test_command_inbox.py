"""Issue 37, the node's own cost: the command subscriptions are waited on by a thread of their own
(cgp_sim_ros/ros/inbox.py), not by the node's executor, which rebuilt its wait set from every per-body
subscription on every spin.  What must hold: the node's executor leaves them out; a command sent to a paused node,
acknowledged by its reader, is applied by the next step even though nothing spun the executor in between; the
inbox is bounded (the oldest dropped, the flood reported with its count); after a body is deleted (also 40 times
while commands pour in) the others still take commands; the publishers' QoS warnings, whose events the thread now
waits on, still come out.

Each test runs a node in a child process (its own rclpy context; the session's ROS_DOMAIN_ID) with a peer node
publishing over DDS from the same process, waiting on matching and acknowledgement with deadlines; the effect is
checked in the physics: zero_g's ``box`` (2 kg, no gravity) gains momentum F·dt for one tick of a force F.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

PRELUDE = textwrap.dedent("""
    import json, sys, time
    import numpy as np
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from geometry_msgs.msg import WrenchStamped
    from cgp_sim_msgs.msg import ApplyWrench
    from cgp_sim_ros.ros import inbox
    from cgp_sim_ros.ros.node import SimNode
    from cgp_sim_ros.ros.qos import COMMAND_QOS

    def until(condition, seconds, what):
        deadline = time.monotonic() + seconds
        while not condition():
            if time.monotonic() > deadline:
                raise SystemExit(f"timed out waiting for {what}")
            time.sleep(0.01)

    def publisher(peer, msg_type, topic):
        pub = peer.create_publisher(msg_type, topic, COMMAND_QOS)
        until(lambda: pub.get_subscription_count() >= 1, 30, f"the node's reader on {topic}")
        return pub

    def momentum(node, body="box"):
        return node.world.body_state.linear_momentum[node.world.body_model.names.index(body)].copy()

    rclpy.init()
    node = SimNode(parameter_overrides=[Parameter("scene", value="zero_g"), Parameter("realtime", value=False),
                                        Parameter("start_paused", value=True)])
    peer = rclpy.create_node("inbox_test_peer")
    out = {"dt": node.world.dt}
""")

CODA = textwrap.dedent("""
    print("RESULT " + json.dumps(out))
    node.close()
    node.destroy_node()
    peer.destroy_node()
    rclpy.shutdown()
""")


def run(body: str) -> dict:
    proc = subprocess.run([sys.executable, "-c", PRELUDE + textwrap.dedent(body) + CODA], capture_output=True,
                          text=True, timeout=180)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    (line,) = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    return json.loads(line[len("RESULT "):])


def test_the_executor_leaves_the_commands_out_and_a_command_sent_before_a_step_is_applied_by_it():
    out = run("""
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        out["commands"] = sorted(node.command_inputs)
        out["waited_by_executor"] = sorted(s.topic_name for s in node.subscriptions if executor.can_execute(s))
        pub = publisher(peer, WrenchStamped, "/cgp_sim/bodies/box/wrench")
        before = momentum(node)
        msg = WrenchStamped()
        msg.header.frame_id = "world"
        msg.wrench.force.x, msg.wrench.force.y = 4.0, -2.0
        pub.publish(msg)
        assert pub.wait_for_all_acked(rclpy.duration.Duration(seconds=30)), "not acknowledged"
        # nothing spins the node's executor: the step's own take must find it (~/step does this, then ticks)
        node.commands.take_arrived()
        node.tick()
        out["gained"] = (momentum(node) - before).tolist()
        node.tick()
        out["gained_after_next"] = (momentum(node) - before).tolist()
    """)
    assert "/cgp_sim/bodies/box/wrench" in out["commands"] and "/cgp_sim/apply_wrench" in out["commands"]
    assert not set(out["waited_by_executor"]) & set(out["commands"]), out["waited_by_executor"]
    dt = out["dt"]
    assert out["gained"] == pytest.approx([4.0 * dt, -2.0 * dt, 0.0], abs=1e-12)
    assert out["gained_after_next"] == out["gained"]  # a body wrench holds for one tick


def test_a_full_inbox_drops_the_oldest_and_reports_how_many():
    out = run("""
        inbox.MAX_INBOX = 10  # the bound, small enough to fill with one DDS history's worth (depth 100)
        rejected = []
        node.report_rejection = lambda source, error, count=1: rejected.append((source, str(error), count))
        pub = publisher(peer, ApplyWrench, "/cgp_sim/apply_wrench")
        before = momentum(node)
        for i in range(30):  # forces 1, 2, ..., 30 N along x, each for one tick
            msg = ApplyWrench(body="box")
            msg.header.frame_id = "world"
            msg.point.z = 2.0  # the box's centre: no torque
            msg.wrench.force.x = float(i + 1)
            pub.publish(msg)
        assert pub.wait_for_all_acked(rclpy.duration.Duration(seconds=30)), "not acknowledged"
        node.commands.take_arrived()
        node.tick()
        out["gained"] = (momentum(node) - before).tolist()
        out["rejected"] = rejected
    """)
    dt = out["dt"]
    # the newest ten (21..30 N) were applied, the 20 oldest dropped and reported once, with their count
    assert out["gained"][0] == pytest.approx(sum(range(21, 31)) * dt, rel=1e-12)
    assert [(s, c) for s, _, c in out["rejected"]] == [("commands", 20)], out["rejected"]
    assert "more than 10 commands waiting" in out["rejected"][0][1]


def test_after_a_body_is_deleted_the_others_still_take_commands():
    """Its subscription is destroyed while the inbox's thread may be waiting on it (rclpy defers that until the
    wait lets go); the thread's next wait is without it."""
    out = run("""
        node.world.delete("spinner")
        node.world_edited()
        out["node_subscriptions"] = sorted(s.topic_name for s in node.subscriptions)
        pub = publisher(peer, WrenchStamped, "/cgp_sim/bodies/box/wrench")
        before = momentum(node)
        msg = WrenchStamped()
        msg.wrench.force.z = 6.0
        pub.publish(msg)
        assert pub.wait_for_all_acked(rclpy.duration.Duration(seconds=30)), "not acknowledged"
        node.commands.take_arrived()
        node.tick()
        out["gained"] = (momentum(node) - before).tolist()
    """)
    assert "/cgp_sim/bodies/spinner/wrench" not in out["node_subscriptions"]
    assert "/cgp_sim/bodies/box/wrench" in out["node_subscriptions"]
    assert out["gained"][2] == pytest.approx(6.0 * out["dt"], rel=1e-12)


def test_a_subscriber_asking_for_an_incompatible_qos_is_warned_about(start_node, probe):
    """The publishers' QoS events are waited on by the inbox's thread now, not the executor: rclpy's warning about
    an incompatible subscriber must still come out (``~/bodies/poses`` is volatile; this reader asks for
    transient local)."""
    import time

    from geometry_msgs.msg import PoseArray
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    node = start_node("--scene", "zero_g", "--start-paused", "true")
    probe.wait_for_publisher("/cgp_sim/bodies/poses", timeout=60)
    probe.subscribe("/cgp_sim/bodies/poses", PoseArray, QoSProfile(
        depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    warning = "bodies/poses', requesting incompatible QoS"  # rclpy names the topic as given: ~/bodies/poses
    deadline = time.monotonic() + 30
    while warning not in node.log():
        assert time.monotonic() < deadline, node.log()[-3000:]
        probe.spin_for(0.1)
    assert "DURABILITY" in node.log()


def test_bodies_deleted_and_restored_while_commands_arrive_leave_the_thread_taking_them():
    """Subscriptions destroyed and made again 40 times (a body deleted, then the world reset) while another
    thread publishes to them without pause: the inbox's thread may be reading a subscription as it is destroyed
    (rclpy then raises InvalidHandle there); it must go on waiting, and a command afterwards still arrives."""
    out = run("""
        import threading
        spinner = publisher(peer, WrenchStamped, "/cgp_sim/bodies/spinner/wrench")
        box = publisher(peer, WrenchStamped, "/cgp_sim/bodies/box/wrench")
        done = threading.Event()

        def flood():
            msg = WrenchStamped()
            msg.wrench.force.y = 1.0
            while not done.is_set():
                spinner.publish(msg)
                box.publish(msg)
                time.sleep(0.0005)

        flooder = threading.Thread(target=flood)
        flooder.start()
        for _ in range(40):
            node.world.delete("spinner")
            node.world_edited()
            rclpy.spin_once(node, timeout_sec=0.0)  # the executor drains what the inbox took
            node.reset()
            rclpy.spin_once(node, timeout_sec=0.0)
        done.set()
        flooder.join()
        out["alive"] = node.inbox._thread.is_alive()
        node.commands.take_arrived()
        node.commands.clear_pending()
        until(lambda: box.get_subscription_count() >= 1, 30, "the box's reader after the resets")
        before = momentum(node)
        msg = WrenchStamped()
        msg.wrench.force.x = 3.0
        box.publish(msg)
        assert box.wait_for_all_acked(rclpy.duration.Duration(seconds=30)), "not acknowledged"
        node.commands.take_arrived()
        node.tick()
        out["gained"] = (momentum(node) - before).tolist()
    """)
    assert out["alive"]
    assert out["gained"][0] == pytest.approx(3.0 * out["dt"], rel=1e-12)

"""~/contacts through the node (the `contacts` scene: a 2 kg box launched at 3 m/s slides to rest, μ = 0.5):
another process decodes contact points and forces consistent with the physics (μ m g against the sliding, m g up
at rest), the contact markers arrive with contact_markers:=true, the topic does not exist with contacts:=false,
and the bag holds every tick's ~/contacts, readable by mcap's reader.  One start of each node for every check."""

from __future__ import annotations

import os

import numpy as np
import pytest
from conftest import NodeProcess
from mcap_ros2.reader import read_ros2_messages
from ros_probe import pause, step
from visualization_msgs.msg import MarkerArray

G, M, MU = 9.81, 2.0, 0.5
TICKS = 90  # --duration 1.5 at 60 Hz: 37 ticks sliding, then at rest (asleep from ~1.1 s)


@pytest.fixture(scope="module")
def run(ros, tmp_path_factory):
    """The contacts scene with contact markers and a bag, started paused and resumed once this process listens,
    run for 1.5 s; beside it a node with contacts:=false, paused.  Yields (probe, contacts, markers, bag, the
    quiet node's markers)."""
    from cgp_sim_msgs.msg import Contacts
    from ros_probe import Probe

    tmp = tmp_path_factory.mktemp("node_contacts")
    node = NodeProcess(["--scene", "contacts", "--contact-markers", "true", "--bag", str(tmp / "bag"),
                        "--duration", "1.5", "--start-paused", "true"], tmp / "node.log")
    quiet = NodeProcess(["--scene", "contacts", "--contacts", "false", "--start-paused", "true",
                         "--ros-args", "-r", "__node:=quiet"], tmp / "quiet.log")
    probe = Probe(f"contacts_probe_{os.getpid()}")
    try:
        contacts = probe.subscribe("/cgp_sim/contacts", Contacts)
        markers = probe.subscribe("/cgp_sim/markers", MarkerArray)
        quiet_markers = probe.subscribe("/quiet/markers", MarkerArray)
        probe.wait_until_matched("/cgp_sim/contacts", "/cgp_sim/markers", "/quiet/markers", timeout=60)
        pause(probe, False)
        probe.spin_until(lambda: not node.alive(), 60, "the node to end after its 1.5 s")
        assert node.wait(10) == 0, node.log()[-3000:]
        probe.spin_for(0.2)
        yield probe, contacts.messages, markers.messages, tmp / "bag", quiet_markers
    finally:
        probe.close()
        node.stop()
        quiet.stop()


def wrench_of(msg, name="slider"):
    (w,) = [w for w in msg.wrenches if w.entity == name]
    return np.array([w.wrench.force.x, w.wrench.force.y, w.wrench.force.z]), \
        np.array([w.wrench.torque.x, w.wrench.torque.y, w.wrench.torque.z])


def test_contact_points_and_forces_arrive_and_agree_with_the_physics(run):
    _probe, contacts, _markers, _bag, _quiet = run
    assert len(contacts) >= TICKS // 2  # every tick is published; a few of the last may be in flight at exit
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in contacts]
    ticks = np.round(np.array(stamps) * 60e-9).astype(int)  # the tick each message is of (1, 2, ...)
    for tick, msg in zip(ticks, contacts):
        assert msg.header.frame_id == "world" and msg.duration == pytest.approx(1 / 60)
        assert len(msg.contacts) == 4
        assert {(c.entity_a, c.entity_b) for c in msg.contacts} == {("ground", "slider")}
        normal = np.array([[c.normal.x, c.normal.y, c.normal.z] for c in msg.contacts])
        np.testing.assert_allclose(normal, np.tile([0, 0, 1.0], (4, 1)), atol=1e-12)
        impulses = np.array([c.normal_impulse for c in msg.contacts])
        assert impulses.sum() == pytest.approx(M * G / 60, rel=1e-6)  # m g dt: the box neither sinks nor jumps
        force, torque = wrench_of(msg)
        if tick <= 36:  # sliding: kinetic friction μ m g against the motion (+x), at every corner
            friction = np.array([[c.friction_impulse.x, c.friction_impulse.y, c.friction_impulse.z]
                                 for c in msg.contacts])
            assert (friction[:, 0] < 0).all()
            np.testing.assert_allclose(np.linalg.norm(friction, axis=1), MU * impulses, rtol=1e-6)
            np.testing.assert_allclose(force, [-MU * M * G, 0, M * G], rtol=1e-6, atol=1e-6)
        elif tick >= 45:  # at rest (asleep from ~1.1 s: its last contacts held): m g up, nothing else
            np.testing.assert_allclose(force, [0, 0, M * G], atol=1e-4)
        np.testing.assert_allclose(torque, 0.0, atol=1e-6)
    assert ticks.min() <= 36 and ticks.max() >= 45  # both phases seen


def test_contact_markers_arrive_with_the_parameter_and_nothing_with_contacts_off(run):
    probe, contacts, markers, _bag, quiet_markers = run
    drawn = markers[-1].markers
    (points,) = [m for m in drawn if m.ns == "contacts/points"]
    arrows = [m for m in drawn if m.ns == "contacts/forces" and m.action == m.ADD]
    assert points.type == points.SPHERE_LIST and len(points.points) == 4
    assert sorted(a.id for a in arrows) == [0, 1, 2, 3] and all(a.type == a.ARROW for a in arrows)
    # each arrow starts at a contact point and is the contact force (m g / 4 up at rest) × 0.01 m/N long
    for a in arrows:
        start, tip = (np.array([p.x, p.y, p.z]) for p in a.points)
        assert min(np.linalg.norm(start - np.array([q.x, q.y, q.z])) for q in points.points) < 1e-12
        assert tip[2] - start[2] == pytest.approx(0.01 * M * G / 4, rel=0.3)
    # contacts:=false: no ~/contacts topic at all, and its markers (one step) draw no contacts
    assert "/quiet/contacts" not in probe.topic_types() and "/quiet/markers" in probe.topic_types()
    step(probe, "/quiet")
    probe.spin_until(lambda: quiet_markers.messages, 20, "the quiet node's markers")
    assert not [m for m in quiet_markers.messages[-1].markers if m.ns.startswith("contacts")]


def test_the_bag_holds_every_ticks_contacts_readable_by_mcap(run):
    _probe, _contacts, _markers, bag, _quiet = run
    (mcap_file,) = sorted(bag.glob("*.mcap"))
    decoded = [m for m in read_ros2_messages(str(mcap_file), topics=["/cgp_sim/contacts"])]
    assert len(decoded) == TICKS
    assert decoded[0].schema.name == "cgp_sim_msgs/msg/Contacts"
    first, last = decoded[0].ros_msg, decoded[-1].ros_msg
    assert [c.entity_b for c in first.contacts] == ["slider"] * 4
    force, _ = wrench_of(first)
    assert force[0] == pytest.approx(-MU * M * G, rel=1e-6)
    force, _ = wrench_of(last)
    np.testing.assert_allclose(force, [0, 0, M * G], atol=1e-4)

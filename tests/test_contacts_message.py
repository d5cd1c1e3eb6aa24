"""~/contacts and the contact markers without a node: the numpy-built cgp_sim_msgs/Contacts bytes are the message
rclpy builds from the same report (rclpy's building took ~7-10 ms for a 100-box pile's 360 contacts, ours
~0.2 ms, measured once side by side; not in benchmarks/ yet), the markers draw every contact's point and force
and retire the arrows of contacts gone, and cgp-sim-render draws the arrows."""

from __future__ import annotations

import numpy as np
import pytest
from test_cdr import assert_equivalent

from cgp_core import World, parse_scene
from cgp_sim_ros.interface import Frames
from cgp_sim_ros.render.primitives import primitives
from cgp_sim_ros.ros.messages import TickMessages
from cgp_sim_ros.wire import cdr

# names of 1 to 4 characters: every padding of the strings before the floats; a box on a box on the ground and a
# fixed wall: ground, body-body and fixed-body contacts
SCENE = """
world: {gravity: [-2, 0, -9.81], ground: true, sleep: false}  # tilted: the sphere leans on the wall
bodies:
  - {name: a, shape: box, size: [0.4, 0.4, 0.4], mass: 2.0, position: [0, 0, 0.2], linear_velocity: [1, 0, 0]}
  - {name: bb, shape: box, size: [0.3, 0.3, 0.3], mass: 1.0, position: [0.02, 0.01, 0.55]}
  - {name: ccc, shape: sphere, radius: 0.1, mass: 0.5, position: [-1.1, 0, 0.1]}
  - {name: wall, shape: box, size: [0.2, 2, 1], position: [-1.35, 0, 0.5], fixed: true}
"""


def stepped(ticks: int) -> World:
    w = World(parse_scene(SCENE), dt=1 / 60)
    w.report_contacts = True
    for _ in range(ticks):
        w.step()
    return w


def rclpy_message(r, names, stamp_ns: int, frame_id: str = "world"):
    """The :class:`~cgp_core.solver.report.ContactReport` ``r`` of bodies ``names``, built field by field as an
    rclpy user would (also benchmarks/bench_contact_report.py's reference)."""
    from cgp_sim_msgs.msg import Contact, Contacts, EntityWrench

    msg = Contacts(duration=r.duration)
    msg.header.frame_id = frame_id
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    for i in range(r.count):
        c = Contact(entity_a=cdr.GROUND_ENTITY if r.body_a[i] < 0 else names[r.body_a[i]],
                    entity_b=names[r.body_b[i]], separation=float(r.separation[i]),
                    normal_impulse=float(r.normal_impulse[i]))
        c.position.x, c.position.y, c.position.z = map(float, r.point[i])
        c.normal.x, c.normal.y, c.normal.z = map(float, r.normal[i])
        c.friction_impulse.x, c.friction_impulse.y, c.friction_impulse.z = map(float, r.friction_impulse[i])
        msg.contacts.append(c)
    for j, i in enumerate(r.body):
        e = EntityWrench(entity=names[i])
        e.wrench.force.x, e.wrench.force.y, e.wrench.force.z = map(float, r.force[j])
        e.wrench.torque.x, e.wrench.torque.y, e.wrench.torque.z = map(float, r.torque[j])
        msg.wrenches.append(e)
    return msg


@pytest.mark.parametrize("ticks", [0, 1, 30])  # no contacts yet; the first; several kinds, every padding
def test_contacts_bytes_are_the_message_rclpy_builds(ticks):
    w = stepped(ticks)
    if ticks == 30:
        r = w.contacts
        assert {"ground", "a", "bb", "ccc", "wall"} <= {cdr.GROUND_ENTITY if i < 0 else w.body_model.names[i]
                                                        for i in (*r.body_a, *r.body_b)}
        assert 3 in r.body  # the fixed wall is listed with the reaction on it
    stamp = 12_345_678_901
    for prefix in ("", "sim1/"):  # two phases of the header
        frames = Frames(prefix)
        expected = rclpy_message(w.contacts, list(w.body_model.names), stamp, frames.world)
        assert_equivalent(TickMessages(w, frames).contacts(stamp), expected)


def test_contact_markers_draw_points_and_force_arrows_and_retire_the_gone_ones():
    w = stepped(30)
    scale = 0.02
    messages = TickMessages(w, contact_force_scale=scale)
    drawn = cdr.read_marker_array(messages.markers(1, tick=1))
    points = [m for m in drawn if m.ns == "contacts/points"]
    arrows = [m for m in drawn if m.ns == "contacts/forces"]
    r = w.contacts
    assert len(points) == 1 and points[0].type == cdr.SPHERE_LIST
    np.testing.assert_array_equal(points[0].points, r.point)
    assert [m.id for m in arrows] == list(range(r.count)) and all(m.type == cdr.ARROW for m in arrows)
    tips = np.array([m.points[1] for m in arrows])
    np.testing.assert_allclose(tips, r.point + scale * (r.normal_impulse[:, None] * r.normal + r.friction_impulse)
                               / r.duration, rtol=0, atol=1e-12)
    # cgp-sim-render draws the arrows (a shaft and a cone each), no longer skipping them
    assert "ARROW" not in primitives(drawn).skipped and len(primitives(arrows).triangles) >= r.count
    # fewer contacts later (everything flies off): the arrows beyond are deleted, in the same array
    w.body_state.position[:3, 2] += 5.0
    w.step()
    later = cdr.read_marker_array(messages.markers(2, tick=2))
    deleted = sorted(m.id for m in later if m.ns == "contacts/forces" and m.action == cdr.DELETE)
    assert w.contacts.count < r.count and deleted == list(range(w.contacts.count, r.count))
    # and without contact markers there are none
    assert not [m for m in cdr.read_marker_array(TickMessages(w).markers(3, tick=3)) if m.ns.startswith("contacts")]


def test_the_renderer_draws_an_arrow_from_its_start_to_its_tip():
    arrow = cdr.MarkerFields(marker_type=cdr.ARROW, points=np.array([[1, 2, 0], [1, 2, 3.0]]), scale=(0.1, 0.2, 0.5))
    marker = cdr.read_marker(cdr.marker(arrow))
    tris = primitives([marker]).triangles.reshape(-1, 3)
    np.testing.assert_allclose(tris.min(0), [0.9, 1.9, 0.0], atol=1e-12)  # the head is 0.2 wide
    np.testing.assert_allclose(tris.max(0), [1.1, 2.1, 3.0], atol=1e-12)
    assert np.isclose(tris[:, 2], 3.0).any() and np.isclose(tris[:, 2], 2.5).any()  # the tip and the head's base

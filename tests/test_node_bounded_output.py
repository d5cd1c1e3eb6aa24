"""Issue 38: what a tick sends is bounded, as a subscriber in another process sees it.

- 300 convex bodies with 1,000-vertex hulls made ``~/markers`` 43 MB per tick.  Now the level of detail draws the
  hulls ``low`` (at most 48 triangles) and the bodies in parts, one part per tick, every body within the plan's
  B ticks: each marker array stays within the body budget per tick (``drawing/detail.py``), and the plan is on
  ``~/events``.  (120 such bodies here, 17 MB per tick in full: the scene loader's hull of 1,000 points takes
  ~0.1 s, and 300 made the node's start-up a minute long.)
- ``~/contacts`` carries at most ``MAX_CONTACTS_PER_MESSAGE`` contacts (the strongest) while the wrenches stay
  every body's total: 600 boxes resting on the ground (2,400 contacts) still weigh 600 m g on the wrenches.

(Static meshes on the latched ``~/static_markers``: tests/test_node_convex.py.)"""

from __future__ import annotations

import json
import struct

import numpy as np
from cgp_sim_msgs.msg import Contacts
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String
from test_robustness_faults import wait_ticking
from visualization_msgs.msg import Marker, MarkerArray

from cgp_sim_ros.drawing.detail import BODY_MARKER_BYTES_PER_S
from cgp_sim_ros.interface import MAX_CONTACTS_PER_MESSAGE
from cgp_sim_ros.ros.qos import EVENTS_QOS

RATE_HZ = 60.0
BIG_HULLS = 120


def sphere_hull_stl(path, vertices: int = 1000, radius: float = 0.2):
    """A binary STL of the convex hull of ``vertices`` random points on a sphere (outward triangles)."""
    from scipy.spatial import ConvexHull

    p = np.random.default_rng(38).normal(size=(vertices, 3))
    p *= radius / np.linalg.norm(p, axis=1)[:, None]
    tri = ConvexHull(p).simplices.copy()
    inward = np.einsum("ij,ij->i", np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]]), p[tri[:, 0]]) < 0
    tri[inward] = tri[inward][:, ::-1]
    record = np.zeros(len(tri), dtype=[("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    record["v"] = p[tri]
    path.write_bytes(b"\0" * 80 + struct.pack("<I", len(tri)) + record.tobytes())
    return path


def test_many_big_hulls_are_drawn_within_the_body_budget(start_node, probe, tmp_path):
    stl = sphere_hull_stl(tmp_path / "ball.stl")
    bodies = "\n".join(f"  - {{name: b{k}, shape: convex, mesh: ball.stl, mass: 1, fixed: true, "
                       f"position: [{(k % 20) * 0.6 - 6}, {(k // 20) * 0.6 - 4}, 0.3]}}" for k in range(BIG_HULLS))
    scene = tmp_path / "hulls.yaml"
    scene.write_text(f"bodies:\n{bodies}\n")
    assert stl.exists()
    clock = probe.subscribe("/clock", Clock)
    # ~/events keeps its last lines for a late subscriber (transient local): the plan, sent at start-up, whenever
    # discovery completes
    events = probe.subscribe("/cgp_sim/events", String, qos=EVENTS_QOS)
    markers = probe.subscribe("/cgp_sim/markers", MarkerArray, raw=True)
    node = start_node("--scene", str(scene), "--rate-hz", str(RATE_HZ), "--start-paused", "true")
    probe.wait_until_matched("/clock", "/cgp_sim/markers", "/cgp_sim/events", timeout=60)
    probe.spin_until(lambda: any(json.loads(m.data).get("event") == "level_of_detail" for m in events.messages), 30,
                     "the level-of-detail plan on ~/events")
    plan = next(json.loads(m.data) for m in events.messages if json.loads(m.data).get("event") == "level_of_detail")
    assert plan["hull_detail"] == "low" and plan["body_markers_every"] > 1, plan
    every = plan["body_markers_every"]
    from std_srvs.srv import SetBool

    probe.call(SetBool, "/cgp_sim/pause", SetBool.Request(data=False))
    wait_ticking(probe, node, clock, 3 * every + 2, timeout=60)
    probe.spin_until(lambda: len(markers.messages) >= 3 * every, 30, "the marker arrays")
    arrays = markers.messages[:3 * every]
    budget = BODY_MARKER_BYTES_PER_S / RATE_HZ
    assert max(len(a) for a in arrays) <= 1.2 * budget + 2000, [len(a) for a in arrays]  # 43 MB before
    drawn: dict[str, int] = {}
    for k, raw in enumerate(arrays[:every]):
        for m in deserialize_message(raw, MarkerArray).markers:
            if m.ns.startswith("bodies/"):
                assert m.type == Marker.TRIANGLE_LIST and 0 < len(m.points) <= 3 * 48, (m.ns, len(m.points))
                drawn[m.ns] = k
    assert len(drawn) == BIG_HULLS  # every body within B consecutive ticks
    assert node.alive(), node.log()


def test_contacts_are_capped_and_the_wrenches_stay_whole(start_node, probe, tmp_path):
    mass, side = 2.0, 0.3
    bodies = "\n".join(f"  - {{name: b{k}, shape: box, size: [{side}, {side}, {side}], mass: {mass}, "
                       f"position: [{(k % 30) * 0.5 - 7.5}, {(k // 30) * 0.5 - 5}, {side / 2 + 0.001}]}}"
                       for k in range(600))
    scene = tmp_path / "boxes.yaml"
    scene.write_text(f"bodies:\n{bodies}\n")
    clock = probe.subscribe("/clock", Clock)
    contacts = probe.subscribe("/cgp_sim/contacts", Contacts)
    events = probe.subscribe("/cgp_sim/events", String)
    # paused until the probe's subscription is matched: the report is summed only while someone listens, and the
    # boxes (resting from the start) fall asleep within half a second of ticking
    node = start_node("--scene", str(scene), "--contacts", "true", "--start-paused", "true")
    probe.wait_until_matched("/clock", "/cgp_sim/contacts", "/cgp_sim/events", timeout=60)
    from std_srvs.srv import SetBool

    probe.call(SetBool, "/cgp_sim/pause", SetBool.Request(data=False))
    wait_ticking(probe, node, clock, 60, timeout=90)
    probe.spin_until(lambda: len(contacts.messages) >= 60, 30, "60 contact messages")
    last = contacts.messages[-1]
    assert len(last.contacts) == MAX_CONTACTS_PER_MESSAGE  # 4 per box on the ground: 2,400 in the tick
    assert len(last.wrenches) == 600
    weight = sum(w.wrench.force.z for w in last.wrenches)
    assert abs(weight - 600 * mass * 9.81) < 0.02 * 600 * mass * 9.81, weight  # every contact's share
    probe.spin_until(lambda: any("~/contacts:" in json.loads(m.data).get("text", "") for m in events.messages), 30,
                     "the cap reported on ~/events")
    assert node.alive(), node.log()

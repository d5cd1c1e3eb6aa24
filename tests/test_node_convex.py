"""Issue 25's shapes through the node, as another process sees them (one node start): spawning a convex body from
points, from an STL file given as the request's ``uri``, a compound body and a static mesh from a YAML file whose
``mesh:`` is read next to it; bad mesh files and bad points refused naming the file, the key and the reason while
the node keeps ticking; their markers (a hull and a static mesh as TRIANGLE_LISTs in the body frame, a compound
as one marker per part with stable ids); the load reports on ``~/events``."""

from __future__ import annotations

import json
import shutil

import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from sim_client import OK, vec
from simulation_interfaces.srv import SpawnEntity
from std_msgs.msg import String
from test_node_sim_services import start_paused
from visualization_msgs.msg import Marker, MarkerArray

from cgp_core.scene import builtin_mesh_dir

#: a late joiner's profile for latched topics (what RViz's "Transient Local" durability asks for)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)

PYRAMID = "body: {shape: convex, mass: 2.0, points: [[0, 0, 0], [0.4, 0, 0], [0, 0.4, 0], [0.4, 0.4, 0], " \
          "[0.2, 0.2, 0.3], [0.2, 0.2, 0.1]]}"  # 5 corners, and a point inside


def test_spawning_the_new_shapes_and_what_the_node_publishes_of_them(start_node, probe, tmp_path):
    clock = probe.subscribe("/clock", Clock)
    events = probe.subscribe("/cgp_sim/events", String)
    markers = probe.subscribe("/cgp_sim/markers", MarkerArray, raw=True)
    node, sim = start_paused(start_node, probe, "ramp")
    scene_entities = set(sim.names())
    probe.wait_until_matched("/clock", "/cgp_sim/events", "/cgp_sim/markers")
    R = SpawnEntity.Response

    # convex from points (one inside: said on ~/events), from an STL file as uri
    assert sim.spawn("pyramid", PYRAMID, position=(0, 0, 5)).result.result == OK
    rock = tmp_path / "my rock.stl"
    shutil.copy(builtin_mesh_dir() / "rock.stl", rock)
    assert sim.spawn("rock", uri=rock.as_uri(), position=(1, 0, 5)).result.result == OK
    # a compound with a convex part from a mesh next to its YAML file, and a static mesh
    (tmp_path / "table.yaml").write_text(
        "body:\n  shape: compound\n  mass: 3\n  parts:\n"
        "    - {shape: box, size: [0.6, 0.6, 0.04], position: [0, 0, 0.4]}\n"
        "    - {shape: capsule, radius: 0.02, length: 0.36, position: [0.25, 0.25, 0.2]}\n"
        "    - {shape: sphere, radius: 0.05, position: [-0.25, -0.25, 0.05]}\n"
        "    - {shape: convex, mesh: 'my rock.stl', scale: 0.3, position: [0.25, -0.25, 0.05]}\n")
    assert sim.spawn("table", uri=str(tmp_path / "table.yaml"), position=(-2, 0, 5)).result.result == OK
    assert sim.spawn("land", "body: {shape: mesh, mesh: terrain.obj, fixed: true}").result.result == OK

    # refused: a file that is no mesh, points in a plane, a movable mesh — the world unchanged, the node ticking
    junk = tmp_path / "junk.obj"
    junk.write_text("this is not an obj file\n")
    refused = sim.spawn("junk", uri=junk.as_uri()).result
    assert refused.result == R.RESOURCE_PARSE_ERROR and "junk.obj" in refused.error_message \
        and "mesh" in refused.error_message, refused
    flat = sim.spawn("flat", "body: {shape: convex, points: [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]}").result
    assert flat.result == R.RESOURCE_PARSE_ERROR and "body (flat).points" in flat.error_message \
        and "coplanar" in flat.error_message, flat
    loose = sim.spawn("loose", "body: {shape: mesh, mesh: terrain.obj}").result
    assert loose.result == R.RESOURCE_PARSE_ERROR and "body (loose).fixed" in loose.error_message, loose
    assert set(sim.names()) == scene_entities | {"pyramid", "rock", "table", "land"}

    ticks_before = len(clock.messages)
    assert sim.step(3).result.result == OK
    probe.spin_until(lambda: len(clock.messages) >= ticks_before + 3, 20, "three more ticks")
    assert node.alive(), node.log()

    # the COM of the pyramid (not the origin of its points) is its pose, and it falls under gravity
    state = sim.state("pyramid").state
    assert vec(state.pose.position)[2] < 5.0 + 0.3 and state.twist.linear.z < 0.0

    # markers: every body drawn once, in its own TF frame (frame_locked: a viewer moves it with /tf), on the latched
    # ~/static_markers, so a subscriber that comes after the spawns gets the whole set (a DELETEALL, then every
    # body); ~/markers carries none (issue 37); the static mesh at its pose in frame world (issue 38: it was
    # re-sent every second on ~/markers)
    probe.spin_until(lambda: len(markers.messages) >= 1, 20, "a marker array")
    assert not [m for raw in markers.messages for m in deserialize_message(raw, MarkerArray).markers
                if m.ns.startswith("bodies/")]
    static = probe.subscribe("/cgp_sim/static_markers", MarkerArray, qos=LATCHED)
    (array,) = probe.wait_for_messages("/cgp_sim/static_markers", 1)
    assert array.markers[0].action == Marker.DELETEALL
    assert all(m.action == Marker.ADD for m in array.markers[1:])
    last = {(m.ns, m.id): m for m in array.markers[1:]}
    assert {ns for ns, _ in last} >= {f"bodies/{name}" for name in ("pyramid", "rock", "table", "land")}
    pyramid = last[("bodies/pyramid", 0)]
    assert pyramid.type == Marker.TRIANGLE_LIST and len(pyramid.points) == 3 * 6  # 5 corners: 6 triangles
    assert pyramid.header.frame_id == "pyramid" and pyramid.frame_locked
    assert list(vec(pyramid.pose.position)) == [0.0, 0.0, 0.0] and pyramid.pose.orientation.w == 1.0
    assert last[("bodies/rock", 0)].type == Marker.TRIANGLE_LIST and len(last[("bodies/rock", 0)].points) == 3 * 60
    parts = sorted(i for ns, i in last if ns == "bodies/table")
    assert parts == [0, 3, 4, 5, 6, 9]  # box, capsule + its two caps, sphere, hull
    assert [last[("bodies/table", i)].type for i in parts] == [Marker.CUBE, Marker.CYLINDER, Marker.SPHERE,
                                                              Marker.SPHERE, Marker.SPHERE, Marker.TRIANGLE_LIST]
    assert all(last[("bodies/table", i)].header.frame_id == "table" for i in parts)
    top, foot = last[("bodies/table", 0)], last[("bodies/table", 6)]
    assert np.allclose([top.scale.x, top.scale.y, top.scale.z], [0.6, 0.6, 0.04])
    assert abs(top.pose.position.z - foot.pose.position.z - 0.35) < 1e-6  # the parts' poses in the body frame
    land = last[("bodies/land", 0)]
    assert land.header.frame_id == "world" and land.type == Marker.TRIANGLE_LIST and len(land.points) == 3 * 1152
    probe.spin_for(0.5)
    assert len(static.messages) == 1  # sent once, not every tick

    # ~/events: the hull of non-convex points and the BVH built
    texts = [json.loads(m.data).get("text", "") for m in events.messages]
    assert any("pyramid" in t and "1 of the 6 points" in t for t in texts), texts
    assert any("static mesh land: terrain.obj, 1152 triangles" in t and "BVH" in t for t in texts), texts

"""Level of detail for big flocks (cgp_sim_ros/drawing/detail.py, shapes.py): the plan keeps the marker and bag
budgets for any flock size and keeps the default scene's full fish on every tick; the low-detail fish is the
full fish's outline seen from above plus its tail fin, drawn at the boid's pose; and through the node: what the
plan says is what the bag holds — each flock's marker in parts, one per tick, flock poses at the planned ticks,
the plan in metadata.yaml and on ~/events — and the recorded markers still draw every fish where the bag says
it is."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from rclpy.serialization import deserialize_message
from scipy.spatial import ConvexHull

from cgp_core.boids import FlockParams
from cgp_core.rotation import quat_to_matrix
from cgp_sim_ros import interface as itf
from cgp_sim_ros.drawing import detail
from cgp_sim_ros.drawing.shapes import FISH_DETAILS, FISH_LOW_TEMPLATE, FISH_TEMPLATE, VERTEX_QUANTUM, fish_triangles


def test_the_default_scene_keeps_its_full_fish_on_every_tick():
    plan = detail.plan([FlockParams(name="fish", count=300, model="fish")], 60.0)
    assert plan.fish_detail == {"fish": "full"}
    assert (plan.markers_every, plan.flock_poses_every) == (1, 1)
    assert plan.marker_bytes == 300 * 30 * 24
    custom = plan.custom_data({"fish": "/cgp_sim/flocks/fish/poses"}, "/cgp_sim/markers")
    assert json.loads(custom["cgp_sim.recorded_every_n_ticks"]) == {}  # everything on every tick


def test_fifteen_thousand_fish_get_low_detail_and_lower_rates_within_the_budgets():
    plan = detail.plan([FlockParams(name="school", count=15_000, model="fish")], 60.0)
    assert plan.fish_detail == {"school": "low"}
    assert plan.marker_bytes == 15_000 * 9 * 24
    assert plan.markers_every == math.ceil(plan.marker_bytes * 60 / detail.MARKER_BYTES_PER_S)  # 7
    assert plan.flock_poses_every == 2  # 15,000 × 56 B × 60 Hz = 50.4 MB/s > 32 MB/s
    assert plan.marker_bytes * 60 / plan.markers_every <= detail.MARKER_BYTES_PER_S
    assert plan.pose_bytes * 60 / plan.flock_poses_every <= detail.BAG_POSES_BYTES_PER_S
    custom = plan.custom_data({"school": "/cgp_sim/flocks/school/poses"}, "/cgp_sim/markers")
    assert json.loads(custom["cgp_sim.recorded_every_n_ticks"]) == {"/cgp_sim/flocks/school/poses": 2}
    assert json.loads(custom["cgp_sim.flock_markers_redrawn_every_n_ticks"]) == {"/cgp_sim/markers": 7}
    assert json.loads(custom["cgp_sim.fish_detail"]) == {"school": "low"}
    assert "low detail" in custom["cgp_sim.level_of_detail"] and "every 7 ticks" in custom["cgp_sim.level_of_detail"]


@pytest.mark.parametrize("rate", [10.0, 60.0, 240.0])
def test_the_budgets_hold_for_any_flock_size(rate):
    for count in (1, 10, 300, 1_000, 5_000, 15_000, 100_000, 400_000):
        for model in ("fish", "sphere"):
            flocks = [FlockParams(name="a", count=count, model=model), FlockParams(name="b", count=count // 3 + 1)]
            plan = detail.plan(flocks, rate)
            if plan.markers_every > 1:
                assert plan.marker_bytes * rate / plan.markers_every <= detail.MARKER_BYTES_PER_S
                assert plan.marker_bytes * rate / (plan.markers_every - 1) > detail.MARKER_BYTES_PER_S  # smallest N
            if plan.flock_poses_every > 1:
                assert plan.pose_bytes * rate / plan.flock_poses_every <= detail.BAG_POSES_BYTES_PER_S
            full = sum(p.count * (30 if p.model == "fish" else 1) for p in flocks) * 24
            if model == "fish":
                assert plan.fish_detail["a"] == ("full" if full * rate <= detail.MARKER_BYTES_PER_S else "low")


def test_parameters_override_their_rule_and_bad_values_are_refused():
    flocks = [FlockParams(name="school", count=15_000, model="fish")]
    plan = detail.plan(flocks, 60.0, fish_detail="full", markers_every=30, flock_poses_every=1)
    assert (plan.fish_detail, plan.markers_every, plan.flock_poses_every) == ({"school": "full"}, 30, 1)
    assert detail.plan(flocks, 60.0, markers_every=3).fish_detail == {"school": "low"}  # the rest still automatic
    with pytest.raises(ValueError, match="fish_detail must be one of auto, full, low"):
        detail.plan(flocks, 60.0, fish_detail="medium")
    # the parameter offers exactly the details the shapes have, and "auto"
    (spec,) = [s for s in itf.PARAMETERS if s.name == "fish_detail"]
    assert spec.choices == itf.FISH_DETAIL_CHOICES == ("auto", *FISH_DETAILS)


def test_seen_from_above_the_low_fish_has_the_full_fishs_outline():
    outline = [ConvexHull(template[:, :2]) for template in (FISH_TEMPLATE, FISH_LOW_TEMPLATE)]
    np.testing.assert_allclose(outline[0].volume, outline[1].volume, rtol=1e-12)  # the area, in 2D
    corners = [sorted(map(tuple, np.round(t[h.vertices, :2], 12))) for t, h in zip((FISH_TEMPLATE, FISH_LOW_TEMPLATE),
                                                                                   outline)]
    assert corners[0] == corners[1]
    assert np.ptp(FISH_LOW_TEMPLATE[:, 2]) > 0.2, "the tail fin stands up: seen from the side there is a fish too"


@pytest.mark.parametrize("level", ["full", "low"])
def test_fish_vertices_are_the_template_at_the_boid_pose_rounded_to_a_millimetre(level):
    rng = np.random.default_rng(3)
    positions = rng.uniform(-30, 30, (500, 3))
    q = rng.normal(size=(500, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    vertices = fish_triangles(positions, q, 0.3, level)
    template = FISH_DETAILS[level]
    expected = positions[:, None, :] + np.einsum("nij,vj->nvi", quat_to_matrix(q), 0.3 * template)
    np.testing.assert_allclose(vertices.reshape(500, len(template), 3), expected, rtol=0, atol=VERTEX_QUANTUM / 2)
    scaled = vertices / VERTEX_QUANTUM
    np.testing.assert_array_equal(scaled, np.round(scaled))  # multiples of 1/1024 m: low bytes zero
    exact = fish_triangles(positions, q, 0.3, level, quantum=0.0)
    np.testing.assert_allclose(exact.reshape(500, len(template), 3), expected, rtol=0, atol=1e-12)


# ---- through the node ---------------------------------------------------------------------------------

SCENE = """
world: {gravity: [0, 0, -9.81], ground: true}
bodies:
  - {name: ball, shape: sphere, radius: 0.5, mass: 1.0, position: [0, 0, 3]}
flocks:
  - name: school
    count: 1000
    model: fish
    spawn: {center: [0, 0, 8], extent: [12, 12, 6]}
    seed: 2
"""


def _messages(bag_dir):
    """{topic: {log_time: raw bytes}} of every .mcap in the bag (the node's topics carry one message per tick)
    and the raw ~/events lines in order (several can share a tick's time)."""
    out, events = {}, []
    for path in sorted(bag_dir.glob("*.mcap")):
        with open(path, "rb") as f:
            for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
                if channel.topic == "/cgp_sim/events":
                    events.append(message.data)
                else:
                    out.setdefault(channel.topic, {})[message.log_time] = message.data
    out["/cgp_sim/events"] = events
    return out


def test_the_bag_holds_what_the_plan_says_and_its_markers_draw_every_fish(start_node, tmp_path):
    """1,000 fish at 600 Hz: in full they would be 432 MB/s of markers, so they are drawn low (130 MB/s) and
    redrawn every 5th tick — in 5 parts of 200 fish, one per tick — and their poses (33.6 MB/s) are recorded
    on every 2nd tick."""
    from geometry_msgs.msg import PoseArray
    from std_msgs.msg import String
    from visualization_msgs.msg import Marker, MarkerArray

    scene = tmp_path / "school.yaml"
    scene.write_text(SCENE)
    bag = tmp_path / "bag"
    node = start_node("--scene", str(scene), "--rate-hz", "600", "--duration", "0.1", "--realtime", "false",
                      "--bag", str(bag))
    assert node.wait(timeout=120) == 0, node.log()
    log = node.log()
    assert "level of detail: fish drawn with low detail" in log and "every 5 ticks" in log, log

    dt = round(1e9 / 600)
    messages = _messages(bag)
    ticks = sorted(messages["/clock"])
    assert len(ticks) == 60
    assert sorted(messages["/cgp_sim/bodies/poses"]) == ticks  # the small topics: every tick
    tick_of = {t: k + 1 for k, t in enumerate(ticks)}  # world.ticks after the tick that published at t
    assert sorted(messages["/cgp_sim/markers"]) == ticks  # one part of the flock on every tick
    assert all(tick_of[t] % 2 == 0 for t in messages["/cgp_sim/flocks/school/poses"])
    assert len(messages["/cgp_sim/flocks/school/poses"]) == 30
    assert all(b - a == dt for a, b in zip(ticks, ticks[1:]))

    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9
    custom = info["custom_data"]
    assert json.loads(custom["cgp_sim.recorded_every_n_ticks"]) == {"/cgp_sim/flocks/school/poses": 2}
    assert json.loads(custom["cgp_sim.flock_markers_redrawn_every_n_ticks"]) == {"/cgp_sim/markers": 5}
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in info["topics_with_message_count"]}
    assert counts["/cgp_sim/markers"] == 60 and counts["/cgp_sim/flocks/school/poses"] == 30
    events = [json.loads(deserialize_message(raw, String).data) for raw in messages["/cgp_sim/events"]]
    plan = next(e for e in events if e["event"] == "level_of_detail")
    assert plan["fish_detail"] == {"school": "low"} and plan["markers_every"] == 5
    assert plan["bag_flock_poses_every"] == 2

    # each tick's part draws its 200 fish at the poses recorded for that tick (on the ticks both are recorded:
    # every part comes round on them, the parts taking turns)
    parts_seen = set()
    for t in sorted(messages["/cgp_sim/flocks/school/poses"]):
        array = deserialize_message(messages["/cgp_sim/markers"][t], MarkerArray)
        (fish,) = [m for m in array.markers if m.ns == "flocks/school"]
        assert fish.type == Marker.TRIANGLE_LIST and fish.header.frame_id == "world"
        assert fish.id == tick_of[t] % 5
        parts_seen.add(fish.id)
        first, last = 200 * fish.id, 200 * (fish.id + 1)
        poses = deserialize_message(messages["/cgp_sim/flocks/school/poses"][t], PoseArray).poses[first:last]
        p = np.array([[o.position.x, o.position.y, o.position.z] for o in poses])
        q = np.array([[o.orientation.x, o.orientation.y, o.orientation.z, o.orientation.w] for o in poses])
        vertices = np.array([[v.x, v.y, v.z] for v in fish.points]).reshape(200, 9, 3)
        expected = p[:, None, :] + np.einsum("nij,vj->nvi", quat_to_matrix(q), 0.3 * FISH_LOW_TEMPLATE)
        np.testing.assert_allclose(vertices, expected, rtol=0, atol=VERTEX_QUANTUM / 2 + 1e-12)
    assert parts_seen == {0, 1, 2, 3, 4}, "every fish is drawn"


def test_changing_the_detail_at_run_time_shows_in_the_markers_the_log_the_events_and_the_bag(
        start_node, probe, tmp_path):
    """fish_detail and markers_every are settable while the node runs: the next ticks draw and publish as the
    new plan says, and the change is logged, put on ~/events and into the bag's metadata — as is a new
    rate_hz, for which the plan is made."""
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    from ros_probe import step
    from std_msgs.msg import String
    from visualization_msgs.msg import MarkerArray

    bag = tmp_path / "bag"
    node = start_node("--scene", "default", "--bag", str(bag), "--start-paused", "true")
    probe.wait_for_publisher("/cgp_sim/markers", timeout=30)
    params = [ParameterMsg(name="fish_detail", value=ParameterValue(type=ParameterType.PARAMETER_STRING,
                                                                    string_value="low")),
              ParameterMsg(name="markers_every", value=ParameterValue(type=ParameterType.PARAMETER_INTEGER,
                                                                      integer_value=3)),
              ParameterMsg(name="rate_hz", value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                                                double_value=30.0))]
    results = probe.call(SetParameters, "/cgp_sim/set_parameters", SetParameters.Request(parameters=params)).results
    assert all(r.successful for r in results), results
    for _ in range(9):
        step(probe)
    assert node.stop() == 0
    log = node.log_path.read_text(errors="replace")
    assert "level of detail changed: fish drawn 'low' (fish_detail parameter)" in log, log

    messages = _messages(bag)
    ticks = sorted(messages["/clock"])
    assert len(ticks) == 9
    tick_of = {t: k + 1 for k, t in enumerate(ticks)}
    assert sorted(messages["/cgp_sim/markers"]) == ticks
    for t, raw in messages["/cgp_sim/markers"].items():
        (fish,) = [m for m in deserialize_message(raw, MarkerArray).markers if m.ns == "flocks/fish"]
        assert fish.id == tick_of[t] % 3 and len(fish.points) == 100 * 9  # low detail, a third of the flock
    events = [json.loads(deserialize_message(raw, String).data) for raw in messages["/cgp_sim/events"]]
    plans = [e for e in events if e["event"] == "level_of_detail"]
    # the start-up plan, then one per parameter set (the service sets them one by one)
    assert plans[0]["fish_detail"] == {"fish": "full"} and plans[0]["markers_every"] == 1
    assert plans[-1]["fish_detail"] == {"fish": "low"} and plans[-1]["markers_every"] == 3
    assert plans[-1]["rate_hz"] == 30.0
    assert len(plans) == 4
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["custom_data"]["cgp_sim.rate_hz"] == "30"
    assert json.loads(info["custom_data"]["cgp_sim.fish_detail"]) == {"fish": "low"}
    assert json.loads(info["custom_data"]["cgp_sim.recorded_every_n_ticks"]) == {}
    assert json.loads(info["custom_data"]["cgp_sim.flock_markers_redrawn_every_n_ticks"]) == {"/cgp_sim/markers": 3}


def test_a_reset_redraws_every_part_after_its_deleteall():
    """Parts take turns tick by tick; after a reset (DELETEALL first) the array carries every part, so that no
    fish is missing until its part's turn comes."""
    from visualization_msgs.msg import Marker, MarkerArray

    from cgp_core.scene import parse_scene
    from cgp_core.world import World
    from cgp_sim_ros.ros.messages import TickMessages

    world = World(parse_scene(SCENE))
    messages = TickMessages(world, itf.UNPREFIXED, detail.plan([f.params for f in world.flocks], 60.0, markers_every=4))

    def fish_markers(data):
        return [m for m in deserialize_message(data, MarkerArray).markers if m.ns == "flocks/school"]

    assert [m.id for m in fish_markers(messages.markers(0, tick=6))] == [2]
    array = deserialize_message(messages.markers(0, delete_all_first=True, tick=6), MarkerArray).markers
    assert array[0].action == Marker.DELETEALL
    parts = fish_markers(messages.markers(0, delete_all_first=True, tick=6))
    assert [m.id for m in parts] == [0, 1, 2, 3]
    assert sum(len(m.points) for m in parts) == 1000 * len(FISH_DETAILS[messages.fish_detail["school"]])  # all, once


def test_markers_no_longer_drawn_are_deleted_fewer_parts_or_a_deleted_flock(start_node, probe, tmp_path):
    """A flock drawn in K parts has K marker ids.  When it is drawn in fewer parts (markers_every lowered) the
    ids beyond them, and when it is deleted every id, get a DELETE — a marker without a lifetime never expires,
    so a viewer would keep the old fish for ever.  Read back from the bag, in the order recorded."""
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    from ros_probe import step
    from simulation_interfaces.msg import Result
    from simulation_interfaces.srv import DeleteEntity
    from visualization_msgs.msg import Marker, MarkerArray

    bag = tmp_path / "bag"
    node = start_node("--scene", "default", "--bag", str(bag), "--start-paused", "true")
    probe.wait_for_publisher("/cgp_sim/markers", timeout=30)

    def markers_every(k: int) -> None:
        value = ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=k)
        request = SetParameters.Request(parameters=[ParameterMsg(name="markers_every", value=value)])
        assert all(r.successful for r in probe.call(SetParameters, "/cgp_sim/set_parameters", request).results)

    markers_every(3)
    for _ in range(3):
        step(probe)
    markers_every(2)
    for _ in range(2):
        step(probe)
    reply = probe.call(DeleteEntity, "/cgp_sim/delete_entity", DeleteEntity.Request(entity="fish"),
                       idempotent=False)
    assert reply.result.result == Result.RESULT_OK, reply.result.error_message
    step(probe)
    assert node.stop() == 0

    arrays = []
    for path in sorted(bag.glob("*.mcap")):
        with open(path, "rb") as f:
            for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
                if channel.topic == "/cgp_sim/markers":
                    arrays.append(deserialize_message(message.data, MarkerArray).markers)
    fish = [[(m.action, m.id) for m in array if m.ns == "flocks/fish"] for array in arrays]
    drawn = [ids for ids in fish if ids and all(action == Marker.ADD for action, _ in ids)]
    deletes = [sorted(i for _, i in ids) for ids in fish if ids and all(a == Marker.DELETE for a, _ in ids)]
    assert [ids[0][1] for ids in drawn] == [1, 2, 0, 0, 1], fish  # ticks 1-3: id tick % 3; 4-5: tick % 2
    assert deletes == [[2], [0, 1]], fish  # markers_every 3 -> 2: part 2 gone; the flock deleted: parts 0 and 1
    assert fish[-1] == [], "the tick after the delete draws no fish"


# ---- bodies (issue 38) --------------------------------------------------------------------------------------------

def test_a_low_detail_hull_is_small_inside_the_hull_and_faces_outward():
    from cgp_core.collision.convex import convex_hull
    from cgp_sim_ros.drawing.bodies import hull_drawing

    points = np.random.default_rng(38).normal(size=(1000, 3))
    points *= 0.2 / np.linalg.norm(points, axis=1)[:, None]
    hull = convex_hull(points)
    drawing = hull_drawing(hull)
    assert len(drawing.full) == 3 * len(hull.triangles) and len(drawing.low) <= 3 * 48
    inside = ConvexHull(hull.vertices).equations
    assert np.all(drawing.low @ inside[:, :3].T + inside[:, 3] <= 1e-12)  # its vertices are the hull's
    tri = drawing.low.reshape(-1, 3, 3)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centre = drawing.low.mean(axis=0)
    assert np.all(np.einsum("ij,ij->i", normal, tri[:, 0] - centre) > 0)  # counter-clockwise seen from outside
    tetra = convex_hull(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]))
    small = hull_drawing(tetra)
    assert small.low is small.full  # a hull of 48 triangles or fewer is drawn as it is


def test_a_big_static_mesh_is_clustered_to_its_cap_and_keeps_its_extent():
    from cgp_sim_ros.drawing.bodies import cluster_vertices

    n = 301  # a 301 x 301 grid: 180,000 triangles
    x, y = np.meshgrid(np.linspace(0, 30, n), np.linspace(0, 30, n))
    vertices = np.stack([x.ravel(), y.ravel(), np.sin(x.ravel())], axis=1)
    index = np.arange(n * n).reshape(n, n)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    triangles = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    merged_vertices, merged = cluster_vertices(vertices, triangles, 20_000)
    assert 5_000 < len(merged) <= 20_000
    assert np.allclose(merged_vertices[merged].reshape(-1, 3).min(axis=0), vertices.min(axis=0), atol=0.3)
    assert np.allclose(merged_vertices[merged].reshape(-1, 3).max(axis=0), vertices.max(axis=0), atol=0.3)
    up = np.cross(*(merged_vertices[merged[:, k]] - merged_vertices[merged[:, 0]] for k in (1, 2)))[:, 2]
    assert np.mean(up > 0) > 0.99  # the winding kept (the grid faces +z)


def test_the_body_budget_picks_low_hulls_then_parts():
    small = detail.plan([], 60.0, body_bytes=(100_000, 20_000))
    assert (small.hull_detail, small.body_markers_every) == ("full", 1)
    big = detail.plan([], 60.0, body_bytes=(43_000_000, 1_100_000))  # 300 hulls of 1,000 vertices
    assert big.hull_detail == "low"
    assert big.body_markers_every == math.ceil(1_100_000 * 60 / detail.BODY_MARKER_BYTES_PER_S)
    assert big.body_marker_bytes * 60 / big.body_markers_every <= detail.BODY_MARKER_BYTES_PER_S
    assert big.event()["hull_detail"] == "low" and "hulls drawn with low detail" in " ".join(big.lines)
    custom = big.custom_data({}, "/cgp_sim/markers")
    assert custom["cgp_sim.hull_detail"] == "low"
    assert custom["cgp_sim.body_markers_redrawn_every_n_ticks"] == str(big.body_markers_every)


def test_the_bodies_set_sent_once_has_a_cap_past_which_hulls_are_low():
    """Issue 37: the bodies are drawn once, in their own frames, on ~/static_markers; the set's bytes, not a rate,
    decide the hull detail, and nothing is split into parts (~/markers carries no body without robots)."""
    pile = detail.plan([], 60.0, body_set_bytes=(275_000, 120_000))  # bench_convex_pile's 100 hulls
    assert (pile.hull_detail, pile.body_markers_every, pile.body_set_bytes) == ("full", 1, 275_000)
    assert "bodies drawn once, in their own TF frames" in " ".join(pile.lines)
    big = detail.plan([], 60.0, body_set_bytes=(43_000_000, 1_100_000))  # 300 hulls of 1,000 vertices
    assert (big.hull_detail, big.body_markers_every, big.body_set_bytes) == ("low", 1, 1_100_000)
    assert big.body_set_bytes <= detail.BODY_SET_BYTES < 43_000_000
    assert "over its 8.0 MB cap" in " ".join(big.lines)


def test_body_parts_have_about_equal_bytes_and_keep_the_bodies_in_order():
    from cgp_sim_ros.ros.messages import body_parts

    sizes = np.random.default_rng(1).integers(100, 10_000, 500)
    part = body_parts(sizes, 7)
    assert np.all(np.diff(part) >= 0) and set(part.tolist()) == set(range(7))
    per_part = np.bincount(part, weights=sizes)
    assert per_part.max() <= sizes.sum() / 7 + sizes.max()
    assert np.all(body_parts(sizes, 1) == 0)

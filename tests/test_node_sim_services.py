"""Issue 13 over DDS: the node runs as its own process and this process drives it through ROS 2's
``simulation_interfaces`` (Jazzy 1.5.1), as any tool written against the standard would.

Each service and the ``simulate_steps`` action, every result code the node gives, and what follows a spawn or a
delete as another node sees it (topics appear and go, poses, markers, wrench commands).  Expected motions are
closed forms (free fall from rest: v = −g t), not the code's.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from geometry_msgs.msg import PoseArray, WrenchStamped
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from sim_client import OK, SimClient, quat, vec
from simulation_interfaces.action import SimulateSteps
from simulation_interfaces.msg import Bounds, EntityCategory, Result, SimulationState, SimulatorFeatures
from simulation_interfaces.srv import (
    GetEntities,
    GetEntitiesStates,
    GetSimulatorFeatures,
    ResetSimulation,
    SetEntityState,
    SetSimulationState,
    SpawnEntity,
)
from std_msgs.msg import String
from visualization_msgs.msg import Marker, MarkerArray

from cgp_sim_ros.ros.qos import LATCHED_QOS

G = 9.81
DT = round(1e9 / 60) * 1e-9  # the tick: 1/60 s rounded to whole nanoseconds, as the node steps
S = SimulationState
R = SpawnEntity.Response
FAILED = Result.RESULT_OPERATION_FAILED
BOX = "body: {shape: box, size: [0.4, 0.4, 0.4], mass: 2.0, color: [0.2, 0.8, 0.2, 1.0]}"


def stamp_ns(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def clock_ns(msg) -> int:
    return msg.clock.sec * 1_000_000_000 + msg.clock.nanosec


def start_paused(start_node, probe, scene: str, *extra: str):
    """The node on ``scene``, paused, with the probe matched to its services."""
    node = start_node("--scene", scene, "--start-paused", "true", *extra)
    probe.client(GetSimulatorFeatures, "/cgp_sim/get_simulator_features", timeout=30)
    return node, SimClient(probe)


def events_of(events, name: str) -> list[dict]:
    return [e for e in (json.loads(m.data) for m in events.messages) if e.get("name") == name]


def test_features_states_and_stepping(start_node, probe):
    clock = probe.subscribe("/clock", Clock)
    events = probe.subscribe("/cgp_sim/events", String)
    node, sim = start_paused(start_node, probe, "zero_g")
    probe.wait_for_publisher("/clock")
    probe.wait_for_publisher("/cgp_sim/events")

    features = sim.call(GetSimulatorFeatures).features
    F = SimulatorFeatures
    assert {F.SPAWNING, F.DELETING, F.SPAWNING_RESOURCE_STRING, F.ENTITY_STATE_GETTING,
            F.ENTITY_STATE_SETTING, F.SIMULATION_RESET, F.SIMULATION_RESET_STATE,
            F.SIMULATION_RESET_SPAWNED, F.SIMULATION_STATE_GETTING,
            F.SIMULATION_STATE_SETTING, F.SIMULATION_STATE_PAUSE,
            F.STEP_SIMULATION_SINGLE, F.STEP_SIMULATION_MULTIPLE, F.STEP_SIMULATION_ACTION} <= set(features.features)
    # (the whole set, with issue 36's worlds, batches, info, bounds and named poses: tests/test_node_worlds.py)
    assert list(features.spawn_formats) == ["yaml", "stl", "obj", "urdf", "xacro"]
    assert "body, flock or robot" in features.custom_info

    assert sim.simulation_state() == S.STATE_PAUSED
    again = sim.set_simulation_state(S.STATE_PAUSED)
    assert again.result.result == SetSimulationState.Response.ALREADY_IN_TARGET_STATE, again.result
    for state, code in ((S.STATE_NO_WORLD, SetSimulationState.Response.INCORRECT_TRANSITION),
                        (9, SetSimulationState.Response.INCORRECT_TRANSITION)):
        refused = sim.set_simulation_state(state)
        assert refused.result.result == code and refused.result.error_message, refused.result
    assert clock.messages == []  # nothing ticked yet

    # exactly `steps` ticks while paused; the reply comes when they are done
    assert sim.step(5).result.result == OK
    tick_ns = round(1e9 / 60)  # dt in whole ns
    probe.spin_until(lambda: bool(clock.messages) and clock_ns(clock.messages[-1]) == 5 * tick_ns, 10,
                     "the clock 5 ticks on")
    probe.spin_for(0.3)
    # /clock keeps its last sample only (KEEP_LAST 1): a reader may miss some of a burst's ticks, but sees the last,
    # and none twice or out of order
    stamps = [clock_ns(m) for m in clock.messages]
    assert stamps[-1] == 5 * tick_ns and stamps == sorted(set(stamps))
    assert set(stamps) <= {k * tick_ns for k in range(1, 6)}
    assert sim.simulation_state() == S.STATE_PAUSED
    zero = sim.step(0)
    assert zero.result.result == FAILED and "at least 1" in zero.result.error_message

    # playing: stepping is the failure the standard names, time runs
    assert sim.set_simulation_state(S.STATE_PLAYING).result.result == OK
    assert sim.simulation_state() == S.STATE_PLAYING
    playing = sim.step(1)
    assert playing.result.result == FAILED and "playing" in playing.result.error_message
    probe.spin_until(lambda: len(clock.messages) > 20, 10, "ticks while playing")

    # push the box, then STOPPED: paused and reset to the scene as loaded; the clock never goes back
    pub = probe.publisher("/cgp_sim/bodies/box/wrench", WrenchStamped)
    probe.wait_for_subscriber(pub)
    push = WrenchStamped()
    push.wrench.force.x = 100.0
    pub.publish(push)
    probe.spin_until(lambda: sim.state("box").state.twist.linear.x > 0.1, 10, "the box to move")
    assert sim.set_simulation_state(S.STATE_STOPPED).result.result == OK
    assert sim.simulation_state() == S.STATE_STOPPED
    box = sim.state("box").state
    assert vec(box.pose.position) == [0.0, 0.0, 2.0] and vec(box.twist.linear) == [0.0, 0.0, 0.0]
    stopped_at = clock_ns(clock.messages[-1])
    assert sim.step(1).result.result == OK  # stepping a stopped world: it is paused, and no longer "reset"
    probe.spin_until(lambda: clock_ns(clock.messages[-1]) > stopped_at, 10, "one more tick")
    assert clock_ns(clock.messages[-1]) == stopped_at + round(1e9 / 60)
    assert sim.simulation_state() == S.STATE_PAUSED
    assert sim.set_simulation_state(S.STATE_STOPPED).result.result == OK
    assert sim.set_simulation_state(S.STATE_PAUSED).result.result == OK  # STOPPED -> PAUSED is allowed
    assert sim.simulation_state() == S.STATE_PAUSED

    # every call is on ~/events with its result
    def state_calls():
        return [(c["state"], c["result"]) for c in events_of(events, "set_simulation_state")]

    probe.spin_until(lambda: state_calls()[-3:] == [("STOPPED", "OK"), ("STOPPED", "OK"), ("PAUSED", "OK")], 10,
                     "the last state calls on ~/events")
    assert [("PAUSED", "ALREADY_IN_TARGET_STATE"), ("NO_WORLD", "INCORRECT_TRANSITION"), (9, "INCORRECT_TRANSITION"),
            ("PLAYING", "OK")] == state_calls()[-7:-3]
    steps = [e for e in events_of(events, "step_simulation") if e["steps"] == 5]
    assert len(steps) == 1 and steps[0]["result"] == "OK" and steps[0]["done"] == 5
    assert events_of(events, "get_simulator_features")


def test_simulate_steps_action_feedback_and_cancel(start_node, probe):
    clock = probe.subscribe("/clock", Clock)
    # the feedback as it goes over the wire (rclpy's ActionClient drops feedback that arrives before it has
    # processed the goal's acceptance, which ticks as fast as realtime:=false can outrun)
    wire = probe.subscribe("/cgp_sim/simulate_steps/_action/feedback", SimulateSteps.Impl.FeedbackMessage)
    node, sim = start_paused(start_node, probe, "zero_g", "--realtime", "false")
    probe.wait_for_publisher("/clock")
    client = probe.action_client(SimulateSteps, "/cgp_sim/simulate_steps")
    probe.spin_until(client.server_is_ready, 30, "the simulate_steps action server")
    # feedback is a topic: wait until the server's feedback writer is matched, or the first ticks' are lost
    probe.spin_until(lambda: probe.node.count_publishers("/cgp_sim/simulate_steps/_action/feedback") > 0, 30,
                     "the action's feedback publisher")

    def run(steps: int, cancel_after: int | None = None):
        feedback = []
        sent = client.send_goal_async(SimulateSteps.Goal(steps=steps),
                                      feedback_callback=lambda m: feedback.append(m.feedback))
        probe.spin_until(sent.done, 30, "the goal to be accepted")
        handle = sent.result()
        assert handle.accepted
        if cancel_after is not None:
            probe.spin_until(lambda: len(feedback) >= cancel_after, 30, "feedback before cancelling")
            cancelled = handle.cancel_goal_async()
            probe.spin_until(cancelled.done, 30, "the cancel reply")
        result = handle.get_result_async()
        probe.spin_until(result.done, 60, "the action result")
        return result.result(), feedback

    # one-step goals until one's feedback arrives on the wire: then the feedback topic is matched for sure (a
    # feedback sent before the reader matched is lost, which is DDS, not the node)
    warm_up = 0
    while True:
        outcome, _ = run(1)
        warm_up += 1
        assert outcome.status == 4 and outcome.result.result.result == OK  # GoalStatus.STATUS_SUCCEEDED
        try:
            probe.spin_until(lambda: wire.messages, 2.0, "the one-step goal's feedback")
            break
        except AssertionError:
            assert warm_up < 5, "no feedback from five one-step goals"
    # /clock keeps its last sample only (KEEP_LAST 1): a burst of ticks may reach a reader as its last one, so the
    # ticks are counted by the clock's time (tick k at k dt, dt in whole ns), not by messages
    tick_ns = round(1e9 / 60)

    def clock_at(tick: int):
        return lambda: bool(clock.messages) and clock_ns(clock.messages[-1]) == tick * tick_ns

    probe.spin_until(clock_at(warm_up), 10, "the warm-up ticks' clock")

    # 10 steps: feedback after each tick, then the result; exactly 10 ticks
    before = len(wire.messages)
    outcome, feedback = run(10)
    assert outcome.status == 4 and outcome.result.result.result == OK
    probe.spin_until(clock_at(warm_up + 10), 10, "the clock 10 ticks on")
    probe.spin_for(0.3)
    assert clock_ns(clock.messages[-1]) == (warm_up + 10) * tick_ns  # and no more
    # feedback is a topic, the result a service: the last feedback may arrive after the result
    probe.spin_until(lambda: len(wire.messages) >= before + 10, 10, "10 feedback messages")
    sent = wire.messages[before:]
    assert len({bytes(m.goal_id.uuid) for m in sent}) == 1
    assert [(m.feedback.completed_steps, m.feedback.remaining_steps) for m in sent] == \
        [(k, 10 - k) for k in range(1, 11)]
    # what rclpy's action client passed on is some of it, in order (it may drop feedback, see above)
    passed_on = [f.completed_steps for f in feedback]
    assert passed_on == sorted(set(passed_on)) and set(passed_on) <= set(range(1, 11))

    # cancel a long one: it stops, the world stays paused
    outcome, feedback = run(100_000, cancel_after=3)
    assert outcome.status == 5  # STATUS_CANCELED
    assert outcome.result.result.result == FAILED and "canceled after" in outcome.result.result.error_message
    done = int(outcome.result.result.error_message.split("canceled after ")[1].split()[0])
    assert 3 <= done < 100_000
    ticks = warm_up + 10 + done
    probe.spin_until(clock_at(ticks), 10, "the clock at the canceled goal's last tick")
    probe.spin_for(0.3)
    assert clock_ns(clock.messages[-1]) == ticks * tick_ns and sim.simulation_state() == S.STATE_PAUSED

    # a second stepping request while one runs is refused at once
    sent = client.send_goal_async(SimulateSteps.Goal(steps=100_000))
    probe.spin_until(sent.done, 30, "the goal to be accepted")
    probe.spin_until(lambda: clock_ns(clock.messages[-1]) > (ticks + 2) * tick_ns, 30, "the goal to tick")
    busy = sim.step(1)
    assert busy.result.result == FAILED and "another stepping request" in busy.result.error_message
    # playing interrupts it (the steps were to be taken while paused)
    assert sim.set_simulation_state(S.STATE_PLAYING).result.result == OK
    result = sent.result().get_result_async()
    probe.spin_until(result.done, 30, "the interrupted goal's result")
    assert result.result().status == 6 and "interrupted" in result.result().result.result.error_message  # ABORTED

    # while playing, a goal is aborted with OPERATION_FAILED
    outcome, _ = run(5)
    assert outcome.status == 6 and outcome.result.result.result == FAILED
    assert "playing" in outcome.result.result.error_message


def test_spawn_watch_it_fall_teleport_and_delete(start_node, probe):
    """The worked example of docs/simulation-interfaces.md, checked: spawn a box above the crate, it falls
    (v = −g t), teleport it, delete it — and everything per body follows, as another node sees it."""
    poses = probe.subscribe("/cgp_sim/bodies/poses", PoseArray)
    odom = probe.subscribe("/cgp_sim/bodies/box1/odom", Odometry)
    markers = probe.subscribe("/cgp_sim/markers", MarkerArray, raw=True)
    # the bodies' shapes: once per change of the set, in their own TF frames (issue 37)
    static = probe.subscribe("/cgp_sim/static_markers", MarkerArray, raw=True, qos=LATCHED_QOS)
    node, sim = start_paused(start_node, probe, "default")
    assert sim.names() == ["ball", "crate", "capsule", "tetromino", "pillar", "fish"]
    assert sim.step(120).result.result == OK  # the scene's bodies land; the crate rests where it tumbled to
    crate = sim.state("crate").state.pose.position
    assert crate.z == pytest.approx(0.25, abs=5e-3)  # on its 0.5 m side

    reply = sim.spawn("box1", BOX, position=(crate.x, crate.y, 2.0))
    assert reply.result.result == OK and reply.entity_name == "box1", reply.result
    assert sim.names() == ["ball", "crate", "capsule", "tetromino", "pillar", "box1", "fish"]
    probe.wait_for_publisher("/cgp_sim/bodies/box1/odom")
    probe.spin_until(lambda: probe.node.count_subscribers("/cgp_sim/bodies/box1/wrench") > 0, 20,
                     "the box's wrench subscription")
    assert sim.step(6).result.result == OK
    state = sim.state("box1")
    assert state.result.result == OK and state.state.header.frame_id == "world"
    t = 6 * DT
    assert state.state.twist.linear.z == pytest.approx(-G * t, abs=1e-9)  # free fall from rest
    assert state.state.acceleration.linear.z == pytest.approx(-G, abs=1e-6)
    assert state.state.pose.position.z < 2.0
    # the odometry and the pose array of that tick carry it, the markers draw it
    now = stamp_ns(state.state.header)
    probe.spin_until(lambda: any(stamp_ns(m.header) == now for m in odom.messages)
                     and any(stamp_ns(m.header) == now for m in poses.messages), 10, "this tick's odom and poses")
    tick_odom = next(m for m in odom.messages if stamp_ns(m.header) == now)
    tick_poses = next(m for m in poses.messages if stamp_ns(m.header) == now)
    assert tick_odom.child_frame_id == "box1" and len(tick_poses.poses) == 6
    assert tick_odom.pose.pose.position.z == state.state.pose.position.z
    assert tick_poses.poses[5].position.z == state.state.pose.position.z
    probe.spin_until(lambda: markers.messages and static.messages, 10, "markers")
    drawn = deserialize_message(static.messages[-1], MarkerArray)
    assert any(m.ns == "bodies/box1" and m.type == Marker.CUBE and m.header.frame_id == "box1" and m.frame_locked
               for m in drawn.markers)

    # it lands on the crate: crate top (0.25 + 0.25) + its own half size 0.2
    assert sim.step(84).result.result == OK
    landed = sim.state("box1").state
    assert landed.pose.position.z == pytest.approx(0.7, abs=5e-3)
    assert [landed.pose.position.x, landed.pose.position.y] == pytest.approx([crate.x, crate.y], abs=0.05)
    assert np.linalg.norm(vec(landed.twist.linear)) < 0.05

    # a wrench command on the spawned body acts on it: Δv = F Δt / m over one tick
    # (in the air, so no contact takes part: put it there first)
    assert sim.set_state("box1", (0.0, -8.0, 5.0)).result.result == OK
    pub = probe.publisher("/cgp_sim/bodies/box1/wrench", WrenchStamped)
    probe.wait_for_subscriber(pub)
    push = WrenchStamped()
    push.wrench.force.x = 12.0
    pub.publish(push)
    probe.spin_for(0.3)  # let the command arrive before the tick
    assert sim.step(1).result.result == OK
    assert sim.state("box1").state.twist.linear.x == pytest.approx(12.0 * DT / 2.0, abs=1e-9)

    # teleport: exactly that pose and twist, woken and moving from there
    q = (0.0, 0.0, math.sin(0.25), math.cos(0.25))
    assert sim.set_state("box1", (3.0, -3.0, 2.0), q, linear=(0.0, 1.0, 0.0)).result.result == OK
    moved = sim.state("box1").state
    assert vec(moved.pose.position) == [3.0, -3.0, 2.0]
    np.testing.assert_allclose(quat(moved.pose.orientation), q, atol=1e-15)
    assert vec(moved.twist.linear) == pytest.approx([0.0, 1.0, 0.0], abs=1e-12)
    assert sim.step(1).result.result == OK
    assert sim.state("box1").state.pose.position.y == pytest.approx(-3.0 + DT, abs=1e-9)

    # delete: its endpoints go, its markers are deleted, queries do not know it
    assert sim.delete("box1").result.result == OK
    gone = sim.delete("box1")
    assert gone.result.result == Result.RESULT_NOT_FOUND and "box1" in gone.result.error_message
    assert sim.state("box1").result.result == Result.RESULT_NOT_FOUND
    probe.spin_until(lambda: probe.node.count_publishers("/cgp_sim/bodies/box1/odom") == 0
                     and probe.node.count_subscribers("/cgp_sim/bodies/box1/wrench") == 0, 20,
                     "box1's endpoints to go")
    probe.spin_until(lambda: static.messages and not any(
        m.ns == "bodies/box1" for m in deserialize_message(static.messages[-1], MarkerArray).markers), 10,
        "the bodies' markers again, without box1 (after their DELETEALL)")
    assert deserialize_message(static.messages[-1], MarkerArray).markers[0].action == Marker.DELETEALL
    assert sim.step(1).result.result == OK
    probe.spin_until(lambda: poses.messages and len(poses.messages[-1].poses) == 5, 10, "5 bodies in the poses")
    assert sim.names() == ["ball", "crate", "capsule", "tetromino", "pillar", "fish"]


def test_every_refusal_has_its_code_and_changes_nothing(start_node, probe, tmp_path):
    node, sim = start_paused(start_node, probe, "default")
    before = sim.names()
    flock_file = tmp_path / "school.yaml"
    flock_file.write_text("flock: {count: 20, spawn: {extent: [2, 2, 2]}, model: sphere}\n")
    urdf = tmp_path / "robot.urdf"
    urdf.write_text("<robot/>")

    cases = [
        (dict(name="b"), R.NO_RESOURCE, "both empty"),
        (dict(name="b", uri=str(tmp_path / "robot.sdf")), R.UNSUPPORTED_FORMAT,
         "not a .yaml, .stl, .obj, .urdf or .xacro file"),
        (dict(name="b", uri=str(urdf)), R.RESOURCE_PARSE_ERROR, "no <link>"),
        (dict(name="b", resource="<robot name='r'><link name='a'>"), R.RESOURCE_PARSE_ERROR,
         "resource_string: robot.urdf_xml: URDF text: malformed XML"),
        (dict(name="b", uri="package://robots/robot.yaml"), R.UNSUPPORTED_FORMAT, "only local files are spawned"),
        (dict(name="b", uri=str(tmp_path / "missing.yaml")), R.RESOURCE_PARSE_ERROR, "cannot read"),
        (dict(name="b", resource="body: {shape: box, size: [1, 1"), R.RESOURCE_PARSE_ERROR, "malformed YAML: line 2"),
        (dict(name="b", resource="body: {shape: box, size: [1, -1, 1]}"), R.RESOURCE_PARSE_ERROR,
         "resource_string: body (b).size[1]: must be > 0, got -1"),
        (dict(name="b", resource="tree: {}"), R.RESOURCE_PARSE_ERROR, "exactly one key, body, flock or robot"),
        (dict(name="crate", resource=BOX), R.NAME_NOT_UNIQUE, "name 'crate' is taken by a body"),
        (dict(name="fish", resource=BOX), R.NAME_NOT_UNIQUE, "taken by a flock"),
        (dict(name="", resource=BOX), R.NAME_INVALID, "name is empty"),
        (dict(name="my box", resource=BOX), R.NAME_INVALID, "not usable"),
        (dict(name="b", resource=BOX, position=(math.nan, 0, 1)), R.INVALID_POSE, "must be finite"),
        (dict(name="b", resource=BOX, orientation=(0, 0, 0, 0)), R.INVALID_POSE, "zero quaternion"),
        (dict(name="b", resource=BOX, frame="map"), R.INVALID_POSE, "'map'"),
        (dict(name="b", resource=BOX, namespace="robot1"), Result.RESULT_FEATURE_UNSUPPORTED, "entity_namespace"),
    ]
    for kwargs, code, text in cases:
        reply = sim.spawn(**kwargs)
        assert reply.result.result == code and text in reply.result.error_message, (kwargs, reply.result)
        assert reply.entity_name == ""
    assert sim.names() == before

    # allow_renaming: a taken or empty name gets a free one; a file works as uri
    renamed = sim.spawn("crate", BOX, position=(8, 8, 1), allow_renaming=True)
    assert renamed.result.result == OK and renamed.entity_name == "crate_2"
    generated = sim.spawn("", BOX, position=(8, -8, 1), allow_renaming=True)
    assert generated.result.result == OK and generated.entity_name == "body"
    from_file = sim.spawn("school", uri=f"file://{flock_file}", position=(0, 0, 10))
    assert from_file.result.result == OK, from_file.result
    assert sim.names() == [*before[:-1], "crate_2", "body", "fish", "school"]

    # entity states: unknown names, frames, NaN, fixed bodies and flocks with a twist
    SR = SetEntityState.Response
    for kwargs, code, text in [
        (dict(name="nobody"), Result.RESULT_NOT_FOUND, "no body, flock or robot named 'nobody'"),
        (dict(name="crate", position=(0, 0, math.inf)), SR.INVALID_POSE, "must be finite"),
        (dict(name="crate", position=(0, 0, 1), frame="odom"), SR.INVALID_POSE, "'odom'"),
        (dict(name="pillar", position=(6, 0, 4), linear=(1, 0, 0)), FAILED, "pillar is fixed"),
        (dict(name="fish", position=(0, 0, 8), linear=(1, 0, 0)), FAILED, "steer themselves"),
        (dict(name="fish", position=(0, 0, 8), orientation=(0, 0, 1, 0)), SR.INVALID_POSE, "no orientation"),
        (dict(name="fish", position=(0, 0, 200)), FAILED, "outside its bounds"),
    ]:
        name = kwargs.pop("name")
        reply = sim.set_state(name, **kwargs)
        assert reply.result.result == code and text in reply.result.error_message, (name, kwargs, reply.result)
    assert vec(sim.state("crate").state.pose.position) == [-2.0, 1.0, 3.0]

    # queries: POSIX ERE filter, sphere bounds, unsupported filters
    assert sim.names("^c") == ["crate", "capsule", "crate_2"]
    assert sim.names("[[:digit:]]$") == ["crate_2"]
    bad = GetEntities.Request()
    bad.filters.filter = "("
    reply = sim.call(GetEntities, bad)
    assert reply.result.result == FAILED and "invalid regular expression" in reply.result.error_message
    categories = GetEntities.Request()
    categories.filters.categories = [EntityCategory(category=EntityCategory.CATEGORY_ROBOT)]
    robots = sim.call(GetEntities, categories)  # (categories and tags: tests/test_node_worlds.py)
    assert robots.result.result == OK and list(robots.entities) == []
    near = GetEntitiesStates.Request()
    near.filters.bounds.type = Bounds.TYPE_SPHERE
    near.filters.bounds.points = [_point(7.0, 0.0, 4.0), _point(0.6, 0.0, 0.0)]  # 0.5 m from the pillar's face
    reply = sim.call(GetEntitiesStates, near)
    assert reply.result.result == OK and list(reply.entities) == ["pillar"]
    assert vec(reply.states[0].pose.position) == [6.0, 0.0, 4.0]
    near.filters.bounds.type = Bounds.TYPE_BOX
    assert sim.call(GetEntitiesStates, near).result.result == Result.RESULT_FEATURE_UNSUPPORTED

    # reset scopes
    unsupported = sim.reset(ResetSimulation.Request.SCOPE_TIME)
    assert unsupported.result.result == Result.RESULT_FEATURE_UNSUPPORTED and "SCOPE_TIME" in \
        unsupported.result.error_message
    assert sim.names() == [*before[:-1], "crate_2", "body", "fish", "school"]
    assert sim.delete("crate").result.result == OK
    assert sim.reset(ResetSimulation.Request.SCOPE_SPAWNED).result.result == OK
    assert sim.names() == ["ball", "capsule", "tetromino", "pillar", "fish"]
    assert sim.reset(ResetSimulation.Request.SCOPE_DEFAULT).result.result == OK  # ALL: as loaded
    assert sim.names() == before


def _point(x, y, z):
    from geometry_msgs.msg import Vector3

    return Vector3(x=float(x), y=float(y), z=float(z))


def test_a_flock_of_1000_spawns_in_one_request_and_moves_rigidly(start_node, probe):
    school = probe.subscribe("/cgp_sim/flocks/school/poses", PoseArray)
    node, sim = start_paused(start_node, probe, "zero_g")
    resource = ("flock: {count: 1000, spawn: {extent: [8, 8, 8]}, bounds: {min: [-40, -40, -40], "
                "max: [40, 40, 40]}, model: fish}")
    reply = sim.spawn("school", resource, position=(0.0, -20.0, 0.0))
    assert reply.result.result == OK, reply.result
    probe.wait_for_publisher("/cgp_sim/flocks/school/poses")
    assert sim.step(1).result.result == OK
    probe.spin_until(lambda: school.messages, 20, "the school's poses")
    assert len(school.messages[-1].poses) == 1000
    centroid = np.mean([vec(p.position) for p in school.messages[-1].poses], axis=0)
    state = sim.state("school").state
    np.testing.assert_allclose(vec(state.pose.position), centroid, atol=1e-9)
    np.testing.assert_allclose(vec(state.pose.position), [0.0, -20.0, 0.0], atol=0.5)
    assert quat(state.pose.orientation) == [0.0, 0.0, 0.0, 1.0]
    assert sim.set_state("school", (5.0, 5.0, 5.0)).result.result == OK
    np.testing.assert_allclose(vec(sim.state("school").state.pose.position), [5.0, 5.0, 5.0], atol=1e-9)
    assert sim.delete("school").result.result == OK
    probe.spin_until(lambda: probe.node.count_publishers("/cgp_sim/flocks/school/poses") == 0, 20,
                     "the school's publisher to go")

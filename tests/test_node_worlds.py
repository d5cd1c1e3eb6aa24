"""Issue 36, the rest of ``simulation_interfaces`` 1.5 over DDS: the node runs as its own process and this process
drives it as a tool written against the standard would — worlds (``get_available_worlds``, ``load_world``,
``unload_world``, ``get_current_world``), ``get_spawnables``, ``spawn_entities`` (all or nothing), entity info
and bounds, named poses, and ``get_simulator_features`` saying exactly that.  Waits have deadlines, never sleeps.
"""

from __future__ import annotations

import json

import pytest
from geometry_msgs.msg import PoseArray
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from sim_client import OK, SimClient
from simulation_interfaces.msg import (
    Bounds,
    EntityCategory,
    EntityInfo,
    Resource,
    Result,
    SimulationState,
    SimulatorFeatures,
    TagsFilter,
)
from simulation_interfaces.msg import SpawnEntity as SpawnEntityEntry
from simulation_interfaces.srv import (
    GetAvailableWorlds,
    GetCurrentWorld,
    GetEntities,
    GetEntityBounds,
    GetEntityInfo,
    GetNamedPoseBounds,
    GetNamedPoses,
    GetSimulatorFeatures,
    GetSpawnables,
    LoadWorld,
    SetEntityInfo,
    SetSimulationState,
    SpawnEntities,
    SpawnEntity,
    UnloadWorld,
)
from std_msgs.msg import String

from cgp_core.scene import builtin_scene_names

S = SimulationState
F = SimulatorFeatures
NOT_FOUND = Result.RESULT_NOT_FOUND
FAILED = Result.RESULT_OPERATION_FAILED
DEFAULT = ["ball", "crate", "capsule", "tetromino", "pillar", "fish"]
#: the `arm` scene's entities: its bodies, the 7-DoF arm's link bodies (the hand merged into the flange by its fixed
#: joint), the robot
ARM = ["pedestal", "table", "box_red", "box_green", "box_blue", "arm/base_link", "arm/shoulder_link",
       "arm/upper_arm_link", "arm/upper_arm_roll_link", "arm/forearm_link", "arm/forearm_roll_link", "arm/wrist_link",
       "arm/flange", "arm/finger_left", "arm/finger_right", "arm"]
BOX = "body: {shape: box, size: [0.4, 0.4, 0.4], mass: 2.0}"


def clock_ns(msg) -> int:
    return msg.clock.sec * 1_000_000_000 + msg.clock.nanosec


def load(sim, uri: str = "", resource: str = "", ignore: bool = False):
    return sim.call(LoadWorld, LoadWorld.Request(uri=uri, resource_string=resource,
                                                 ignore_missing_or_unsupported_assets=ignore), timeout=60.0)


def entry(name: str, resource: str, position=(0.0, 0.0, 0.0), allow_renaming: bool = False) -> SpawnEntityEntry:
    request = SpawnEntityEntry(name=name, entity_resource=Resource(resource_string=resource),
                               allow_renaming=allow_renaming)
    p = request.initial_pose.pose.position
    p.x, p.y, p.z = map(float, position)
    return request


def publishers(probe, topic: str) -> int:
    return probe.node.count_publishers(topic)


def test_features_say_exactly_what_is_supported(start_node, probe):
    start_node("--scene", "zero_g", "--start-paused", "true")
    probe.client(GetSimulatorFeatures, "/cgp_sim/get_simulator_features", timeout=60)
    features = SimClient(probe).call(GetSimulatorFeatures).features
    assert set(features.features) == {
        F.SPAWNING, F.DELETING, F.SPAWNING_RESOURCE_STRING, F.ENTITY_STATE_GETTING, F.ENTITY_STATE_SETTING,
        F.SIMULATION_RESET, F.SIMULATION_RESET_STATE, F.SIMULATION_RESET_SPAWNED, F.SIMULATION_STATE_GETTING,
        F.SIMULATION_STATE_SETTING, F.SIMULATION_STATE_PAUSE, F.STEP_SIMULATION_SINGLE, F.STEP_SIMULATION_MULTIPLE,
        F.STEP_SIMULATION_ACTION, F.WORLD_LOADING, F.WORLD_RESOURCE_STRING, F.WORLD_UNLOADING, F.WORLD_INFO_GETTING,
        F.WORLD_TAGS,
        F.AVAILABLE_WORLDS, F.SPAWNABLES, F.SPAWNING_ENTITIES, F.ENTITY_INFO_GETTING, F.ENTITY_INFO_SETTING,
        F.ENTITY_CATEGORIES, F.ENTITY_TAGS, F.ENTITY_BOUNDS, F.NAMED_POSES, F.POSE_BOUNDS}
    # not claimed: SIMULATION_RESET_TIME (time never goes back), ENTITY_BOUNDS_BOX / _CONVEX filters
    assert not {F.SIMULATION_RESET_TIME, F.ENTITY_BOUNDS_BOX, F.ENTITY_BOUNDS_CONVEX} & set(features.features)


def test_load_world_switches_scenes_with_clients_connected(start_node, probe, tmp_path):
    clock = probe.subscribe("/clock", Clock)
    events = probe.subscribe("/cgp_sim/events", String)
    joint_states = probe.subscribe("/cgp_sim/robots/arm/joint_states", JointState)
    fish_poses = probe.subscribe("/cgp_sim/flocks/fish/poses", PoseArray)
    start_node("--scene", "default")
    probe.client(GetSimulatorFeatures, "/cgp_sim/get_simulator_features", timeout=60)
    sim = SimClient(probe)
    probe.wait_for_publisher("/clock")

    # the gallery: every built-in scene, by name, with its description
    worlds = sim.call(GetAvailableWorlds)
    assert worlds.result.result == OK, worlds.result
    assert [w.name for w in worlds.worlds] == builtin_scene_names()
    assert all(w.world_resource.uri == w.name and w.description and w.tags for w in worlds.worlds)
    robots = sim.call(GetAvailableWorlds, GetAvailableWorlds.Request(filter=TagsFilter(tags=["robot"])))
    assert [w.name for w in robots.worlds] == ["arm", "arm_teleop"]
    assert list(robots.worlds[0].tags) == ["robot", "urdf", "contacts", "trajectory"]
    both = TagsFilter(tags=["flock", "couzin"], filter_mode=TagsFilter.FILTER_MODE_ALL)
    assert [w.name for w in sim.call(GetAvailableWorlds, GetAvailableWorlds.Request(filter=both)).worlds] == \
        ["couzin_torus", "predator"]
    current = sim.call(GetCurrentWorld)
    assert current.result.result == OK and current.world.name == "default" and current.world.world_resource.uri \
        == "default"
    assert "fish" in current.world.description and list(current.world.tags) == ["flock", "rigid_bodies"]
    assert sim.names() == DEFAULT
    probe.spin_until(lambda: len(fish_poses.messages) > 0, 20, "the fish school's poses")
    probe.spin_until(lambda: len(clock.messages) > 10, 20, "the default scene ticking")
    before = clock_ns(clock.messages[-1])

    # default -> arm: the entities, their topics and the clock follow; the world is left STOPPED
    loaded = load(sim, uri="arm")
    assert loaded.result.result == OK, loaded.result
    assert loaded.world.name == "arm" and loaded.world.world_resource.uri == "arm"
    assert sim.simulation_state() == S.STATE_STOPPED
    assert sim.names() == ARM
    assert sim.call(GetCurrentWorld).world.name == "arm"
    probe.spin_until(lambda: publishers(probe, "/cgp_sim/flocks/fish/poses") == 0, 20, "the fish publisher gone")
    probe.spin_until(lambda: publishers(probe, "/cgp_sim/bodies/box_red/odom") == 1, 20, "box_red's odom publisher")
    assert sim.set_simulation_state(S.STATE_PLAYING).result.result == OK
    probe.spin_until(lambda: len(joint_states.messages) > 5, 30, "the arm's joint_states")
    assert list(joint_states.messages[-1].name)[:2] == ["shoulder_pan", "shoulder_lift"]
    probe.spin_until(lambda: clock_ns(clock.messages[-1]) > before + 10 * round(1e9 / 60), 20, "time going on")

    # and back: the fish again, the arm's topics gone
    fish_before = len(fish_poses.messages)
    back = load(sim, uri="default")
    assert back.result.result == OK, back.result
    assert sim.names() == DEFAULT
    assert sim.set_simulation_state(S.STATE_PLAYING).result.result == OK
    probe.spin_until(lambda: len(fish_poses.messages) > fish_before + 5, 30, "the fish school again")
    probe.spin_until(lambda: publishers(probe, "/cgp_sim/robots/arm/joint_states") == 0, 20, "the arm's topics gone")
    stamps = [clock_ns(m) for m in clock.messages]
    assert all(b > a for a, b in zip(stamps, stamps[1:])), "the clock went backwards or stood still in /clock"

    # refused, named, and the running world stays
    broken = tmp_path / "broken.yaml"
    broken.write_text("bodies:\n  - {name: b, shape: box, size: [1, -1, 1]}\n")
    for request, code, words in (
            (dict(uri="no_such_world"), NOT_FOUND, "no built-in scene of that name"),
            (dict(uri=str(tmp_path / "missing.yaml")), NOT_FOUND, "no such scene file"),
            (dict(uri="/x/world.sdf"), LoadWorld.Response.UNSUPPORTED_FORMAT, ".sdf file"),
            (dict(uri="https://example.com/w.yaml"), LoadWorld.Response.UNSUPPORTED_FORMAT, "local files"),
            (dict(uri=str(broken)), LoadWorld.Response.RESOURCE_PARSE_ERROR, "size[1]: must be > 0"),
            (dict(uri="/dev/zero"), LoadWorld.Response.RESOURCE_PARSE_ERROR, "not a regular file"),
            (dict(resource="bodies: {a: 1"), LoadWorld.Response.RESOURCE_PARSE_ERROR, "resource_string"),
            (dict(), LoadWorld.Response.NO_RESOURCE, "both empty"),
            (dict(uri="arm", ignore=True), Result.RESULT_FEATURE_UNSUPPORTED, "loaded whole or not at all")):
        refused = load(sim, **request)
        assert refused.result.result == code and words in refused.result.error_message, (request, refused.result)
    assert sim.names() == DEFAULT and sim.call(GetCurrentWorld).world.name == "default"

    # a scene as text
    text = load(sim, resource="bodies: [{name: lone, shape: sphere, radius: 0.5, position: [0, 0, 3]}]")
    assert text.result.result == OK and sim.names() == ["lone"]
    assert sim.call(GetCurrentWorld).world.name == "resource_string"

    # unloaded: no world, no entities, nothing to play; loading brings one back.  (The first call of a client may
    # lose its reply to a Fast DDS race and be re-sent, ros_probe.Probe.call: its second answer is then
    # NO_WORLD_LOADED — the world is unloaded either way, which the calls after it check.)
    first = sim.call(UnloadWorld)
    assert first.result.result in (OK, UnloadWorld.Response.NO_WORLD_LOADED), first.result
    assert sim.call(GetCurrentWorld).result.result == GetCurrentWorld.Response.NO_WORLD_LOADED
    assert sim.names() == []
    assert sim.simulation_state() == S.STATE_NO_WORLD
    refused = sim.set_simulation_state(S.STATE_PLAYING)
    assert refused.result.result == SetSimulationState.Response.INCORRECT_TRANSITION, refused.result
    again = sim.call(UnloadWorld)
    assert again.result.result == UnloadWorld.Response.NO_WORLD_LOADED, again.result
    nowhere = sim.spawn("b1", BOX)
    assert nowhere.result.result == Result.RESULT_INCORRECT_STATE and "no world" in nowhere.result.error_message
    assert load(sim, uri="default").result.result == OK
    assert sim.names() == DEFAULT and sim.simulation_state() == S.STATE_STOPPED
    probe.spin_for(0.2)
    loads = [json.loads(m.data) for m in events.messages if json.loads(m.data).get("name") == "load_world"]
    # (the first: sim_client's warm-up request, refused as NO_RESOURCE) every call is a line on ~/events
    assert [(e["uri"], e["result"]) for e in loads[:3]] == [("", "NO_RESOURCE"), ("arm", "OK"), ("default", "OK")]
    assert [e["result"] for e in loads[3:6]] == ["NOT_FOUND", "NOT_FOUND", "UNSUPPORTED_FORMAT"]
    assert loads[1]["world"] == "arm"


def test_spawn_entities_info_bounds_named_poses(start_node, probe):
    start_node("--scene", "default", "--start-paused", "true")
    probe.client(GetSimulatorFeatures, "/cgp_sim/get_simulator_features", timeout=60)
    sim = SimClient(probe)

    # all or nothing: one bad entry, nothing spawned; the reply names which and why
    bad = sim.call(SpawnEntities, SpawnEntities.Request(spawn_requests=[
        entry("b1", BOX, (3, -3, 1)), entry("b2", "body: {shape: box, size: [0.4, -1, 0.4]}")]))
    assert bad.result.result == SpawnEntities.Response.ENTITIES_SPAWN_FAILED, bad.result
    assert "1 (b2)" in bad.result.error_message and "nothing was spawned" in bad.result.error_message
    assert bad.results[1].result.result == SpawnEntity.Response.RESOURCE_PARSE_ERROR
    assert "size[1]" in bad.results[1].result.error_message
    assert bad.results[0].result.result == FAILED and "not spawned" in bad.results[0].result.error_message
    assert sim.names() == DEFAULT
    twice = sim.call(SpawnEntities, SpawnEntities.Request(spawn_requests=[entry("b1", BOX), entry("b1", BOX)]))
    assert twice.results[1].result.result == SpawnEntity.Response.NAME_NOT_UNIQUE and sim.names() == DEFAULT
    taken = sim.call(SpawnEntities, SpawnEntities.Request(spawn_requests=[entry("b1", BOX), entry("crate", BOX)]))
    assert taken.results[1].result.result == SpawnEntity.Response.NAME_NOT_UNIQUE and sim.names() == DEFAULT
    empty = sim.call(SpawnEntities, SpawnEntities.Request())
    assert empty.result.result == FAILED and "empty" in empty.result.error_message
    many = sim.call(SpawnEntities, SpawnEntities.Request(spawn_requests=[entry(f"m{k}", BOX) for k in range(65)]))
    assert many.result.result == FAILED and "at most 64" in many.result.error_message and sim.names() == DEFAULT

    good = sim.call(SpawnEntities, SpawnEntities.Request(spawn_requests=[
        entry("b1", BOX, (3, -3, 1)), entry("", "body: {shape: sphere, radius: 0.25}", (5, -3, 1), True)]))
    assert good.result.result == OK, good.result
    assert [r.entity_name for r in good.results] == ["b1", "body"]
    assert sim.names() == DEFAULT[:5] + ["b1", "body", "fish"]
    probe.spin_until(lambda: publishers(probe, "/cgp_sim/bodies/body/odom") == 1, 20, "the batch's odom publishers")

    # entity info: what it is by default, what it is told, and the filters that use it
    info = sim.call(GetEntityInfo, GetEntityInfo.Request(entity="pillar")).info
    assert info.category.category == EntityCategory.CATEGORY_STATIC_OBJECT and info.description == "fixed box body"
    assert sim.call(GetEntityInfo, GetEntityInfo.Request(entity="fish")).info.category.category == \
        EntityCategory.CATEGORY_DYNAMIC_OBJECT
    told = EntityInfo(category=EntityCategory(category=EntityCategory.CATEGORY_DYNAMIC_OBJECT),
                      description="a parcel", tags=["cargo", "red"])
    assert sim.call(SetEntityInfo, SetEntityInfo.Request(entity="b1", info=told)).result.result == OK
    got = sim.call(GetEntityInfo, GetEntityInfo.Request(entity="b1")).info
    assert (got.category.category, got.description, list(got.tags)) == (4, "a parcel", ["cargo", "red"])
    by_category = GetEntities.Request()
    by_category.filters.categories = [EntityCategory(category=EntityCategory.CATEGORY_DYNAMIC_OBJECT)]
    assert list(sim.call(GetEntities, by_category).entities) == ["b1", "fish"]
    by_tags = GetEntities.Request()
    by_tags.filters.tags = TagsFilter(tags=["red", "blue"], filter_mode=TagsFilter.FILTER_MODE_ANY)
    assert list(sim.call(GetEntities, by_tags).entities) == ["b1"]
    by_tags.filters.tags.filter_mode = TagsFilter.FILTER_MODE_ALL
    assert list(sim.call(GetEntities, by_tags).entities) == []
    unknown = sim.call(SetEntityInfo, SetEntityInfo.Request(entity="nobody", info=told))
    assert unknown.result.result == NOT_FOUND and "nobody" in unknown.result.error_message
    wrong = SetEntityInfo.Request(entity="b1", info=EntityInfo(category=EntityCategory(category=3)))
    refused = sim.call(SetEntityInfo, wrong)
    assert refused.result.result == FAILED and "category 3" in refused.result.error_message
    assert sim.call(GetEntityInfo, GetEntityInfo.Request(entity="b1")).info.description == "a parcel"

    # bounds: TYPE_BOX in the entity's own frame, the standard's order (upper corner, then lower)
    for name, half in (("b1", (0.2, 0.2, 0.2)), ("crate", (0.4, 0.3, 0.25)), ("body", (0.25, 0.25, 0.25)),
                       ("capsule", (0.2, 0.2, 0.7))):
        bounds = sim.call(GetEntityBounds, GetEntityBounds.Request(entity=name)).bounds
        assert bounds.type == Bounds.TYPE_BOX and len(bounds.points) == 2
        upper, lower = ([p.x, p.y, p.z] for p in bounds.points)
        assert upper == pytest.approx(half, abs=1e-12) and lower == pytest.approx([-h for h in half], abs=1e-12)
    missing = sim.call(GetEntityBounds, GetEntityBounds.Request(entity="nobody"))
    assert missing.result.result == NOT_FOUND and "nobody" in missing.result.error_message

    # named poses from the scene file, filtered by tags; their bounds
    poses = sim.call(GetNamedPoses).poses
    assert [p.name for p in poses] == ["drop_zone", "pillar_top", "school_centre"]
    assert [poses[1].pose.position.x, poses[1].pose.position.y, poses[1].pose.position.z] == [6.0, 0.0, 8.5]
    spawn = GetNamedPoses.Request(tags=TagsFilter(tags=["spawn", "lookout"], filter_mode=TagsFilter.FILTER_MODE_ALL))
    assert [p.name for p in sim.call(GetNamedPoses, spawn).poses] == ["pillar_top"]
    box = sim.call(GetNamedPoseBounds, GetNamedPoseBounds.Request(name="drop_zone")).bounds
    assert box.type == Bounds.TYPE_BOX and [[p.x, p.y, p.z] for p in box.points] == [[4, -2, 4], [2, -4, 0]]
    ball = sim.call(GetNamedPoseBounds, GetNamedPoseBounds.Request(name="pillar_top")).bounds
    assert ball.type == Bounds.TYPE_SPHERE and [ball.points[0].z, ball.points[1].x] == [8.5, 0.5]
    none = sim.call(GetNamedPoseBounds, GetNamedPoseBounds.Request(name="school_centre"))
    assert none.result.result == OK and none.bounds.type == Bounds.TYPE_EMPTY
    nowhere = sim.call(GetNamedPoseBounds, GetNamedPoseBounds.Request(name="nowhere"))
    assert nowhere.result.result == NOT_FOUND and "drop_zone" in nowhere.result.error_message

    # the spawnables: the shipped robots and meshes by the uri spawn_entity takes, and the YAML entries
    spawnables = sim.call(GetSpawnables)
    uris = [s.uri for s in spawnables.spawnables]
    assert {"arm.urdf", "pendulum.urdf", "rock.stl", "mug.obj"} <= set(uris)
    assert any("{flock:" in s.description for s in spawnables.spawnables)
    rock = sim.spawn("rock", uri="rock.stl", position=(-3, -3, 2))
    assert rock.result.result == OK, rock.result

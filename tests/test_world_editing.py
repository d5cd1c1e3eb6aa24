"""Editing a running world (cgp_core, no ROS): spawn, delete, teleport, query, reset scopes.

What must hold: a spawned body obeys the same physics as a scene body (closed forms), everything per body
follows a spawn or delete (state, wrenches, contacts, sleep, the boids' obstacles), the bodies that stay are
untouched, and a refused edit changes nothing.
"""

from __future__ import annotations

import numpy as np
import pytest

from cgp_core import EditError, SceneError, World, parse_scene

G = 9.81
BOX = {"body": {"shape": "box", "size": [0.4, 0.4, 0.4], "mass": 2.0}}

RESTING = """
world: {gravity: [0, 0, -9.81], ground: true, rolling_resistance: 0.01}
bodies:
  - {name: base, shape: box, size: [1.0, 1.0, 0.5], mass: 5.0, position: [0, 0, 0.25]}
"""


def settle(world: World, ticks: int = 200) -> None:
    for _ in range(ticks):
        world.step()


def snapshot(world: World) -> dict:
    """Everything a refused edit must leave as it was."""
    return {"model": world.body_model, "names": world.entity_names(), "flocks": list(world.flocks),
            "state": {k: getattr(world.body_state, k).copy() for k in
                      ("position", "orientation", "linear_momentum", "angular_momentum")},
            "boids": [f.positions.copy() for f in world.flocks], "spawned": list(world.spawned),
            "version": world.model_version, "wrenches": world.wrenches.active}


def assert_unchanged(world: World, before: dict) -> None:
    assert world.body_model is before["model"] and world.entity_names() == before["names"]
    assert world.flocks == before["flocks"] and world.spawned == before["spawned"]
    assert world.model_version == before["version"] and world.wrenches.active == before["wrenches"]
    for key, value in before["state"].items():
        np.testing.assert_array_equal(getattr(world.body_state, key), value, err_msg=key)
    for flock, positions in zip(world.flocks, before["boids"]):
        np.testing.assert_array_equal(flock.positions, positions)


# ---- spawn ------------------------------------------------------------------------------------------------

def test_a_spawned_body_falls_freely_and_reports_g():
    """Constant force from rest: v = −g t exactly (whatever the integrator, the kick is exact for a constant
    force), and the acceleration of the last tick is −g."""
    world = World.from_scene("default")
    model_before = world.body_model
    assert world.spawn(BOX, name="box1", position=[10, 10, 20]) == "body"
    assert world.body_model is not model_before  # a new model object: caches keyed on it rebuild
    assert world.body_model.names[-1] == "box1" and world.spawned == ["box1"]
    state = world.entity_state("box1")
    np.testing.assert_array_equal(state.linear_acceleration, 0.0)  # no tick yet
    for _ in range(30):
        world.step()
    state = world.entity_state("box1")
    t = 30 * world.dt
    np.testing.assert_allclose(state.linear_velocity, [0, 0, -G * t], atol=1e-12)
    np.testing.assert_allclose(state.linear_acceleration, [0, 0, -G], atol=1e-9)
    np.testing.assert_allclose(state.angular_velocity, 0.0, atol=1e-15)
    assert state.position[2] == pytest.approx(20 - 0.5 * G * t ** 2, abs=G * t * world.dt)  # within one step
    # later edits do not erase what the last tick did to the others
    world.spawn(BOX, name="box2", position=[-10, 10, 20])
    world.set_body_state("box2", [-10, 10, 21], [0, 0, 0, 1])
    np.testing.assert_allclose(world.entity_state("box1").linear_acceleration, [0, 0, -G], atol=1e-9)
    np.testing.assert_array_equal(world.entity_state("box2").linear_acceleration, 0.0)
    world.delete("ball")
    np.testing.assert_allclose(world.entity_state("box1").linear_acceleration, [0, 0, -G], atol=1e-9)


def test_spawn_errors_are_the_scene_file_errors_with_the_key_path():
    entry = {"shape": "box", "size": [0.4, -1, 0.4], "mass": 2.0}
    with pytest.raises(SceneError) as from_scene:
        parse_scene("bodies: [{name: box1, shape: box, size: [0.4, -1, 0.4], mass: 2.0}]", "scene.yaml")
    world = World.from_scene("zero_g")
    before = snapshot(world)
    with pytest.raises(SceneError) as from_spawn:
        world.spawn({"body": entry}, name="box1", source="spawn_entity")
    assert str(from_scene.value) == "scene.yaml: bodies[0] (box1).size[1]: must be > 0, got -1"
    assert str(from_spawn.value) == "spawn_entity: body (box1).size[1]: must be > 0, got -1"
    assert_unchanged(world, before)

    cases = [
        ({"body": {**entry, "size": [1, 1, 1], "position": [0, 0, 1]}},
         "spawn_entity: body.position: given by the request's initial_pose; leave it out"),
        ({"body": {**entry, "size": [1, 1, 1], "name": "x"}},
         "spawn_entity: body.name: given by the request's name; leave it out"),
        ({"flock": {"count": 10, "spawn": {"center": [0, 0, 1]}}},
         "spawn_entity: flock.spawn.center: given by the request's initial_pose (the spawn centre); leave it out"),
        ({"tree": {}}, "spawn_entity: must be a mapping with exactly one key, body, flock or robot (a scene "
                       "file's bodies / flocks / robots entry), got a mapping of 1 keys, none of them body, flock "
                       "or robot"),
        ({"robot": {}}, "spawn_entity: robot.urdf: missing (a .urdf or .xacro file, or urdf_xml: URDF XML text)"),
        ({"body": {"shape": "cube"}}, "spawn_entity: body (box1).shape: must be one of sphere, box, capsule, "
                                      "particles, convex, compound, mesh, got 'cube'\n"
                                      "spawn_entity: body (box1).radius: missing"),
        ({"flock": {"count": 0}}, "spawn_entity: flock (box1).count: must be >= 1, got 0"),
    ]
    for data, message in cases:
        with pytest.raises(SceneError) as error:
            world.spawn(data, name="box1", source="spawn_entity")
        assert str(error.value) == message
        assert_unchanged(world, before)


def test_refused_names_and_poses_change_nothing():
    world = World.from_scene("default")
    before = snapshot(world)
    for name, kind in (("crate", "name_taken"), ("fish", "name_taken"), ("", "name_invalid"),
                       ("2box", "name_invalid"), ("a/b", "name_invalid"), ("x" * 200, "name_invalid")):
        with pytest.raises(EditError) as error:
            world.spawn(BOX, name=name)
        assert error.value.kind == kind, name
    for position, orientation in (([np.nan, 0, 1], [0, 0, 0, 1]), ([0, 0, 1], [0, 0, 0, 0]),
                                  ([0, 0, np.inf], [0, 0, 0, 1]), ([0, 0, 1], [0, np.nan, 0, 1])):
        with pytest.raises(EditError) as error:
            world.spawn(BOX, name="box1", position=position, orientation=orientation)
        assert error.value.kind == "invalid_pose"
        with pytest.raises(EditError) as error:
            world.set_body_state("crate", position, orientation)
        assert error.value.kind == "invalid_pose"
    with pytest.raises(EditError) as error:
        world.set_body_state("pillar", [6, 0, 4], [0, 0, 0, 1], linear_velocity=[1, 0, 0])
    assert error.value.kind == "not_possible" and "pillar is fixed" in str(error.value)
    for name in ("nobody", "fish"):
        with pytest.raises(EditError) as error:
            world.set_body_state(name, [0, 0, 1], [0, 0, 0, 1])
        assert error.value.kind == ("unknown" if name == "nobody" else "not_possible")
    with pytest.raises(EditError) as error:
        world.delete("nobody")
    assert error.value.kind == "unknown" and "no body, flock or robot named 'nobody'" in str(error.value)
    with pytest.raises(EditError) as error:
        world.move_flock("fish", [0, 0, 100])  # outside its bounds
    assert error.value.kind == "not_possible"
    with pytest.raises(EditError):
        world.spawn({"flock": {"count": 5}}, name="school", position=[0, 0, 8], orientation=[0, 0, 1, 0])
    assert_unchanged(world, before)


def test_a_spawned_box_lands_on_a_resting_one_and_both_come_to_rest_stacked():
    world = World(parse_scene(RESTING))
    settle(world, 120)
    assert world.bodies_asleep
    world.spawn(BOX, name="top", position=[0.1, 0.0, 1.5])
    assert not world.bodies_asleep  # a spawn wakes the bodies
    settle(world, 240)
    top, base = world.entity_state("top"), world.entity_state("base")
    assert top.position[2] == pytest.approx(0.5 + 0.2, abs=5e-3)  # resting on the base's top face
    assert base.position[2] == pytest.approx(0.25, abs=5e-3)
    assert np.linalg.norm(top.linear_velocity) < 0.05


def test_a_flock_of_1000_spawns_in_one_call_and_boids_avoid_a_body_spawned_among_them():
    world = World.from_scene("zero_g")
    world.spawn({"flock": {"count": 1000, "spawn": {"extent": [6, 6, 6]}, "bounds": {"min": [-20, -20, -20],
                                                                                      "max": [20, 20, 20]}}},
                name="school", position=[0, 0, -8])
    school = world.flocks[-1]
    assert school.count == 1000 and world.entity_kind("school") == "flock"
    np.testing.assert_allclose(school.positions.mean(axis=0), [0, 0, -8], atol=0.3)
    # a fixed ball dropped into the middle of the school: some boids are inside it now
    radius = 1.5
    world.spawn({"body": {"shape": "sphere", "radius": radius, "fixed": True}}, name="rock", position=[0, 0, -8])
    inflated = radius + 0.5 * school.params.boid_size
    inside = np.linalg.norm(school.positions - [0, 0, -8], axis=1) < inflated
    assert inside.sum() > 10
    world.step()  # the boids see the new body (Obstacles.from_bodies each tick) and are put out of it
    distance = np.linalg.norm(school.positions - [0, 0, -8], axis=1)
    assert distance.min() >= inflated - 1e-9


def test_moving_a_flock_translates_it_rigidly():
    world = World.from_scene("zero_g")
    birds = world.flocks[0]
    positions, velocities = birds.positions.copy(), birds.velocities.copy()
    target = np.array([1.0, 18.0, 12.0])
    world.move_flock("birds", target)
    np.testing.assert_allclose(birds.positions.mean(axis=0), target, atol=1e-12)
    np.testing.assert_allclose(birds.positions - positions, np.broadcast_to(target - positions.mean(axis=0),
                                                                            positions.shape), atol=1e-12)
    np.testing.assert_array_equal(birds.velocities, velocities)
    state = world.entity_state("birds")
    np.testing.assert_allclose(state.position, target, atol=1e-12)
    np.testing.assert_allclose(state.linear_velocity, velocities.mean(axis=0))
    np.testing.assert_array_equal(state.orientation, [0, 0, 0, 1])


# ---- delete -----------------------------------------------------------------------------------------------

def test_the_bodies_that_stay_are_untouched_by_a_spawn_and_a_delete():
    """zero_g, no contacts: spawning a far-away body and deleting it again leaves the other bodies' and the
    flock's trajectories bit for bit those of a world that never had it."""
    edited, plain = World.from_scene("zero_g"), World.from_scene("zero_g")
    for world in (edited, plain):
        world.apply_wrench("spinner", force=[0, 1, 0], point=[3.1, 0, 2], duration=-1)
    edited.spawn(BOX, name="visitor", position=[-50, 0, 0])
    for _ in range(20):
        edited.step()
        plain.step()
    edited.delete("visitor")
    assert edited.body_model.names == plain.body_model.names
    for _ in range(20):
        edited.step()
        plain.step()
    for key in ("position", "orientation", "linear_momentum", "angular_momentum"):
        np.testing.assert_array_equal(getattr(edited.body_state, key), getattr(plain.body_state, key))
    np.testing.assert_array_equal(edited.flocks[0].positions, plain.flocks[0].positions)


def test_deleting_a_body_clears_its_wrenches_and_the_others_follow_their_body():
    world = World.from_scene("zero_g")
    world.apply_wrench("box", force=[1, 0, 0], duration=-1)
    world.apply_wrench("spinner", force=[0, 2, 0], duration=-1)  # spinner's index goes 1 -> 0
    world.delete("box")
    assert world.body_model.names == ["spinner"] and world.wrenches.active == 1
    v0 = world.entity_state("spinner").linear_velocity
    for _ in range(60):
        world.step()
    v = world.entity_state("spinner").linear_velocity
    np.testing.assert_allclose(v - v0, [0, 2.0 * 60 * world.dt / 1.0, 0], atol=1e-12)  # Δv = F t / m, m = 1 kg
    world.delete("birds")
    assert world.entity_names() == ["spinner"] and world.flocks == []
    world.step()


def test_a_deleted_support_lets_the_sleeping_body_on_it_fall():
    world = World(parse_scene(RESTING))
    world.spawn(BOX, name="top", position=[0, 0, 0.7])
    settle(world, 200)
    assert world.bodies_asleep
    world.delete("base")
    assert not world.bodies_asleep
    settle(world, 60)
    assert world.entity_state("top").position[2] == pytest.approx(0.2, abs=5e-3)  # now on the ground


# ---- teleport ---------------------------------------------------------------------------------------------

def test_teleport_sets_pose_and_momenta_from_the_twist_and_wakes_the_bodies():
    world = World(parse_scene(RESTING))
    settle(world, 120)
    assert world.bodies_asleep
    v, w = np.array([1.0, 0.0, 2.0]), np.array([0.0, 0.0, 3.0])
    q = np.array([0.0, 0.0, np.sin(0.3), np.cos(0.3)])
    world.set_body_state("base", [0, 0, 3], q, v, w)
    assert not world.bodies_asleep
    state = world.entity_state("base")
    np.testing.assert_allclose(state.position, [0, 0, 3])
    np.testing.assert_allclose(state.orientation, q)
    np.testing.assert_allclose(state.linear_velocity, v, atol=1e-12)
    np.testing.assert_allclose(state.angular_velocity, w, atol=1e-12)
    np.testing.assert_array_equal(state.linear_acceleration, 0.0)  # a teleport is not an acceleration
    world.step()
    state = world.entity_state("base")
    np.testing.assert_allclose(state.linear_velocity, v + [0, 0, -G * world.dt], atol=1e-9)  # free flight
    np.testing.assert_allclose(state.linear_acceleration, [0, 0, -G], atol=1e-6)


def test_a_teleported_fixed_body_takes_the_pose():
    world = World.from_scene("default")
    world.set_body_state("pillar", [5, 1, 4], [0, 0, 0, 1])
    np.testing.assert_array_equal(world.entity_state("pillar").position, [5, 1, 4])
    world.step()
    np.testing.assert_array_equal(world.entity_state("pillar").position, [5, 1, 4])


# ---- query ------------------------------------------------------------------------------------------------

def test_entity_names_filter_is_a_posix_extended_regex_and_sphere_overlap_is_exact():
    world = World.from_scene("default")
    world.spawn(BOX, name="box7", position=[10, 0, 0.2])
    assert world.entity_names() == ["ball", "crate", "capsule", "tetromino", "pillar", "box7", "fish"]
    assert world.entity_names("^c") == ["crate", "capsule"]
    assert world.entity_names("[[:digit:]]$") == ["box7"]
    assert world.entity_names("(ball|fish)") == ["ball", "fish"]
    with pytest.raises(ValueError, match="invalid regular expression"):
        world.entity_names("(")
    # the pillar is the box [5.5, 6.5] x [-0.5, 0.5] x [0, 8]: a ball at x = 7 touches it for r >= 0.5
    assert "pillar" in world.entities_in_sphere([7.0, 0.0, 4.0], 0.5)
    assert "pillar" not in world.entities_in_sphere([7.0, 0.0, 4.0], 0.49)
    assert world.entities_in_sphere([0, 0, 8], 0.01) in (["fish"], [])  # boids near the spawn centre


# ---- reset ------------------------------------------------------------------------------------------------

def test_reset_scopes():
    world = World.from_scene("default")
    world.spawn(BOX, name="box1", position=[8, 8, 3])
    world.spawn({"flock": {"count": 20}}, name="school", position=[0, 0, 12])
    settle(world, 30)
    # state only: the spawned stay, back at their spawn state; time keeps running
    t = world.time
    world.reset(state=True, spawned=False)
    assert world.time == t and world.spawned == ["box1", "school"]
    np.testing.assert_allclose(world.entity_state("box1").position, [8, 8, 3])
    np.testing.assert_allclose(world.entity_state("ball").position, [0, 0, 4])
    settle(world, 30)
    # spawned only: they go, the others keep their state
    ball = world.entity_state("ball").position
    world.reset(state=False, spawned=True)
    assert "box1" not in world.entity_names() and "school" not in world.entity_names()
    np.testing.assert_array_equal(world.entity_state("ball").position, ball)
    # both: the scene as loaded, deleted scene entities back
    world.delete("crate")
    world.delete("fish")
    world.reset()
    assert world.entity_names() == ["ball", "crate", "capsule", "tetromino", "pillar", "fish"]
    assert world.spawned == []
    np.testing.assert_allclose(world.entity_state("crate").position, [-2, 1, 3])
    settle(world, 5)


def test_body_distances_are_the_closed_forms_for_every_shape():
    from cgp_core.editing import body_distances

    world = World(parse_scene("""
world: {gravity: [0, 0, 0], ground: false}
bodies:
  - {name: ball, shape: sphere, radius: 1.0, position: [0, 0, 0]}
  - {name: crate, shape: box, size: [2, 4, 6], position: [10, 0, 0],
     orientation: [0, 0, 0.7071067811865476, 0.7071067811865476]}
  - {name: pill, shape: capsule, radius: 0.5, length: 2.0, position: [0, 10, 0]}
  - {name: trio, shape: particles, radius: 0.25, particles: [[0, 0, 0, 1], [2, 0, 0, 1], [0, 2, 0, 1]],
     position: [0, 0, 10]}
"""))
    point = np.array([0.0, 0.0, 5.0])
    expected = [4.0,                                     # |p| - r
                np.hypot(np.hypot(10 - 2, 0), 5 - 3),    # box turned 90° about z: x half size 2 (was y), z half 3
                np.hypot(10, 5 - 1) - 0.5,               # capsule segment z in [-1, 1] around (0, 10, 0)
                np.linalg.norm([0, 0, 10 - 5]) - 0.25]   # nearest particle: the one at the origin (0, 0, 10)
    np.testing.assert_allclose(body_distances(world.body_model, world.body_state, point), expected, atol=1e-12)
    assert world.entities_in_sphere(point, 4.0) == ["ball"]
    assert world.entities_in_sphere(point, 3.99) == []

"""Issue 36 in the core, without ROS: another scene loaded into a running :class:`cgp_core.World` (and unloaded),
entity info, entity bounds against the shapes' closed forms, the ``named_poses`` section of the scene format
(parsing and validation), and a spawn batch added all or nothing."""

from __future__ import annotations

import re

import numpy as np
import pytest

from cgp_core import EditError, SceneError, World
from cgp_core.entities import body_frame_bounds, box_corners
from cgp_core.rotation import quat_to_matrix
from cgp_core.scene import available_scenes, builtin_scene_names, load_scene, parse_scene
from cgp_core.scene.loading import GALLERY_KEYS, gallery_fields
from cgp_core.user_input import UserInputError, load_yaml


def fresh(name: str) -> World:
    return World.from_scene(name)


def test_load_replaces_everything_and_keeps_the_clock():
    world = fresh("default")
    world.spawn({"body": {"shape": "box", "size": [0.4, 0.4, 0.4]}}, name="box1", position=[3, -3, 2])
    world.set_entity_info("crate", "dynamic_object", "told", ["t"])
    world.apply_wrench("crate", force=[0, 0, 50])
    for _ in range(5):
        world.step()
    time_ns, ticks, version = world.time_ns, world.ticks, world.model_version

    world.load("arm")
    arm = fresh("arm")
    assert world.entity_names() == arm.entity_names()
    assert (world.time_ns, world.ticks) == (time_ns, ticks)  # time keeps running: never back to 0
    assert world.model_version > version and world.spawned == [] and world.wrenches.active == 0
    assert world.robots is not None and world.scene.source == arm.scene.source
    np.testing.assert_array_equal(world.body_state.position, arm.body_state.position)  # the arm's initial state
    assert "crate" not in world.entity_names() and world.entity_info("box_red").description == "box body, 0.5 kg"
    world.step()
    assert world.time_ns == time_ns + world.dt_ns and world.ticks == ticks + 1
    world.spawn({"body": {"shape": "sphere", "radius": 0.1}}, name="extra", position=[1, 1, 1])
    world.delete("box_red")
    world.reset()  # back to the loaded scene, not the first one
    assert world.entity_names() == arm.entity_names()
    np.testing.assert_array_equal(world.body_state.position, arm.body_state.position)

    world.load("default")
    default = fresh("default")
    assert world.entity_names() == default.entity_names()
    np.testing.assert_array_equal(world.body_state.position, default.body_state.position)
    np.testing.assert_array_equal(world.flocks[0].positions, default.flocks[0].positions)
    assert world.robots is None and world.gravity.tolist() == [0.0, 0.0, -9.81]


def test_a_refused_scene_changes_nothing():
    world = fresh("default")
    world.step()
    names, version, time_ns = world.entity_names(), world.model_version, world.time_ns
    body_model = world.body_model
    with pytest.raises(SceneError, match=r"size\[1\]: must be > 0"):
        world.load(parse_scene("bodies: [{name: b, shape: box, size: [1, -1, 1]}]"))
    with pytest.raises(SceneError, match="no built-in scene of that name"):
        world.load("no_such_scene")
    assert world.entity_names() == names and world.model_version == version and world.time_ns == time_ns
    assert world.body_model is body_model and world.loaded


def test_the_callers_settings_stay_and_a_scene_that_cannot_take_them_is_refused():
    world = World.from_scene("default", substeps=2, dt=1 / 120)
    world.load("zero_g")
    assert world.substeps == 2 and world.dt_ns == round(1e9 / 120)


def test_unload_leaves_an_empty_world_that_still_steps():
    world = fresh("default")
    world.step()
    world.unload()
    assert not world.loaded and world.entity_names() == [] and world.named_poses == []
    t = world.time_ns
    world.step()
    assert world.time_ns == t + world.dt_ns
    world.load("default")
    assert world.loaded and world.entity_names() == fresh("default").entity_names()


def test_entity_info_defaults_set_and_lifetime():
    world = fresh("arm")
    assert world.entity_info("arm").category == "robot"
    assert world.entity_info("arm/flange").category == "robot"
    assert world.entity_info("arm/flange").description == "link flange of robot arm"
    assert world.entity_info("box_red").category == "object"
    assert world.entity_info("table").category == "static_object"
    world.spawn({"body": {"shape": "box", "size": [1, 1, 1], "fixed": True}}, name="wall", position=[5, 5, 0.5])
    assert world.entity_info("wall").category == "static_object"
    world.spawn({"flock": {"count": 10}}, name="birds", position=[0, 0, 5])
    assert world.entity_info("birds").category == "dynamic_object"

    world.set_entity_info("wall", "human", "not really", ["a", "b"])
    world.set_entity_info("box_red", "dynamic_object", "", ["b"])
    assert world.entity_info("wall").tags == ("a", "b")
    assert world.entities_with_info(world.entity_names(), ["human", "dynamic_object"]) == ["box_red", "wall", "birds"]
    assert world.entities_with_info(world.entity_names(), tags=["a", "b"], match_all=True) == ["wall"]
    assert world.entities_with_info(world.entity_names(), tags=["b"]) == ["box_red", "wall"]
    for args, words in ((("wall", "vehicle"), "category 'vehicle'"), (("wall", "object", "", [""]), r"tags\[0\]"),
                        (("wall", "object", "x" * 1001), "description"), (("nobody", "object"), "nobody")):
        with pytest.raises(EditError, match=words):
            world.set_entity_info(*args)
    assert world.entity_info("wall").category == "human"  # a refusal changed nothing

    world.reset()  # the spawned wall goes, and with it what it was told; box_red keeps its info
    assert world.entity_info("box_red").description == "" and world.entity_info("box_red").tags == ("b",)
    world.spawn({"body": {"shape": "sphere", "radius": 0.2}}, name="wall", position=[5, 5, 1])
    assert world.entity_info("wall").category == "object"  # a new entity of the same name starts afresh
    world.delete("box_red")
    world.reset()
    assert world.entity_info("box_red").category == "object"  # deleted, its info went; back from the scene afresh


BODIES = """
bodies:
  - {name: s, shape: sphere, radius: 0.3, position: [0, 0, 5], orientation: [0.3, 0.1, 0.2, 0.9]}
  - {name: b, shape: box, size: [0.8, 0.6, 0.5], position: [2, 0, 5], orientation: [0.3, 0.1, 0.2, 0.9]}
  - {name: c, shape: capsule, radius: 0.2, length: 1.0, position: [4, 0, 5]}
  - {name: p, shape: particles, radius: 0.1, particles: [[0, 0, 0, 1], [1, 0, 0, 1], [0, 1, 0, 1], [1, 1, 0, 1]],
     position: [6, 0, 5]}
  - {name: h, shape: convex, points: [[0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 2]], position: [8, 0, 5]}
  - name: k
    shape: compound
    position: [10, 0, 5]
    parts:
      - {shape: box, size: [1.0, 0.2, 0.4], orientation: [0, 0, 0.7071067811865476, 0.7071067811865476]}
      - {shape: sphere, radius: 0.1, position: [0, 0, 1.0]}
      - {shape: sphere, radius: 0.1, position: [0, 0, -1.0]}
flocks:
  - {name: f, count: 50, spawn: {center: [0, 0, 10], extent: [4, 4, 2]}, boid_size: 0.3}
"""


def test_bounds_of_the_shapes_are_their_closed_forms():
    world = World(parse_scene(BODIES))

    def bounds(name):
        lower, upper = world.entity_bounds(name)
        return np.round(lower, 12).tolist(), np.round(upper, 12).tolist()

    assert bounds("s") == ([-0.3] * 3, [0.3] * 3)
    assert bounds("b") == ([-0.4, -0.3, -0.25], [0.4, 0.3, 0.25])  # the body's own axes: turning it changes nothing
    assert bounds("c") == ([-0.2, -0.2, -0.7], [0.2, 0.2, 0.7])  # half length 0.5 + radius along z
    assert bounds("p") == ([-0.6, -0.6, -0.1], [0.6, 0.6, 0.1])  # about the COM at the square's centre
    # a tetrahedron of uniform density: COM at the mean of its vertices (0.5, 0.5, 0.5)
    assert bounds("h") == ([-0.5] * 3, [1.5] * 3)
    # compound: a 1.0 x 0.2 x 0.4 box turned 90 degrees about z (0.2 x 1.0 x 0.4) between spheres of 0.1 at
    # z = +-1 (the COM at the origin by symmetry)
    assert bounds("k") == ([-0.1, -0.5, -1.1], [0.1, 0.5, 1.1])
    lower, upper = world.entity_bounds("f")
    offsets = world.flocks[0].positions - world.flocks[0].centroid()
    assert np.allclose(lower, offsets.min(axis=0) - 0.15) and np.allclose(upper, offsets.max(axis=0) + 0.15)
    with pytest.raises(EditError, match="nobody"):
        world.entity_bounds("nobody")


def test_a_robots_bounds_hold_every_link_in_its_root_frame():
    world = fresh("arm")
    for _ in range(3):
        world.step()
    lower, upper = world.entity_bounds("arm")
    root = world.entity_state("arm")
    R0 = quat_to_matrix(root.orientation[None])[0]
    corners = []
    for name in [n for n in world.body_model.names if n.startswith("arm/")]:
        i = world.body_model.names.index(name)
        R = quat_to_matrix(world.body_state.orientation[i][None])[0]
        points = world.body_state.position[i] + box_corners(*body_frame_bounds(world.body_model, i)) @ R.T
        corners.append((points - root.position) @ R0)
    corners = np.concatenate(corners)
    assert np.all(corners >= lower - 1e-9) and np.all(corners <= upper + 1e-9)
    np.testing.assert_allclose(corners.min(axis=0), lower, atol=1e-9)  # tight: every face touches a link's box
    np.testing.assert_allclose(corners.max(axis=0), upper, atol=1e-9)
    assert upper[2] > 0.5  # the arm stands up from its base (the upper arm and forearm are 0.4 m each)


NAMED = """
named_poses:
  - {name: dock, position: [4, -2, 0], description: by the wall, tags: [spawn, robot],
     bounds: {min: [-1, -1, 0], max: [1, 1, 2]}}
  - {name: perch, position: [0, 0, 3], orientation: [0, 0, 2, 0], bounds: {radius: 0.5}}
  - {name: goal, position: [1, 2, 3]}
"""


def test_named_poses_are_parsed():
    scene = parse_scene(NAMED)
    dock, perch, goal = scene.named_poses
    assert (dock.name, dock.description, dock.tags) == ("dock", "by the wall", ("spawn", "robot"))
    assert dock.bounds.lower.tolist() == [-1, -1, 0] and dock.bounds.upper.tolist() == [1, 1, 2]
    assert perch.orientation.tolist() == [0, 0, 1, 0] and perch.bounds.radius == 0.5  # normalized
    assert goal.bounds is None and goal.orientation.tolist() == [0, 0, 0, 1] and goal.tags == ()
    world = World(scene)
    assert [p.name for p in world.named_poses] == ["dock", "perch", "goal"]
    assert world.named_pose("perch") is perch
    with pytest.raises(EditError, match="no named pose 'nowhere' .*dock, perch, goal"):
        world.named_pose("nowhere")


def test_scene_tags_and_the_gallery():
    assert parse_scene("tags: [indoor, robot]\n").tags == ("indoor", "robot")
    assert parse_scene("bodies: []\n").tags == ()
    for text, problem in (("tags: indoor", "tags: must be a list of strings"),
                          ("tags: [1]", "tags[0]: must be a string"),
                          (f"tags: {list(map(str, range(33)))}", "tags: 33 tags; at most 32")):
        with pytest.raises(SceneError, match=re.escape(problem)):
            parse_scene(text + "\n")
    gallery = {g.name: g for g in available_scenes()}
    assert sorted(gallery) == builtin_scene_names()
    for name, entry in gallery.items():  # what the gallery reads without validating is what loading gives
        scene = load_scene(name)
        assert (entry.tags, entry.description) == (scene.tags, scene.description), name
        assert entry.tags and len(entry.description) > 80


@pytest.mark.parametrize("text", [
    "tags: [a]\ndescription: d\nbodies: []\n",
    "# a comment\n---\ndescription: >\n  two\n  lines\ntags:\n- a\n- b\nworld: {substeps: 2}\n",
    "bodies:\n  - {name: x, shape: sphere}\ndescription: late\ntags: [z]  # after the bodies\n",
    "description: |\n  kept\n\n  as is\n\ntags: []\n",
    "{description: flow, tags: [f]}\n",                 # a flow mapping: the whole load
    "base: &t [x, y]\ntags: *t\ndescription: alias\n",  # an alias the entry needs: the whole load
    "description: one\n'quoted': 1\ntags: [q]\n",      # a quoted key at column 0: the whole load
    "world: {}\n",                                     # neither key
    "- a list\n",                                      # not a mapping
])
def test_the_gallery_reads_its_two_keys_as_the_whole_document_has_them(text):
    """The node lists the gallery at start-up from each scene's top-level description and tags only
    (gallery_fields), and gets what loading the whole document gives."""
    whole = load_yaml(text)
    expected = {k: whole[k] for k in GALLERY_KEYS if k in whole} if isinstance(whole, dict) else {}
    assert gallery_fields(text) == expected
    # a mistake after them does not hide them (the scene's load names it); one in them, or a key given twice, is
    # refused as the whole load refuses it
    broken_rest = "description: d\ntags: [t]\nbodies: [unclosed\n"
    assert gallery_fields(broken_rest) == {"description": "d", "tags": ["t"]}
    with pytest.raises(UserInputError):
        load_yaml(broken_rest)
    for bad in ("tags: [a]\ntags: [b]\n", "description: [unclosed\ntags: []\n", "a: 1\n---\nb: 2\n"):
        with pytest.raises(UserInputError):
            load_yaml(bad)
        with pytest.raises(UserInputError):
            gallery_fields(bad)


@pytest.mark.parametrize("entries, problems", [
    ("[{name: a, position: [0, 0, 0]}, {name: a, position: [1, 0, 0]}]", ["named_poses[1].name: duplicate named "
                                                                            "pose 'a'"]),
    ("[{name: a}]", ["named_poses[0] (a): missing key 'position'"]),
    ("[{name: 1a, position: [0, 0, 0]}]", ["named_poses[0].name: '1a' is not a ROS-safe name"]),
    ("[{name: a, position: [0, 0, 0], orientation: [0, 0, 0, 0]}]", ["named_poses[0] (a).orientation: zero "
                                                                       "quaternion"]),
    ("[{name: a, position: [0, 0, 2e6]}]", ["named_poses[0] (a).position[2]: must be in"]),
    ("[{name: a, position: [0, 0, 0], tags: spawn}]", ["named_poses[0] (a).tags: must be a list of strings"]),
    ("[{name: a, position: [0, 0, 0], tags: [1]}]", ["named_poses[0] (a).tags[0]: must be a string"]),
    ("[{name: a, position: [0, 0, 0], size: 3}]", ["named_poses[0].size: unknown key"]),
    ("[{name: a, position: [0, 0, 0], bounds: {radius: 0}}]", ["named_poses[0] (a).bounds.radius: must be > 0"]),
    ("[{name: a, position: [0, 0, 0], bounds: {radius: 1, min: [0, 0, 0]}}]", ["give either min and max (a box "
                                                                                "about the position) or radius "
                                                                                "(a sphere), not both"]),
    ("[{name: a, position: [0, 0, 0], bounds: {min: [0, 0, 0], max: [1, 0, 1]}}]", ["min must be below max on "
                                                                                     "every axis; not on y"]),
    ("[{name: a, position: [0, 0, 0], bounds: {min: [0, 0, 0]}}]", ["a box needs both min and max, missing max"]),
    ("{a: 1}", ["named_poses: must be a list of named poses, got a mapping"]),
    # every problem of the section at once
    ("[{name: a}, {name: b, position: [0, 0, 0], bounds: {radius: -1}}]",
     ["named_poses[0] (a): missing key 'position'", "named_poses[1] (b).bounds.radius: must be > 0"]),
])
def test_named_poses_are_validated(entries, problems):
    with pytest.raises(SceneError) as caught:
        parse_scene(f"named_poses: {entries}\n", "poses.yaml")
    text = str(caught.value)
    assert "poses.yaml" in text
    for problem in problems:
        assert problem in text, text


def test_a_batch_is_added_whole_or_not_at_all():
    world = fresh("default")
    taken = set(world.entity_names())
    box = {"body": {"shape": "box", "size": [0.4, 0.4, 0.4]}}
    one = world.prepare_spawn(box, name="one", taken=taken, position=[3, -3, 1])
    again = world.prepare_spawn(box, name="one", taken=taken, position=[4, -3, 1])
    crate = world.prepare_spawn(box, name="crate", taken=set(), position=[5, -3, 1])
    names, version = world.entity_names(), world.model_version
    with pytest.raises(EditError, match=r"entry 1 \(one\): name 'one' is also entry 0's"):
        world.add_spawned_all([one, again])
    with pytest.raises(EditError, match=r"entry 1 \(crate\): name 'crate' is taken by a body") as caught:
        world.add_spawned_all([one, crate])
    assert caught.value.entry == 1 and caught.value.kind == "name_taken"
    assert world.entity_names() == names and world.model_version == version
    two = world.prepare_spawn({"flock": {"count": 5}}, name="two", taken=taken, position=[0, 0, 5])
    assert world.add_spawned_all([one, two]) == ["body", "flock"]
    assert world.entity_names() == names[:-1] + ["one", "fish", "two"] and world.spawned == ["one", "two"]


def test_a_batch_refused_while_adding_takes_back_what_it_added():
    """The limit on boids is checked as each entity is added: the second flock passes it, so the first one, already
    added, goes again."""
    world = fresh("default")
    names, boids = world.entity_names(), sum(len(f.positions) for f in world.flocks)
    big = {"flock": {"count": 100_000, "spawn": {"extent": [100, 100, 100]},
                     "bounds": {"min": [-60, -60, -60], "max": [60, 60, 60]}}}
    first = world.prepare_spawn(big, name="first", taken=set(names), position=[0, 0, 0])
    second = world.prepare_spawn(big, name="second", taken=set(names), position=[0, 0, 0])
    with pytest.raises(EditError, match=r"entry 1 \(second\): the world has 100300 boids") as caught:
        world.add_spawned_all([first, second])
    assert caught.value.entry == 1 and caught.value.kind == "not_possible"
    assert world.entity_names() == names and world.spawned == []
    assert sum(len(f.positions) for f in world.flocks) == boids
    world.step()  # and it still steps

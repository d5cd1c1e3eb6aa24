"""A scene robot's ``trajectory:`` (cgp_core.robots.trajectory, cgp_core.scene.robots.parse_trajectory): followed
through the position drives from the world's start, as joint_trajectory_controller interpolates (the same
functions as the node's ``joint_trajectory``); a looping one goes on from its first point; a joint command wins
(a ``Robots.command`` from Python, ``World.stop_trajectory``, which the node calls for a ROS command); a reset, a
load and a spawn start it.  Every refusal names the file, the key path and the reason.  (The `arm` gallery scene's
point: tests/test_gallery.py; a ROS command winning over DDS: tests/test_node_robots.py.)"""

from __future__ import annotations

import copy

import numpy as np
import pytest
import yaml

from cgp_core import World
from cgp_core.robots.trajectory import check_trajectory, loop_time, sample, sample_many, sample_velocity
from cgp_core.scene import SceneError, load_scene

#: the 4-joint arm.urdf (limits: shoulder_pan ±3.1, shoulder_lift ±2, elbow ±2.5, wrist ±2 rad; velocity limits
#: 2, 2, 2.5, 3 rad/s; finger_right_joint mimics finger_left_joint) going out and back
ENTRY = {"name": "arm", "urdf": "arm.urdf", "joints": {"elbow": 0.5},
         "trajectory": {"points": [
             {"time": 1.0, "positions": {"shoulder_pan": 0.8, "elbow": 1.0}},
             {"time": 2.0, "positions": {"shoulder_pan": -0.4, "elbow": 0.5}}]}}
#: the joint error allowed while following: the drives' targets move once per tick (60 Hz) and the joints follow
#: within the tick, about a tick's motion at the trajectory's speeds (≤ 1.2 rad/s here: 0.02 rad)
TRACKING = 0.02


def scene(tmp_path, entry=ENTRY, name="traj.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump({"world": {"gravity": [0, 0, -9.81]}, "robots": [entry]}, sort_keys=False))
    return path


def joints(world, names=("shoulder_pan", "elbow")) -> np.ndarray:
    all_names, q, _, _ = world.robots.joint_state("arm")
    return np.array([q[all_names.index(j)] for j in names])


def run(world, seconds: float, each=None) -> None:
    for _ in range(round(seconds / world.dt)):
        world.step()
        if each is not None:
            each(world)


def test_sample_velocity_is_the_derivative_and_a_loop_repeats_its_cycle():
    for velocities in ([[], [], []], [[0.5, 0.0], [-1.0, 0.3], [0.5, 0.0]]):
        tr = check_trajectory(["a", "b"], 0, [1.0, 2.0, 3.5], [[1.0, 0.0], [0.0, 1.0], [1.0, 0.0]], velocities)
        start = np.array([0.2, -0.3])
        for t in (0.3, 0.9, 1.4, 2.2, 3.1):
            h = 1e-6
            slope = (sample(tr, t + h, start) - sample(tr, t - h, start)) / (2 * h)
            np.testing.assert_allclose(sample_velocity(tr, t, start), slope, atol=1e-6)
        np.testing.assert_array_equal(sample_velocity(tr, 4.0, start), [0.0, 0.0])
        many = np.array([0.0, 0.3, 0.9, 1.0 + 1e-9, 1.4, 2.2, 3.1, 3.5 + 1e-9, 4.0])  # (off the points' own times)
        positions, speeds = sample_many(tr, many, start)  # the scene's path check: vectorized, the same numbers
        np.testing.assert_allclose(positions, [sample(tr, t, start) for t in many], atol=1e-12)
        np.testing.assert_allclose(speeds, [sample_velocity(tr, t, start) for t in many], atol=1e-9)
        assert loop_time(tr, 3.0, True) == 3.0 and loop_time(tr, 4.0, False) == 4.0
        assert loop_time(tr, 3.5 + 0.7, True) == pytest.approx(1.0 + 0.7)  # the cycle [1, 3.5] s again
        assert loop_time(tr, 3.5 + 2.5 * 3 + 0.2, True) == pytest.approx(1.2)


def test_a_robot_follows_its_scene_trajectory_and_holds_its_last_point(tmp_path):
    world = World.from_scene(scene(tmp_path))
    followed = world.trajectories.robots["arm"]
    np.testing.assert_allclose(followed.start_positions, [0.0, 0.5])  # the initial pose (the lead-in's start)
    worst = 0.0

    def check(w):
        nonlocal worst
        expected = sample(followed.trajectory, w.time, followed.start_positions)
        worst = max(worst, float(np.abs(joints(w) - expected).max()))

    run(world, 2.0, check)
    assert worst <= TRACKING, worst
    assert "arm" not in world.trajectories.robots  # its last point commanded: the drives hold it
    run(world, 1.0)
    np.testing.assert_allclose(joints(world), [-0.4, 0.5], atol=1e-3)
    assert not world.take_events()


def test_a_looping_trajectory_goes_on_from_its_first_point(tmp_path):
    entry = copy.deepcopy(ENTRY)
    entry["trajectory"]["loop"] = True
    entry["trajectory"]["points"].append({"time": 3.0, "positions": {"shoulder_pan": 0.8, "elbow": 1.0}})
    world = World.from_scene(scene(tmp_path, entry))
    followed = world.trajectories.robots["arm"]
    worst = 0.0

    def check(w):
        nonlocal worst
        expected = sample(followed.trajectory, loop_time(followed.trajectory, w.time, True), followed.start_positions)
        worst = max(worst, float(np.abs(joints(w) - expected).max()))

    run(world, 6.0, check)  # the lead-in, then 2.5 cycles of 2 s
    assert worst <= TRACKING, worst
    assert "arm" in world.trajectories.robots
    np.testing.assert_allclose(joints(world), [-0.4, 0.5], atol=TRACKING)  # t = 6 s: point 1 (1 + 5 mod 2 s)


def test_a_command_wins_and_a_reset_a_load_and_a_spawn_start_the_trajectory(tmp_path):
    path = scene(tmp_path)
    world = World.from_scene(path)
    world.robots.command("arm", ["shoulder_pan"], effort=[0.0])  # before the first tick: it wins too
    world.step()
    assert "arm" not in world.trajectories.robots
    world.reset()  # the trajectory again
    assert "arm" in world.trajectories.robots
    run(world, 0.5)
    # a joint command from Python between ticks: the robot stops following (an info event says so)
    assert world.robots.command("arm", ["elbow"], position=[1.5]) == []
    world.step()
    assert "arm" not in world.trajectories.robots
    assert any("stops following its scene trajectory" in e.text for e in world.take_events())
    run(world, 2.0)
    assert abs(joints(world)[1] - 1.5) <= 1e-3  # the command held, not the trajectory's 0.5

    # a reset: from the start again, at the time of the reset
    world.reset()
    assert world.trajectories.robots["arm"].start_ns == world.time_ns
    t0 = world.time
    run(world, 1.0)
    np.testing.assert_allclose(joints(world), [0.8, 1.0], atol=TRACKING)  # its first point, 1 s after the reset
    assert world.stop_trajectory("arm") and not world.stop_trajectory("arm")
    run(world, 1.0)
    np.testing.assert_allclose(joints(world), [0.8, 1.0], atol=1e-3)  # stopped: the drives hold the last targets

    # a load, and a spawned robot: each from its own start
    world.load(path)
    assert world.trajectories.robots["arm"].start_ns == world.time_ns > t0
    run(world, 0.5)
    spawned_at = world.time_ns
    world.spawn({"robot": {k: v for k, v in ENTRY.items() if k != "name"}}, name="arm2", position=(0, 1.5, 0))
    assert world.trajectories.robots["arm2"].start_ns == spawned_at
    assert world.trajectories.robots["arm"].start_ns == spawned_at - round(0.5 / world.dt) * world.dt_ns
    run(world, 1.0)
    names, q, _, _ = world.robots.joint_state("arm2")
    np.testing.assert_allclose([q[names.index("shoulder_pan")], q[names.index("elbow")]], [0.8, 1.0], atol=TRACKING)
    world.delete("arm2")
    world.step()
    assert set(world.trajectories.robots) == {"arm"}


def _points(*points):
    return [{"time": t, "positions": p, **({"velocities": v} if v is not None else {})} for t, p, v in points]


REFUSALS = [
    ({"points": _points((1.0, {"knee": 0.1}, None))}, "trajectory.points[0].positions.knee",
     "not a movable joint of arm"),
    ({"points": _points((1.0, {"finger_right_joint": 0.01}, None))},
     "trajectory.points[0].positions.finger_right_joint", "mimics another joint"),
    ({"points": _points((1.0, {"elbow": 0.1}, None), (1.0, {"elbow": 0.2}, None))}, "trajectory.points[1].time",
     "times must increase"),
    ({"points": _points((1.0, {"elbow": 0.1}, None), (2.0, {"elbow": 2.7}, None))},
     "trajectory.points[1].positions.elbow", "outside the joint's limits [-2.5, 2.5]"),
    ({"points": _points((1.0, {"elbow": 0.1}, None), (2.0, {"wrist": 0.2}, None))},
     "trajectory.points[1].positions", "same joints as the first; missing elbow; extra wrist"),
    ({"points": _points((1.0, {"elbow": 0.1}, {"elbow": 0.0}), (2.0, {"elbow": 0.2}, None))},
     "trajectory.points[1].velocities", "at every point"),
    ({"points": _points((1.0, {"elbow": 0.1}, {"elbow": 4.0}))}, "trajectory.points[0].velocities.elbow",
     "beyond the joint's velocity limit"),
    ({"loop": True, "points": _points((1.0, {"elbow": 0.1}, None), (2.0, {"elbow": 0.2}, None))},
     "trajectory.points[1].positions", "ends where it starts"),
    ({"points": _points((0.2, {"shoulder_pan": 1.5}, None))}, "trajectory",
     "moves joint shoulder_pan at 7.5 at"),
    ({"points": _points((0.0, {"elbow": 0.2}, None))}, "trajectory.points[0].time", "not the robot's initial ones"),
    ({"points": _points((1.0, {"elbow": 0.1}, None)), "speed": 2}, "trajectory.speed", "unknown key"),
    ({"points": []}, "trajectory.points", "non-empty list"),
    ({"points": _points((1.0, {"elbow": "fast"}, None))}, "trajectory.points[0].positions.elbow",
     "must be a number"),
]


@pytest.mark.parametrize("trajectory, key, reason", REFUSALS, ids=[f"{r[1]}-{r[2][:16]}" for r in REFUSALS])
def test_a_bad_trajectory_is_refused_naming_the_file_the_key_and_the_reason(tmp_path, trajectory, key, reason):
    with pytest.raises(SceneError) as info:
        load_scene(scene(tmp_path, {**ENTRY, "trajectory": trajectory}, "bad.yaml"))
    text = str(info.value)
    assert f"bad.yaml: robots[0].{key}: " in text and reason in text, text


def test_a_cubic_that_overshoots_a_limit_is_refused(tmp_path):
    """Points inside the limits, velocities that make the cubic between them pass elbow's upper limit (2.5)."""
    trajectory = {"points": _points((1.0, {"elbow": 1.0}, {"elbow": 0.0}), (3.0, {"elbow": 2.4}, {"elbow": -2.4}))}
    with pytest.raises(SceneError, match=r"robots\[0\]\.trajectory: the path from point 0 to point 1 takes joint "
                                         r"elbow to 2\.5\d* at .* outside its limits \[-2\.5, 2\.5\]"):
        load_scene(scene(tmp_path, {**ENTRY, "trajectory": trajectory}))


def test_any_trajectory_value_is_a_scene_or_a_named_refusal():
    """Hypothesis: whatever a ``trajectory:`` holds (nesting, types, NaN, huge numbers, keys of every level in
    the wrong place), the scene loads or is refused with a SceneError naming the key — nothing else."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from cgp_core.scene import scene_from_dict

    keys = st.sampled_from(["points", "loop", "time", "positions", "velocities", "shoulder_pan", "elbow",
                            "finger_right_joint", "knee", "x"])
    leaves = (st.none() | st.booleans() | st.integers(-10, 10) | st.floats(allow_nan=True, allow_infinity=True)
              | st.sampled_from(["elbow", "1.0", ""]))
    values = st.recursive(leaves, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(keys, inner,
                                                                                              max_size=4),
                          max_leaves=20)
    point = st.fixed_dictionaries({"time": st.floats(-1, 5) | leaves,
                                   "positions": st.dictionaries(keys, st.floats(-3, 3) | leaves, max_size=3)},
                                  optional={"velocities": st.dictionaries(keys, st.floats(-3, 3), max_size=3)})
    shaped = st.fixed_dictionaries({"points": st.lists(point, max_size=4)}, optional={"loop": st.booleans()})

    @settings(max_examples=150, deadline=None)
    @given(value=values | shaped)
    def check(value):
        try:
            scene = scene_from_dict({"robots": [{**ENTRY, "trajectory": value}]}, "<fuzz>")
        except SceneError as exc:
            assert "robots[0].trajectory" in str(exc), str(exc)
            return
        assert (scene.robots[0].trajectory is None) == (value is None)  # (an empty `trajectory:` is none)

    check()

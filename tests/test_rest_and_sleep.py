"""Coming to rest: rolling resistance (a closed form) and sleeping bodies (exactly still, woken by commands)."""

import numpy as np
import pytest
from _bodies import make_bodies, sphere

from cgp_core import World, parse_scene
from cgp_core.collision import Ground
from cgp_core.dynamics import step_bodies
from cgp_core.integrators import make_integrator
from cgp_core.solver import make_solver
from cgp_core.world import SLEEP_SPEED, SLEEP_TIME

G = 9.81


# ---- rolling resistance -----------------------------------------------------------------------------------

@pytest.mark.parametrize("c_rr", [0.01, 0.05])
def test_a_rolling_ball_decelerates_at_five_sevenths_c_rr_g(c_rr):
    """The resisting torque c_rr N r about the contact point, against the ball's inertia about that point
    (7/5 m r²), decelerates a ball rolling without slipping at a = (5/7) c_rr g; it keeps rolling (ω = v/r)."""
    r, v0 = 0.1, 2.0
    model, state = make_bodies([sphere(r, position=(0, 0, r), velocity=(v0, 0, 0), angular_velocity=(0, v0 / r, 0))])
    integrator, solver = make_integrator("symplectic_euler"), make_solver(rolling_resistance=c_rr)
    h, steps = 1 / 240, 240
    speeds = []
    for _ in range(steps):
        step_bodies(model, state, integrator, solver, h, gravity=(0, 0, -G), ground=Ground())
        speeds.append(state.linear_velocity(model)[0, 0])
    t = np.arange(1, steps + 1) * h
    deceleration = -np.polyfit(t[24:], np.array(speeds)[24:], 1)[0]  # after a tenth of a second of contact
    assert deceleration == pytest.approx(5 / 7 * c_rr * G, rel=0.03)
    np.testing.assert_allclose(state.angular_velocity(model)[0, 1] * r, speeds[-1], rtol=1e-2)


def test_rolling_resistance_only_removes_energy_and_stops_a_ball_for_good():
    r, v0, c_rr = 0.1, 0.3, 0.05
    model, state = make_bodies([sphere(r, position=(0, 0, r), velocity=(v0, 0, 0), angular_velocity=(0, v0 / r, 3.0))])
    integrator, solver = make_integrator("symplectic_euler"), make_solver(rolling_resistance=c_rr)
    energy = []
    for _ in range(480):
        step_bodies(model, state, integrator, solver, 1 / 240, gravity=(0, 0, -G), ground=Ground())
        energy.append(state.kinetic_energy(model).sum() + G * state.position[0, 2])
    assert np.all(np.diff(energy) <= 1e-9)
    # stopped (spin about the vertical included), not rolling back: x only ever grew
    assert np.linalg.norm(state.linear_velocity(model)) < 1e-6
    assert np.linalg.norm(state.angular_velocity(model)) < 1e-5


def test_without_rolling_resistance_a_ball_rolls_on_for_ever():
    r, v0 = 0.1, 2.0
    model, state = make_bodies([sphere(r, position=(0, 0, r), velocity=(v0, 0, 0), angular_velocity=(0, v0 / r, 0))])
    integrator, solver = make_integrator("symplectic_euler"), make_solver()
    for _ in range(240):
        step_bodies(model, state, integrator, solver, 1 / 240, gravity=(0, 0, -G), ground=Ground())
    assert state.linear_velocity(model)[0, 0] == pytest.approx(v0, rel=1e-9)


# ---- sleeping ---------------------------------------------------------------------------------------------

SCENE = """
world: {{sleep: {sleep}}}
bodies:
  - {{name: crate, shape: box, size: [0.4, 0.4, 0.4], mass: 2.0, position: [0, 0, 0.5]}}
  - {{name: ball, shape: sphere, radius: 0.1, mass: 1.0, position: [2, 0, 0.1], linear_velocity: [0.2, 0, 0]}}
  - {{name: wall, shape: box, size: [0.2, 4, 1], position: [-3, 0, 0.5], fixed: true}}
"""


def world(sleep=True) -> World:
    return World(parse_scene(SCENE.format(sleep=str(sleep).lower())), dt=1 / 60)


def step_until_asleep(w: World, limit_s: float = 10.0) -> None:
    while not w.bodies_asleep:
        assert w.time < limit_s, "never fell asleep"
        w.step()


def test_bodies_fall_asleep_only_after_resting_for_the_sleep_time_and_then_stay_exactly_still():
    w = world()
    rest_started = None
    while not w.bodies_asleep:
        assert w.time < 10.0, "never fell asleep"
        w.step()
        v = np.linalg.norm(w.body_state.linear_velocity(w.body_model), axis=1)
        if (v[~w.body_model.fixed] >= SLEEP_SPEED).any():
            rest_started = None
        elif rest_started is None:
            rest_started = w.time
    # the crate fell, the ball rolled to a stop: asleep SLEEP_TIME after the last of them came to rest
    assert w.time - rest_started >= SLEEP_TIME - 2 * w.dt
    assert w.body_state.position[0, 2] == pytest.approx(0.2, abs=2e-3)
    asleep = w.body_state.copy()
    assert not asleep.linear_momentum.any() and not asleep.angular_momentum.any()
    for _ in range(120):
        w.step()
    np.testing.assert_array_equal(w.body_state.position, asleep.position)
    np.testing.assert_array_equal(w.body_state.orientation, asleep.orientation)


def test_a_thrown_body_is_never_put_to_sleep_at_its_apex():
    """Thrown straight up at 1 m/s, a body is slower than SLEEP_SPEED for 2 SLEEP_SPEED / g ≈ 10 ms around its
    apex, far less than SLEEP_TIME: it flies exactly as in a world without sleeping."""
    text = ("world: {{ground: false, sleep: {}}}\nbodies:\n  - {{name: b, shape: sphere, radius: 0.1, mass: 1, "
            "position: [0, 0, 0], linear_velocity: [0, 0, 1.0]}}\n")
    w, reference = World(parse_scene(text.format("true"))), World(parse_scene(text.format("false")))
    for _ in range(60):
        w.step()
        reference.step()
        assert not w.bodies_asleep
    np.testing.assert_array_equal(w.body_state.position, reference.body_state.position)
    assert w.body_state.position[0, 2] < -3.0  # it went up, stopped and fell


def test_a_wrench_wakes_sleeping_bodies_and_acts_in_full():
    w = world()
    step_until_asleep(w)
    force = np.array([0.0, 3.0, 0.0])
    w.apply_wrench("ball", force=force)  # one tick, at the COM
    w.step()
    assert not w.bodies_asleep
    ball = w.body_model.index("ball")
    # the same impulse F dt as an awake body gets (friction with the ground takes a share; no gravity work)
    p = w.body_state.linear_momentum[ball]
    assert p[1] > 0.5 * force[1] * w.dt
    assert w.body_state.position[ball, 1] != 0.0


def test_reset_wakes_and_sleep_false_keeps_stepping():
    w = world()
    step_until_asleep(w)
    w.reset()
    assert not w.bodies_asleep and w.rest_time == 0.0
    w.step()
    assert w.body_state.position[0, 2] < 0.5  # the crate falls again
    never = world(sleep=False)
    for _ in range(600):
        never.step()
    assert not never.bodies_asleep


def test_scene_rejects_a_bad_rolling_resistance_or_sleep():
    from cgp_core import SceneError

    with pytest.raises(SceneError) as err:
        parse_scene("world: {rolling_resistance: -0.1, sleep: maybe}\n")
    assert "world.rolling_resistance: must be >= 0" in str(err.value)
    assert "world.sleep: must be true or false" in str(err.value)


# ---- islands: one rolling ball does not keep a resting pile awake -------------------------------------------

ISLANDS = """
world: {{sleep: true, rolling_resistance: 0.01}}
bodies:
  - {{name: low, shape: box, size: [0.4, 0.4, 0.4], mass: 2.0, position: [0, 0, 0.2]}}
  - {{name: high, shape: box, size: [0.4, 0.4, 0.4], mass: 2.0, position: [0, 0, 0.6]}}
  - {{name: lone, shape: box, size: [0.4, 0.4, 0.4], mass: 2.0, position: [0, 3, 0.2]}}
  - {{name: ball, shape: sphere, radius: 0.1, mass: 1.0, position: [{ball_x}, 0, 0.1],
     linear_velocity: [{ball_v}, 0, 0], angular_velocity: [0, {ball_w}, 0]}}
"""


def islands_world(ball_x, ball_v) -> World:
    return World(parse_scene(ISLANDS.format(ball_x=ball_x, ball_v=ball_v, ball_w=ball_v / 0.1)), dt=1 / 60)


def asleep(w: World, name: str) -> bool:
    return bool(w.islands().asleep[w.body_model.index(name)])


def test_a_resting_stack_sleeps_and_stays_exactly_still_while_a_ball_rolls_elsewhere():
    w = islands_world(ball_x=3.0, ball_v=1.0)  # rolling away from the stack, for ~14 s (a = 5/7 c_rr g)
    while not asleep(w, "low"):
        assert w.time < 3.0, "the stack never fell asleep"
        w.step()
    assert asleep(w, "high") and asleep(w, "lone") and not asleep(w, "ball")
    # the stack is one island (the boxes touch), the lone box another, the ball a third
    island = w.islands().island
    assert island[0] == island[1] != island[2] != island[3]
    stack = w.body_state.copy()
    for _ in range(120):
        w.step()
        assert asleep(w, "low") and asleep(w, "high") and not asleep(w, "ball")
    np.testing.assert_array_equal(w.body_state.position[:3], stack.position[:3])
    np.testing.assert_array_equal(w.body_state.orientation[:3], stack.orientation[:3])
    assert w.body_state.position[3, 0] > stack.position[3, 0] + 1.0  # the ball rolled on, 2 s more
    assert not w.bodies_asleep


def test_a_ball_rolling_into_a_sleeping_stack_wakes_it_and_pushes_it():
    w = islands_world(ball_x=-3.0, ball_v=3.0)  # the stack sleeps after ~0.5 s; the ball arrives after ~1 s
    woke = None
    slept = False
    while w.time < 3.0:
        w.step()
        slept |= asleep(w, "low")
        if slept and woke is None and not asleep(w, "low"):
            woke = w.time
            assert not asleep(w, "high")  # the whole island
            assert asleep(w, "lone")  # not the other one
    assert slept and woke is not None
    ball_x = w.body_state.position[3, 0]
    assert ball_x < -0.2 + 1e-3  # it did not pass through the stack
    assert w.body_state.position[0, 0] > 1e-3  # the stack was pushed along +x


def test_a_wrench_wakes_the_island_of_its_body_only():
    w = islands_world(ball_x=3.0, ball_v=0.0)
    while not w.bodies_asleep:
        assert w.time < 3.0, "never fell asleep"
        w.step()
    lone = w.body_state.position[2].copy()
    w.apply_wrench("high", force=[0.0, 30.0, 0.0], point=[0.0, 0.0, 0.75])
    w.step()
    assert not asleep(w, "high") and not asleep(w, "low")  # the stack: one island
    assert asleep(w, "lone") and asleep(w, "ball")
    np.testing.assert_array_equal(w.body_state.position[2], lone)
    assert w.body_state.linear_momentum[1, 1] > 0.0


def test_wake_named_bodies_after_a_teleport():
    w = islands_world(ball_x=3.0, ball_v=0.0)
    while not w.bodies_asleep:
        w.step()
    lone = w.body_model.index("lone")
    w.body_state.position[lone, 2] = 1.0  # teleported 0.8 m up
    w.wake(["lone"])
    assert not asleep(w, "lone") and asleep(w, "low") and asleep(w, "ball")
    for _ in range(60):
        w.step()
    assert w.body_state.position[lone, 2] == pytest.approx(0.2, abs=2e-3)  # fell back down
    with pytest.raises(KeyError, match="unknown body"):
        w.wake(["nobody"])


def test_a_new_body_model_object_starts_every_cache_afresh():
    """Removing a body (the model and state replaced by new objects built by selecting rows): the sleep state,
    the collision primitives and the warm-start memory are rebuilt for the new model, nothing stale is reused."""
    from dataclasses import replace as dc_replace

    from cgp_core import BodyState

    w = islands_world(ball_x=3.0, ball_v=0.0)
    while not w.bodies_asleep:
        w.step()
    keep = np.array([0, 1, 3])  # delete the lone box
    m = w.body_model
    w.body_model = dc_replace(m, names=[m.names[i] for i in keep], particles=[m.particles[i] for i in keep],
                              **{f: getattr(m, f)[keep] for f in ("shape", "radius", "half_extents", "mass",
                                                                  "inv_mass", "inertia_body", "inv_inertia_body",
                                                                  "restitution", "friction", "fixed", "color")})
    st = w.body_state
    w.body_state = BodyState(position=st.position[keep], orientation=st.orientation[keep],
                             linear_momentum=st.linear_momentum[keep], angular_momentum=st.angular_momentum[keep])
    assert not w.bodies_asleep  # a new model: every body awake
    assert w.islands().count == 3
    w.step()
    assert w.solver.detector.collision_model(w.body_model).body_reach.shape == (3,)
    for _ in range(60):
        w.step()
    np.testing.assert_allclose(w.body_state.position[:2, 2], [0.2, 0.6], atol=2e-3)  # the stack still stands
    assert w.bodies_asleep  # and sleeps again

"""Contact response through :func:`cgp_core.dynamics.step_bodies` with the symplectic Euler integrator:
closed forms (rebound height, sliding acceleration, elastic exchange), conservation laws, stability."""

import numpy as np
import pytest
from _bodies import box, capsule, make_bodies, mechanical_energy, particles, sphere

from cgp_core.collision import CollisionDetector, ContactSet, Ground
from cgp_core.dynamics import step_bodies
from cgp_core.integrators import make_integrator
from cgp_core.rotation import quat_from_rotvec, quat_rotate, quat_to_matrix
from cgp_core.solver import SolverSettings, make_solver

G = 9.81
GRAVITY = (0.0, 0.0, -G)
NO_GRAVITY = (0.0, 0.0, 0.0)


#: the ground plane z = 0 of every simulate() call that does not pass its own (``ground=None``: no ground)
DEFAULT_GROUND = Ground()


def simulate(model, state, steps, h=1 / 240, *, gravity=GRAVITY, ground=DEFAULT_GROUND, solver=None, each=None):
    integrator = make_integrator("symplectic_euler")
    solver = solver or make_solver()
    for k in range(steps):
        step_bodies(model, state, integrator, solver, h, gravity=gravity, ground=ground)
        if each is not None:
            each(k, state, solver)
    return solver


def total_momenta(state):
    """Total linear momentum and total angular momentum about the world origin."""
    P = state.linear_momentum.sum(axis=0)
    L = (np.cross(state.position, state.linear_momentum) + state.angular_momentum).sum(axis=0)
    return P, L


# ---- restitution ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("shape, e, drop", [("sphere", 0.5, 1.0), ("sphere", 0.8, 1.0), ("sphere", 0.8, 0.5),
                                            ("sphere", 0.3, 2.0), ("box", 0.5, 1.0), ("box", 0.8, 0.7)])
def test_dropped_body_rebounds_to_e_squared_of_its_drop_height(shape, e, drop):
    """Closed form: impact speed √(2 g H), rebound speed e √(2 g H), apex e² H — for a ball and for a box
    landing flat on its 4 corners.  h = 1/960 s (a 240 Hz tick with 4 sub-steps): the integrator itself
    (kick-drift) misses apexes by O(h·v), 0.5 % here, so the 2 % band tests the contact.  The ground's e = 0
    and the max rule leave the body's e in charge."""
    r = 0.1
    body = sphere(r, restitution=e, position=(0, 0, r + drop)) if shape == "sphere" else \
        box((0.15, 0.1, r), restitution=e, position=(0, 0, r + drop))
    model, state = make_bodies([body])
    heights, velocities = [], []

    def record(k, st, solver):
        heights.append(st.position[0, 2] - r)
        velocities.append(st.linear_momentum[0, 2])

    simulate(model, state, int(2.5 / (1 / 960)), h=1 / 960, each=record)
    heights, velocities = np.array(heights), np.array(velocities)
    assert heights.min() > -1e-3  # never sank into the ground
    up = np.argmax(velocities > 0.0)  # first step after the bounce
    down_again = up + np.argmax(velocities[up:] <= 0.0)
    assert up > 0 and down_again > up
    apex = heights[up:down_again + 1].max()
    assert apex == pytest.approx(e * e * drop, rel=0.02)


def test_inelastic_ball_stays_down_and_slow_impacts_do_not_bounce():
    r = 0.1
    model, state = make_bodies([sphere(r, restitution=0.0, position=(0, 0, r + 1.0)),
                                sphere(r, restitution=0.9, position=(1.0, 0, r + 0.005))])  # lands at 0.31 m/s
    simulate(model, state, 480)
    np.testing.assert_allclose(state.position[:, 2], r, atol=1e-3)
    assert np.abs(state.linear_momentum).max() < 1e-6


def test_head_on_elastic_collision_exchanges_velocities():
    model, state = make_bodies([sphere(0.1, restitution=1.0, position=(0, 0, 1), velocity=(2.0, 0, 0)),
                                sphere(0.1, restitution=1.0, position=(0.5, 0, 1))])
    simulate(model, state, 120, gravity=NO_GRAVITY, ground=None)
    v = state.linear_velocity(model)
    np.testing.assert_allclose(v[0], [0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(v[1], [2.0, 0, 0], atol=1e-12)
    assert np.abs(state.angular_momentum).max() < 1e-15  # central impact: no spin


def test_head_on_collision_with_restitution_matches_the_closed_form():
    """Equal masses, one at rest: v₁' = u (1 − e) / 2, v₂' = u (1 + e) / 2 (e = max(0.2, 0.6) = 0.6)."""
    u, e = 3.0, 0.6
    model, state = make_bodies([sphere(0.1, restitution=0.2, position=(0, 0, 1), velocity=(u, 0, 0)),
                                sphere(0.1, restitution=e, position=(0.5, 0, 1))])
    simulate(model, state, 120, gravity=NO_GRAVITY, ground=None)
    v = state.linear_velocity(model)
    np.testing.assert_allclose(v[:, 0], [u * (1 - e) / 2, u * (1 + e) / 2], atol=1e-12)


# ---- friction ------------------------------------------------------------------------------------------

def block_on_ramp(theta_deg, mu):
    theta = np.radians(theta_deg)
    q = quat_from_rotvec(np.array([0.0, -theta, 0.0]))  # turned about y: the surface rises towards +x
    normal = quat_rotate(q, np.array([0.0, 0.0, 1.0]))
    downhill = -quat_rotate(q, np.array([1.0, 0.0, 0.0]))
    ramp_half = np.array([3.0, 1.0, 0.1])
    centre = np.array([0.0, 0.0, 1.0])
    start = centre + normal * (ramp_half[2] + 0.1)
    model, state = make_bodies([box(ramp_half, fixed=True, position=centre, orientation=q, friction=mu),
                                box((0.1, 0.1, 0.1), position=start, orientation=q, friction=mu)])
    return model, state, downhill, theta


@pytest.mark.parametrize("theta_deg, mu", [(20.0, 0.5), (25.0, 0.5), (15.0, 0.3)])
def test_block_on_a_ramp_sticks_when_tan_theta_below_mu(theta_deg, mu):
    model, state, downhill, theta = block_on_ramp(theta_deg, mu)
    assert np.tan(theta) < mu
    solver = simulate(model, state, 60, ground=None)  # settle (it starts exactly touching)
    start = state.position[1].copy()
    simulate(model, state, 480, ground=None, solver=solver)
    assert abs((state.position[1] - start) @ downhill) < 1e-6  # no creep over 2 s
    assert np.linalg.norm(state.linear_velocity(model)[1]) < 1e-6


@pytest.mark.parametrize("theta_deg, mu", [(30.0, 0.5), (35.0, 0.5), (20.0, 0.2)])
def test_block_on_a_ramp_slides_with_acceleration_g_sin_minus_mu_cos(theta_deg, mu):
    model, state, downhill, theta = block_on_ramp(theta_deg, mu)
    assert np.tan(theta) > mu
    speeds = []
    simulate(model, state, 240, ground=None,
             each=lambda k, st, so: speeds.append(st.linear_velocity(model)[1] @ downhill))
    expected = G * (np.sin(theta) - mu * np.cos(theta))
    t = np.arange(1, 241) / 240
    acceleration = np.polyfit(t[24:], np.array(speeds)[24:], 1)[0]
    assert acceleration == pytest.approx(expected, rel=0.01)
    # it slides without tumbling
    assert np.linalg.norm(state.angular_velocity(model)[1]) < 1e-6


def test_sliding_ball_starts_rolling_at_five_sevenths_of_its_speed():
    """A solid ball thrown flat without spin slides, friction μ m g decelerates it and spins it up, and it
    rolls from t = 2 v₀ / (7 μ g) on with v = 5/7 v₀ and ω = v / r (angular momentum about the contact
    point is conserved)."""
    r, v0, mu = 0.1, 3.0, 0.3
    model, state = make_bodies([sphere(r, position=(0, 0, r), velocity=(v0, 0, 0), friction=mu)])
    ground = Ground(friction=mu)
    speeds = []
    simulate(model, state, 240, ground=ground, each=lambda k, st, so: speeds.append(st.linear_velocity(model)[0, 0]))
    np.testing.assert_allclose(state.linear_velocity(model)[0], [5 / 7 * v0, 0, 0], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(state.angular_velocity(model)[0], [0, 5 / 7 * v0 / r, 0], rtol=1e-6)
    # the sliding phase: deceleration μ g until t = 2 v₀ / (7 μ g) ≈ 0.29 s
    t = np.arange(1, 241) / 240
    sliding = t < 2 * v0 / (7 * mu * G) - 0.01
    np.testing.assert_allclose(np.array(speeds)[sliding], v0 - mu * G * t[sliding], atol=1e-9)


# ---- stacking and resting ------------------------------------------------------------------------------

def test_ten_box_stack_stands_for_ten_seconds():
    """10 boxes of 0.2 m, each turned by up to ±3° about the vertical and shifted by up to ±5 mm (a stack as
    a hand would build it, so no symmetry helps), 2400 sub-steps of 1/240 s.  Every box keeps its place
    within 1 % of a box size (2 mm) sideways; vertically the stack only settles into the allowed penetration
    of its 10 contact layers (≤ slop each); nothing tilts, and it is at rest at the end."""
    half = 0.1
    slop = SolverSettings().penetration_slop
    rng = np.random.default_rng(1)
    model, state = make_bodies([
        box((half, half, half), position=(*rng.uniform(-0.005, 0.005, size=2), half + 2 * half * i),
            orientation=quat_from_rotvec(np.array([0.0, 0.0, rng.uniform(-0.05, 0.05)]))) for i in range(10)])
    start = state.position.copy()
    simulate(model, state, 2400)
    drift = state.position - start
    assert np.abs(drift[:, :2]).max() <= 0.01 * 2 * half
    assert -10 * slop <= drift[-1, 2] <= 0.0
    tilt = 2 * np.arcsin(np.linalg.norm(state.orientation[:, :2], axis=1))  # about horizontal axes
    assert tilt.max() < 1e-3
    assert np.linalg.norm(state.linear_velocity(model), axis=1).max() < 1e-3


def test_resting_pile_never_gains_energy():
    """Boxes and balls dropped into a narrow bin settle into a pile.  From then on the total mechanical
    energy (kinetic + gravitational) ends no higher than it started and never rises above it by more than
    lifting the pile by 1 µm (the recovery may give back the potential energy of a sub-micron sag; it adds no
    kinetic energy).  Fails if the solver pumps energy (e.g. over-strong warm starting, or a manifold update
    that is not dissipative)."""
    rng = np.random.default_rng(4)
    specs = []
    for i in range(16):
        x, y = rng.uniform(-0.08, 0.08, size=2)
        position, q = (x, y, 0.1 + 0.16 * i), quat_from_rotvec(rng.normal(size=3))
        if i % 3:
            specs.append(box(rng.uniform(0.04, 0.07, size=3), position=position, orientation=q, restitution=0.2))
        else:
            specs.append(sphere(0.05, position=position, restitution=0.2))
    walls = [box((0.25, 0.05, 0.6), fixed=True, position=(0, s * 0.25, 0.6)) for s in (-1, 1)]
    walls += [box((0.05, 0.25, 0.6), fixed=True, position=(s * 0.25, 0, 0.6)) for s in (-1, 1)]
    model, state = make_bodies(specs + walls)
    solver = simulate(model, state, 720)  # 3 s to settle
    movable = model.inv_mass > 0
    assert state.position[movable, 2].max() > 0.2  # a pile, not a single layer
    kinetic, energy = [], []

    def record(k, st, so):
        kinetic.append(st.kinetic_energy(model).sum())
        energy.append(mechanical_energy(model, st))

    simulate(model, state, 240, solver=solver, each=record)
    kinetic, energy = np.array(kinetic), np.array(energy)
    assert kinetic.max() < 1e-3  # resting (a ball may still roll or spin slowly: no rolling resistance)
    micron = G * model.mass[movable].sum() * 1e-6  # the whole pile lifted by 1 µm
    assert np.all(energy - energy[0] <= micron)
    # and ends no higher than it started, up to the pile lifted by 10 nm: a ball still rolling at ~6 mm/s over
    # the pile (no rolling resistance) moves its load across the boxes below, which sag and rise by tens of nm
    # (the slop's compliance), the potential energy with them (±8e-8 J over the 240 steps, 1.4e-8 J up at the end
    # of the settled state reached since bounces take one time of impact per manifold; its kinetic energy is
    # constant to 1e-15 J)
    assert energy[-1] <= energy[0] + 0.01 * micron


def test_penetration_recovery_adds_no_kinetic_energy():
    """Two spinning, moving boxes overlapping by 2 cm: the recovery stage separates them (positions and
    orientations change) and leaves their kinetic energy exactly as it was."""
    q = quat_from_rotvec(np.array([0.2, 0.4, 0.1]))
    model, state = make_bodies([
        box((0.2, 0.1, 0.1), mass=2.0, position=(0, 0, 1), orientation=q, velocity=(0.3, 0, 0),
            angular_velocity=(1, 2, 3)),
        box((0.1, 0.15, 0.1), mass=1.0, position=(0.26, 0.02, 1.05), velocity=(-0.2, 0.1, 0),
            angular_velocity=(-2, 0.5, 1))])
    solver = make_solver()
    h = 1 / 240
    contacts = solver.detector.detect(model, state, h, ground=None)
    assert contacts.separation.min() < -0.01
    solver.solve_velocities(model, state, contacts, h)
    make_integrator("symplectic_euler").step(model, state, h)
    before = state.copy()
    kinetic = state.kinetic_energy(model).sum()
    solver.recover_penetration(model, state, h)
    assert np.abs(state.position - before.position).max() > 1e-4  # it did move them
    assert state.kinetic_energy(model).sum() == pytest.approx(kinetic, rel=1e-13)
    np.testing.assert_array_equal(state.linear_momentum, before.linear_momentum)


@pytest.mark.parametrize("gaps, xs, tilt", [
    ((0.0037, 0.0014, 0.0015), (-0.035, -0.0327, -0.0308), (-0.0187, -0.0187, -0.0141)),  # convex_pile's rock_5
    ((0.0037, 0.0014, 0.0015), (0.0, 0.0, 0.0), (-0.0187, -0.0187, -0.0141)),
    ((0.0037, 0.0014, 0.0025), (0.0, 0.0005, 0.0), (0.0, 0.0, 0.005)),
])
def test_a_bounce_at_its_time_of_impact_moves_the_body_by_its_gaps_not_metres(gaps, xs, tilt):
    """A box falls at 2 m/s onto three speculative points of the static world (restitution 0.1) that lie nearly
    on a line, with nearly parallel normals and different gaps (a hull landing on terrain triangles): its normal
    block is nearly singular.  The bounce happens when the first point arrives, and the position stage's shift
    that puts it there is one rigid motion of the box, no bigger than the gaps (≤ (1 + e) × the gap each); taken
    per point from its own gap, the three shifts fitted no rigid motion and the block met them through its
    near-null mode: the box moved 0.1–0.6 m and turned ~3 rad at 4 mm from the ground."""
    model, state = make_bodies([box((0.1, 0.1, 0.1), position=(0, 0, 0.1 + max(gaps)), velocity=(0, 0, -2.0),
                                    restitution=0.1)])
    normal = np.array([[0.0, t, 1.0] for t in tilt])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    point = np.array([[x, y, 0.0] for x, y in zip(xs, (-0.035, 0.0, 0.035))])
    contacts = ContactSet(np.full(3, -1, np.intp), np.zeros(3, np.intp), normal, np.array(gaps), point,
                          np.arange(3, dtype=np.int64), np.full(3, 0.6), np.full(3, 0.1))
    solver, h = make_solver(), 1 / 240
    solver.solve_velocities(model, state, contacts, h)
    assert state.linear_momentum[0, 2] > 0.0  # it bounced
    make_integrator("symplectic_euler").step(model, state, h)
    before = state.copy()
    solver.recover_penetration(model, state, h)
    moved = np.linalg.norm(state.position[0] - before.position[0])
    turned = 2.0 * np.arccos(min(abs(float(state.orientation[0] @ before.orientation[0])), 1.0))
    assert 0.0 < moved <= 2.0 * max(gaps), moved  # it was moved back towards the impact, by about a gap
    assert turned * np.sqrt(3) * 0.1 <= 2.0 * max(gaps), turned  # no corner moved by more either


def test_resting_contacts_keep_penetration_near_the_slop():
    slop = SolverSettings().penetration_slop
    model, state = make_bodies([sphere(0.1, position=(0.3 * i, 0, 0.1 + 0.21 * j)) for i in range(3)
                                for j in range(3)] + [box((0.1, 0.1, 0.1), position=(1.0, 0, 0.1 + 0.2 * j))
                                                     for j in range(3)])
    # spheres in columns fall off each other; boxes stack
    simulate(model, state, 720)
    contacts = CollisionDetector(speculative_distance=0.0).detect(model, state, 1e-9, ground=Ground())
    assert contacts.count > 0
    assert contacts.penetration().max() <= slop * 1.2


def test_particle_bodies_rest_on_their_spheres():
    """A dumbbell and a 4 × 4 particle plate (16 contacts with the ground, one group) land and rest level,
    their particles' spheres on the ground."""
    dumbbell = particles([[-0.2, 0, 0.5, 1.0], [0.2, 0, 0.5, 2.0]], radius=0.05)
    grid = [[0.1 * i, 0.1 * j, 0.3 + 0.01 * i, 0.25] for i in range(4) for j in range(4)]
    plate = particles(grid, radius=0.04, position=(1.0, 0, 0))
    model, state = make_bodies([dumbbell, plate])
    simulate(model, state, 480)
    assert state.position[0, 2] == pytest.approx(0.05, abs=1e-3)
    assert state.position[1, 2] == pytest.approx(0.04, abs=1e-3)
    assert np.abs(state.linear_momentum).max() < 1e-6


# ---- conservation --------------------------------------------------------------------------------------

def test_body_body_impacts_conserve_linear_and_angular_momentum():
    """Oblique, spinning impacts of a box, a sphere, a capsule and a small box with friction and
    restitution, no gravity, no ground: total P and total L about the origin are conserved to round-off
    (every contact impulse is an equal-and-opposite pair at one point)."""
    q = quat_from_rotvec(np.array([0.3, 0.2, 0.1]))
    model, state = make_bodies([
        box((0.2, 0.1, 0.15), mass=2.0, position=(0, 0, 0), orientation=q, velocity=(1, 0, 0),
            angular_velocity=(0, 1, 2), friction=0.8, restitution=0.4),
        sphere(0.15, mass=1.0, position=(0.6, 0.1, 0.05), velocity=(-2, 0, 0), friction=0.8, restitution=0.4),
        capsule(0.08, 0.2, mass=1.5, position=(0.3, -0.5, 0.1), velocity=(0, 2, 0), angular_velocity=(3, 0, 0),
                friction=0.6),
        box((0.1, 0.1, 0.1), mass=0.5, position=(-0.6, 0.05, 0.0), velocity=(3, 0, 0),
            angular_velocity=(0, 0, 5))])
    P0, L0 = total_momenta(state)
    hits = []
    simulate(model, state, 240, gravity=NO_GRAVITY, ground=None,
             each=lambda k, st, so: hits.append(so.stats["contacts"]))
    assert sum(h > 0 for h in hits) > 20  # they did collide, repeatedly
    P, L = total_momenta(state)
    np.testing.assert_allclose(P, P0, atol=1e-13)
    np.testing.assert_allclose(L, L0, atol=1e-13)


# ---- tunnelling ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("speed", [10.0, 100.0, 1000.0])
def test_fast_small_sphere_does_not_tunnel_through_the_ground(speed):
    """A 2 cm sphere at up to 1000 m/s moves up to 4 m per sub-step; speculative contacts stop it at the
    surface (no speed limit for translation)."""
    r = 0.02
    model, state = make_bodies([sphere(r, position=(0, 0, 3.0), velocity=(0, 0, -speed))])
    lowest = []
    simulate(model, state, 120, each=lambda k, st, so: lowest.append(st.position[0, 2] - r))
    assert min(lowest) > -1e-3
    assert state.position[0, 2] == pytest.approx(r, abs=1e-3)


def test_fast_sphere_does_not_pass_a_thin_wall():
    r = 0.02
    model, state = make_bodies([box((0.005, 1.0, 1.0), fixed=True, position=(1.0, 0, 1.0)),
                                sphere(r, position=(0.0, 0, 1.0), velocity=(200.0, 0, 0))])
    simulate(model, state, 60, gravity=NO_GRAVITY, ground=None)
    assert state.position[1, 0] < 1.0 - 0.005 - r + 1e-3  # still on its side of the wall


# ---- settings and errors -------------------------------------------------------------------------------

def test_fixed_bodies_never_move():
    model, state = make_bodies([box((1.0, 1.0, 0.1), fixed=True, position=(0, 0, 0.5)),
                                sphere(0.1, position=(0, 0, 1.0), velocity=(0, 0, -5.0))])
    start = state.copy()
    simulate(model, state, 120)
    np.testing.assert_array_equal(state.position[0], start.position[0])
    np.testing.assert_array_equal(state.orientation[0], start.orientation[0])
    assert state.position[1, 2] == pytest.approx(0.7, abs=1e-3)


def test_forces_added_before_the_step_act_with_gravity():
    """A wrench force equal to the weight, accumulated by the caller, holds a body in the air."""
    model, state = make_bodies([sphere(0.1, mass=2.0, position=(0, 0, 1.0))])
    integrator, solver = make_integrator("symplectic_euler"), make_solver()
    for _ in range(240):
        state.force[0] += (0.0, 0.0, 2.0 * G)
        step_bodies(model, state, integrator, solver, 1 / 240, gravity=GRAVITY, ground=Ground())
    assert state.position[0, 2] == pytest.approx(1.0, abs=1e-12)
    assert np.all(state.force == 0.0)  # accumulators cleared


def test_bad_settings_and_inputs_are_named():
    with pytest.raises(ValueError, match="unknown contact solver 'pgs'; valid: sequential_impulse"):
        make_solver("pgs")
    with pytest.raises(ValueError, match="unknown solver setting"):
        make_solver(iterations=3)
    with pytest.raises(ValueError, match="velocity_iterations"):
        SolverSettings(velocity_iterations=0)
    with pytest.raises(ValueError, match="penetration_slop"):
        SolverSettings(penetration_slop=-1.0)
    with pytest.raises(ValueError, match="ground friction"):
        Ground(friction=-0.1)
    with pytest.raises(ValueError, match="ground restitution"):
        Ground(restitution=1.5)
    model, state = make_bodies([sphere(0.1)])
    with pytest.raises(ValueError, match="sub-step h"):
        step_bodies(model, state, make_integrator("symplectic_euler"), make_solver(), 0.0, gravity=GRAVITY,
                    ground=None)
    with pytest.raises(ValueError, match="gravity"):
        step_bodies(model, state, make_integrator("symplectic_euler"), make_solver(), 0.01, gravity=(0, 0),
                    ground=None)


def test_solver_works_with_every_integrator():
    """A box dropped on the ground comes to rest on its face with each integrator of the registry.  (Only
    positions are compared: rk4 drifts with the mid-step momentum P + h F / 2, so a body at rest on the
    ground keeps P = −m g h / 2 between steps while staying put.)"""
    from cgp_core.integrators import INTEGRATORS

    for name in INTEGRATORS:
        model, state = make_bodies([box((0.1, 0.1, 0.1), position=(0, 0, 0.5),
                                        orientation=quat_from_rotvec(np.array([0.3, 0.1, 0.0])))])
        integrator, solver = make_integrator(name), make_solver()
        for _ in range(600):
            step_bodies(model, state, integrator, solver, 1 / 240, gravity=GRAVITY, ground=Ground())
        rest = state.copy()
        for _ in range(240):
            step_bodies(model, state, integrator, solver, 1 / 240, gravity=GRAVITY, ground=Ground())
        assert state.position[0, 2] == pytest.approx(0.1, abs=2e-3), name
        assert np.abs(state.position - rest.position).max() < 1e-5, name
        R = quat_to_matrix(state.orientation[0])
        assert np.abs(R[2]).max() == pytest.approx(1.0, abs=1e-6), name  # a body axis vertical: flat on a face


def test_a_blown_up_body_does_not_stop_the_others():
    """A body whose state went NaN (World resets it after the tick) is left out of collisions; the rest of
    the scene steps on."""
    model, state = make_bodies([sphere(0.1, position=(0, 0, 0.1)), sphere(0.1, position=(1.0, 0, 0.5))])
    state.position[0] = np.nan
    state.angular_momentum[0] = np.inf
    with np.errstate(invalid="ignore"):
        simulate(model, state, 60)
    assert np.isfinite(state.position[1]).all() and state.position[1, 2] < 0.5


def test_a_body_whose_speed_overflows_does_not_drag_its_neighbour_along():
    """A body pushed to a speed whose square overflows (|v| = inf: its speculative margin is unbounded) is left
    out of collisions, as a NaN body is; its neighbour keeps its own motion (World then resets the runaway)."""
    model, state = make_bodies([sphere(0.1, position=(0, 0, 1)),
                                sphere(0.1, position=(0.5, 0, 1), angular_velocity=(0, 0, 3.0))])
    spin = state.angular_momentum[1].copy()
    state.linear_momentum[0] = (1e200, 0.0, 0.0)
    with np.errstate(over="ignore", invalid="ignore"):
        solver = simulate(model, state, 1, gravity=NO_GRAVITY, ground=None)
    assert solver.stats["contacts"] == 0
    np.testing.assert_array_equal(state.angular_momentum[1], spin)
    np.testing.assert_array_equal(state.position[1], (0.5, 0, 1))

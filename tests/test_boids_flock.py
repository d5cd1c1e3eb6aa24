"""Flock behaviour: determinism per seed, world bounds (soft walls and wrap), speed limits, the goal, and no
boid ever entering a rigid body (spheres, boxes, capsules, particle sets, the ground) — checked against
``geometry.py``'s signed distances at every step, including a boid flying straight at a sphere."""

from __future__ import annotations

import numpy as np
import pytest

from cgp_core.bodies import BodyModel, BodyState, Shape
from cgp_core.boids import Flock, FlockParams, Obstacles
from cgp_core.geometry import box_distance, capsule_distance, sphere_distance
from cgp_core.rotation import quat_from_euler, quat_to_matrix

DT = 1.0 / 60.0


def test_same_seed_same_flock_and_reset_restores_the_start():
    params = FlockParams(count=120, seed=9)
    a, b = Flock(params), Flock(params)
    start_x, start_v, start_q = a.positions.copy(), a.velocities.copy(), a.orientations.copy()
    for _ in range(90):
        a.step(DT)
        b.step(DT)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.orientations, b.orientations)
    assert not np.allclose(a.positions, start_x)
    a.reset()
    np.testing.assert_array_equal(a.positions, start_x)
    np.testing.assert_array_equal(a.velocities, start_v)
    np.testing.assert_array_equal(a.orientations, start_q)
    assert a.time == 0.0 and a.steps == 0
    for _ in range(90):  # and after a reset it replays exactly
        a.step(DT)
    np.testing.assert_array_equal(a.positions, b.positions)
    other = Flock(params.with_seed(10))
    assert not np.allclose(other.positions, start_x)


def test_speeds_stay_within_limits():
    params = FlockParams(count=200, seed=4, min_speed=0.7, max_speed=1.6)
    flock = Flock(params)
    for _ in range(120):
        flock.step(DT)
        speed = np.linalg.norm(flock.velocities, axis=1)
        assert speed.min() >= params.min_speed - 1e-9 and speed.max() <= params.max_speed + 1e-9


def test_soft_walls_keep_every_boid_inside_even_when_the_goal_is_outside():
    params = FlockParams(count=200, seed=1, bounds_min=[-5, -5, 0.5], bounds_max=[5, 5, 6], spawn_center=[0, 0, 3],
                         spawn_extent=[6, 6, 3], goal=[40, 0, 3], goal_weight=15.0, max_speed=3.0)
    flock = Flock(params)
    reached_wall = False
    for _ in range(600):
        flock.step(DT)
        x = flock.positions
        assert np.all(x >= params.bounds_min) and np.all(x <= params.bounds_max)
        reached_wall |= bool(np.any(x[:, 0] > params.bounds_max[0] - 0.5))
    assert reached_wall, "the goal must press the flock against the wall for this test to mean anything"


def test_wrap_keeps_boids_in_the_box_and_lets_them_cross():
    params = FlockParams(count=150, seed=2, bounds_mode="wrap", bounds_min=[-4, -4, 0], bounds_max=[4, 4, 5],
                         spawn_center=[0, 0, 2.5], spawn_extent=[8, 8, 5], goal=[100, 0, 2.5], goal_weight=5.0)
    flock = Flock(params)
    crossed = 0
    for _ in range(300):
        before = flock.positions[:, 0].copy()
        flock.step(DT)
        x = flock.positions
        assert np.all(x >= params.bounds_min) and np.all(x < params.bounds_max)
        crossed += int(np.sum(flock.positions[:, 0] < before - 4.0))  # jumped from +x face to −x face
    assert crossed > 10


def test_goal_attracts_the_flock():
    params = FlockParams(count=100, seed=6, goal=[20, 0, 10], goal_weight=3.0)
    flock = Flock(params)
    start = np.linalg.norm(flock.positions.mean(axis=0) - params.goal)
    for _ in range(900):
        flock.step(DT)
    assert np.linalg.norm(flock.positions.mean(axis=0) - params.goal) < 0.25 * start


# ---- obstacles --------------------------------------------------------------------------------------------

def _bodies(entries):
    """BodyModel + BodyState from (shape, position, rpy, radius, half_extents, particles) tuples."""
    n = len(entries)
    model = BodyModel(
        names=[f"b{i}" for i in range(n)], shape=np.array([e[0] for e in entries], dtype=np.int8),
        radius=np.array([e[3] for e in entries], dtype=float),
        half_extents=np.array([e[4] for e in entries], dtype=float), mass=np.ones(n), inv_mass=np.zeros(n),
        inertia_body=np.tile(np.eye(3), (n, 1, 1)), inv_inertia_body=np.zeros((n, 3, 3)),
        restitution=np.zeros(n), friction=np.zeros(n), fixed=np.ones(n, bool),
        particles=[None if e[5] is None else np.asarray(e[5], float) for e in entries], color=np.ones((n, 4)))
    state = BodyState(position=np.array([e[1] for e in entries], dtype=float),
                      orientation=np.array([quat_from_euler(*e[2]) for e in entries]),
                      linear_momentum=np.zeros((n, 3)), angular_momentum=np.zeros((n, 3)))
    return model, state


def _signed_distances(model, state, points):
    """(m, n) distance from each point to each body (particles: the nearest particle sphere), geometry.py."""
    R = quat_to_matrix(state.orientation)
    columns = []
    for b in range(model.count):
        shape = model.shape[b]
        if shape == Shape.SPHERE:
            d, _ = sphere_distance(points, state.position[b:b + 1], model.radius[b:b + 1])
        elif shape == Shape.BOX:
            d, _ = box_distance(points, state.position[b:b + 1], R[b:b + 1], model.half_extents[b:b + 1])
        elif shape == Shape.CAPSULE:
            d, _ = capsule_distance(points, state.position[b:b + 1], R[b:b + 1, :, 2], model.half_extents[b:b + 1, 2],
                                    model.radius[b:b + 1])
        else:
            centres = state.position[b] + model.particles[b][:, :3] @ R[b].T
            d, _ = sphere_distance(points, centres, np.full(len(centres), model.radius[b]))
            d = d.min(axis=1, keepdims=True)
        columns.append(d[:, 0])
    return np.stack(columns, axis=1)


OBSTACLE_COURSE = [
    (Shape.SPHERE, [6, 0, 10], [0, 0, 0], 1.5, [0, 0, 0], None),
    (Shape.BOX, [12, 1, 10], [0.3, 0.2, 0.7], 0.0, [0.8, 2.5, 1.5], None),
    (Shape.CAPSULE, [18, -1, 10], [1.2, 0.0, 0.4], 0.6, [0, 0, 1.5], None),
    (Shape.PARTICLES, [24, 0, 10], [0, 0, 0.5], 0.5, [1.0, 1.0, 0.5],
     [[-1.0, 0, 0, 1], [0, 0, 0, 1], [1.0, 0, 0, 1], [0, 1.0, 0, 1]]),
    (Shape.BOX, [15, 0, 10], [0, 0, 0], 0.0, [0.05, 0.05, 0.05], None),  # small: easy to clip
]


@pytest.mark.parametrize("avoid", [True, False])
def test_no_boid_ever_enters_a_body(avoid):
    """A flock driven by a goal straight through a course of bodies: with avoidance the boids steer around
    them; without it they are only projected out — in both cases no boid centre is ever inside a body grown
    by half the boid size."""
    model, state = _bodies(OBSTACLE_COURSE)
    obstacles = Obstacles.from_bodies(model, state)
    params = FlockParams(count=150, seed=8, spawn_center=[0, 0, 10], spawn_extent=[4, 4, 3], goal=[40, 0, 10],
                         goal_weight=8.0, bounds_mode="none", avoid_bodies=avoid, max_speed=4.0, boid_size=0.3)
    flock = Flock(params)
    inflate = 0.5 * params.boid_size
    passed = np.zeros(params.count, bool)
    closest = np.inf
    for _ in range(900):
        flock.step(DT, obstacles)
        d = _signed_distances(model, state, flock.positions)
        closest = min(closest, float(d.min()))
        assert d.min() >= inflate - 1e-6, f"a boid is {inflate - d.min():.3g} m inside a body"
        passed |= flock.positions[:, 0] > 26.0
    assert passed.mean() > 0.8, "the flock must get through the course for the test to mean anything"
    if not avoid:
        assert closest < inflate + 0.01, "without avoidance boids reach the surfaces (and are held there)"


def test_a_boid_aimed_straight_at_a_sphere_goes_around_it():
    model, state = _bodies([(Shape.SPHERE, [5, 0, 10], [0, 0, 0], 1.0, [0, 0, 0], None)])
    obstacles = Obstacles.from_bodies(model, state)
    params = FlockParams(count=1, spawn_center=[0, 0, 10], spawn_extent=[0, 0, 0], goal=[12, 0, 10],
                         goal_weight=5.0, bounds_mode="none", min_speed=1.0, max_speed=3.0)
    flock = Flock(params)
    flock.velocities[:] = [3.0, 0.0, 0.0]  # dead centre
    for _ in range(600):
        flock.step(DT, obstacles)
        assert np.linalg.norm(flock.positions[0] - [5, 0, 10]) >= 1.0 + 0.5 * params.boid_size - 1e-6
    assert flock.positions[0, 0] > 8.0, "it must get past the sphere, not stay pinned on it"


def test_ground_plane_is_an_obstacle():
    params = FlockParams(count=100, seed=3, bounds_mode="none", goal=[0, 0, -30], goal_weight=10.0,
                         spawn_center=[0, 0, 3], spawn_extent=[4, 4, 2])
    flock = Flock(params)
    empty = BodyState(position=np.zeros((0, 3)), orientation=np.zeros((0, 4)), linear_momentum=np.zeros((0, 3)),
                      angular_momentum=np.zeros((0, 3)))
    obstacles = Obstacles.from_bodies(BodyModel.empty(), empty, ground=True)
    for _ in range(300):
        flock.step(DT, obstacles)
        assert flock.positions[:, 2].min() >= 0.5 * params.boid_size - 1e-9
    assert flock.positions[:, 2].max() < 2.0, "pressed to the ground"


def test_obstacles_from_bodies_covers_every_shape():
    model, state = _bodies(OBSTACLE_COURSE)
    obstacles = Obstacles.from_bodies(model, state, ground=True)
    assert len(obstacles.sphere_radii) == 1 + 4  # the sphere and the 4 particles
    assert len(obstacles.box_centers) == 2 and len(obstacles.capsule_centers) == 1
    assert obstacles.ground_height == 0.0 and obstacles.shape_count == 9
    # particles are placed with the body's pose
    R = quat_to_matrix(state.orientation[3])
    np.testing.assert_allclose(obstacles.sphere_centers[1:], state.position[3] + np.array(
        OBSTACLE_COURSE[3][5])[:, :3] @ R.T)
    # the query agrees with geometry.py on random points
    rng = np.random.default_rng(0)
    points = rng.uniform([-2, -4, 6], [28, 4, 14], (4000, 3))
    hits = obstacles.query(points.T, 0.7)
    reference = _signed_distances(model, state, points)
    near = np.minimum(reference.min(axis=1), points[:, 2])
    assert set(np.unique(hits.point)) == set(np.flatnonzero(near < 0.7))
    # every hit is one (point, shape) pair within reach, in point order, with that pair's distance: the
    # bodies' (the particle set: each particle sphere's, column 3 is their minimum) and the ground's
    assert np.all(np.diff(hits.point) >= 0) and np.all(hits.distance < 0.7)
    particles = state.position[3] + np.array(OBSTACLE_COURSE[3][5])[:, :3] @ R.T
    for point, distance in zip(hits.point, hits.distance):
        p = points[point]
        candidates = np.concatenate([reference[point, [0, 1, 2, 4]], np.linalg.norm(particles - p, axis=1) - 0.5,
                                     [p[2]]])
        assert np.min(np.abs(candidates - distance)) < 1e-9
    per_point = np.bincount(hits.point, minlength=len(points))
    particle_distance = np.linalg.norm(points[:, None] - particles, axis=2) - 0.5
    expected = ((reference[:, [0, 1, 2, 4]] < 0.7).sum(axis=1) + (particle_distance < 0.7).sum(axis=1)
                + (points[:, 2] < 0.7))
    np.testing.assert_array_equal(per_point, expected)


def test_compiled_point_shape_distances_are_geometry_pys():
    """The obstacle query's per-pair closest-point formulas (compiled, one point and one shape) give what
    geometry.py's points × shapes functions give: distances and normals, inside and outside, on the axes."""
    from cgp_core.boids.obstacles import box_distance_to, capsule_distance_to, sphere_distance_to

    rng = np.random.default_rng(5)
    points = np.concatenate([rng.uniform(-3, 3, (600, 3)), np.zeros((1, 3))])  # the last one: at the centres
    centers = np.zeros((4, 3))
    centers[1:] = rng.normal(size=(3, 3))
    R = quat_to_matrix(np.array([quat_from_euler(*angles) for angles in rng.uniform(-3, 3, (4, 3))]))
    half = rng.uniform(0.2, 1.5, (4, 3))
    radii = rng.uniform(0.2, 1.0, 4)
    for fast, (distance, normal) in (
            (lambda p, k: sphere_distance_to(*p, *centers[k], radii[k]), sphere_distance(points, centers, radii)),
            (lambda p, k: box_distance_to(*p, centers[k], R[k], half[k]), box_distance(points, centers, R, half)),
            (lambda p, k: capsule_distance_to(*p, centers[k], R[k][:, 2], half[k, 2], radii[k]),
             capsule_distance(points, centers, R[:, :, 2], half[:, 2], radii))):
        got = np.array([[fast(p, k) for k in range(4)] for p in points])  # (m, k, 4)
        np.testing.assert_allclose(got[..., 0], distance, rtol=0, atol=1e-12)
        np.testing.assert_allclose(got[..., 1:], normal, rtol=0, atol=1e-12)
    assert (box_distance(points, centers, R, half)[0] < 0).any(), "some points must be inside a box"


# ---- parameters -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("bad, message", [
    (dict(count=0), "count"),
    (dict(count=2.5), "count"),
    (dict(radius=-1.0), "radius"),
    (dict(separation_radius=3.0, radius=2.0), "separation_radius"),
    (dict(min_speed=3.0, max_speed=2.0), "min_speed"),
    (dict(fov_deg=400.0), "fov_deg"),
    (dict(bounds_mode="bounce"), "bounds_mode"),
    (dict(model="bird"), "model"),
    (dict(neighbor_search="octree"), "neighbor_search"),
    (dict(spawn_center=[0, 0]), "spawn_center"),
    (dict(spawn_extent=[1, -1, 1]), "spawn_extent"),
    (dict(bounds_min=[0, 0, 0], bounds_max=[1, 1, 0]), "bounds_max"),
    (dict(bounds_mode="wrap", bounds_min=[0, 0, 0], bounds_max=[3, 30, 30], spawn_center=[1.5, 5, 5],
          spawn_extent=[1, 1, 1]), "2 \\* radius"),
    (dict(spawn_center=[100, 0, 10]), "spawn box"),
    (dict(cohesion_weight=float("nan")), "cohesion_weight"),
    (dict(avoid_bodies="yes"), "avoid_bodies"),
    (dict(goal=[1, 2]), "goal"),
])
def test_bad_parameters_name_the_field(bad, message):
    with pytest.raises(ValueError, match=message) as error:
        FlockParams(name="school", **bad)
    assert "school" in str(error.value)


def test_bad_dt_is_rejected():
    flock = Flock(FlockParams(count=3))
    for dt in (0.0, -0.01, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="dt"):
            flock.step(dt)

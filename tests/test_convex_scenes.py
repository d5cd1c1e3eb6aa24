"""Issue 25's gallery scenes and continuous collision (in-process): ``convex_pile`` settles on its terrain mesh and
sleeps; ``bullet``'s ball and hull at 300 m/s never get behind the thin convex wall or the one-triangle mesh wall at
30, 60 and 240 Hz — and with the continuous collision turned off they do; a plank turning a quarter turn per
sub-step next to a thin wall is stopped by the time of impact, which the speculative margins alone miss."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cgp_core import World, parse_scene
from cgp_core.collision.bvh import bvh_raycast
from cgp_core.collision.contacts import FEATURE_SLOTS
from cgp_core.collision.epa import penetration
from cgp_core.collision.gjk import NO_ADJACENCY, Core, no_adjacency
from cgp_core.rotation import quat_to_matrix
from cgp_core.scene import load_scene


def hull_world_vertices(world: World, i: int) -> np.ndarray:
    R = quat_to_matrix(world.body_state.orientation[i])
    return world.body_model.hulls[i].vertices @ R.T + world.body_state.position[i]


def test_convex_pile_settles_on_the_terrain_and_sleeps():
    """The rocks and hulls fall onto terrain.obj, pile up and are all asleep within 5 s; none has sunk into the
    terrain (every vertex at most 5 mm under the surface straight below it) and none moves."""
    world = World.from_scene("convex_pile")
    model = world.body_model
    terrain = model.meshes[model.names.index("terrain")]
    for tick in range(300):
        world.step()
        if tick == 60:  # piling up: the contacts' keys are unique, their features small (below FEATURE_SLOTS)
            contacts = world.solver.detector.detect(model, world.body_state, world.dt / 4, ground=world.ground)
            assert contacts.count > 30 and len(np.unique(contacts.key)) == contacts.count
            assert (contacts.key % FEATURE_SLOTS).max() < 4  # a pair gives at most 4 points, ranked 0 .. 3
        if world.bodies_asleep:
            break
    assert world.bodies_asleep, f"still awake after {world.time:.1f} s"
    asleep_at = world.time
    for _ in range(30):  # asleep bodies stay exactly where they are
        world.step()
    assert not np.any(world.body_state.linear_momentum) and not np.any(world.body_state.angular_momentum)
    lowest = np.inf
    for i in np.flatnonzero(model.shape == int(model.shape[1])):  # the hulls
        for x, y, z in hull_world_vertices(world, i):
            hit, t, *_ = bvh_raycast(terrain.arrays, np.array([x, y, 5.0]), np.array([0.0, 0.0, -1.0]), 10.0)
            assert hit >= 0
            lowest = min(lowest, z - (5.0 - t))
    assert lowest > -0.005, lowest
    assert asleep_at < 5.0


def test_convex_pile_bodies_never_jump_further_than_their_velocity_carries_them():
    """No body moves or turns in one tick by more than its speed carries it plus a position correction's worth
    (5 cm, 0.1 rad: max_correction, 5 cm a sub-step, is for deep penetration; the pile's is ≤ a few mm).  The
    rocks and hulls land on the terrain with several speculative corners each, nearly in a line: with each
    bouncing corner's time-of-impact shift taken from its own gap, the position stage was asked for
    displacements no rigid motion makes, and met them through the block's near-null mode — rock_5 moved 0.53 m at
    tick 19, hull_7 0.31 m at 44, hull_5 0.21 m at 45, turned by up to 3 rad, none deeper than 1 mm."""
    world = World.from_scene("convex_pile")
    model, state = world.body_model, world.body_state
    moving = model.inv_mass > 0.0

    def speed_and_spin():
        return (np.linalg.norm(state.linear_velocity(model), axis=1),
                np.linalg.norm(state.angular_velocity(model), axis=1))

    for tick in range(60):
        position, orientation = state.position.copy(), state.orientation.copy()
        speed, spin = speed_and_spin()
        world.step()
        speed, spin = np.maximum((speed, spin), speed_and_spin())
        moved = np.linalg.norm(state.position - position, axis=1)
        turned = 2.0 * np.arccos(np.minimum(np.abs(np.einsum("ni,ni->n", state.orientation, orientation)), 1.0))
        for i in np.flatnonzero(moving):
            assert moved[i] <= speed[i] * world.dt + 0.05, (tick, model.names[i], moved[i], speed[i] * world.dt)
            assert turned[i] <= spin[i] * world.dt + 0.1, (tick, model.names[i], turned[i], spin[i] * world.dt)


@pytest.mark.parametrize("detection", ["every_substep", "once_per_tick"])
@pytest.mark.parametrize("rate_hz", [30, 60, 240])
def test_bullets_never_get_behind_the_thin_wall_or_the_one_triangle_wall(rate_hz, detection):
    """At 300 m/s the ball and the hull cover 2.5 m (30 Hz), 1.25 m (60 Hz) or 0.31 m (240 Hz) per sub-step,
    far more than the 5 mm wall or a triangle: they stop at its front (x = 0; a hull's corner may be a contact's
    penetration, 2.5 mm at most, into it — the position stage takes that back) on every tick — with the contacts
    found every sub-step, and once per tick (margins for the tick, separations carried: cgp_core/collision/carry.py).
    The same run without continuous collision (no motion in the margins, no time of impact) goes straight through
    both."""
    def run(continuous: bool) -> dict:
        scene = load_scene("bullet")
        scene.world.contact_detection = detection
        world = World(scene, dt=1.0 / rate_hz)
        world.solver.detector.continuous = continuous
        names = world.body_model.names
        front = {}
        for _ in range(round(0.3 * rate_hz)):
            world.step()
            for name in ("ball_wall", "ball_mesh", "hull_wall", "hull_mesh"):
                i = names.index(name)
                reach = world.body_state.position[i, 0] + world.body_model.radius[i] if name.startswith("ball") \
                    else hull_world_vertices(world, i)[:, 0].max()
                front[name] = max(front.get(name, -np.inf), reach)
        return front

    caught, missed = run(True), run(False)
    for name, x in caught.items():
        assert x <= 2.5e-3, (name, x)  # never past the walls' front face x = 0 (a contact's penetration at most)
        assert x > -0.05, (name, x)  # and they did get there
    assert all(x > 50.0 for x in missed.values()), missed


SPINNER = """
world: {{gravity: [0, 0, 0], ground: false, substeps: 1, sleep: false}}
bodies:
  - {{name: wall, shape: convex, fixed: true, points: [[-0.2, 0.79, -0.5], [0.2, 0.79, -0.5], [-0.2, 0.81, -0.5],
     [0.2, 0.81, -0.5], [-0.2, 0.79, 0.5], [0.2, 0.79, 0.5], [-0.2, 0.81, 0.5], [0.2, 0.81, 0.5]]}}
  - {{name: plank, shape: convex, mass: 1.0, angular_velocity: [0, 0, {spin}],
     points: [[-1, -0.02, -0.05], [1, -0.02, -0.05], [-1, 0.02, -0.05], [1, 0.02, -0.05],
              [-1, -0.02, 0.05], [1, -0.02, 0.05], [-1, 0.02, 0.05], [1, 0.02, 0.05]]}}
"""


def test_a_plank_turning_a_quarter_turn_per_step_is_stopped_by_the_time_of_impact():
    """A 2 m plank lies along x, 0.77 m from a 0.4 m wide, 2 cm thin fixed wall in front of its middle, and turns
    about z by a quarter turn per sub-step (377 rad/s at 240 Hz): at the start its closest points to the wall are
    near its middle, which does not approach, so a start-of-step (speculative) contact does not stop it; its end
    sweeps through the wall within the first step.  The time of impact (conservative advancement over the
    step's rotation) puts it back where it first touches: it never gets into or behind the wall.  Without the
    time of impact (margins alone) it does."""
    rate = 240.0

    def run(sweep: bool) -> tuple[float, float]:
        world = World(parse_scene(SPINNER.format(spin=(math.pi / 2) * rate), "spinner.yaml"), dt=1 / rate)
        if not sweep:
            world.solver.detector.sweep_fast_rotation = lambda *args: None
        wall, plank = world.body_model.hulls
        deepest, through = np.inf, -np.inf
        for _ in range(8):
            world.step()
            R = quat_to_matrix(world.body_state.orientation[1])
            separation = penetration(
                Core(plank.vertices, no_adjacency(plank.vertices), NO_ADJACENCY, world.body_state.position[1], R), 0.0,
                Core(wall.vertices, no_adjacency(wall.vertices), NO_ADJACENCY, world.body_state.position[0],
                     np.eye(3)), 0.0)[0]
            deepest = min(deepest, separation)
            corners = hull_world_vertices(world, 1)
            beside = np.abs(corners[:, 0]) < 0.2
            through = max(through, corners[beside, 1].max() if beside.any() else -np.inf)
        return deepest, through

    deepest, through = run(True)
    assert deepest > -0.005 and through < 0.79 + 0.005, (deepest, through)
    deepest, through = run(False)
    assert deepest < -0.05 or through > 0.81, (deepest, through)


def test_hull_bounds_are_the_turned_local_box_then_exact_where_a_pair_or_the_ground_is_near():
    """pose_shapes bounds a hull by its local box turned (|R| e, Bullet's and PhysX's bound: it holds the exact AABB);
    tighten_hull_bounds gives the hulls in a candidate pair or near the ground their exact AABB (their turned
    vertices') and keeps the pairs whose exact AABBs overlap: the pairs of exact bounds, as before the cheap bound."""
    from cgp_core.collision.convex_phase import HULL, ShapePoses, pose_shapes, tighten_hull_bounds
    from cgp_core.collision.primitives import primitive_bounds

    world = World.from_scene("convex_pile")
    for _ in range(20):
        world.step()
    model, state, det = world.body_model, world.body_state, world.solver.detector
    shapes = det.shape_model(model)
    p, P = det.collision_model(model).count, shapes.count
    R = state.rotation_matrices()
    rng = np.random.default_rng(3)
    motion = (state.position, np.ascontiguousarray(R), rng.normal(size=(model.count, 3)),
              rng.normal(size=(model.count, 3)))
    h, spec = 1 / 240, det.speculative_distance
    first = primitive_bounds(tuple(det.collision_model(model)), motion, h, spec)
    poses = ShapePoses(np.empty((P, 3)), np.empty((P, 3, 3)), np.empty((P, 3)), np.empty((P, 3)), np.empty(P))
    poses.centre[:p], poses.lo[:p], poses.hi[:p], poses.margin[:p] = first.centre, first.lo, first.hi, first.margin
    pose_shapes(shapes.plain(), motion, h, spec, tuple(poses))
    prims, hulls = shapes.primitives, shapes.hulls
    exact_lo, exact_hi = poses.lo.copy(), poses.hi.copy()
    hull_rows = [k for k in range(p, P) if prims.kind[k] == HULL]
    assert len(hull_rows) >= 10
    for k in hull_rows:
        v = hulls.vertices[hulls.vertex_start[prims.hull[k]]:hulls.vertex_start[prims.hull[k] + 1]]
        turned = v @ poses.rotation[k].T
        exact_lo[k] = poses.centre[k] + turned.min(0) - poses.margin[k]
        exact_hi[k] = poses.centre[k] + turned.max(0) + poses.margin[k]
    cheap_lo, cheap_hi = poses.lo.copy(), poses.hi.copy()
    assert (cheap_lo <= exact_lo + 1e-12).all() and (cheap_hi >= exact_hi - 1e-12).all()

    def overlapping(lo, hi):
        i, j = np.triu_indices(P, 1)
        keep = (prims.body[i] != prims.body[j]) & np.all((lo[i] <= hi[j]) & (lo[j] <= hi[i]), axis=1)
        return i[keep].astype(np.int64), j[keep].astype(np.int64)

    i, j = overlapping(cheap_lo, cheap_hi)
    ki, kj = tighten_hull_bounds(prims.kind, prims.hull, tuple(hulls), prims.first_new, tuple(poses), i, j, True,
                                 np.zeros((P, 6), np.int64))
    ei, ej = overlapping(exact_lo, exact_hi)
    assert len(ei) < len(i)  # the cheap bound is looser: some of its pairs are not pairs of exact bounds
    assert list(zip(ki, kj)) == list(zip(ei, ej))
    near = np.zeros(P, bool)
    near[i], near[j] = True, True
    near |= cheap_lo[:, 2] < poses.margin
    for k in hull_rows:
        if near[k]:
            np.testing.assert_allclose(poses.lo[k], exact_lo[k], rtol=0, atol=1e-12)
            np.testing.assert_allclose(poses.hi[k], exact_hi[k], rtol=0, atol=1e-12)
        else:
            assert (poses.lo[k] == cheap_lo[k]).all() and (poses.hi[k] == cheap_hi[k]).all()

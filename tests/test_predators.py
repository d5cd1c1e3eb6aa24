"""Predators (cgp_core/boids/predators.py): the escape direction and strength, fleeing winning over cohesion in
both rule sets, and the fountain effect of the built-in `predator` scene — a predator pushed through a school
by a wrench command (benchmarks/figures/predator_run.py's `attack`, the very run `make figures` draws)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from cgp_core.boids import Flock, FlockParams
from cgp_core.boids.params import CouzinParams
from cgp_core.boids.predators import BEHIND_FADE, Predators, flee
from cgp_core.scene import SceneError, parse_scene

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks" / "figures"))
from predator_run import MARGIN, attack  # noqa: E402


def predator(position, velocity=(0.0, 0.0, 0.0), radius=1.0) -> Predators:
    return Predators(np.array([position], float), np.array([velocity], float), np.array([radius], float))


def flee_acceleration(boids: np.ndarray, predators: Predators, fright_radius: float, full_strength: float):
    """Every boid's escape acceleration, (N, 3)."""
    out = np.zeros_like(boids)
    flee(boids, predators, fright_radius, full_strength, out)
    return out


def test_a_predator_at_rest_is_fled_radially_with_a_strength_that_fades_at_the_fright_radius():
    boids = np.array([[3.0, 0.0, 0.0], [0.0, -4.0, 0.0], [0.0, 0.0, 5.0], [0.0, 0.0, 6.5], [8.0, 0, 0]])
    a = flee_acceleration(boids, predator([0.0, 0.0, 0.0]), fright_radius=5.0, full_strength=20.0)
    # clearances 2, 3, 4, 5.5, 7 from the 1 m sphere: full in the inner half (< 2.5), then linear to 0 at 5
    np.testing.assert_allclose(a[0], [20.0, 0, 0])
    np.testing.assert_allclose(a[1], [0, -20.0 * 2 * (5 - 3) / 5, 0])
    np.testing.assert_allclose(a[2], [0, 0, 20.0 * 2 * (5 - 4) / 5])
    np.testing.assert_allclose(a[3:], 0.0)


def test_a_moving_predator_is_fled_off_its_path_and_not_once_it_has_passed():
    moving = predator([0.0, 0.0, 0.0], velocity=[6.0, 0.0, 0.0])
    boids = np.array([[2.0, 0.5, 0.0], [0.0, 2.0, 0.0], [-0.5, 2.5, 0.0], [-2.0, 0.5, 0.0]])
    a = flee_acceleration(boids, moving, fright_radius=5.0, full_strength=20.0)
    away = boids[0] / np.linalg.norm(boids[0])
    expected = away + np.array([0.0, 1.0, 0.0])  # away + the unit sideways direction off the path
    np.testing.assert_allclose(a[0], 20.0 * expected / np.linalg.norm(expected))
    np.testing.assert_allclose(a[1], [0.0, 20.0, 0.0])  # abeam: straight off the path
    fade = 1.0 + (-0.5 / math.hypot(0.5, 2.5)) / BEHIND_FADE  # a little behind: fading out
    assert np.linalg.norm(a[2]) == pytest.approx(20.0 * fade)
    np.testing.assert_allclose(a[3], 0.0)  # well behind the passing predator: no fright


def test_two_predators_add_up():
    boids = np.array([[0.0, 0.0, 0.0]])
    both = Predators(np.array([[-3.0, 0.0, 0.0], [0.0, 3.5, 0.0]]), np.zeros((2, 3)), np.array([1.0, 1.0]))
    a = flee_acceleration(boids, both, fright_radius=5.0, full_strength=20.0)
    np.testing.assert_allclose(a[0], [20.0, -20.0, 0.0])  # clearances 2 and 2.5: both at full strength


@pytest.mark.parametrize("rules", ["reynolds", "couzin"])
def test_fleeing_beats_cohesion(rules):
    # two boids 4 m apart, swimming side by side (+y); a predator at rest sits between them, 1.5 m from boid 0's
    # surface side: cohesion / attraction pulls boid 0 towards boid 1 (+x), the predator is in the way
    extra = dict(rules="couzin", couzin=CouzinParams(orientation_width=1.0, attraction_width=8.0,
                                                     turning_rate_deg=720.0)) if rules == "couzin" else {}
    flock = Flock(FlockParams(count=2, spawn_center=[0, 0, 0], spawn_extent=[0, 0, 0], bounds_mode="none",
                              fright_radius=4.0, **extra))
    flock.positions[:] = [[0.0, 0.0, 0.0], [4.0, 0.0, 0.0]]
    speed = np.linalg.norm(flock.velocities[0])
    flock.velocities[:] = [[0.0, speed, 0.0], [0.0, speed, 0.0]]
    flock.headings[:] = [[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]]
    shark = predator([1.5 + 1.0, 0.0, 0.0], radius=1.0)
    start = np.linalg.norm(flock.positions[0] - shark.position[0])
    for _ in range(30):
        flock.step(1 / 60, predators=shark)
        assert flock.velocities[0, 0] < 0.0  # moving away from the predator, not towards its flockmate
    assert np.linalg.norm(flock.positions[0] - shark.position[0]) > start + 0.3


def test_a_spawned_body_can_be_a_predator_and_deleting_it_ends_the_fright():
    """World.step builds the predators from the bodies there are now (BodyModel.predator follows spawn and
    delete): a shark spawned in a school's middle accelerates every fish outwards; once deleted, the school
    steps exactly as one that never saw it."""
    from cgp_core import World

    scene = parse_scene("world: {gravity: [0, 0, 0], ground: false}\nflocks: [{name: f, count: 60, "
                        "spawn: {center: [0, 0, 0], extent: [3, 3, 3]}, bounds: {mode: none}, fright_radius: 6.0}]")
    world, twin = World(scene), World(scene)
    world.spawn({"body": {"shape": "sphere", "radius": 0.5, "mass": 1.0, "predator": True}}, name="shark",
                position=[0.0, 0.0, 0.0])
    assert world.body_model.predator.tolist() == [True]
    school = world.flocks[0]
    x0, v0 = school.positions.copy(), school.velocities.copy()
    world.step()
    outwards = np.einsum("ij,ij->i", school.velocities - v0, x0)
    assert np.all(outwards > 0.0)  # every fish: the shark's flight beats its flockmates' pull
    world.delete("shark")
    assert world.body_model.predator.tolist() == []
    for flock, other in zip(world.flocks, twin.flocks):
        for name in ("positions", "velocities", "headings", "dorsals", "orientations"):
            getattr(other, name)[:] = getattr(flock, name)
    world.step()
    twin.step()
    np.testing.assert_array_equal(world.flocks[0].positions, twin.flocks[0].positions)


def test_predator_flag_is_validated():
    with pytest.raises(SceneError, match=r"bodies\[0\] \(shark\)\.predator: must be true or false, got a string"):
        parse_scene("bodies: [{name: shark, shape: sphere, radius: 1, predator: 'yes'}]", "bad.yaml")


def one_group(positions: np.ndarray, link: float) -> float:
    tree = cKDTree(positions)
    _, labels = connected_components(tree.sparse_distance_matrix(tree, link, output_type="coo_matrix"),
                                     directed=False)
    return np.bincount(labels).max() / len(positions)


def test_fountain_effect_when_a_predator_is_pushed_through_the_school():
    record = attack()  # the built-in `predator` scene; the predator pushed by one wrench command to 6 m/s
    before = record.before
    assert before.polarization > 0.95  # a polarized school before the attack
    passing = int(np.argmax(np.array(record.along) <= 0.0))
    assert record.along[passing] <= 0.0 < record.along[0], "the predator must pass the school's centroid"
    # no fish ever comes within the predator's radius + margin
    assert min(record.clearance) > MARGIN, min(record.clearance)
    # the school splits ahead of it: as it passes, the fish beside it are spread around its path (surround 0
    # when all are on one side, as when a school merely dodges; measured 0.51 here: more fish below the path
    # than above, as the figure shows)
    assert record.beside[passing] >= 20 and record.surround[passing] > 0.4, (record.beside[passing],
                                                                            record.surround[passing])
    # the attack disturbed the school (it spreads and loses its alignment) ...
    assert min(record.polarization) < 0.85 and max(record.radius_of_gyration) > 1.3 * before.radius_of_gyration
    # ... and it closes again behind the predator: one group, as compact as before, polarized again
    positions, _ = record.snapshots["after"]
    assert one_group(positions, 2.0) == 1.0
    assert record.radius_of_gyration[-1] < 1.1 * before.radius_of_gyration
    assert record.polarization[-1] > 0.95

"""Reynolds' rules: hand-made configurations with known answers, each rule alone doing what it says, and the
default flock polarizing from a random start while keeping its spacing."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from cgp_core.boids import BruteForceSearch, Flock, FlockParams
from cgp_core.boids.rules import alignment, cohesion, neighbor_sums, steering

DT = 1.0 / 60.0


def _sums(positions, velocities, radius, separation_radius, fov_deg=360.0):
    """NeighborSums of a hand-made configuration (brute-force neighbour lists)."""
    positions = np.asarray(positions, dtype=float)
    velocities = np.asarray(velocities, dtype=float)
    headings = velocities / np.linalg.norm(velocities, axis=1, keepdims=True)
    neighbors = BruteForceSearch().neighbors(positions, radius)
    cos_half = math.cos(math.radians(fov_deg / 2)) if fov_deg < 360 else -1.0
    return (neighbor_sums(neighbors, positions, velocities, headings, separation_radius, cos_half), positions,
            velocities)


def test_hand_made_configuration_gives_the_slide_vectors():
    # boid 0 at the origin flying +x; 1 and 2 ahead/left; 3 close by (inside s = 0.5); 4 out of range
    positions = [[0, 0, 0], [1.0, 0, 0], [0, 1.0, 0], [0.3, -0.1, 0], [5.0, 0, 0]]
    velocities = [[1, 0, 0], [0, 2, 0], [1, 1, 0], [1, 0, 1], [3, 3, 3]]
    sums, x, v = _sums(positions, velocities, radius=1.5, separation_radius=0.5)
    # cohesion v1 = centroid of neighbours − b (boid 0 is crowded by boid 3, so the gated rule gives 0)
    v1 = cohesion(sums, gated=False)
    np.testing.assert_allclose(v1[0], np.mean([[1.0, 0, 0], [0, 1.0, 0], [0.3, -0.1, 0]], axis=0), atol=1e-12)
    assert np.all(cohesion(sums, gated=True)[0] == 0.0)
    # alignment v3 = mean neighbour velocity − b_v
    v3 = alignment(sums, v)
    np.testing.assert_allclose(v3[0], np.mean([[0, 2, 0], [1, 1, 0], [1, 0, 1]], axis=0) - [1, 0, 0], atol=1e-12)
    # separation pushes 0 away from 3 (slide erratum: the slide's sign would pull it closer):
    # (b − x_3) (s − r) / r with r = |b − x_3|
    offset = np.array([-0.3, 0.1, 0.0])
    r = np.linalg.norm(offset)
    np.testing.assert_allclose(sums.separation[0], offset * (0.5 - r) / r, atol=1e-12)
    np.testing.assert_allclose(sums.separation[3], -offset * (0.5 - r) / r, atol=1e-12)
    # a boid with no neighbour gets nothing
    assert sums.count[4] == 0
    np.testing.assert_array_equal(steering(sums, v, 1.0, 1.0, 1.0)[4], 0.0)


def test_field_of_view_hides_the_boid_behind():
    # boid 0 flies +x; boid 1 straight behind it, boid 2 beside it
    positions = [[0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0]]
    velocities = [[1, 0, 0], [1, 0, 0], [1, 0, 0]]
    seen, _, _ = _sums(positions, velocities, radius=2.0, separation_radius=0.1, fov_deg=270.0)
    assert seen.count[0] == 1  # sees 2 only
    np.testing.assert_allclose(seen.offset_sum[0], [0, 1.0, 0], atol=1e-12)
    assert seen.count[1] == 2  # boid 1 sees both ahead of it
    everything, _, _ = _sums(positions, velocities, radius=2.0, separation_radius=0.1, fov_deg=360.0)
    assert everything.count[0] == 2


def _rms_radius(flock):
    x = flock.positions
    return float(np.sqrt(((x - x.mean(axis=0)) ** 2).sum(axis=1).mean()))


def _only(rule: str, **overrides) -> FlockParams:
    weights = dict(cohesion_weight=0.0, separation_weight=0.0, alignment_weight=0.0)
    weights[f"{rule}_weight"] = overrides.pop("weight")
    params = dict(count=80, seed=3, fov_deg=360.0, bounds_mode="none", radius=20.0, separation_radius=1.0,
                  spawn_center=[0, 0, 20], spawn_extent=[6, 6, 6], min_speed=0.2, max_speed=2.0)
    params.update(weights)
    params.update(overrides)
    return FlockParams(**params)


def test_only_cohesion_contracts_the_flock():
    flock = Flock(_only("cohesion", weight=4.0))
    start = _rms_radius(flock)
    for _ in range(300):
        flock.step(DT)
    assert _rms_radius(flock) < 0.3 * start


def test_only_separation_spreads_boids_to_the_separation_radius():
    """All boids fly the same velocity, packed 3 per separation radius: without separation their relative
    positions would never change.  With it, within a few seconds no pair stays inside s."""
    params = _only("separation", weight=300.0, spawn_extent=[2.0, 2.0, 2.0], count=40)
    flock = Flock(params)
    flock.velocities[:] = [1.0, 0.0, 0.0]
    distances = cKDTree(flock.positions).query(flock.positions, k=2)[0][:, 1]
    assert distances.min() < 0.3 * params.separation_radius
    closest = []
    for step in range(360):
        flock.step(DT)
        if step >= 240:
            closest.append(cKDTree(flock.positions).query(flock.positions, k=2)[0][:, 1].min())
    assert min(closest) > 0.97 * params.separation_radius


def test_only_alignment_aligns_velocities():
    flock = Flock(_only("alignment", weight=3.0))
    assert flock.polarization() < 0.3
    for _ in range(180):
        flock.step(DT)
    assert flock.polarization() > 0.99


@pytest.mark.parametrize("seed", [0, 1])
def test_default_flock_polarizes_and_keeps_its_spacing(seed):
    """From a random start with the default weights: polarization |Σ v̂| / N > 0.9 within 20 s, and the mean
    nearest-neighbour distance above the separation radius on average (over the last 10 s)."""
    params = FlockParams(seed=seed)
    flock = Flock(params)
    assert flock.polarization() < 0.2
    first_polarized = None
    nearest = []
    for step in range(int(20.0 / DT)):
        flock.step(DT)
        if first_polarized is None and flock.polarization() > 0.9:
            first_polarized = flock.time
        if flock.time > 10.0 and step % 15 == 0:
            nearest.append(cKDTree(flock.positions).query(flock.positions, k=2)[0][:, 1].mean())
    assert first_polarized is not None and first_polarized <= 20.0
    assert np.mean(nearest) > params.separation_radius
    assert flock.polarization() > 0.9

"""Vicsek et al. 1995 (PRL 75:1226) as a test of alignment alone: Couzin's rule set reduced to its zone of
orientation (r_r = 0, Δr_a = 0, no blind volume, no turning limit) is the Vicsek model in 3D — each particle
takes its neighbours' mean heading, rotated by noise, and moves at constant speed.  In a periodic box at fixed
density the polarization falls monotonically as the noise grows, and for noise so large that headings are
random it is the polarization of N random unit vectors, sqrt(8 / (3πN)) in 3D (√π / (2√N) in Vicsek's plane:
0.051 at N = 300; the 3D value is 0.053)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cgp_core.boids import Flock, FlockParams
from cgp_core.boids.params import CouzinParams

N = 300
BOX = 5.0  # density 2.4 per unit³: ~10 neighbours within the interaction radius 1
DT = 0.1  # = τ: the noise per step is σ


def vicsek_flock(noise: float, seed: int = 1) -> Flock:
    return Flock(FlockParams(
        count=N, seed=seed, rules="couzin", bounds_mode="wrap", bounds_min=[0, 0, 0], bounds_max=[BOX] * 3,
        spawn_center=[BOX / 2] * 3, spawn_extent=[BOX] * 3,
        couzin=CouzinParams(repulsion_radius=0.0, orientation_width=1.0, attraction_width=0.0,
                            field_of_view_deg=360.0, turning_rate_deg=1e5, speed=0.3, noise=noise)))


def mean_polarization(noise: float, transient: int = 150, steps: int = 150) -> float:
    """Time-averaged polarization at ``noise``, from an aligned start (a random start orders by slow
    coarsening of domains: hundreds of steps more for the same stationary value)."""
    flock = vicsek_flock(noise)
    flock.headings[:] = [1.0, 0.0, 0.0]
    flock.velocities[:] = [0.3, 0.0, 0.0]
    values = []
    for step in range(transient + steps):
        flock.step(DT)
        if step >= transient:
            values.append(flock.order().polarization)
    return float(np.mean(values))


def test_polarization_falls_monotonically_with_noise_down_to_random_headings():
    noises = [0.05, 0.15, 0.25, 0.35, 0.45, 100.0]  # rad per step; 100: a uniformly random angle
    p = [mean_polarization(noise) for noise in noises]
    assert p[0] > 0.99 and p[-2] < 0.1, p  # ordered at low noise, disordered past σ ≈ 0.35
    assert all(a > b for a, b in zip(p, p[1:])), p
    random_headings = math.sqrt(8.0 / (3.0 * math.pi * N))
    # 150 nearly independent samples of a Maxwell-distributed |Σ v̂| / N (s.d. 0.42 of its mean): s.e. 0.002
    assert p[-1] == pytest.approx(random_headings, abs=0.008), p

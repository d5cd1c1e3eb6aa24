"""Fish frames: orthonormal, right-handed, x along the velocity, banked like a coordinated turn, continuous
(no roll flips at a change of turn direction, defined in vertical flight), and the quaternions are those of
the frame matrices."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cgp_core.boids import Flock, FlockParams
from cgp_core.boids.frames import (
    GRAVITY,
    frames_to_quaternions,
    initial_dorsal,
    parallel_transport,
    unit_headings,
    update_frames,
)
from cgp_core.rotation import matrix_to_quat, quat_rotate, quat_to_matrix

DT = 1.0 / 60.0


def _check_frames(heading, dorsal, velocity=None):
    """Unit, orthogonal, right-handed (det = +1 by construction of y = z × x), x along the velocity."""
    np.testing.assert_allclose(np.linalg.norm(heading, axis=0), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(dorsal, axis=0), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.einsum("ij,ij->j", heading, dorsal), 0.0, atol=1e-9)
    assert np.all(np.isfinite(heading)) and np.all(np.isfinite(dorsal))
    if velocity is not None:
        np.testing.assert_allclose(heading, velocity / np.linalg.norm(velocity, axis=0), atol=1e-9)


def test_steady_circle_banks_by_the_coordinated_turn_angle():
    """On a horizontal circle of radius R at speed v the dorsal axis tilts towards the centre by
    atan(v² / (R g)) (bank_gain 1), or by atan(k v² / (R g)) for bank_gain k."""
    speed = np.array([2.0, 5.0, 3.0, 4.0])
    radius = np.array([1.0, 4.0, 2.0, 10.0])
    gain = np.array([1.0, 1.0, 0.5, 1.0])
    omega = np.array([1.0, -1.0, 1.0, -1.0]) * speed / radius  # counter-clockwise and clockwise
    steps = 240
    heading = dorsal = None
    for k in range(steps):
        phase = omega * k * DT
        velocity = np.stack((-np.sin(phase), np.cos(phase), np.zeros(4))) * speed * np.sign(omega)
        if heading is None:
            heading = unit_headings(velocity)
            dorsal = initial_dorsal(heading)
            continue
        # one call per gain (the function takes a scalar gain)
        new_h, new_d = heading.copy(), dorsal.copy()
        for g in np.unique(gain):
            m = gain == g
            new_h[:, m], new_d[:, m] = update_frames(heading[:, m], dorsal[:, m], velocity[:, m], DT, g, 0.15)
        heading, dorsal = new_h, new_d
        _check_frames(heading, dorsal, velocity)
    position_dir = np.stack((np.cos(phase), np.sin(phase), np.zeros(4)))  # centre is at −position_dir
    expected = np.arctan(gain * speed**2 / (radius * GRAVITY))
    tilt_towards_centre = np.arctan2(np.einsum("ij,ij->j", dorsal, -position_dir), dorsal[2])
    np.testing.assert_allclose(tilt_towards_centre, expected, atol=0.02)


def test_straight_flight_is_level_and_vertical_flight_keeps_its_roll():
    rng = np.random.default_rng(1)
    velocity = rng.normal(size=(3, 50))
    heading = unit_headings(velocity)
    dorsal = initial_dorsal(heading)
    for _ in range(30):
        heading, dorsal = update_frames(heading, dorsal, velocity, DT, 1.0, 0.15)
    _check_frames(heading, dorsal, velocity)
    # level: the dorsal axis is world up made perpendicular to the heading
    up = np.array([0.0, 0.0, 1.0])[:, None]
    level = up - np.einsum("ij,ij->j", up * np.ones_like(heading), heading) * heading
    level /= np.linalg.norm(level, axis=0)
    np.testing.assert_allclose(dorsal, level, atol=1e-6)

    # pitch up to vertical over 1 s, then fly straight up: no NaN, and the roll does not move once vertical
    heading = np.array([[1.0], [0.0], [0.0]])
    dorsal = initial_dorsal(heading)
    for k in range(1, 61):
        angle = 0.5 * math.pi * min(1.0, k / 60)
        v = np.array([[math.cos(angle)], [0.0], [math.sin(angle)]])
        heading, dorsal = update_frames(heading, dorsal, v, DT, 1.0, 0.15)
        _check_frames(heading, dorsal, v)
    vertical_roll = dorsal.copy()
    for _ in range(30):
        heading, dorsal = update_frames(heading, dorsal, np.array([[0.0], [0.0], [3.0]]), DT, 1.0, 0.15)
        _check_frames(heading, dorsal)
    np.testing.assert_allclose(dorsal, vertical_roll, atol=1e-9)
    assert dorsal[0, 0] < -0.99, "pitching up keeps the back towards where it was (−x after a loop up)"


def test_s_curve_banks_into_each_turn_without_rolling_over():
    """Alternate left and right turns: the Frenet normal flips at each inflection, the banked dorsal axis
    must not — it swings continuously from one side to the other and always stays up."""
    speed = 3.0
    turn_rate = 1.5  # rad/s, alternating sign every 1.5 s
    heading_angle = 0.0
    heading = np.array([[1.0], [0.0], [0.0]])
    dorsal = initial_dorsal(heading)
    blend = 1.0 - math.exp(-DT / 0.15)
    # the low-pass moves the dorsal axis at most asin(α / (1 − α)) per tick (α = the blend fraction)
    max_roll = math.asin(blend / (1.0 - blend))
    sides = []
    for k in range(540):
        rate = turn_rate if (k * DT) % 3.0 < 1.5 else -turn_rate
        heading_angle += rate * DT
        v = speed * np.array([[math.cos(heading_angle)], [math.sin(heading_angle)], [0.0]])
        carried = parallel_transport(dorsal, heading, v / speed)
        heading, dorsal = update_frames(heading, dorsal, v, DT, 1.0, 0.15)
        _check_frames(heading, dorsal, v)
        roll_step = math.acos(np.clip(np.dot(carried[:, 0], dorsal[:, 0]), -1.0, 1.0))
        assert roll_step <= max_roll + 1e-3, f"roll jumped {math.degrees(roll_step):.1f}° at step {k}"
        assert dorsal[2, 0] > 0.8, "stays upright"
        left = np.array([-math.sin(heading_angle), math.cos(heading_angle), 0.0])
        sides.append((rate, float(np.dot(dorsal[:, 0], left))))
    # after settling in each turn, the dorsal axis leans to the inside of the turn
    settled = [(rate, lean) for i, (rate, lean) in enumerate(sides) if (i * DT) % 1.5 > 0.75]
    assert all(np.sign(lean) == np.sign(rate) for rate, lean in settled)
    expected = math.atan(speed * turn_rate / GRAVITY)  # centripetal a = v ω
    assert max(abs(lean) for _, lean in settled) == pytest.approx(math.sin(expected), abs=0.02)


def test_quaternions_are_those_of_the_frame_matrices():
    rng = np.random.default_rng(4)
    q = rng.normal(size=(5000, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    # half turns (w = 0) and near half turns, where the quaternion signs are delicate
    q[:4] = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0.6, 0.8, 0, 0]]
    q[4:200, 3] = rng.normal(0.0, 1e-5, 196)
    q[4:200] /= np.linalg.norm(q[4:200], axis=1, keepdims=True)
    q[200] = [0, 0, 0, 1]
    R = quat_to_matrix(q)
    got = frames_to_quaternions(np.ascontiguousarray(R[:, :, 0].T), np.ascontiguousarray(R[:, :, 2].T)).T
    reference = matrix_to_quat(R)
    same_rotation = np.minimum(np.abs(got - reference).max(axis=1), np.abs(got + reference).max(axis=1))
    assert same_rotation.max() < 1e-6
    np.testing.assert_allclose(quat_to_matrix(got), R, atol=1e-6)
    assert np.all(got[:, 3] >= 0.0)


def test_fish_flock_frames_follow_the_velocity_and_never_flip():
    params = FlockParams(count=150, model="fish", seed=2)
    flock = Flock(params)
    for step in range(240):
        heading_old = flock.headings.T.copy()
        dorsal_old = flock.dorsals.T.copy()
        flock.step(DT)
        v = flock.velocities.T
        heading = flock.headings.T
        dorsal = flock.dorsals.T
        _check_frames(heading, dorsal, v)
        # the published quaternions rotate x to the heading and z to the dorsal axis
        q = flock.orientations
        np.testing.assert_allclose(quat_rotate(q, np.array([1.0, 0.0, 0.0])), heading.T, atol=1e-6)
        np.testing.assert_allclose(quat_rotate(q, np.array([0.0, 0.0, 1.0])), dorsal.T, atol=1e-6)
        np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
        # continuity: beyond following the heading the roll changes by a few degrees per tick (the low-pass
        # moves at most ~7° at 60 Hz; slow boids can turn tens of degrees per tick, which adds a little);
        # a flip would be 180°
        carried = parallel_transport(dorsal_old, heading_old, heading)
        roll = np.arccos(np.clip(np.einsum("ij,ij->j", carried, dorsal), -1.0, 1.0))
        assert np.degrees(roll.max()) < 30.0, f"step {step}: roll jumped {np.degrees(roll.max()):.1f}°"

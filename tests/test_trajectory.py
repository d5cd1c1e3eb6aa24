"""cgp_sim_ros/trajectory.py: joint trajectories sampled as joint_trajectory_controller interpolates them (linear
between points without velocities, cubic Hermite with them, from the start state to the first point, the last
point held), and the refusals of what cannot be followed."""

from __future__ import annotations

import numpy as np
import pytest

from cgp_sim_ros.trajectory import TrajectoryError, check_trajectory, sample


def test_linear_between_points_without_velocities_and_the_last_point_held():
    tr = check_trajectory(["a", "b"], 0, [1.0, 3.0], [[1.0, -1.0], [3.0, 1.0]], [[], []])
    start = np.array([0.0, 0.0])
    np.testing.assert_allclose(sample(tr, 0.0, start), [0.0, 0.0])
    np.testing.assert_allclose(sample(tr, 0.5, start), [0.5, -0.5])  # start state → first point
    np.testing.assert_allclose(sample(tr, 1.0, start), [1.0, -1.0])
    np.testing.assert_allclose(sample(tr, 2.0, start), [2.0, 0.0])
    np.testing.assert_allclose(sample(tr, 10.0, start), [3.0, 1.0])
    assert tr.start_ns is None and tr.duration == 3.0


def test_cubic_with_velocities_matches_positions_and_velocities_at_the_points():
    times, q, v = [0.5, 1.5], [[0.2], [1.0]], [[0.4], [-0.3]]
    tr = check_trajectory(["j"], 7, times, q, v)
    start = np.array([0.0])
    eps = 1e-6
    for t, qi, vi in zip(times, q, v):
        np.testing.assert_allclose(sample(tr, t - 1e-12, start), qi, atol=1e-9)
        slope = (sample(tr, t - eps, start) - sample(tr, t - 2 * eps, start)) / eps
        np.testing.assert_allclose(slope, vi, atol=1e-4)
    # a cubic: its third difference is constant on a segment
    s = np.array([sample(tr, t, start)[0] for t in np.linspace(0.6, 1.4, 9)])
    third = np.diff(s, 3)
    np.testing.assert_allclose(third, third[0], atol=1e-12)
    assert tr.start_ns == 7


@pytest.mark.parametrize("args, field", [
    (([], 0, [1.0], [[]], [[]]), "joint_names"),
    ((["a", "a"], 0, [1.0], [[0, 0]], [[]]), "joint_names"),
    ((["a"], 0, [], [], []), "points"),
    ((["a", "b"], 0, [1.0], [[0.0]], [[]]), "points[0].positions"),
    ((["a"], 0, [1.0, 2.0], [[0.0], [1.0]], [[1.0, 2.0], []]), "points[0].velocities"),
    ((["a"], 0, [1.0, 1.0], [[0.0], [1.0]], [[], []]), "points.time_from_start"),
    ((["a"], 0, [1.0], [[float("nan")]], [[]]), "points"),
    ((["a"], 0, [1.0], [[0.0]], [[float("inf")]]), "points.velocities"),
])
def test_refusals_name_the_field(args, field):
    with pytest.raises(TrajectoryError) as info:
        check_trajectory(*args)
    assert info.value.field == field


def test_any_input_is_a_trajectory_or_a_named_refusal():
    """Hypothesis: whatever a JointTrajectory carries (lengths, NaN, infinities, huge numbers, unordered times),
    check_trajectory gives a Trajectory whose samples are finite, or a TrajectoryError — nothing else."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    number = st.floats(allow_nan=True, allow_infinity=True, width=64)
    row = st.lists(number, max_size=4)

    @settings(max_examples=300, deadline=None)
    @given(joints=st.lists(st.sampled_from(["a", "b", "c", "d"]), max_size=4), stamp=st.integers(0, 2**62),
           times=st.lists(number, max_size=5), positions=st.lists(row, max_size=5),
           velocities=st.lists(row, max_size=5), t=number)
    def check(joints, stamp, times, positions, velocities, t):
        m = len(times)
        positions, velocities = (positions + [[]] * m)[:m], (velocities + [[]] * m)[:m]
        try:
            tr = check_trajectory(joints, stamp, times, positions, velocities)
        except TrajectoryError as exc:
            assert exc.field and exc.kind
            return
        if np.isfinite(t) and abs(t) < 1e12 and np.all(np.abs(tr.positions) < 1e100) and (
                tr.velocities is None or np.all(np.abs(tr.velocities) < 1e100)):
            assert np.all(np.isfinite(sample(tr, t, np.zeros(len(tr.joints)))))

    check()

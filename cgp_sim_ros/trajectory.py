"""Joint trajectories as joint_trajectory_controller follows them (ROS-free: numbers in, numbers out), for
``~/robots/<robot>/joint_trajectory`` (trajectory_msgs/JointTrajectory; the node's side:
:mod:`cgp_sim_ros.ros.commands`).

A trajectory is a list of points (time from its start, positions, optionally velocities) for a set of joints.
Sampled at a time t, it gives the joints' position targets, interpolated as joint_trajectory_controller does:

- between two points that both have velocities: the cubic Hermite polynomial matching both positions and both
  velocities (joint_trajectory_controller's cubic spline; accelerations, if given, are not used: no quintic);
- otherwise: linear in time between the two positions;
- before the first point: from the joints' positions when the trajectory was taken (velocity 0) to the first
  point, by the same rule (the controller's "start from the current state");
- after the last point: the last point's positions (held by the position drive).

The start time is the message's ``header.stamp`` in simulation time, or the time it is taken when that stamp
is zero (the controller's "start now").  :func:`check_trajectory` refuses what cannot be followed, naming the
field and why.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: points of one trajectory at most (a 7-joint arm at 100 Hz for 100 s: 10,000)
MAX_TRAJECTORY_POINTS = 10_000
#: joints of one trajectory at most
MAX_TRAJECTORY_JOINTS = 256


class TrajectoryError(ValueError):
    """A trajectory that cannot be followed: ``field`` names the message field, ``kind`` the kind of problem."""

    def __init__(self, field: str, reason: str, kind: str = "invalid"):
        self.field = field
        self.kind = kind
        self.reason = reason
        super().__init__(f"{field}: {reason}")


@dataclass(frozen=True)
class Trajectory:
    """A checked trajectory: ``joints`` (k names), ``start_ns`` (simulation time of time_from_start 0; None =
    when it is taken), ``times`` (m,) seconds from the start, strictly increasing, ≥ 0, ``positions`` (m, k),
    ``velocities`` (m, k) or None."""

    joints: tuple[str, ...]
    start_ns: int | None
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray | None

    @property
    def duration(self) -> float:
        return float(self.times[-1])


def check_trajectory(joints, start_ns: int, times, positions, velocities) -> Trajectory:
    """A :class:`Trajectory` from a JointTrajectory's fields (``start_ns`` 0 = start when taken; ``positions`` /
    ``velocities``: one sequence per point, a point's velocities may be empty), or :class:`TrajectoryError`."""
    joints = tuple(joints)
    if not joints:
        raise TrajectoryError("joint_names", "empty: name the joints the trajectory moves", "empty")
    if len(joints) > MAX_TRAJECTORY_JOINTS:
        raise TrajectoryError("joint_names", f"{len(joints)} joints, more than {MAX_TRAJECTORY_JOINTS}", "too many")
    if len(set(joints)) != len(joints):
        raise TrajectoryError("joint_names", "a joint is named twice", "duplicate")
    m = len(times)
    if m == 0:
        raise TrajectoryError("points", "no points (an empty trajectory stops nothing here: send joint_commands)",
                              "empty")
    if m > MAX_TRAJECTORY_POINTS:
        raise TrajectoryError("points", f"{m} points, more than {MAX_TRAJECTORY_POINTS}", "too many")
    k = len(joints)
    if any(len(p) != k for p in positions):
        bad = next(i for i, p in enumerate(positions) if len(p) != k)
        raise TrajectoryError(f"points[{bad}].positions", f"{len(positions[bad])} values for {k} joints",
                              "length mismatch")
    with_velocities = [len(v) for v in velocities]
    if any(n not in (0, k) for n in with_velocities):
        bad = next(i for i, n in enumerate(with_velocities) if n not in (0, k))
        raise TrajectoryError(f"points[{bad}].velocities", f"{with_velocities[bad]} values for {k} joints (give "
                              "one per joint or none)", "length mismatch")
    t = np.asarray(times, dtype=float)
    q = np.asarray(positions, dtype=float).reshape(m, k)
    if not np.all(np.isfinite(t)) or not np.all(np.isfinite(q)):
        raise TrajectoryError("points", "a time_from_start or a position is not finite", "non-finite")
    if t[0] < 0.0 or np.any(np.diff(t) <= 0.0):
        raise TrajectoryError("points.time_from_start", "must be ≥ 0 and strictly increasing", "not increasing")
    v = None
    if all(n == k for n in with_velocities):
        v = np.asarray(velocities, dtype=float).reshape(m, k)
        if not np.all(np.isfinite(v)):
            raise TrajectoryError("points.velocities", "a velocity is not finite", "non-finite")
    return Trajectory(joints, int(start_ns) if start_ns else None, t, q, v)


def sample(trajectory: Trajectory, t: float, start_positions: np.ndarray) -> np.ndarray:
    """The position targets (k,) at ``t`` seconds from the trajectory's start (``start_positions`` (k,): the joints'
    positions when it was taken, the segment before the first point starts there)."""
    times, q, v = trajectory.times, trajectory.positions, trajectory.velocities
    if t >= times[-1]:
        return q[-1].copy()
    i = int(np.searchsorted(times, t, side="right"))  # the segment [i - 1, i] (i = 0: before the first point)
    if i == 0:
        t0, t1, q0, q1 = 0.0, times[0], np.asarray(start_positions, float), q[0]
        v0, v1 = (np.zeros_like(q1), v[0]) if v is not None else (None, None)
    else:
        t0, t1, q0, q1 = times[i - 1], times[i], q[i - 1], q[i]
        v0, v1 = (v[i - 1], v[i]) if v is not None else (None, None)
    span = t1 - t0
    if span <= 0.0:
        return q1.copy()
    s = (t - t0) / span
    if v0 is None:
        return q0 + s * (q1 - q0)
    # cubic Hermite: positions and velocities at both ends
    h00 = 2 * s**3 - 3 * s**2 + 1
    h10 = s**3 - 2 * s**2 + s
    h01 = -2 * s**3 + 3 * s**2
    h11 = s**3 - s**2
    return h00 * q0 + h10 * span * v0 + h01 * q1 + h11 * span * v1

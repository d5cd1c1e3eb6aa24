"""Joint trajectories as joint_trajectory_controller follows them (no ROS: numbers in, numbers out): a scene
robot's ``trajectory:`` key (:func:`cgp_core.scene.robots.parse_trajectory`, followed by :class:`Following` in
:meth:`cgp_core.world.World.step`) and ``~/robots/<robot>/joint_trajectory`` (trajectory_msgs/JointTrajectory;
the node's side, :mod:`cgp_sim_ros.ros.commands`, through the thin adapter :mod:`cgp_sim_ros.trajectory`).

A trajectory is a list of points (time from its start, positions, optionally velocities) for a set of joints.
Sampled at a time t, it gives the joints' position targets, interpolated as joint_trajectory_controller does:

- between two points that both have velocities: the cubic Hermite polynomial matching both positions and both
  velocities (joint_trajectory_controller's cubic spline; accelerations, if given, are not used: no quintic);
- otherwise: linear in time between the two positions;
- before the first point: from the joints' positions when the trajectory was taken (velocity 0) to the first
  point, by the same rule (the controller's "start from the current state");
- after the last point: the last point's positions (held by the position drive).

A ROS message's start time is its ``header.stamp`` in simulation time, or the time it is taken when that stamp
is zero (the controller's "start now"); a scene's trajectory starts when the world does (its load, a reset, the
robot's spawn), and a looping one (``loop: true``) goes on from its first point after its last
(:func:`loop_time`).  :func:`check_trajectory` refuses what cannot be followed, naming the field and why.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

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


class _Segment(NamedTuple):
    """One segment of a trajectory: its ends' times [s], positions (k,) and velocities (k,) (``None`` without)."""

    t0: float
    t1: float
    q0: np.ndarray
    q1: np.ndarray
    v0: np.ndarray | None
    v1: np.ndarray | None


def _segment(trajectory: Trajectory, t: float, start_positions: np.ndarray) -> _Segment:
    """The segment holding ``t`` (before the last point's time); before the first point, the lead-in from
    ``start_positions`` at time 0 at rest."""
    times, q, v = trajectory.times, trajectory.positions, trajectory.velocities
    i = int(np.searchsorted(times, t, side="right"))  # the segment [i - 1, i] (i = 0: before the first point)
    if i == 0:
        q1 = q[0]
        v0, v1 = (np.zeros_like(q1), v[0]) if v is not None else (None, None)
        return _Segment(0.0, times[0], np.asarray(start_positions, float), q1, v0, v1)
    v0, v1 = (v[i - 1], v[i]) if v is not None else (None, None)
    return _Segment(times[i - 1], times[i], q[i - 1], q[i], v0, v1)


def sample(trajectory: Trajectory, t: float, start_positions: np.ndarray) -> np.ndarray:
    """The position targets (k,) at ``t`` seconds from the trajectory's start (``start_positions`` (k,): the joints'
    positions when it was taken, the segment before the first point starts there)."""
    times, q = trajectory.times, trajectory.positions
    if t >= times[-1]:
        return q[-1].copy()
    t0, t1, q0, q1, v0, v1 = _segment(trajectory, t, start_positions)
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


def sample_velocity(trajectory: Trajectory, t: float, start_positions: np.ndarray) -> np.ndarray:
    """The velocities (k,) of :func:`sample`'s curve at ``t`` (its time derivative: the cubic's, or a linear
    segment's slope; 0 after the last point), the position drives' feed-forward for a scene trajectory."""
    times, q = trajectory.times, trajectory.positions
    if t >= times[-1]:
        return np.zeros(q.shape[1])
    t0, t1, q0, q1, v0, v1 = _segment(trajectory, t, start_positions)
    span = t1 - t0
    if span <= 0.0:
        return np.zeros(q.shape[1])
    if v0 is None:
        return (q1 - q0) / span
    s = (t - t0) / span
    d00 = (6 * s**2 - 6 * s) / span
    d10 = 3 * s**2 - 4 * s + 1
    d01 = (-6 * s**2 + 6 * s) / span
    d11 = 3 * s**2 - 2 * s
    return d00 * q0 + d10 * v0 + d01 * q1 + d11 * v1


def sample_many(trajectory: Trajectory, t: np.ndarray, start_positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sample` and :func:`sample_velocity` at many times at once: ``(positions (n, k), velocities (n, k))``
    (the velocity at a point's time is the segment's that ends there, as just before it)."""
    times, q, v = trajectory.times, trajectory.positions, trajectory.velocities
    t = np.asarray(t, float)
    start = np.asarray(start_positions, float)[None]
    i = np.searchsorted(times, t, side="left")  # the segment ending at times[i] (i = 0: the lead-in)
    after = i >= len(times)
    i = np.minimum(i, len(times) - 1)
    t0 = np.concatenate(([0.0], times))[i]
    t1 = times[i]
    q0, q1 = np.concatenate((start, q))[i], q[i]
    span = np.maximum(t1 - t0, 1e-300)[:, None]
    s = np.clip((t - t0)[:, None] / span, 0.0, 1.0)
    if v is None:
        position = q0 + s * (q1 - q0)
        velocity = np.broadcast_to((q1 - q0) / span, position.shape).copy()
    else:
        v0, v1 = np.concatenate((np.zeros_like(start), v))[i], v[i]
        position = ((2 * s**3 - 3 * s**2 + 1) * q0 + (s**3 - 2 * s**2 + s) * span * v0
                    + (-2 * s**3 + 3 * s**2) * q1 + (s**3 - s**2) * span * v1)
        velocity = ((6 * s**2 - 6 * s) / span * q0 + (3 * s**2 - 4 * s + 1) * v0
                    + (-6 * s**2 + 6 * s) / span * q1 + (3 * s**2 - 2 * s) * v1)
    position[after] = q[-1]
    velocity[after] = 0.0
    return position, velocity


def loop_time(trajectory: Trajectory, t: float, loop: bool) -> float:
    """The trajectory's own time at ``t`` seconds from its start: ``t`` itself, or for a looping trajectory past
    its last point, the same phase of the cycle from its first point to its last (the segment before the first
    point, from the start positions, is run once)."""
    first, last = float(trajectory.times[0]), float(trajectory.times[-1])
    if not loop or t <= last or last <= first:
        return t
    return first + (t - first) % (last - first)


@dataclass(frozen=True)
class SceneTrajectory:
    """A scene robot's checked ``trajectory:`` (:func:`cgp_core.scene.robots.parse_trajectory`)."""

    trajectory: Trajectory
    loop: bool = False


@dataclass
class Followed:
    """A scene trajectory a robot follows: the trajectory, whether it loops, its start (simulation time, ns), the
    joints' positions then, and the drive targets it set last (to tell when someone else commanded a joint)."""

    spec: object  # the robot's RobotSpec (a robot spawned again under the same name is another one)
    trajectory: Trajectory
    loop: bool
    start_ns: int
    start_positions: np.ndarray
    last: tuple | None = None  # (dofs, mode, target_position, target_velocity) as set at the last tick (the
    # dofs may move in the world's joint space when another robot is added or removed; the values go with them)


class Following:
    """The scene trajectories (``robots[].trajectory``) a world's robots follow, through their position drives.

    Each tick (:meth:`command`, at the start of :meth:`cgp_core.world.World.step`) every followed robot's joints
    are commanded (``Robots.command``, as a JointState position command is) to the trajectory's positions at the
    end of the tick, with its velocities as the drives' feed-forward.  A robot stops following when anything else
    commands one of its joints: a ROS ``joint_commands`` or ``joint_trajectory`` (the node calls
    :meth:`stop`), or a ``Robots.command`` from Python between ticks (seen here as a drive target that is not the
    one set at the last tick); the command wins, and the trajectory comes back only with a reset or a load."""

    def __init__(self):
        self.robots: dict[str, Followed] = {}

    def start(self, robots, now_ns: int, names=None) -> None:
        """Start the scene trajectories of ``robots`` (:class:`cgp_core.robots.world.Robots`; only ``names`` if
        given) at simulation time ``now_ns``, from the joints' positions now."""
        if names is None:
            self.robots = {}
        if robots is None:
            return
        for r in robots.robots:
            entry = getattr(r.spec, "trajectory", None)
            if entry is None or (names is not None and r.name not in names):
                continue
            joint_names, position, _, _ = robots.joint_state(r.name)
            index = {name: i for i, name in enumerate(joint_names)}
            start = np.array([position[index[j]] for j in entry.trajectory.joints])
            # the drives as they are now: a command before the first tick is seen as one after it is
            dofs = np.array([r.dof_slice.start + r.model.dof_names.index(j) for j in entry.trajectory.joints],
                            np.int64)
            d = robots.drives
            now = (dofs, d.mode[dofs].copy(), d.target_position[dofs].copy(), d.target_velocity[dofs].copy())
            self.robots[r.name] = Followed(r.spec, entry.trajectory, entry.loop, int(now_ns), start, now)

    def stop(self, robot: str, robots=None) -> bool:
        """Stop ``robot``'s scene trajectory: its position drives hold the targets they were last given, without
        the trajectory's velocity feed-forward (``robots``: the world's :class:`~cgp_core.robots.world.Robots`,
        whose drives are released so); whether it had one."""
        f = self.robots.pop(robot, None)
        if f is not None and robots is not None:
            _release(robots, f)
        return f is not None

    def command(self, robots, t_end_ns: int) -> list[tuple[str, str]]:
        """Command every followed robot's joints for the tick ending at ``t_end_ns``; returns ``(level, text)``
        notes: a robot that stopped following because another command came, a target clamped to a limit."""
        notes = []
        if robots is None:
            self.robots = {}
            return notes
        from .joint_solver import DRIVE_POSITION

        for name, f in list(self.robots.items()):
            try:
                r = robots.robot(name)
            except KeyError:
                r = None
            if r is None or r.spec is not f.spec:  # deleted (or replaced by another robot of that name)
                del self.robots[name]
                continue
            dofs = np.array([r.dof_slice.start + r.model.dof_names.index(j) for j in f.trajectory.joints], np.int64)
            d = robots.drives
            if f.last is not None and not (np.array_equal(d.mode[dofs], f.last[1])
                                           and np.array_equal(d.target_position[dofs], f.last[2])
                                           and np.array_equal(d.target_velocity[dofs], f.last[3])):
                del self.robots[name]
                _release(robots, f)
                notes.append(("info", f"robot {name}: stops following its scene trajectory (a joint command came: "
                                      "the command wins until a reset or a load)"))
                continue
            t = loop_time(f.trajectory, (t_end_ns - f.start_ns) * 1e-9, f.loop)
            targets = sample(f.trajectory, t, f.start_positions)
            velocities = sample_velocity(f.trajectory, t, f.start_positions)
            problems = robots.command(name, list(f.trajectory.joints), targets.tolist(), [], [])
            notes.extend(("warn", f"robot {name}: scene trajectory: {text}") for text in problems)
            moving = d.mode[dofs] == DRIVE_POSITION
            d.target_velocity[dofs[moving]] = velocities[moving]
            if not f.loop and t >= f.trajectory.duration:
                del self.robots[name]  # its last point commanded: the drives hold it
                continue
            f.last = (dofs, d.mode[dofs].copy(), d.target_position[dofs].copy(), d.target_velocity[dofs].copy())
        return notes


def _release(robots, f: Followed) -> None:
    """The drives ``f`` set last and nobody changed since: their velocity feed-forward back to 0 (a position
    drive holding its last target; a feed-forward left behind would hold the joint off it by kd v / kp)."""
    r = next((r for r in robots.robots if r.spec is f.spec), None)
    if f.last is None or r is None:
        return
    dofs = np.array([r.dof_slice.start + r.model.dof_names.index(j) for j in f.trajectory.joints], np.int64)
    _, mode, target, velocity = f.last
    d = robots.drives
    ours = (d.mode[dofs] == mode) & (d.target_position[dofs] == target) & (d.target_velocity[dofs] == velocity)
    d.target_velocity[dofs[ours]] = 0.0

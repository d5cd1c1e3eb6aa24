"""``robots`` entries of a scene: articulated robots from URDF (issue 35), parsed into :class:`RobotSpec`.

A robot entry::

    robots:
      - name: arm                      # ROS-safe, unique among bodies, flocks and robots; its links are named
                                       # <name>/<link> in the world's bodies
        urdf: arm3.urdf                # a .urdf or .xacro file: relative to the scene file, then the built-in
                                       # msgs_config/robots/; or file:// / package:// (package_paths, then
                                       # AMENT_PREFIX_PATH / ROS_PACKAGE_PATH)
        position: [0, 0, 0]            # the root link's frame in the world [m]
        orientation: [0, 0, 0, 1]      # (x, y, z, w)
        fixed_base: true               # root welded to the world (false: a floating base, 6 dof)
        joints: {shoulder: 0.3}        # initial joint positions [rad or m] by joint name (default 0)
        hold: true                     # position drives on every movable joint holding the initial positions
        stiffness: 1.0e5               # the position drives' gains [N m/rad or N/m] and [N m s/rad or N s/m]
        damping: 1.0e3                 #   (implicit, bounded by each joint's effort limit; also what a
                                       #   joint_commands position or velocity target is driven with)
        self_collision: false          # links of the robot collide with each other (never directly jointed ones)
        friction: 0.8                  # Coulomb μ and restitution of every link
        restitution: 0.0
        xacro_args: {}                 # arguments of a .xacro file
        package_paths: {}              # package name -> directory, for package:// URIs
        joint_integrator: gauss_legendre_6  # its joint-space integrator (default: the world's joint_integrator;
                                       # cgp_core.robots.joint_integrators)
        trajectory:                    # a joint trajectory followed through the position drives from the start
          loop: true                   # (the world's load or reset, the robot's spawn); loop: from the first
          points:                      # point again after the last (which must equal the first)
            - {time: 1.0, positions: {shoulder: 0.5}, velocities: {shoulder: 0.0}}   # velocities: optional
            - {time: 3.0, positions: {shoulder: -0.5}, velocities: {shoulder: 0.0}}  #   (all points or none)

The URDF is loaded while the scene is (:func:`cgp_core.robots.urdf.load_urdf`), so a bad URDF is a scene error
naming the entry, like any other value; so is a trajectory that cannot be followed (:func:`parse_trajectory`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ..robots.joint_integrators import DEFAULT_JOINT_INTEGRATOR, JOINT_INTEGRATORS
from .validation import COORDINATES, Validator, kind_of, short_repr

ROBOT_KEYS = {"name", "urdf", "position", "orientation", "fixed_base", "joints", "hold", "stiffness", "damping",
              "self_collision", "friction", "restitution", "xacro_args", "package_paths", "trajectory",
              "joint_integrator"}
TRAJECTORY_KEYS = {"points", "loop"}
POINT_KEYS = {"time", "positions", "velocities"}
#: a scene trajectory's path is checked against the joints' limits and velocity limits at this many instants per
#: segment (a cubic between two points within the limits may overshoot them)
TRAJECTORY_CHECKS_PER_SEGMENT = 64
#: a looping trajectory's last point equals its first to this [rad or m; rad/s or m/s]
LOOP_TOLERANCE = 1e-9
#: the most robots a scene holds (each a dense joint-space system of its own, solved on its own: the cost grows
#: linearly with the robots; 64 arms are issue 35's benchmark)
MAX_ROBOTS = 256
#: a spawned robot's entry (``{robot: {...}}``, :func:`cgp_core.scene.spawn_entry`) may give the URDF as XML text
#: instead of a file: ``urdf_xml`` (never expanded as xacro: xacro evaluates expressions and includes files)
SPAWN_ROBOT_KEYS = (ROBOT_KEYS - {"name"}) | {"urdf_xml"}


@dataclass
class RobotSpec:
    name: str
    model: Any  # cgp_core.robots.model.RobotModel
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    orientation: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))
    joints: dict = field(default_factory=dict)  # joint name -> initial position
    hold: bool = True
    stiffness: float = 1.0e5
    damping: float = 1.0e3
    self_collision: bool = False
    friction: float = 0.8
    restitution: float = 0.0
    notes: list = field(default_factory=list)
    #: the joint trajectory it follows from the start (cgp_core.robots.trajectory.SceneTrajectory), or None
    trajectory: Any = None
    #: the articulation of a scene's ``joints:`` this robot is (cgp_core.robots.articulations.Articulation): its
    #: links are the scene's own bodies (their names kept), its drives and initial velocities its joints'; None
    #: for a URDF robot
    articulation: Any = None
    #: its joint-space integrator (a name of cgp_core.robots.joint_integrators.JOINT_INTEGRATORS); None: the
    #: world's ``joint_integrator`` (a scene fills it in; a spawned robot without one takes the world's)
    joint_integrator: str | None = None


def articulation_spec(articulation, joint_integrator: str | None = None) -> RobotSpec:
    """The :class:`RobotSpec` of an articulation of the scene's ``joints:`` (cgp_core.scene.joints), integrated by
    ``joint_integrator`` (the world's)."""
    return RobotSpec(name=articulation.name, model=articulation.model, position=articulation.position.copy(),
                     orientation=articulation.orientation.copy(), hold=False, self_collision=True,
                     articulation=articulation, joint_integrator=joint_integrator)


def builtin_robot_dir() -> Path:
    """The robots shipped with the package (``msgs_config/robots``)."""
    return Path(str(resources.files("msgs_config") / "robots"))


def robot_file(v: Validator, value: Any, key: str) -> Path | str | None:
    """Where ``urdf:`` points: a ``package://`` URI as given (the loader resolves it), a ``file://`` URI or an
    absolute path, or a relative path from the scene file's directory, then the built-in robots."""
    if not isinstance(value, str) or not value:
        v.fail(key, f"must be a file name or URI (.urdf or .xacro), got {kind_of(value)} {short_repr(value)}")
        return None
    if value.startswith("package://"):
        return value
    path = Path(value[len("file://"):] if value.startswith("file://") else value)
    if path.is_absolute():
        return path
    source = Path(v.source)
    for candidate in ([source.parent / path] if source.is_file() else []) + [builtin_robot_dir() / path]:
        if candidate.is_file():
            return candidate
    v.fail(key, f"no robot file {short_repr(value)} (looked next to the scene file and in the built-in robots: "
                f"{', '.join(sorted(p.name for p in builtin_robot_dir().glob('*.urdf')))})")
    return None


def parse_robots(v: Validator, raw: Any, seen: set[str]) -> list[RobotSpec]:
    if raw is None:
        return []
    if not isinstance(raw, list):
        v.fail("robots", f"must be a list of robot entries, got {kind_of(raw)}")
        return []
    if len(raw) > MAX_ROBOTS:
        v.fail("robots", f"{len(raw)} robots; a scene holds at most {MAX_ROBOTS}")
        return []
    specs = []
    for i, entry in enumerate(raw):
        spec = parse_robot(v, entry, f"robots[{i}]", seen)
        if spec is not None:
            specs.append(spec)
    return specs


def parse_robot(v: Validator, raw: Any, key: str, seen: set[str], *, name: str | None = None) -> RobotSpec | None:
    """One robot entry (``name`` given: a spawn, whose entry has none; it may give ``urdf_xml``, URDF XML text,
    instead of ``urdf``)."""
    from ..robots.urdf import UrdfError, load_urdf

    before = len(v.problems)
    d = v.mapping(raw, key)
    if not d and not isinstance(raw, dict):
        return None
    v.no_unknown_keys(d, ROBOT_KEYS if name is None else SPAWN_ROBOT_KEYS, key)
    if name is None:
        if "name" not in d:
            v.fail(f"{key}.name", "missing")
            return None
        name = v.name(d["name"], f"{key}.name", seen)
    xml = d.get("urdf_xml") if name is not None else None
    if "urdf" in d and "urdf_xml" in d:
        v.fail(f"{key}.urdf_xml", "give urdf (a file) or urdf_xml (URDF text), not both")
        return None
    if "urdf" not in d and xml is None:
        v.fail(f"{key}.urdf", "missing (a .urdf or .xacro file" + (", or urdf_xml: URDF XML text)" if name is not None
                                                                  else ")"))
        return None
    if xml is not None and not (isinstance(xml, str) and xml.lstrip().startswith("<")):
        v.fail(f"{key}.urdf_xml", f"must be URDF XML text (starting with '<'), got {kind_of(xml)}"
                                  f"{'' if not isinstance(xml, str) else f' of {len(xml)} characters'}")
        return None
    position = v.vector(d.get("position", [0, 0, 0]), f"{key}.position", 3, within=COORDINATES, unit="m")
    q = v.vector(d.get("orientation", [0, 0, 0, 1]), f"{key}.orientation", 4, default=np.array([0, 0, 0, 1.0]))
    if np.linalg.norm(q) < 1e-9:
        v.fail(f"{key}.orientation", "zero quaternion (x, y, z, w); identity is [0, 0, 0, 1]")
    fixed_base = v.boolean(d.get("fixed_base", True), f"{key}.fixed_base", True)
    hold = v.boolean(d.get("hold", True), f"{key}.hold", True)
    self_collision = v.boolean(d.get("self_collision", False), f"{key}.self_collision", False)
    stiffness = v.number(d.get("stiffness", 1.0e5), f"{key}.stiffness", minimum=0.0, maximum=1e9)
    damping = v.number(d.get("damping", 1.0e3), f"{key}.damping", minimum=0.0, maximum=1e9)
    friction = v.number(d.get("friction", 0.8), f"{key}.friction", minimum=0.0, maximum=10.0)
    restitution = v.number(d.get("restitution", 0.0), f"{key}.restitution", minimum=0.0, maximum=1.0)
    xacro_args = _string_map(v, d.get("xacro_args", {}), f"{key}.xacro_args")
    joint_integrator = None
    if "joint_integrator" in d:
        joint_integrator = v.choice(d["joint_integrator"], f"{key}.joint_integrator", sorted(JOINT_INTEGRATORS),
                                    DEFAULT_JOINT_INTEGRATOR)
    package_paths = _string_map(v, d.get("package_paths", {}), f"{key}.package_paths")
    joints_raw = v.mapping(d.get("joints", {}), f"{key}.joints")
    joints = {}
    for joint, value in joints_raw.items():
        joints[str(joint)] = v.number(value, f"{key}.joints.{joint}", within=(-1e4, 1e4), unit="rad or m")
    if xml is not None:
        path, urdf_key = xml, f"{key}.urdf_xml"
        if xacro_args:
            v.fail(f"{key}.xacro_args", "urdf_xml is never expanded as xacro: give a .xacro file as urdf")
    else:
        path, urdf_key = robot_file(v, d["urdf"], f"{key}.urdf"), f"{key}.urdf"
    if path is None or len(v.problems) > before:
        return None
    try:
        with warnings.catch_warnings(record=True) as caught:  # an inertia repaired says so: a note, not stderr
            warnings.simplefilter("always")
            model = load_urdf(path, package_paths=package_paths, xacro_args=xacro_args or None,
                              fixed_base=fixed_base, name=name)
    except UrdfError as exc:
        v.fail(urdf_key, str(exc))
        return None
    notes = [("warn", f"{v.source}: {key}: robot {name}: {w.message}") for w in caught]
    movable = set(model.dof_names) | set(model.joint_names)
    for joint, value in joints.items():
        if joint not in movable:
            v.fail(f"{key}.joints.{joint}", f"{name} has no movable joint {joint!r} (its joints: "
                                            f"{', '.join(model.dof_names) or 'none'})")
            continue
        if joint in model.dof_names:
            k = model.dof_names.index(joint)
            if not model.lower[k] <= value <= model.upper[k]:
                v.fail(f"{key}.joints.{joint}", f"{value:g} is outside the joint's limits "
                                                f"[{model.lower[k]:g}, {model.upper[k]:g}]")
    if len(v.problems) > before:
        return None
    trajectory = None
    if d.get("trajectory") is not None:  # (an empty `trajectory:` is none)
        trajectory = parse_trajectory(v, d["trajectory"], f"{key}.trajectory", model, joints, name)
        if trajectory is None:
            return None
    return RobotSpec(name=name, model=model, position=position, orientation=q / np.linalg.norm(q), joints=joints,
                     hold=hold, stiffness=stiffness, damping=damping, self_collision=self_collision,
                     friction=friction, restitution=restitution, notes=notes, trajectory=trajectory,
                     joint_integrator=joint_integrator)


def parse_trajectory(v: Validator, raw: Any, key: str, model, initial: dict, robot: str):
    """A robot entry's ``trajectory:`` (:class:`cgp_core.robots.trajectory.SceneTrajectory`), or None with the
    problems recorded: every point names the same movable joints of the robot (not a mimic follower), times are
    ≥ 0 and strictly increasing, positions inside the joints' limits, velocities at every point or at none; the
    path (from ``initial``, the robot's initial positions, to the first point, then point to point, interpolated
    as joint_trajectory_controller does) stays inside the position limits and under the velocity limits; a
    looping one ends where it starts."""
    from ..robots.trajectory import (
        MAX_TRAJECTORY_POINTS,
        SceneTrajectory,
        TrajectoryError,
        check_trajectory,
        sample_many,
    )

    before = len(v.problems)
    d = v.mapping(raw, key)
    if not isinstance(raw, dict):
        return None
    v.no_unknown_keys(d, TRAJECTORY_KEYS, key)
    loop = v.boolean(d.get("loop", False), f"{key}.loop", False)
    points = d.get("points")
    if not isinstance(points, list) or not points:
        v.fail(f"{key}.points", f"must be a non-empty list of points ({{time, positions, velocities?}}), got "
                                f"{kind_of(points)} {short_repr(points)}")
        return None
    if len(points) > MAX_TRAJECTORY_POINTS:
        v.fail(f"{key}.points", f"{len(points)} points; a trajectory has at most {MAX_TRAJECTORY_POINTS}")
        return None
    followers = {model.dof_names[int(f)] for f in np.asarray(model.mimic_follower).reshape(-1)}
    joints: list[str] | None = None
    times, positions, velocities = [], [], []
    for i, raw_point in enumerate(points):
        where = f"{key}.points[{i}]"
        if not isinstance(raw_point, dict):
            v.fail(where, f"must be a point {{time, positions, velocities?}}, got {kind_of(raw_point)}")
            continue
        point = raw_point
        v.no_unknown_keys(point, POINT_KEYS, where)
        if "time" not in point or "positions" not in point:
            v.fail(where, "needs time (s from the start) and positions ({joint: value})")
            continue
        times.append(v.number(point["time"], f"{where}.time", minimum=0.0, maximum=1e6, unit="s"))
        given = v.mapping(point["positions"], f"{where}.positions")
        if joints is None:
            joints = [str(j) for j in given]
            if not joints:
                v.fail(f"{where}.positions", "names no joint")
                return None
            for j in joints:
                if j not in model.dof_names or j in followers:
                    why = ("mimics another joint: give its leader" if j in followers else
                           f"is not a movable joint of {robot}")
                    v.fail(f"{where}.positions.{j}", f"{why} (its joints: "
                                                     f"{', '.join(n for n in model.dof_names if n not in followers)})")
            if len(v.problems) > before:
                return None
        if sorted(map(str, given)) != sorted(joints):
            missing, extra = sorted(set(joints) - set(map(str, given))), sorted(set(map(str, given)) - set(joints))
            v.fail(f"{where}.positions", "every point names the same joints as the first"
                   + (f"; missing {', '.join(missing)}" if missing else "")
                   + (f"; extra {', '.join(extra)}" if extra else ""))
            continue
        positions.append([v.number(given[j], f"{where}.positions.{j}", within=(-1e4, 1e4), unit="rad or m")
                          for j in joints])
        if "velocities" in point:
            speeds = v.mapping(point["velocities"], f"{where}.velocities")
            if sorted(map(str, speeds)) != sorted(joints):
                v.fail(f"{where}.velocities", f"give one per joint of positions ({', '.join(joints)}), or none")
                continue
            velocities.append([v.number(speeds[j], f"{where}.velocities.{j}", within=(-1e4, 1e4),
                                        unit="rad/s or m/s") for j in joints])
        else:
            velocities.append([])
    if len(v.problems) > before:
        return None
    given_velocities = [len(row) > 0 for row in velocities]
    if any(given_velocities) and not all(given_velocities):
        v.fail(f"{key}.points[{given_velocities.index(not given_velocities[0])}].velocities",
               "give velocities at every point (cubic interpolation) or at none (linear)")
        return None
    for i in range(1, len(times)):
        if times[i] <= times[i - 1]:
            v.fail(f"{key}.points[{i}].time", f"{times[i]:g} s is not after the point before's ({times[i - 1]:g} s): "
                                              "times must increase")
    index = [model.dof_names.index(j) for j in joints]
    lower, upper = model.lower[index], model.upper[index]
    speed_limit = model.velocity_limit[index]
    for i, row in enumerate(positions):
        for j, value, lo, hi in zip(joints, row, lower, upper):
            if not lo <= value <= hi:
                v.fail(f"{key}.points[{i}].positions.{j}", f"{value:g} is outside the joint's limits [{lo:g}, {hi:g}]")
        for j, value, limit in zip(joints, velocities[i], speed_limit):
            if abs(value) > limit:
                v.fail(f"{key}.points[{i}].velocities.{j}", f"{value:g} is beyond the joint's velocity limit "
                                                            f"±{limit:g}")
    if len(v.problems) > before:
        return None
    try:
        trajectory = check_trajectory(joints, 0, times, positions, velocities)
    except TrajectoryError as exc:  # (what the checks above let through: none expected)
        v.fail(f"{key}.points", exc.reason)
        return None
    start = np.array([initial.get(j, 0.0) for j in joints])
    if times[0] == 0.0 and np.any(np.abs(trajectory.positions[0] - start) > LOOP_TOLERANCE):
        v.fail(f"{key}.points[0].time", "0, but its positions are not the robot's initial ones (its entry's joints, "
                                        "else 0): give it a time > 0 to get there, or start at the initial pose")
        return None
    if loop:
        if len(times) < 2:
            v.fail(f"{key}.loop", "a looping trajectory needs at least two points")
            return None
        last = len(times) - 1
        for label, values in (("positions", trajectory.positions), ("velocities", trajectory.velocities)):
            if values is not None and np.any(np.abs(values[-1] - values[0]) > LOOP_TOLERANCE):
                v.fail(f"{key}.points[{last}].{label}", f"a looping trajectory ends where it starts: the last point's "
                                                        f"{label} must equal the first's")
        if len(v.problems) > before:
            return None
    # the path between the points (a cubic may overshoot): inside the limits, under the velocity limits, at
    # TRAJECTORY_CHECKS_PER_SEGMENT instants of each segment (in chunks: 10,000 points of 64 joints stay small)
    bounds = np.concatenate(([0.0], trajectory.times))
    fractions = np.arange(1, TRAJECTORY_CHECKS_PER_SEGMENT + 1) / TRAJECTORY_CHECKS_PER_SEGMENT
    segments = np.flatnonzero(np.diff(bounds) > 0.0)  # (a first point at time 0 has no segment before it)
    instants = (bounds[segments, None] + np.diff(bounds)[segments, None] * fractions[None]).reshape(-1)
    segment_of = np.repeat(segments, TRAJECTORY_CHECKS_PER_SEGMENT)
    for chunk in range(0, instants.size, 4096):
        t = instants[chunk:chunk + 4096]
        q, qd = sample_many(trajectory, t, start)
        outside = (q < lower - 1e-9) | (q > upper + 1e-9)
        fast = np.abs(qd) > speed_limit * (1 + 1e-9)
        bad = np.flatnonzero((outside | fast).any(axis=1))
        if not bad.size:
            continue
        n = int(bad[0])
        i = int(segment_of[chunk + n])
        segment = "from the initial positions to point 0" if i == 0 else f"from point {i - 1} to point {i}"
        if outside[n].any():
            k = int(np.flatnonzero(outside[n])[0])
            v.fail(key, f"the path {segment} takes joint {joints[k]} to {q[n, k]:.4g} at {t[n]:.3g} s, outside its "
                        f"limits [{lower[k]:g}, {upper[k]:g}] (interpolated as joint_trajectory_controller does)")
        else:
            k = int(np.flatnonzero(fast[n])[0])
            v.fail(key, f"the path {segment} moves joint {joints[k]} at {qd[n, k]:.4g} at {t[n]:.3g} s, beyond its "
                        f"velocity limit ±{speed_limit[k]:g}: give the points more time")
        return None
    return SceneTrajectory(trajectory, loop)


def _string_map(v: Validator, raw: Any, key: str) -> dict[str, str]:
    d = v.mapping(raw, key)
    out = {}
    for k, value in d.items():
        if not isinstance(value, (str, int, float)) or isinstance(value, bool):
            v.fail(f"{key}.{k}", f"must be a string, got {kind_of(value)}")
            continue
        out[str(k)] = str(value)
    return out

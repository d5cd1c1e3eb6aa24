"""Scenes: YAML files (YAML's safe subset only) describing a world, its rigid bodies and its boid flocks.

A scene is validated completely before anything is built: every error names the file, the key path (e.g.
``bodies[2].size``) and what is wrong, and all errors of a file are reported together.  Parsing uses
PyYAML's ``SafeLoader`` (plain data only: a ``!!python/...`` tag is an error, never executed) with one
addition: a key given twice in one mapping is an error, not silently "the last one wins".  The format
(SI units, frame ``world``, z up as REP-103):

.. code-block:: yaml

    world:
      gravity: [0, 0, -9.81]          # m/s²
      ground: true                     # static plane z = 0
      ground_friction: 0.6             # Coulomb μ of the ground (combined with the body's, see cgp_core.solver)
      ground_restitution: 0.0          # e of the ground
      integrator: implicit_midpoint    # explicit_euler | symplectic_euler | rk4 | implicit_midpoint
      substeps: 4                      # physics sub-steps per tick (the node's `substeps` overrides)
      linear_damping: 0.0              # 1/s
      angular_damping: 0.0             # 1/s
      rolling_resistance: 0.01         # c_rr of every contact: a rolling ball slows at (5/7) c_rr g
      sleep: true                      # bodies sleep once all of them rest (see cgp_core.world.SLEEP_SPEED)
    bodies:
      - name: crate                    # unique, ROS-name-safe ([A-Za-z][A-Za-z0-9_]*)
        shape: box                     # sphere | box | capsule | particles | convex | compound | mesh
        size: [0.4, 0.4, 0.4]          # box: full extents [m]
        # radius: 0.2                  # sphere, capsule; particles: the radius each particle collides with
        # length: 0.5                  # capsule: length of the axis segment (body z), without the caps
        # particles: [[x, y, z, m], ...]  # particles: body-frame positions [m] and masses [kg]
        mass: 2.0                      # kg — or density: kg/m³ (not for particles: masses are per particle)
        position: [0, 0, 2]            # world position of the body origin (the COM; for particles the origin
                                       # of the particle coordinates, the COM is computed from them)
        orientation: [0, 0, 0, 1]      # quaternion x, y, z, w (normalized on load)
        linear_velocity: [0, 0, 0]     # m/s, world
        angular_velocity: [0, 0, 0]    # rad/s, world
        restitution: 0.3
        friction: 0.5
        fixed: false                   # immovable (walls, ramps, obstacles)
        predator: false                # boids of every flock flee it (cgp_core.boids.predators)
        color: [0.8, 0.3, 0.2, 1.0]    # RGBA for markers
      - name: rock                     # issue 25: a convex polyhedron, the hull of points or of a mesh file
        shape: convex
        mesh: rock.stl                 # .stl / .obj: from the scene file's directory, else the built-in meshes
        # points: [[x, y, z], ...]     # ... or the points whose hull it is (>= 4, not coplanar)
        scale: 1.0                     # optional: a factor, or [sx, sy, sz], applied to the points / the mesh
        density: 2600
      - name: table                    # one rigid body made of parts (mass spread over them by volume)
        shape: compound
        parts:
          - {shape: box, size: [1.0, 0.6, 0.04], position: [0, 0, 0.4]}
          - {shape: capsule, radius: 0.03, length: 0.38, position: [0.45, 0.25, 0.19]}
          - {shape: convex, points: [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]], orientation: [0, 0, 0, 1]}
        mass: 8.0
      - name: terrain                  # a static triangle mesh (fixed bodies only), with a BVH
        shape: mesh
        mesh: terrain.obj
        fixed: true
        # two_sided: false             # true: its triangles push from both sides (default: from the front)
    flocks:
      - name: fish
        count: 300
        spawn: {center: [0, 0, 4], extent: [8, 8, 3]}
        radius: 2.0
        separation_radius: 0.6
        weights: {cohesion: 0.6, separation: 2.0, alignment: 1.0}
        min_speed: 1.0
        max_speed: 4.0
        model: fish                    # sphere | fish
        seed: 1
        # ... and the optional keys of cgp_core.boids.FlockParams (field of view, bounds, goal, ...)
        neighbors: {mode: metric, k: 7}   # metric | topological (the k nearest, at any distance)
        fright_radius: 5.0             # flee predators closer than this to their surface [m]
      - name: school                   # Couzin et al. 2002's zonal model (cgp_core.boids.couzin)
        count: 100
        rules: couzin                  # reynolds (default) | couzin
        couzin: {repulsion_radius: 1.0, orientation_width: 2.0, attraction_width: 14.0,
                 field_of_view_deg: 270.0, turning_rate_deg: 40.0, speed: 3.0, noise: 0.05}
        spawn: {center: [0, 0, 20], extent: [10, 10, 10]}
        bounds: {mode: none}
"""

from __future__ import annotations

import math
import re
import reprlib
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from .bodies import BodyModel, BodyState, CompoundParts, Shape, rigid_work
from .inertia import compound_mass_properties, particle_mass_properties, shape_mass_properties
from .integrators import DEFAULT_INTEGRATOR, INTEGRATORS
from .limits import (
    MAX_ACCELERATION,
    MAX_BODIES,
    MAX_BOIDS,
    MAX_BOIDS_BRUTE,
    MAX_BOIDS_PER_FLOCK,
    MAX_COORDINATE,
    MAX_DAMPING,
    MAX_DENSITY,
    MAX_EXPECTED_NEIGHBORS,
    MAX_FILE_BYTES,
    MAX_FRICTION,
    MAX_GRAVITY,
    MAX_LENGTH,
    MAX_MAGNITUDE,
    MAX_MASS,
    MAX_NAME_LENGTH,
    MAX_PARTICLES_PER_BODY,
    MAX_PARTS_PER_BODY,
    MAX_ROLLING_RESISTANCE,
    MAX_SPEED,
    MAX_SPIN,
    MIN_DENSITY,
    MIN_INERTIA_RATIO,
    MIN_LENGTH,
    MIN_MASS,
    rigid_work_refusal,
)
from .rotation import quat_normalize, quat_rotate
from .user_input import YAML12_FLOAT, SceneLoader, UserInputError, load_yaml, read_user_text

ROS_SAFE_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
#: the ground plane's entity name in contact reports (cgp_core.solver.report, the node's ~/contacts): no body or
#: flock may take it, or a contact with the ground could not be told from one with that entity
GROUND_NAME = "ground"
#: the largest scene file (cgp_core.limits.MAX_FILE_BYTES); every other limit is in cgp_core.limits too
MAX_SCENE_BYTES = MAX_FILE_BYTES
#: the scene loader (PyYAML's safe loader, duplicate keys refused, YAML 1.2 floats): cgp_core.user_input
_SceneLoader = SceneLoader
#: a SceneError message lists at most this many problems (all of them are in ``SceneError.problems``)
MAX_REPORTED_PROBLEMS = 50


class SceneError(ValueError):
    """A scene that cannot be loaded; the message lists every problem as ``file: key: reason``."""

    def __init__(self, source: str, problems: list[str]):
        self.source = source
        self.problems = problems
        shown = [f"{source}: {p}" for p in problems[:MAX_REPORTED_PROBLEMS]]
        if len(problems) > MAX_REPORTED_PROBLEMS:
            shown.append(f"{source}: ... and {len(problems) - MAX_REPORTED_PROBLEMS} more problems")
        super().__init__("\n".join(shown))


# ----------------------------------------------------------------------------------------------------------
# The parsed scene: plain data, validated, SI units.  Building arrays from it is World's business.


@dataclass
class WorldSpec:
    gravity: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -9.81]))
    ground: bool = True
    ground_friction: float = 0.6
    ground_restitution: float = 0.0
    integrator: str = DEFAULT_INTEGRATOR
    substeps: int = 4
    linear_damping: float = 0.0
    angular_damping: float = 0.0
    #: c_rr of every contact (cgp_core.solver.SolverSettings.rolling_resistance): 0.01, a rubber tyre on
    #: asphalt or a wooden ball on wood, so balls and logs come to rest; 0 is the ideal rigid model
    rolling_resistance: float = 0.01
    sleep: bool = True


@dataclass
class BodySpec:
    name: str
    shape: Shape
    mass: float
    inertia_body: np.ndarray  # (3, 3) about the COM, body axes
    radius: float = 0.0
    half_extents: np.ndarray = field(default_factory=lambda: np.zeros(3))
    particles: np.ndarray | None = None  # (k, 4) body frame about the COM
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))  # COM, world
    orientation: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))
    linear_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    restitution: float = 0.3
    friction: float = 0.5
    fixed: bool = False
    color: np.ndarray = field(default_factory=lambda: np.array([0.7, 0.7, 0.75, 1.0]))
    predator: bool = False  # boids flee it (issue 14, cgp_core.boids.predators)
    hull: Any = None  # CONVEX: cgp_core.collision.convex.ConvexPolyhedron about the COM
    parts: CompoundParts | None = None  # COMPOUND
    mesh: Any = None  # MESH: cgp_core.collision.bvh.StaticMesh
    two_sided: bool = False  # MESH
    #: what loading it had to say, as (level, text): "warn" (points inside a hull), "info" (a BVH's build
    #: time and memory); World turns them into events
    notes: list = field(default_factory=list)


@dataclass
class Scene:
    source: str
    world: WorldSpec
    bodies: list[BodySpec]
    flocks: list[Any]  # cgp_core.boids.FlockParams

    def rigid_work(self) -> tuple[int, int]:
        """``(shapes, particles)`` of the bodies, the counts a tick's work is bounded by
        (:func:`cgp_core.limits.rigid_work_refusal`)."""
        return rigid_work([b.parts for b in self.bodies], [b.particles for b in self.bodies])

    def build_bodies(self) -> tuple[BodyModel, BodyState]:
        """Static model and initial state arrays of the bodies (see cgp_core.bodies for every shape)."""
        n = len(self.bodies)
        if n == 0:
            return BodyModel.empty(), BodyState(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros((0, 3)))
        mass = np.array([b.mass for b in self.bodies])
        fixed = np.array([b.fixed for b in self.bodies])
        inertia = np.stack([b.inertia_body for b in self.bodies])
        inv_mass = np.where(fixed, 0.0, 1.0 / np.where(fixed, 1.0, mass))  # (a static mesh has no mass)
        inv_inertia = np.linalg.inv(inertia)
        inv_inertia[fixed] = 0.0
        model = BodyModel(
            names=[b.name for b in self.bodies],
            shape=np.array([int(b.shape) for b in self.bodies], dtype=np.int8),
            radius=np.array([b.radius for b in self.bodies]),
            half_extents=np.stack([b.half_extents for b in self.bodies]),
            mass=mass,
            inv_mass=inv_mass,
            inertia_body=inertia,
            inv_inertia_body=inv_inertia,
            restitution=np.array([b.restitution for b in self.bodies]),
            friction=np.array([b.friction for b in self.bodies]),
            fixed=fixed,
            particles=[b.particles for b in self.bodies],
            color=np.stack([b.color for b in self.bodies]),
            predator=np.array([b.predator for b in self.bodies], dtype=bool),
            hulls=[b.hull for b in self.bodies],
            parts=[b.parts for b in self.bodies],
            meshes=[b.mesh for b in self.bodies],
            two_sided=np.array([b.two_sided for b in self.bodies], dtype=bool),
        )
        orientation = np.stack([b.orientation for b in self.bodies])
        from .rotation import quat_to_matrix

        R = quat_to_matrix(orientation)
        # L₀ = I_world ω₀ with numpy's batched matmul, as every scene has been loaded since the first release: the
        # home of these equations (bodies.world_tensor, tensor_times: compiled loops) rounds differently (BLAS
        # fuses multiply-adds), and moving this line there changes the default scene's initial L in the last bit,
        # and every later tick with it (issue 24 kept trajectories bit-identical); move it with the next change
        # that may change trajectories
        inertia_world = R @ inertia @ np.swapaxes(R, -1, -2)
        lin_vel = np.stack([b.linear_velocity for b in self.bodies])
        ang_vel = np.stack([b.angular_velocity for b in self.bodies])
        movable = (~fixed)[:, None]
        state = BodyState(
            position=np.stack([b.position for b in self.bodies]),
            orientation=orientation,
            linear_momentum=mass[:, None] * lin_vel * movable,
            angular_momentum=np.einsum("nij,nj->ni", inertia_world, ang_vel) * movable,
        )
        return model, state


# ----------------------------------------------------------------------------------------------------------
# Loading


def builtin_scene_dir() -> Path:
    return Path(str(resources.files("msgs_config") / "scenes"))


def builtin_scene_names() -> list[str]:
    return sorted(p.stem for p in builtin_scene_dir().glob("*.yaml"))


def scene_description(name_or_path: str | Path) -> str:
    """The ``description:`` of a scene file or built-in scene (whitespace collapsed; "" when it has none)."""
    path = resolve_scene(str(name_or_path))
    try:
        data = load_yaml(read_user_text(path))
    except UserInputError as exc:
        raise SceneError(str(path), [f"cannot read the description: {exc}"]) from None
    text = data.get("description", "") if isinstance(data, dict) else ""
    return " ".join(str(text).split())


def resolve_scene(name_or_path: str) -> Path:
    """A scene file path, or the name of a built-in scene (``default``, ...)."""
    text = str(name_or_path).strip()
    if not text:
        raise SceneError("<scene>", [f"empty scene name; built-in scenes: {', '.join(builtin_scene_names())}"])
    path = Path(text).expanduser()
    if path.suffix in (".yaml", ".yml") or "/" in text:
        if path.is_dir():
            raise SceneError(text, ["is a directory, not a scene file"])
        if not path.exists():
            raise SceneError(text, ["no such scene file"])
        return path  # read_user_file refuses what is not a regular file (a FIFO, a device), naming it
    candidate = builtin_scene_dir() / f"{text}.yaml"
    if candidate.is_file():
        return candidate
    raise SceneError(
        text, [f"no built-in scene of that name; built-in scenes: {', '.join(builtin_scene_names())}"]
    )


def load_scene(name_or_path: str | Path) -> Scene:
    """Read, parse (safe_load) and validate a scene file or built-in scene name."""
    path = resolve_scene(str(name_or_path))
    source = str(path)
    try:  # a regular file only (no FIFO, no device), size-capped before and while reading
        text = read_user_text(path, max_bytes=MAX_SCENE_BYTES)
    except UserInputError as exc:
        raise SceneError(source, [str(exc).replace("files are limited", "scenes are limited")]) from None
    return parse_scene(text, source)


def parse_yaml(text: str, source: str = "<string>") -> Any:
    """YAML text as plain data, read as scenes are (:func:`cgp_core.user_input.load_yaml`: safe subset, YAML 1.2
    floats, duplicate keys rejected, bounded in bytes, depth and nodes); ``SceneError`` with the line and
    column of malformed YAML (never quoting the text)."""
    try:
        return load_yaml(text)
    except UserInputError as exc:
        raise SceneError(source, [str(exc)]) from None


def parse_scene(text: str, source: str = "<string>") -> Scene:
    return scene_from_dict(parse_yaml(text, source), source)


def scene_from_dict(data: Any, source: str = "<dict>") -> Scene:
    """Validate a parsed scene (e.g. from YAML) and return the :class:`Scene`; raises :class:`SceneError`."""
    v = _Validator(source)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise SceneError(source, [f"top level must be a mapping with keys world/bodies/flocks, got {_kind(data)}"])
    v.no_unknown_keys(data, {"world", "bodies", "flocks", "description"}, "")
    world = _parse_world(v, data.get("world", {}))
    bodies = _parse_bodies(v, data.get("bodies", []))
    flocks = _parse_flocks(v, data.get("flocks", []), reserved={b.name for b in bodies})
    scene = Scene(source=source, world=world, bodies=bodies, flocks=flocks)
    refusal = rigid_work_refusal(*scene.rigid_work(), world.substeps)
    if refusal:
        v.fail("world.substeps", refusal)
    total = sum(f.count for f in flocks)
    if total > MAX_BOIDS:
        v.fail("flocks", f"{total} boids in all; a world holds at most {MAX_BOIDS} (cgp_core.limits)")
    v.raise_if_any()
    return scene


#: what a spawned entity may be: one scene-file entry of ``bodies`` or ``flocks``
SPAWN_KINDS = ("body", "flock")


def spawn_entry(data: Any, source: str, *, name: str, taken: set[str] = frozenset(),
                position=(0.0, 0.0, 0.0), orientation=(0.0, 0.0, 0.0, 1.0)):
    """Validate an entity to spawn into a running world: ``{body: <entry>}`` or ``{flock: <entry>}``, where the
    entry is what a scene file's ``bodies`` / ``flocks`` list holds, without ``name`` (``name`` here) and, for a
    body, without ``position`` / ``orientation`` (``position`` (3,), ``orientation`` (4,) xyzw here: the pose of
    the body origin, as a scene gives it); for a flock ``position`` is the spawn centre (``spawn.center``).

    Returns ``("body", BodySpec)`` or ``("flock", FlockParams)``.  Raises :class:`SceneError` with the same
    texts as a scene file, key paths starting at ``body`` / ``flock`` (``body (box1).size[1]: must be > 0``)."""
    v = _Validator(source)
    if not isinstance(data, dict) or len(data) != 1 or next(iter(data)) not in SPAWN_KINDS:
        # not an entry of ours: its keys are not quoted (a uri may name any readable file, /etc/shadow)
        keys = _kind(data)
        if isinstance(data, dict) and data:
            ours = [k for k in SPAWN_KINDS if k in data]
            keys = f"a mapping of {len(data)} keys" + (f" ({' and '.join(ours)} among them)" if ours
                                                       else ", none of them body or flock")
        raise SceneError(source, [f"must be a mapping with exactly one key, body or flock (a scene file's "
                                  f"bodies / flocks entry), got {keys}"])
    kind, raw = next(iter(data.items()))
    if not isinstance(raw, dict):
        raise SceneError(source, [f"{kind}: must be a mapping (a scene file's {kind} entry), got {_kind(raw)}"])
    given_by_request = {"name": "the request's name"}
    if kind == "body":
        given_by_request.update(position="the request's initial_pose", orientation="the request's initial_pose")
    for key, where in given_by_request.items():
        if key in raw:
            v.fail(f"{kind}.{key}", f"given by {where}; leave it out")
    spawn = raw.get("spawn")
    if kind == "flock" and isinstance(spawn, dict) and "center" in spawn:
        v.fail(f"{kind}.spawn.center", "given by the request's initial_pose (the spawn centre); leave it out")
    v.raise_if_any()
    entry = dict(raw, name=name)
    if kind == "body":
        entry.update(position=[float(x) for x in position], orientation=[float(x) for x in orientation])
        spec = _parse_body(v, entry, kind, set(taken))
    else:
        if spawn is None or isinstance(spawn, dict):
            entry["spawn"] = {**(spawn or {}), "center": [float(x) for x in position]}
        spec = _parse_flock(v, entry, kind, set(taken))
    v.raise_if_any()
    return kind, spec


# ----------------------------------------------------------------------------------------------------------
# Validation helpers: each returns a clean value or records a problem and returns a harmless default, so one
# pass reports every problem in the file.


#: the ranges of lengths and coordinates (cgp_core.limits)
LENGTHS = (MIN_LENGTH, MAX_LENGTH)
COORDINATES = (-MAX_COORDINATE, MAX_COORDINATE)

_REPR = reprlib.Repr()
_REPR.maxstring = _REPR.maxother = 60
_REPR.maxlist = _REPR.maxdict = _REPR.maxtuple = 6
_REPR.maxlevel = 1


def _show(value: Any) -> str:
    """A short repr for error messages: a scene can hold huge (or alias-expanded) values."""
    return _REPR.repr(value)


def _kind(value: Any) -> str:
    return {dict: "a mapping", list: "a list", str: "a string", bool: "a boolean", type(None): "nothing"}.get(
        type(value), type(value).__name__
    )


class _Validator:
    def __init__(self, source: str):
        self.source = source
        self.problems: list[str] = []

    def fail(self, key: str, reason: str) -> None:
        self.problems.append(f"{key}: {reason}" if key else reason)

    def raise_if_any(self) -> None:
        if self.problems:
            raise SceneError(self.source, self.problems)

    def no_unknown_keys(self, mapping: dict, allowed: set[str], where: str) -> None:
        for key in mapping:
            if key not in allowed:
                path = f"{where}.{key}" if where else str(key)
                self.fail(path, f"unknown key (valid: {', '.join(sorted(allowed))})")

    def mapping(self, value: Any, key: str) -> dict:
        if value is None:
            return {}
        if not isinstance(value, dict):
            self.fail(key, f"must be a mapping, got {_kind(value)}")
            return {}
        return value

    def number(self, value: Any, key: str, *, minimum: float | None = None, exclusive_min: bool = False,
               maximum: float | None = None, default: float = 0.0, within: tuple[float, float] | None = None,
               unit: str = "") -> float:
        """A finite number (bool is not one) >= / > ``minimum``, <= ``maximum``, then in the range ``within``
        (cgp_core.limits: what the simulation can hold; ``unit`` for the message); without ``maximum`` and
        ``within``, at most MAX_MAGNITUDE in magnitude."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            hint = ""
            if isinstance(value, str) and YAML12_FLOAT.match(value.strip()):
                hint = " (a number in quotes is text in YAML: write it without the quotes)"
            self.fail(key, f"must be a number, got {_kind(value)} {_show(value)}{hint}")
            return default
        try:
            x = float(value)
        except OverflowError:  # an integer literal beyond the float range
            x = math.inf
        if not math.isfinite(x):
            self.fail(key, f"must be finite, got {_show(value)}")
            return default
        if minimum is not None and (x <= minimum if exclusive_min else x < minimum):
            self.fail(key, f"must be {'>' if exclusive_min else '>='} {minimum:g}, got {x:g}")
            return default
        if maximum is not None and x > maximum:
            self.fail(key, f"must be <= {maximum:g}, got {x:g}")
            return default
        if within is not None and not within[0] <= x <= within[1]:
            self.fail(key, f"must be in [{within[0]:g}, {within[1]:g}]{' ' + unit if unit else ''} (what cgp_sim "
                      f"simulates: cgp_core.limits), got {x:g}")
            return default
        if within is None and maximum is None and abs(x) > MAX_MAGNITUDE:
            self.fail(key, f"must be within ±{MAX_MAGNITUDE:g} (cgp_core.limits), got {x:g}")
            return default
        return x

    def integer(self, value: Any, key: str, *, minimum: int | None = None, maximum: int | None = None,
                default: int = 0) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, f"must be an integer, got {_kind(value)} {_show(value)}")
            return default
        if minimum is not None and value < minimum:
            self.fail(key, f"must be >= {minimum}, got {value}")
            return default
        if maximum is not None and value > maximum:
            self.fail(key, f"must be <= {maximum}, got {value}")
            return default
        return value

    def boolean(self, value: Any, key: str, default: bool = False) -> bool:
        if not isinstance(value, bool):
            self.fail(key, f"must be true or false, got {_kind(value)} {_show(value)}")
            return default
        return value

    def string(self, value: Any, key: str, default: str = "") -> str:
        if not isinstance(value, str):
            self.fail(key, f"must be a string, got {_kind(value)}")
            return default
        return value

    def choice(self, value: Any, key: str, options: list[str], default: str) -> str:
        s = self.string(value, key, default)
        if s not in options:
            self.fail(key, f"must be one of {', '.join(options)}, got {_show(s)}")
            return default
        return s

    def vector(self, value: Any, key: str, length: int, *, minimum: float | None = None,
               exclusive_min: bool = False, default: np.ndarray | None = None,
               within: tuple[float, float] | None = None, unit: str = "", max_norm: float | None = None) -> np.ndarray:
        fallback = np.zeros(length) if default is None else np.asarray(default, dtype=float)
        if not isinstance(value, (list, tuple)) or len(value) != length:
            self.fail(key, f"must be a list of {length} numbers, got {_kind(value)} {_show(value)}")
            return fallback
        before = len(self.problems)
        out = np.array([self.number(x, f"{key}[{i}]", minimum=minimum, exclusive_min=exclusive_min, within=within,
                                    unit=unit) for i, x in enumerate(value)])
        if len(self.problems) > before:
            return fallback
        if max_norm is not None and float(np.linalg.norm(out)) > max_norm:
            self.fail(key, f"its magnitude must be at most {max_norm:g}{' ' + unit if unit else ''} (what cgp_sim "
                      f"simulates: cgp_core.limits), got {float(np.linalg.norm(out)):g}")
            return fallback
        return out

    def name(self, value: Any, key: str, seen: set[str]) -> str:
        if not isinstance(value, str):
            self.fail(key, f"must be a string (a ROS-safe name), got {_kind(value)} {_show(value)}")
            return ""
        s = value
        if not ROS_SAFE_NAME.match(s):
            self.fail(key, f"{_show(s)} is not a ROS-safe name (letters, digits, _; starting with a letter)")
        elif len(s) > MAX_NAME_LENGTH:
            self.fail(key, f"{_show(s)} is {len(s)} characters long; names are at most {MAX_NAME_LENGTH}")
        elif s == GROUND_NAME:
            self.fail(key, f"{s!r} is reserved: it names the ground plane in contact reports")
        elif s in seen:
            self.fail(key, f"duplicate name {s!r} (body and flock names must be unique)")
        seen.add(s)
        return s


def _parse_world(v: _Validator, raw: Any) -> WorldSpec:
    d = v.mapping(raw, "world")
    spec = WorldSpec()
    v.no_unknown_keys(d, {f.name for f in fields(WorldSpec)}, "world")
    if "gravity" in d:
        spec.gravity = v.vector(d["gravity"], "world.gravity", 3, max_norm=MAX_GRAVITY, unit="m/s²",
                                within=(-MAX_GRAVITY, MAX_GRAVITY))
    if "ground" in d:
        spec.ground = v.boolean(d["ground"], "world.ground", True)
    if "sleep" in d:
        spec.sleep = v.boolean(d["sleep"], "world.sleep", True)
    if "ground_friction" in d:
        spec.ground_friction = v.number(d["ground_friction"], "world.ground_friction", minimum=0.0, default=0.6,
                                        within=(0.0, MAX_FRICTION))
    if "ground_restitution" in d:
        spec.ground_restitution = v.number(d["ground_restitution"], "world.ground_restitution", minimum=0.0,
                                           maximum=1.0)
    if "integrator" in d:
        spec.integrator = v.choice(d["integrator"], "world.integrator", sorted(INTEGRATORS), DEFAULT_INTEGRATOR)
    if "substeps" in d:
        spec.substeps = v.integer(d["substeps"], "world.substeps", minimum=1, maximum=1000, default=4)
    for key, top, unit in (("linear_damping", MAX_DAMPING, "1/s"), ("angular_damping", MAX_DAMPING, "1/s"),
                           ("rolling_resistance", MAX_ROLLING_RESISTANCE, "")):
        if key in d:
            setattr(spec, key, v.number(d[key], f"world.{key}", minimum=0.0, within=(0.0, top), unit=unit))
    return spec


_BODY_KEYS = {
    "name", "shape", "radius", "size", "length", "particles", "mass", "density", "position", "orientation",
    "linear_velocity", "angular_velocity", "restitution", "friction", "fixed", "color", "predator",
    "points", "mesh", "scale", "parts", "two_sided",
}
_SHAPE_KEYS = {"sphere": {"radius"}, "box": {"size"}, "capsule": {"radius", "length"},
               "particles": {"particles", "radius"}, "convex": {"points", "mesh", "scale"}, "compound": {"parts"},
               "mesh": {"mesh", "scale", "two_sided"}}
#: the shapes a compound body's parts may have, and the keys of a part
_PART_SHAPES = ("sphere", "box", "capsule", "convex")
_PART_KEYS = {"shape", "radius", "size", "length", "points", "mesh", "scale", "position", "orientation"}


def _parse_bodies(v: _Validator, raw: Any) -> list[BodySpec]:
    if raw is None:
        return []
    if not isinstance(raw, list):
        v.fail("bodies", f"must be a list of bodies, got {_kind(raw)}")
        return []
    if len(raw) > MAX_BODIES:
        v.fail("bodies", f"{len(raw)} bodies; at most {MAX_BODIES}")
        return []
    seen: set[str] = set()
    out = []
    for i, item in enumerate(raw):
        spec = _parse_body(v, item, f"bodies[{i}]", seen)
        if spec is not None:
            out.append(spec)
    return out


def _parse_body(v: _Validator, raw: Any, key: str, seen: set[str]) -> BodySpec | None:
    if not isinstance(raw, dict):
        v.fail(key, f"must be a mapping, got {_kind(raw)}")
        return None
    before = len(v.problems)
    v.no_unknown_keys(raw, _BODY_KEYS, key)
    if "name" not in raw:
        v.fail(f"{key}.name", "missing")
    name = v.name(raw.get("name", ""), f"{key}.name", seen) if "name" in raw else f"body{key}"
    key = f"{key} ({name})" if "name" in raw else key
    if "shape" in raw:
        shape_name = v.choice(raw["shape"], f"{key}.shape", list(_SHAPE_KEYS), "sphere")
    else:
        v.fail(f"{key}.shape", f"missing (one of {', '.join(_SHAPE_KEYS)})")
        shape_name = "sphere"
    for other, keys in _SHAPE_KEYS.items():
        for k in keys - _SHAPE_KEYS[shape_name]:
            if k in raw:
                v.fail(f"{key}.{k}", f"does not apply to shape {shape_name} (it is for {other})")

    fixed = v.boolean(raw.get("fixed", False), f"{key}.fixed")
    has_mass, has_density = "mass" in raw, "density" in raw
    mass = density = None
    if shape_name == "particles":
        for k in ("mass", "density"):
            if k in raw:
                v.fail(f"{key}.{k}", "particle bodies take their mass from the particles' 4th column")
    elif shape_name == "mesh":
        if not fixed:
            v.fail(f"{key}.fixed", "a static mesh must be fixed (fixed: true): it is not a solid, only a surface "
                   "(for a movable body from a mesh file use shape: convex with mesh:, its convex hull)")
        for k in ("mass", "density"):
            if k in raw:
                v.fail(f"{key}.{k}", "a static mesh is fixed and has no mass: leave it out")
    elif has_mass and has_density:
        v.fail(key, "give mass or density, not both")
    elif has_mass:
        mass = v.number(raw["mass"], f"{key}.mass", minimum=0.0, exclusive_min=True, default=1.0,
                        within=(MIN_MASS, MAX_MASS), unit="kg")
    elif has_density:
        density = v.number(raw["density"], f"{key}.density", minimum=0.0, exclusive_min=True, default=1000.0,
                           within=(MIN_DENSITY, MAX_DENSITY), unit="kg/m³")
    else:
        density = 1000.0  # water: a sensible default for a body given only its size

    spec = BodySpec(name=name, shape=Shape[shape_name.upper()], mass=1.0, inertia_body=np.eye(3))
    radius = half_length = None
    size = None
    if shape_name in ("sphere", "capsule"):
        if "radius" not in raw:
            v.fail(f"{key}.radius", "missing")
        else:
            radius = v.number(raw["radius"], f"{key}.radius", minimum=0.0, exclusive_min=True, default=0.1,
                              within=LENGTHS, unit="m")
    if shape_name == "capsule":
        if "length" not in raw:
            v.fail(f"{key}.length", "missing (length of the axis segment, without the caps)")
        else:
            half_length = 0.5 * v.number(raw["length"], f"{key}.length", minimum=0.0, exclusive_min=True,
                                         default=1.0, within=LENGTHS, unit="m")
    if shape_name == "box":
        if "size" not in raw:
            v.fail(f"{key}.size", "missing (full extents [x, y, z])")
        else:
            size = v.vector(raw["size"], f"{key}.size", 3, minimum=0.0, exclusive_min=True, default=np.ones(3),
                            within=LENGTHS, unit="m")

    if shape_name == "particles":
        spec.radius = v.number(raw.get("radius", 0.05), f"{key}.radius", minimum=0.0, exclusive_min=True,
                               default=0.05, within=LENGTHS, unit="m")
        particles = _parse_particles(v, raw.get("particles"), f"{key}.particles")
        if particles is not None:
            try:
                total, com, inertia = particle_mass_properties(particles[:, :3], particles[:, 3])
            except ValueError as exc:
                v.fail(f"{key}.particles", str(exc))
            else:
                moments = np.linalg.eigvalsh(inertia)
                if not moments.min() >= MIN_INERTIA_RATIO * moments.max():
                    v.fail(f"{key}.particles", f"principal moments of inertia {moments.min():.3g} .. "
                           f"{moments.max():.3g} kg m²: a body this thin cannot be simulated (their ratio must be "
                           f"at least {MIN_INERTIA_RATIO:g}: cgp_core.limits)")
                spec.mass, spec.inertia_body = total, inertia
                spec.particles = particles.copy()
                spec.particles[:, :3] -= com
                spec.half_extents = np.abs(spec.particles[:, :3]).max(axis=0) + spec.radius
                spec.position = com  # body-frame COM offset; turned into a world position below
    elif shape_name in ("convex", "compound", "mesh"):
        if len(v.problems) == before:
            _parse_issue25_shape(v, raw, key, shape_name, spec, mass, density)
        if len(v.problems) == before and shape_name != "mesh":  # the ranges every solid body is held to
            moments = np.linalg.eigvalsh(spec.inertia_body)
            if not moments.min() >= MIN_INERTIA_RATIO * moments.max():
                v.fail(key, f"principal moments of inertia {moments.min():.3g} .. {moments.max():.3g} kg m²: a body "
                       f"this thin cannot be simulated (their ratio must be at least {MIN_INERTIA_RATIO:g}: "
                       "cgp_core.limits)")
            if not MIN_MASS <= spec.mass <= MAX_MASS:
                v.fail(f"{key}.density", f"gives a mass of {spec.mass:g} kg; masses must be in [{MIN_MASS:g}, "
                       f"{MAX_MASS:g}] kg (what cgp_sim simulates: cgp_core.limits)")
    elif len(v.problems) == before:
        try:
            spec.mass, spec.inertia_body = shape_mass_properties(
                shape_name, radius=radius, size=size, half_length=half_length, mass=mass, density=density)
        except ValueError as exc:
            v.fail(key, str(exc))
        else:
            moments = np.linalg.eigvalsh(spec.inertia_body)
            if not moments.min() >= MIN_INERTIA_RATIO * moments.max():
                v.fail(key, f"principal moments of inertia {moments.min():.3g} .. {moments.max():.3g} kg m²: a body "
                       f"this thin cannot be simulated (their ratio must be at least {MIN_INERTIA_RATIO:g}: "
                       "cgp_core.limits; a 1 cm x 10 m pole has 2e-6)")
            if not MIN_MASS <= spec.mass <= MAX_MASS:
                v.fail(f"{key}.density", f"gives a mass of {spec.mass:g} kg; masses must be in [{MIN_MASS:g}, "
                       f"{MAX_MASS:g}] kg (what cgp_sim simulates: cgp_core.limits)")
        spec.radius = radius or 0.0
        if shape_name == "box":
            spec.half_extents = 0.5 * size
        elif shape_name == "capsule":
            spec.half_extents = np.array([0.0, 0.0, half_length])

    origin = v.vector(raw.get("position", [0, 0, 0]), f"{key}.position", 3, within=COORDINATES, unit="m")
    q = v.vector(raw.get("orientation", [0, 0, 0, 1]), f"{key}.orientation", 4, default=np.array([0, 0, 0, 1.0]))
    if np.linalg.norm(q) < 1e-9:
        v.fail(f"{key}.orientation", "zero quaternion (x, y, z, w); identity is [0, 0, 0, 1]")
        q = np.array([0.0, 0.0, 0.0, 1.0])
    spec.orientation = quat_normalize(q)
    spec.position = origin + quat_rotate(spec.orientation, spec.position)  # COM in world
    spec.linear_velocity = v.vector(raw.get("linear_velocity", [0, 0, 0]), f"{key}.linear_velocity", 3,
                                    max_norm=MAX_SPEED, unit="m/s")
    spec.angular_velocity = v.vector(raw.get("angular_velocity", [0, 0, 0]), f"{key}.angular_velocity", 3,
                                     max_norm=MAX_SPIN, unit="rad/s")
    rim_speed = float(np.linalg.norm(spec.linear_velocity) + np.linalg.norm(spec.angular_velocity) * body_reach(
        spec.shape, spec.radius, spec.half_extents))
    if rim_speed > MAX_SPEED:
        v.fail(f"{key}.angular_velocity", f"its surface would move at up to {rim_speed:.4g} m/s (|v| + |ω| times "
               f"its reach); at most {MAX_SPEED:g} m/s (what cgp_sim simulates: cgp_core.limits)")
    spec.restitution = v.number(raw.get("restitution", 0.3), f"{key}.restitution", minimum=0.0, maximum=1.0)
    spec.friction = v.number(raw.get("friction", 0.5), f"{key}.friction", minimum=0.0, default=0.5,
                             within=(0.0, MAX_FRICTION))
    spec.fixed = fixed
    spec.predator = v.boolean(raw.get("predator", False), f"{key}.predator")
    if "color" in raw:
        spec.color = v.vector(raw["color"], f"{key}.color", 4, minimum=0.0, default=spec.color)
        if np.any(spec.color > 1.0):
            v.fail(f"{key}.color", "RGBA components must be in [0, 1]")
    return spec if len(v.problems) == before else None


def body_reach(shape, radius: float, half_extents) -> float:
    """The farthest a body's surface is from its COM [m] (a particle body: a bound, from its half extents)."""
    half = np.asarray(half_extents, dtype=float)
    if shape == Shape.SPHERE:
        return float(radius)
    if shape == Shape.CAPSULE:
        return float(half[2] + radius)
    return float(np.linalg.norm(half))


# ---- issue 25's shapes: convex hulls, compound bodies, static meshes -------------------------------------------

def builtin_mesh_dir() -> Path:
    """The meshes shipped with the package (``msgs_config/meshes``): where a relative ``mesh:`` not found next to
    the scene file is looked for."""
    return Path(str(resources.files("msgs_config") / "meshes"))


def _parse_issue25_shape(v: _Validator, raw: dict, key: str, shape_name: str, spec: BodySpec, mass, density) -> None:
    """``shape: convex | compound | mesh`` (keys checked by the caller): fills ``spec``'s shape, mass properties
    (exact for the polyhedron, :mod:`cgp_core.inertia`), ``half_extents`` (a box about the COM that holds the
    shape) and ``position`` (the COM in the scene's body coordinates, turned into the world by the caller)."""
    if shape_name == "convex":
        hull = _convex_hull_of(v, raw, key, spec.name, spec.notes)
        if hull is None:
            return
        from .collision.convex import centred_hull

        try:
            centred, spec.mass, com, spec.inertia_body = centred_hull(hull, mass=mass, density=density,
                                                                      what=f"{key}.points")
        except ValueError as exc:
            v.fail("", str(exc))
            return
        spec.hull = centred
        spec.position = com
        spec.half_extents = np.abs(centred.vertices).max(axis=0)
    elif shape_name == "compound":
        _parse_compound(v, raw.get("parts"), f"{key}.parts", spec, mass, density)
    else:
        mesh = _static_mesh(v, raw, key, spec.notes, spec.name)
        if mesh is None:
            return
        spec.mesh = mesh
        spec.two_sided = v.boolean(raw.get("two_sided", False), f"{key}.two_sided")
        spec.mass, spec.inertia_body = 0.0, np.eye(3)  # fixed: never used
        spec.half_extents = np.abs(mesh.vertices).max(axis=0)


def _scale(v: _Validator, raw: dict, key: str) -> np.ndarray | None:
    """``scale``: a positive factor or three ([sx, sy, sz]); (3,)."""
    if "scale" not in raw:
        return np.ones(3)
    value = raw["scale"]
    if isinstance(value, (list, tuple)):
        before = len(v.problems)
        scale = v.vector(value, f"{key}.scale", 3, minimum=0.0, exclusive_min=True)
        return scale if len(v.problems) == before else None
    before = len(v.problems)
    factor = v.number(value, f"{key}.scale", minimum=0.0, exclusive_min=True, default=1.0)
    return np.full(3, factor) if len(v.problems) == before else None


def _mesh_path(v: _Validator, value: Any, key: str) -> Path | None:
    """Where a ``mesh:`` value points: a ``file://`` URI or an absolute path as given; a relative path from the
    scene file's directory (a spawn request's ``uri``: that file's), else from the built-in meshes
    (:func:`builtin_mesh_dir`)."""
    from urllib.parse import unquote, urlparse

    text = v.string(value, key)
    if not text.strip():
        v.fail(key, "must name a mesh file (.stl or .obj): a path, or a file:// URI")
        return None
    parsed = urlparse(text)
    if parsed.scheme == "file":
        return Path(unquote(parsed.path))
    if parsed.scheme and len(parsed.scheme) > 1:
        v.fail(key, f"{_show(text)}: only local files are read (a path, or a file:// URI), not {parsed.scheme}:")
        return None
    path = Path(text).expanduser()
    if path.is_absolute():
        return path
    source = Path(v.source)
    candidates = ([source.parent / path] if source.is_file() else []) + [builtin_mesh_dir() / path]
    return next((c for c in candidates if c.exists()), candidates[0])


#: meshes already read and hulls / BVHs already built, by (file, its size and mtime, scale, what): a pile of
#: rocks from one STL file reads it once (bounded: the oldest entries go)
_MESH_CACHE: dict = {}
_MESH_CACHE_SIZE = 32


def _cached(path: Path, scale: np.ndarray, what: str, build):
    try:
        stat = path.stat()
        ident = (str(path.resolve()), stat.st_size, stat.st_mtime_ns, tuple(scale), what)
    except OSError:
        return build()  # (the loader names the problem)
    if ident not in _MESH_CACHE:
        if len(_MESH_CACHE) >= _MESH_CACHE_SIZE:
            del _MESH_CACHE[next(iter(_MESH_CACHE))]
        _MESH_CACHE[ident] = build()
    return _MESH_CACHE[ident]


def _read_mesh(v: _Validator, raw: dict, key: str, *, closed: bool = False):
    """``(path, vertices (V, 3) scaled, triangles (T, 3))`` of the ``mesh`` key, or None (the problem recorded)."""
    from .collision.meshfile import MeshFileError, load_mesh

    scale = _scale(v, raw, key)
    path = _mesh_path(v, raw.get("mesh"), f"{key}.mesh")
    if path is None or scale is None:
        return None
    try:
        vertices, triangles = _cached(path, scale, "mesh", lambda: load_mesh(path, closed=closed))
    except MeshFileError as exc:
        v.fail(f"{key}.mesh", str(exc))
        return None
    return path, vertices * scale, triangles


def _convex_hull_of(v: _Validator, raw: dict, key: str, name: str, notes: list):
    """The :class:`~cgp_core.collision.convex.ConvexPolyhedron` of a convex body or part: of ``points`` or of the
    vertices of ``mesh`` (exactly one), scaled; a non-convex input gives its hull and a note says so."""
    from .collision.convex import MAX_INPUT_POINTS, HullError, convex_hull

    if ("points" in raw) == ("mesh" in raw):
        v.fail(key, "give points (a list of [x, y, z]) or mesh (an .stl / .obj file): exactly one")
        return None
    if "mesh" in raw:
        loaded = _read_mesh(v, raw, key)
        if loaded is None:
            return None
        path, points, _ = loaded
        what, given = f"{key}.mesh ({path.name})", f"{len(points)} vertices of {path.name}"
    else:
        scale = _scale(v, raw, key)
        points = raw["points"]
        if not isinstance(points, list):
            v.fail(f"{key}.points", f"must be a list of [x, y, z] points, got {_kind(points)}")
            return None
        if len(points) > MAX_INPUT_POINTS:
            v.fail(f"{key}.points", f"{len(points)} points; at most {MAX_INPUT_POINTS}")
            return None
        before = len(v.problems)
        rows = [v.vector(p, f"{key}.points[{i}]", 3, within=COORDINATES, unit="m") for i, p in enumerate(points)]
        if len(v.problems) > before or scale is None:
            return None
        points = np.array(rows, dtype=float).reshape(-1, 3) * scale
        what, given = f"{key}.points", f"{len(points)} points"
    try:
        hull = convex_hull(points, what=what)
    except HullError as exc:
        v.fail("", str(exc))
        return None
    if hull.interior_points:
        notes.append(("warn", f"{v.source}: {key}: {hull.interior_points} of the {given} are not vertices of their "
                              f"convex hull (inside it, on a face or edge, or repeated): body {name} is the hull, "
                              f"{len(hull.vertices)} vertices"))
    return hull


def _static_mesh(v: _Validator, raw: dict, key: str, notes: list, name: str):
    """A fixed body's :class:`~cgp_core.collision.bvh.StaticMesh` (its BVH built once, here), and a note with the
    build time and memory."""
    from .collision.bvh import StaticMesh

    if "mesh" not in raw:
        v.fail(f"{key}.mesh", "missing (an .stl / .obj file)")
        return None
    loaded = _read_mesh(v, raw, key)
    if loaded is None:
        return None
    path, vertices, triangles = loaded
    scale = _scale(v, raw, key)
    mesh = _cached(path, scale, "bvh", lambda: StaticMesh.build(vertices, triangles))
    notes.append(("info", f"static mesh {name}: {path.name}, {len(mesh.triangles)} triangles, "
                          f"{len(mesh.vertices)} vertices; BVH of {len(mesh.node_count)} nodes built in "
                          f"{mesh.build_seconds * 1e3:.1f} ms, {mesh.nbytes / 1e6:.2f} MB with the mesh"))
    return mesh


def _parse_compound(v: _Validator, raw: Any, key: str, spec: BodySpec, mass, density) -> None:
    """A compound body: each part's volume and inertia per unit density (closed forms, or exact for a convex
    part), the body's density (``density``, or ``mass`` over the parts' total volume), and the lecture's
    J = Σ Jᵢ over the parts by the parallel-axis theorem (:func:`cgp_core.inertia.compound_mass_properties`).
    Parts are summed as given: where two overlap, the overlap counts twice."""
    from .collision.convex import centred_hull
    from .rotation import quat_to_matrix

    if not isinstance(raw, list) or not raw:
        v.fail(key, f"must be a non-empty list of parts ({{shape: sphere | box | capsule | convex, <its size "
                    f"keys>, position, orientation}}), got {_kind(raw)}")
        return
    if len(raw) > MAX_PARTS_PER_BODY:
        v.fail(key, f"{len(raw)} parts; at most {MAX_PARTS_PER_BODY}")
        return
    before = len(v.problems)
    shapes, positions, rotations, radii, halves, hulls, volumes, inertias = [], [], [], [], [], [], [], []
    for i, part in enumerate(raw):
        where = f"{key}[{i}]"
        if not isinstance(part, dict):
            v.fail(where, f"must be a mapping, got {_kind(part)}")
            continue
        v.no_unknown_keys(part, _PART_KEYS, where)
        if "shape" not in part:
            v.fail(f"{where}.shape", f"missing (one of {', '.join(_PART_SHAPES)})")
            continue
        shape_name = v.choice(part["shape"], f"{where}.shape", list(_PART_SHAPES), "sphere")
        for other in _PART_SHAPES:
            for k in _SHAPE_KEYS[other] - _SHAPE_KEYS[shape_name]:
                if k in part:
                    v.fail(f"{where}.{k}", f"does not apply to shape {shape_name} (it is for {other})")
        position = v.vector(part.get("position", [0, 0, 0]), f"{where}.position", 3, within=COORDINATES, unit="m")
        q = v.vector(part.get("orientation", [0, 0, 0, 1]), f"{where}.orientation", 4,
                     default=np.array([0, 0, 0, 1.0]))
        if np.linalg.norm(q) < 1e-9:
            v.fail(f"{where}.orientation", "zero quaternion (x, y, z, w); identity is [0, 0, 0, 1]")
            continue
        R = quat_to_matrix(quat_normalize(q)[None])[0]
        radius, half, hull = 0.0, np.zeros(3), None
        part_before = len(v.problems)
        try:
            if shape_name == "convex":
                found = _convex_hull_of(v, part, where, spec.name, spec.notes)
                if found is None:
                    continue
                hull, volume, com, inertia = centred_hull(found, density=1.0, what=f"{where}.points")
                position = position + R @ com  # the part's centre is its COM
            elif shape_name == "box":
                if "size" not in part:
                    v.fail(f"{where}.size", "missing (full extents [x, y, z])")
                    continue
                size = v.vector(part["size"], f"{where}.size", 3, minimum=0.0, exclusive_min=True,
                                default=np.ones(3), within=LENGTHS, unit="m")
                half = 0.5 * size
                volume, inertia = shape_mass_properties("box", size=size, density=1.0)
            else:
                if "radius" not in part:
                    v.fail(f"{where}.radius", "missing")
                    continue
                radius = v.number(part["radius"], f"{where}.radius", minimum=0.0, exclusive_min=True, default=0.1,
                                  within=LENGTHS, unit="m")
                if shape_name == "capsule":
                    if "length" not in part:
                        v.fail(f"{where}.length", "missing (length of the axis segment, without the caps)")
                        continue
                    half[2] = 0.5 * v.number(part["length"], f"{where}.length", minimum=0.0, exclusive_min=True,
                                             default=1.0, within=LENGTHS, unit="m")
                    volume, inertia = shape_mass_properties("capsule", radius=radius, half_length=half[2],
                                                            density=1.0)
                else:
                    volume, inertia = shape_mass_properties("sphere", radius=radius, density=1.0)
        except ValueError as exc:
            v.fail(where, str(exc))
            continue
        if len(v.problems) > part_before:
            continue
        shapes.append(int(Shape[shape_name.upper()]))
        positions.append(position)
        rotations.append(R)
        radii.append(radius)
        halves.append(half)
        hulls.append(hull)
        volumes.append(volume)
        inertias.append(inertia)
    if len(v.problems) > before or not shapes:
        return
    volumes = np.array(volumes)
    rho = density if density is not None else mass / volumes.sum()
    part_mass = rho * volumes
    total, com, inertia = compound_mass_properties(part_mass, np.array(positions), np.array(rotations),
                                                   rho * np.array(inertias))
    offsets = np.array(positions) - com
    spec.mass, spec.inertia_body = total, inertia
    spec.parts = CompoundParts(shape=np.array(shapes, np.int8), position=offsets, rotation=np.array(rotations),
                               radius=np.array(radii), half_extents=np.array(halves), hulls=hulls, mass=part_mass)
    spec.half_extents = compound_half_extents(spec.parts)
    spec.position = com


def compound_half_extents(parts: CompoundParts) -> np.ndarray:
    """(3,) half extents of a box about the body's COM holding every part (the parts turned into body axes)."""
    reach = np.zeros(3)
    for k in range(parts.count):
        R, p = parts.rotation[k], parts.position[k]
        if parts.hulls[k] is not None:
            corners = parts.hulls[k].vertices @ R.T + p
            reach = np.maximum(reach, np.abs(corners).max(axis=0))
        else:
            half = np.abs(R) @ parts.half_extents[k] + parts.radius[k]
            reach = np.maximum(reach, np.abs(p) + half)
    return reach


def _parse_particles(v: _Validator, raw: Any, key: str) -> np.ndarray | None:
    """The (k, 4) rows [x, y, z, mass]: body-frame offsets within ±MAX_LENGTH m, masses in [MIN_MASS, MAX_MASS]
    kg, the total too.  The count is checked before anything is built; the rows are checked as one array (a
    100,000-particle body in ~0.1 s), and one by one, for the messages, only if that finds a problem."""
    if raw is None:
        v.fail(key, "missing (a list of [x, y, z, mass])")
        return None
    if not isinstance(raw, list) or not raw:
        v.fail(key, f"must be a non-empty list of [x, y, z, mass], got {_kind(raw)}")
        return None
    if len(raw) > MAX_PARTICLES_PER_BODY:
        v.fail(key, f"{len(raw)} particles; at most {MAX_PARTICLES_PER_BODY}")
        return None
    numbers = (int, float)
    if all(type(p) is list and len(p) == 4 and all(type(x) in numbers for x in p) for p in raw):
        try:
            arr = np.array(raw, dtype=float)
        except OverflowError:  # an integer beyond float64
            arr = None
        if arr is not None and np.isfinite(arr).all() and (np.abs(arr[:, :3]) <= MAX_LENGTH).all() \
                and ((arr[:, 3] >= MIN_MASS) & (arr[:, 3] <= MAX_MASS)).all():
            return _particle_total(v, arr, key)
    before = len(v.problems)
    rows = []
    for i, p in enumerate(raw):
        row = v.vector(p, f"{key}[{i}]", 4)
        if len(v.problems) == before:
            if not (np.abs(row[:3]) <= MAX_LENGTH).all():
                v.fail(f"{key}[{i}]", f"offsets must be within ±{MAX_LENGTH:g} m of the origin (what cgp_sim "
                       f"simulates: cgp_core.limits), got {row[:3].tolist()}")
            elif not row[3] > 0.0:
                v.fail(f"{key}[{i}]", f"particle mass must be > 0, got {row[3]:g}")
            elif not MIN_MASS <= row[3] <= MAX_MASS:
                v.fail(f"{key}[{i}]", f"particle mass must be in [{MIN_MASS:g}, {MAX_MASS:g}] kg (what cgp_sim "
                       f"simulates: cgp_core.limits), got {row[3]:g}")
        rows.append(row)
    if len(v.problems) > before:
        return None
    return _particle_total(v, np.array(rows), key)


def _particle_total(v: _Validator, arr: np.ndarray, key: str) -> np.ndarray | None:
    total = float(arr[:, 3].sum())
    if total > MAX_MASS:
        v.fail(key, f"total mass {total:g} kg; masses must be in [{MIN_MASS:g}, {MAX_MASS:g}] kg (what cgp_sim "
               "simulates: cgp_core.limits)")
        return None
    return arr


def _parse_flocks(v: _Validator, raw: Any, reserved: set[str]) -> list[Any]:
    if raw is None:
        return []
    if not isinstance(raw, list):
        v.fail("flocks", f"must be a list of flocks, got {_kind(raw)}")
        return []
    seen = set(reserved)
    out = []
    for i, item in enumerate(raw):
        params = _parse_flock(v, item, f"flocks[{i}]", seen)
        if params is not None:
            out.append(params)
    return out


# YAML key -> FlockParams field, for the flat keys (numbers unless listed in the other tables).
_FLOCK_NUMBERS = {
    "radius": ("radius", True), "separation_radius": ("separation_radius", True),
    "min_speed": ("min_speed", True), "max_speed": ("max_speed", True),
    "max_acceleration": ("max_acceleration", True), "fov_deg": ("fov_deg", True),
    "goal_weight": ("goal_weight", False), "obstacle_margin": ("obstacle_margin", False),
    "boid_size": ("boid_size", True), "bank_gain": ("bank_gain", False),
    "orientation_time_constant": ("orientation_time_constant", False),
    "fright_radius": ("fright_radius", False),
}
_FLOCK_KEYS = {"name", "count", "seed", "spawn", "weights", "bounds", "goal", "avoid_bodies", "model",
               "neighbor_search", "rules", "couzin", "neighbors", *_FLOCK_NUMBERS}
#: the upper ends of the flat flock numbers (cgp_core.limits; the others: MAX_MAGNITUDE): YAML key -> (max, unit)
_FLOCK_RANGES = {
    "radius": (MAX_LENGTH, "m"), "separation_radius": (MAX_LENGTH, "m"), "boid_size": (MAX_LENGTH, "m"),
    "obstacle_margin": (MAX_LENGTH, "m"), "fright_radius": (MAX_LENGTH, "m"),
    "min_speed": (MAX_SPEED, "m/s"), "max_speed": (MAX_SPEED, "m/s"),
    "max_acceleration": (MAX_ACCELERATION, "m/s²"), "goal_weight": (MAX_ACCELERATION, "m/s²"),
    "fov_deg": (360.0, "degrees"),
}
#: issue 14: keys of Reynolds' rules, which a Couzin flock does not use (its zones, speed and field of
#: perception are in its `couzin` block)
_REYNOLDS_ONLY_KEYS = ("radius", "separation_radius", "weights", "min_speed", "max_speed", "fov_deg", "goal",
                       "goal_weight")
#: YAML key of the `couzin` block -> (minimum, strictly greater) ; all numbers
_COUZIN_NUMBERS = {
    "repulsion_radius": (0.0, False), "orientation_width": (0.0, False), "attraction_width": (0.0, False),
    "field_of_view_deg": (0.0, True), "turning_rate_deg": (0.0, True), "speed": (0.0, True),
    "noise": (0.0, False),
}


def _parse_flock(v: _Validator, raw: Any, key: str, seen: set[str]):
    """One flock: the scene keys of the flock issue (nested ``spawn``, ``weights``, ``bounds``) mapped onto
    :class:`cgp_core.boids.FlockParams` (whose docstring documents every field, unit and default)."""
    from .boids import BOUNDS_MODES, MODELS, NEIGHBOR_SEARCHES, FlockParams

    if not isinstance(raw, dict):
        v.fail(key, f"must be a mapping, got {_kind(raw)}")
        return None
    before = len(v.problems)
    v.no_unknown_keys(raw, _FLOCK_KEYS, key)
    if "name" not in raw:
        v.fail(f"{key}.name", "missing")
    else:
        name = v.name(raw["name"], f"{key}.name", seen)
        key = f"{key} ({name})"
    kwargs: dict[str, Any] = {"name": raw.get("name", "flock")}
    if "count" not in raw:
        v.fail(f"{key}.count", "missing (number of boids)")
    else:
        kwargs["count"] = v.integer(raw["count"], f"{key}.count", minimum=1, maximum=MAX_BOIDS_PER_FLOCK, default=1)
    if "seed" in raw:
        kwargs["seed"] = v.integer(raw["seed"], f"{key}.seed", minimum=0, maximum=2**63 - 1)
    for yaml_key, (field_name, strictly_positive) in _FLOCK_NUMBERS.items():
        if yaml_key in raw:
            top, unit = _FLOCK_RANGES.get(yaml_key, (MAX_MAGNITUDE, ""))
            kwargs[field_name] = v.number(raw[yaml_key], f"{key}.{yaml_key}", minimum=0.0,
                                          exclusive_min=strictly_positive, default=1.0, within=(0.0, top), unit=unit)
    spawn = v.mapping(raw.get("spawn"), f"{key}.spawn")
    v.no_unknown_keys(spawn, {"center", "extent"}, f"{key}.spawn")
    if "center" in spawn:
        kwargs["spawn_center"] = v.vector(spawn["center"], f"{key}.spawn.center", 3, within=COORDINATES, unit="m")
    if "extent" in spawn:
        kwargs["spawn_extent"] = v.vector(spawn["extent"], f"{key}.spawn.extent", 3, minimum=0.0,
                                          within=(0.0, MAX_COORDINATE), unit="m")
    weights = v.mapping(raw.get("weights"), f"{key}.weights")
    v.no_unknown_keys(weights, {"cohesion", "separation", "alignment"}, f"{key}.weights")
    for rule in ("cohesion", "separation", "alignment"):
        if rule in weights:
            kwargs[f"{rule}_weight"] = v.number(weights[rule], f"{key}.weights.{rule}", minimum=0.0)
    bounds = v.mapping(raw.get("bounds"), f"{key}.bounds")
    v.no_unknown_keys(bounds, {"min", "max", "mode", "margin", "strength"}, f"{key}.bounds")
    if "min" in bounds:
        kwargs["bounds_min"] = v.vector(bounds["min"], f"{key}.bounds.min", 3, within=COORDINATES, unit="m")
    if "max" in bounds:
        kwargs["bounds_max"] = v.vector(bounds["max"], f"{key}.bounds.max", 3, within=COORDINATES, unit="m")
    if "mode" in bounds:
        kwargs["bounds_mode"] = v.choice(bounds["mode"], f"{key}.bounds.mode", list(BOUNDS_MODES), "soft")
    for sub in ("margin", "strength"):
        if sub in bounds:
            kwargs[f"bounds_{sub}"] = v.number(bounds[sub], f"{key}.bounds.{sub}", minimum=0.0, within=(
                0.0, MAX_LENGTH if sub == "margin" else MAX_ACCELERATION), unit="m" if sub == "margin" else "m/s²")
    if raw.get("goal") is not None:
        kwargs["goal"] = v.vector(raw["goal"], f"{key}.goal", 3, within=COORDINATES, unit="m")
    if "avoid_bodies" in raw:
        kwargs["avoid_bodies"] = v.boolean(raw["avoid_bodies"], f"{key}.avoid_bodies", True)
    if "model" in raw:
        kwargs["model"] = v.choice(raw["model"], f"{key}.model", list(MODELS), "sphere")
    if "neighbor_search" in raw:
        kwargs["neighbor_search"] = v.choice(raw["neighbor_search"], f"{key}.neighbor_search",
                                             list(NEIGHBOR_SEARCHES), "grid")
    _parse_flock_rules(v, raw, key, kwargs)
    if len(v.problems) > before:
        return None
    try:  # relations between fields (separation < radius, spawn box inside bounds, ...)
        params = FlockParams(**kwargs)
    except ValueError as exc:
        v.fail(key, str(exc).split(": ", 1)[-1])
        return None
    if params.neighbor_search == "brute" and params.count > MAX_BOIDS_BRUTE:
        v.fail(f"{key}.neighbor_search", f"brute (the O(N²) reference search) is for flocks of at most "
               f"{MAX_BOIDS_BRUTE} boids (cgp_core.limits), this one has {params.count}: use grid or kdtree")
        return None
    crowding = flock_crowding(params)
    if crowding is not None:
        v.fail(f"{key}.count", crowding)
        return None
    return params


def flock_crowding(params) -> str | None:
    """Why a flock is too dense to step in bounded time (None if it is not): its expected neighbours per boid,
    N (4/3)π r³ / V, at its spawn density (V: the spawn box, each side taken as at least 2 r) and, with walls
    (soft / wrap bounds), at the density of its bounds box, must be at most MAX_EXPECTED_NEIGHBORS (a step
    costs N times that: :mod:`cgp_core.limits`)."""
    r = float(params.radius)
    ball = 4.0 / 3.0 * math.pi * r ** 3
    boxes = [("its spawn box", np.maximum(params.spawn_extent, 2.0 * r))]
    if params.bounds_mode != "none":
        boxes.append(("its bounds", np.maximum(params.bounds_max - params.bounds_min, 2.0 * r)))
    for where, size in boxes:
        expected = params.count * min(1.0, ball / float(np.prod(size)))
        if expected > MAX_EXPECTED_NEIGHBORS:
            return (f"{params.count} boids with a neighbourhood radius of {r:g} m would have ~{expected:.0f} "
                    f"neighbours each at the density of {where} ({' x '.join(f'{x:g}' for x in size)} m); at most "
                    f"{MAX_EXPECTED_NEIGHBORS} (a step costs N times that: cgp_core.limits): fewer boids, a larger "
                    "box or a smaller radius")
    return None


def _parse_flock_rules(v: _Validator, raw: dict, key: str, kwargs: dict) -> None:
    """Issue 14's flock keys: ``rules`` and its ``couzin`` block, ``neighbors: {mode, k}`` (``fright_radius``
    is a plain number above)."""
    from .boids.params import NEIGHBOR_MODES, RULES, CouzinParams

    rules = v.choice(raw["rules"], f"{key}.rules", list(RULES), "reynolds") if "rules" in raw else "reynolds"
    kwargs["rules"] = rules
    if rules == "couzin":
        for reynolds_key in _REYNOLDS_ONLY_KEYS:
            if reynolds_key in raw:
                v.fail(f"{key}.{reynolds_key}", "does not apply to rules: couzin (its zones, speed and field of "
                       "perception are set in the couzin block)")
        block = v.mapping(raw.get("couzin"), f"{key}.couzin")
        v.no_unknown_keys(block, set(_COUZIN_NUMBERS), f"{key}.couzin")
        values = {}
        for name, (minimum, strict) in _COUZIN_NUMBERS.items():
            if name in block:
                top, unit = {"speed": (MAX_SPEED, "m/s"), "field_of_view_deg": (360.0, "degrees")}.get(
                    name, (MAX_LENGTH, "m") if name.endswith(("_radius", "_width")) else (MAX_MAGNITUDE, ""))
                values[name] = v.number(block[name], f"{key}.couzin.{name}", minimum=minimum,
                                        exclusive_min=strict, default=1.0, within=(0.0, top), unit=unit)
        if "field_of_view_deg" in values and values["field_of_view_deg"] > 360.0:
            v.fail(f"{key}.couzin.field_of_view_deg", f"must be <= 360, got {values['field_of_view_deg']:g}")
            values.pop("field_of_view_deg")
        try:
            kwargs["couzin"] = CouzinParams(**values)
        except ValueError as exc:
            v.fail(f"{key}.couzin", str(exc).removeprefix("couzin: "))
    elif "couzin" in raw:
        v.fail(f"{key}.couzin", f"only applies to rules: couzin (this flock's rules: {rules})")
    neighbors = v.mapping(raw.get("neighbors"), f"{key}.neighbors")
    v.no_unknown_keys(neighbors, {"mode", "k"}, f"{key}.neighbors")
    if "mode" in neighbors:
        kwargs["neighbor_mode"] = v.choice(neighbors["mode"], f"{key}.neighbors.mode", list(NEIGHBOR_MODES),
                                           "metric")
    if "k" in neighbors:
        # kept with mode: metric too (unused there), so switching the mode is a one-word edit
        kwargs["neighbor_k"] = v.integer(neighbors["k"], f"{key}.neighbors.k", minimum=1, maximum=1000, default=7)

"""Loading a scene: finding it (a file or a built-in name), reading it bounded (:mod:`cgp_core.user_input`),
validating every section (``world`` here; ``bodies`` in :mod:`.bodies`, ``flocks`` in :mod:`.flocks`) into a
:class:`~.specs.Scene`, and one entity to spawn into a running world (:func:`spawn_entry`)."""

from __future__ import annotations

import re
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any

from ..integrators import DEFAULT_INTEGRATOR, INTEGRATORS
from ..limits import (
    MAX_BOIDS,
    MAX_DAMPING,
    MAX_FILE_BYTES,
    MAX_FRICTION,
    MAX_GRAVITY,
    MAX_ROLLING_RESISTANCE,
    rigid_work_refusal,
)
from ..robots.joint_integrators import DEFAULT_JOINT_INTEGRATOR, JOINT_INTEGRATORS
from ..user_input import SceneLoader, UserInputError, load_yaml, read_user_text
from .bodies import parse_bodies, parse_body
from .flocks import parse_flock, parse_flocks
from .joints import parse_joints
from .named_poses import parse_named_poses, parse_tags
from .robots import articulation_spec, parse_robot, parse_robots
from .specs import CONTACT_DETECTION, Scene, WorldSpec
from .validation import SceneError, Validator, kind_of

#: the largest scene file (cgp_core.limits.MAX_FILE_BYTES); every other limit is in cgp_core.limits too
MAX_SCENE_BYTES = MAX_FILE_BYTES
#: the scene loader (PyYAML's safe loader, duplicate keys refused, YAML 1.2 floats): cgp_core.user_input
_SceneLoader = SceneLoader


def builtin_scene_dir() -> Path:
    return Path(str(resources.files("msgs_config") / "scenes"))


def builtin_scene_names() -> list[str]:
    return sorted(p.stem for p in builtin_scene_dir().glob("*.yaml"))


@dataclass(frozen=True)
class Gallery:
    """An entry of the built-in galleries (:func:`available_scenes`, :func:`spawnable_files`): what to pass as
    ``name`` (a scene name or a spawn ``uri``), what it is (``kind``: ``scene``, ``robot``, ``mesh``), its
    description and (a scene) its ``tags:``."""

    name: str
    kind: str
    description: str
    tags: tuple[str, ...] = ()


def available_scenes() -> list[Gallery]:
    """The built-in scenes (``msgs_config/scenes``), each with its ``description:`` and ``tags:`` (read, not
    validated: loading it does that; :func:`gallery_fields`); a scene whose file or entries cannot be read is listed
    without them (loading it names the problem)."""
    scenes = []
    for name in builtin_scene_names():
        path = builtin_scene_dir() / f"{name}.yaml"
        try:
            stat = path.stat()
        except OSError:
            continue
        key = (str(path), stat.st_mtime_ns, stat.st_size)
        if key not in _GALLERY:  # once per file version
            try:
                data = gallery_fields(read_user_text(path))
            except UserInputError:
                data = {}
            tags = data.get("tags", [])
            tags = tuple(t for t in tags if isinstance(t, str)) if isinstance(tags, list) else ()
            _GALLERY[key] = Gallery(name, "scene", " ".join(str(data.get("description", "")).split()), tags)
        scenes.append(_GALLERY[key])
    return scenes


#: available_scenes' entries by (path, modification time, size)
_GALLERY: dict[tuple, Gallery] = {}

#: the scene keys a gallery entry shows
GALLERY_KEYS = ("description", "tags")


def gallery_fields(text: str) -> dict:
    """The top-level :data:`GALLERY_KEYS` of a scene's YAML ``text`` (those it has), as the whole document loaded
    by :func:`~cgp_core.user_input.load_yaml` has them — {} for a document that is not a mapping — without
    composing the rest (so a mistake in the rest does not hide them: loading the scene names it).  Why: the node
    lists the gallery at start-up, and the whole of ``sphere_pile`` (1,000 bodies, 160 kB) took 0.19 s of every
    node start; its two keys take ~1 ms (the whole gallery: 0.20 s -> 6 ms).

    A block mapping at the document's top level starts each of its keys at column 0, so the lines from such a key
    to the next one are its entry; only those of :data:`GALLERY_KEYS` are loaded.  Anything else at column 0 — a
    flow mapping, a quoted or complex key, a directive, a second document, an anchor or alias the entries need, a
    document that does not load — takes the whole document's load, as before.  Raises
    :class:`~cgp_core.user_input.UserInputError` as :func:`~cgp_core.user_input.load_yaml` does."""
    lines = text.splitlines(keepends=True)
    entries: dict[str, list[str]] = {}
    current: list[str] | None = None
    first = True
    for line in lines:
        if line[:1] in ("", " ", "\t", "\n", "\r", "#", "-") and not line.startswith(("---", "...")):
            if current is not None:  # (a block sequence may start at the key's column: still its entry)
                current.append(line)
            continue
        if first and line.rstrip() == "---":  # the document's explicit start
            first = False
            continue
        first = False
        key = _TOP_LEVEL_KEY.match(line)
        if key is None:
            return _whole_document(text)
        current = entries.setdefault(key.group(1), []) if key.group(1) in GALLERY_KEYS else None
        if current is not None and len(current) > 0:
            return _whole_document(text)  # a key given twice: the whole load names it
        if current is not None:
            current.append(line)
    found = "".join("".join(v) for v in entries.values())
    if not found:
        return {}
    try:
        data = load_yaml(found)
    except UserInputError:
        return _whole_document(text)
    return data if isinstance(data, dict) else _whole_document(text)


#: a plain key at column 0 of a block mapping, followed by its value or the end of the line
_TOP_LEVEL_KEY = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)[ \t]*:(?:[ \t]|$)")


def _whole_document(text: str) -> dict:
    data = load_yaml(text)
    return {k: data[k] for k in GALLERY_KEYS if k in data} if isinstance(data, dict) else {}


def spawnable_files() -> list[Gallery]:
    """What a spawn request may name by a bare file name: the built-in robots (``msgs_config/robots``, URDF) and
    meshes (``msgs_config/meshes``, STL / OBJ: a convex body, the mesh's hull)."""
    from .mesh_files import builtin_mesh_dir
    from .robots import builtin_robot_dir

    robots = [Gallery(p.name, "robot", f"robot {p.stem} (URDF)") for p in sorted(builtin_robot_dir().glob("*.urdf"))]
    meshes = [Gallery(p.name, "mesh", f"convex body, the hull of mesh {p.name}")
              for p in sorted(builtin_mesh_dir().iterdir()) if p.suffix.lower() in (".stl", ".obj")]
    return robots + meshes


def scene_identity(source: str) -> tuple[str, str]:
    """``(name, uri)`` of a loaded scene by its ``Scene.source``: a built-in scene is its name twice (``default``
    loads it again); a file its stem and its path; a scene given as text (``resource_string``) that source."""
    path = Path(source)
    if path.suffix in (".yaml", ".yml"):
        if path.parent.resolve() == builtin_scene_dir().resolve():
            return path.stem, path.stem
        return path.stem, source
    return source, ""


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
    v = Validator(source)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise SceneError(source, [f"top level must be a mapping with keys world/bodies/flocks/robots/joints/"
                                  f"named_poses, got {kind_of(data)}"])
    v.no_unknown_keys(data, {"world", "bodies", "flocks", "robots", "joints", "named_poses", "description", "tags"},
                      "")
    world = parse_world(v, data.get("world", {}))
    bodies = parse_bodies(v, data.get("bodies", []))
    flocks = parse_flocks(v, data.get("flocks", []), reserved={b.name for b in bodies})
    seen = {b.name for b in bodies} | {f.name for f in flocks}
    robots = parse_robots(v, data.get("robots", []), seen)
    joints, articulations = parse_joints(v, data.get("joints", []), bodies, seen | {r.name for r in robots})
    named_poses = parse_named_poses(v, data.get("named_poses"))
    description = v.string(data.get("description", ""), "description")
    for robot in robots:  # a robot entry without its own joint_integrator takes the world's
        if robot.joint_integrator is None:
            robot.joint_integrator = world.joint_integrator
    scene = Scene(source=source, world=world, bodies=bodies, flocks=flocks, robots=robots, joints=joints,
                  articulations=[articulation_spec(a, world.joint_integrator) for a in articulations],
                  named_poses=named_poses,
                  description=" ".join(description.split()), tags=parse_tags(v, data.get("tags", []), "tags"))
    refusal = rigid_work_refusal(*scene.rigid_work(), world.substeps)
    if refusal:
        v.fail("world.substeps", refusal)
    total = sum(f.count for f in flocks)
    if total > MAX_BOIDS:
        v.fail("flocks", f"{total} boids in all; a world holds at most {MAX_BOIDS} (cgp_core.limits)")
    v.raise_if_any()
    return scene


#: what a spawned entity may be: one scene-file entry of ``bodies``, ``flocks`` or ``robots``
SPAWN_KINDS = ("body", "flock", "robot")


def spawn_entry(data: Any, source: str, *, name: str, taken: set[str] = frozenset(),
                position=(0.0, 0.0, 0.0), orientation=(0.0, 0.0, 0.0, 1.0)):
    """Validate an entity to spawn into a running world: ``{body: <entry>}`` or ``{flock: <entry>}``, where the
    entry is what a scene file's ``bodies`` / ``flocks`` list holds, without ``name`` (``name`` here) and, for a
    body, without ``position`` / ``orientation`` (``position`` (3,), ``orientation`` (4,) xyzw here: the pose of
    the body origin, as a scene gives it); for a flock ``position`` is the spawn centre (``spawn.center``).

    A robot (``{robot: <entry>}``) is a ``robots`` entry without ``name``, ``position`` and ``orientation`` (the
    root link's pose: ``position`` / ``orientation`` here); instead of ``urdf`` (a file) it may give ``urdf_xml``
    (URDF XML text, parsed by the hardened parser, never expanded as xacro).

    Returns ``("body", BodySpec)``, ``("flock", FlockParams)`` or ``("robot", RobotSpec)``.  Raises
    :class:`SceneError` with the same texts as a scene file, key paths starting at ``body`` / ``flock`` /
    ``robot`` (``body (box1).size[1]: must be > 0``)."""
    v = Validator(source)
    if not isinstance(data, dict) or len(data) != 1 or next(iter(data)) not in SPAWN_KINDS:
        # not an entry of ours: its keys are not quoted (a uri may name any readable file, /etc/shadow)
        keys = kind_of(data)
        if isinstance(data, dict) and data:
            ours = [k for k in SPAWN_KINDS if k in data]
            keys = f"a mapping of {len(data)} keys" + (f" ({' and '.join(ours)} among them)" if ours
                                                       else ", none of them body, flock or robot")
        raise SceneError(source, [f"must be a mapping with exactly one key, body, flock or robot (a scene file's "
                                  f"bodies / flocks / robots entry), got {keys}"])
    kind, raw = next(iter(data.items()))
    if not isinstance(raw, dict):
        raise SceneError(source, [f"{kind}: must be a mapping (a scene file's {kind} entry), got {kind_of(raw)}"])
    given_by_request = {"name": "the request's name"}
    if kind in ("body", "robot"):
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
        spec = parse_body(v, entry, kind, set(taken))
    elif kind == "robot":
        entry = dict(raw, position=[float(x) for x in position], orientation=[float(x) for x in orientation])
        spec = parse_robot(v, entry, kind, set(taken), name=name)
    else:
        if spawn is None or isinstance(spawn, dict):
            entry["spawn"] = {**(spawn or {}), "center": [float(x) for x in position]}
        spec = parse_flock(v, entry, kind, set(taken))
    v.raise_if_any()
    return kind, spec


def parse_world(v: Validator, raw: Any) -> WorldSpec:
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
    if "joint_integrator" in d:
        spec.joint_integrator = v.choice(d["joint_integrator"], "world.joint_integrator", sorted(JOINT_INTEGRATORS),
                                         DEFAULT_JOINT_INTEGRATOR)
    if "substeps" in d:
        spec.substeps = v.integer(d["substeps"], "world.substeps", minimum=1, maximum=1000, default=4)
    if "contact_detection" in d:
        spec.contact_detection = v.choice(d["contact_detection"], "world.contact_detection", list(CONTACT_DETECTION),
                                          "every_substep")
    for key, top, unit in (("linear_damping", MAX_DAMPING, "1/s"), ("angular_damping", MAX_DAMPING, "1/s"),
                           ("rolling_resistance", MAX_ROLLING_RESISTANCE, "")):
        if key in d:
            setattr(spec, key, v.number(d[key], f"world.{key}", minimum=0.0, within=(0.0, top), unit=unit))
    return spec

"""A spawn request's expensive part, as a job for the node's worker process (:mod:`cgp_sim_ros.workers`).

:func:`prepare` is everything ``~/spawn_entity`` does before the entity is added between two ticks: read the
``uri`` (a YAML file or a mesh file, regular files only, size-capped: :mod:`cgp_core.user_input`), parse the YAML
(bounded), validate it as a scene entry, build the entity (:func:`cgp_core.world.prepare_spawn`: hulls, a static
mesh's BVH and active edges, a flock's initial state) and draw it (:func:`cgp_sim_ros.drawing.bodies.model_drawings`:
the hulls' markers at both levels of detail, a static mesh's marker clustered to its cap).  It runs in the worker
process with a copy of what it needs (:class:`SpawnRequest`: the world's scene settings and the names in use),
and answers a :class:`Spawned` or a :class:`Refusal` — plain data that pickles (a refusal is an answer, not an
exception: the node maps its ``kind`` to the service's result code).  The node then adds it between two ticks
and checks the name and the limits again (the world may have changed meanwhile).

A robot (issue 36) is one more such entity: a ``.urdf`` / ``.xacro`` file as ``uri``, URDF XML as
``resource_string`` (it starts with ``<``), or YAML ``{robot: <a scene's robots entry>}``; its URDF is parsed here
(the hardened parser of :mod:`cgp_core.robots.urdf`: no DTD, no entity) and its links' bodies built and drawn.

ROS-free: the worker never imports rclpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote, urlparse

#: the formats spawn_entity takes (SimulatorFeatures.spawn_formats)
SPAWN_FORMATS = ("yaml", "stl", "obj", "urdf", "xacro")


@dataclass(frozen=True)
class SpawnRequest:
    """What the worker needs of a spawn request and of the world (a snapshot)."""

    uri: str
    resource: str  # the request's resource_string (used when uri is empty)
    source: str  # what errors name as the file: the uri or "resource_string"
    name: str
    allow_renaming: bool
    taken: frozenset  # the entity names in use when the request came
    position: tuple  # (3,) m
    orientation: tuple  # (4,) x, y, z, w
    world: object  # the world's cgp_core.scene.WorldSpec


@dataclass
class Spawned:
    """A prepared entity (:class:`cgp_core.world.PreparedSpawn`) and its shapes' drawings (``(shape, drawing)``
    pairs, the shapes the very objects of ``prepared``'s model: pickled together, they stay shared)."""

    prepared: object
    drawings: list = field(default_factory=list)


@dataclass
class Refusal:
    """A refused request: ``kind`` is ``"unsupported_format"``, ``"parse_error"`` (the file or the YAML: its
    reading, parsing or validation), ``"name_taken"``, ``"name_invalid"``, ``"invalid_pose"`` or
    ``"not_possible"``; ``message`` names what was wrong (never the content of a file)."""

    kind: str
    message: str


def prepare(request: SpawnRequest) -> Spawned | Refusal:
    """The spawn worker's job (see the module docstring)."""
    from cgp_core.editing import EditError
    from cgp_core.scene import SPAWN_KINDS, SceneError, parse_yaml
    from cgp_core.world import prepare_spawn, unique_name

    from .drawing.bodies import model_drawings
    from .drawing.robots import visual_drawings

    try:
        mesh = mesh_uri(request.uri) if request.uri else None
        robot = robot_uri(request.uri) if request.uri else None
        source = request.source
        if mesh is not None:  # a mesh file: a convex body, its hull (the file read bounded by the scene loader)
            data, source = {"body": {"shape": "convex", "mesh": str(mesh)}}, str(mesh)
        elif robot is not None:  # a robot's URDF / xacro file (read bounded by the URDF loader); a bare name
            # that is no file here is one of the built-in robots (msgs_config/robots)
            found = robot.is_absolute() or robot.exists()
            data = {"robot": {"urdf": str(robot.absolute()) if found else str(robot)}}
            source = "uri"  # (the loader's messages name the file)
        elif not request.uri and request.resource.lstrip().startswith("<"):  # URDF XML text
            data = {"robot": {"urdf_xml": request.resource}}
        elif request.uri:
            text, source = read_uri(request.uri)
            data = parse_yaml(text, source)
        else:
            data = parse_yaml(request.resource, source)
        kind = next(iter(data)) if isinstance(data, dict) and len(data) == 1 and next(iter(data)) in SPAWN_KINDS \
            else "entity"
        name, taken = request.name, set(request.taken)
        if request.allow_renaming and (not name or name in taken):
            name = unique_name(name or kind, taken)
        prepared = prepare_spawn(data, request.world, name=name, taken=taken, position=request.position,
                                 orientation=request.orientation, source=source)
    except Refused as exc:  # (raised by read_uri)
        return exc.refusal
    except SceneError as exc:
        return Refusal("parse_error", str(exc))
    except EditError as exc:
        return Refusal(exc.kind if exc.kind in ("name_taken", "name_invalid", "invalid_pose") else "not_possible",
                       str(exc))
    drawings = model_drawings(prepared.model) if prepared.model is not None else []
    if prepared.robot is not None and prepared.robot.model is not None:  # its URDF visuals (mesh files read here)
        drawings += visual_drawings(prepared.robot.model)
    return Spawned(prepared, drawings)


def prepare_batch(requests: list[SpawnRequest]) -> list[Spawned | Refusal]:
    """``spawn_entities``' job: :func:`prepare` for each request in order, each seeing the names the earlier
    ones took (``allow_renaming`` picks past them; a name taken twice is refused as taken).  Every request is
    answered, also after a refusal, so that the reply names every entry that was wrong."""
    from dataclasses import replace

    taken = set(requests[0].taken) if requests else set()
    answers = []
    for request in requests:
        answer = prepare(replace(request, taken=frozenset(taken)))
        if isinstance(answer, Spawned):
            taken.add(answer.prepared.name)
        answers.append(answer)
    return answers


class Refused(Exception):
    """A :class:`Refusal` raised (by :func:`read_uri`)."""

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.refusal = Refusal(kind, message)


def mesh_uri(uri: str) -> Path | None:
    """The mesh file a ``uri`` names (a path or ``file://`` URI ending in .stl / .obj), or None.  It is read by the
    scene loader, bounded (:func:`cgp_core.collision.meshfile.load_mesh`: regular files only, size and count caps,
    errors naming the file and the reason)."""
    parsed = urlparse(uri)
    if parsed.scheme not in ("", "file"):
        return None
    path = Path(unquote(parsed.path) if parsed.scheme == "file" else uri).expanduser()
    return path if path.suffix.lower() in (".stl", ".obj") else None


def robot_uri(uri: str) -> Path | None:
    """The robot file a ``uri`` names (a path or ``file://`` URI ending in .urdf / .xacro), or None.  It is read
    by the URDF loader (:func:`cgp_core.robots.urdf.load_urdf`: a regular file only, size-capped, hardened XML;
    a .xacro file expanded by xacro, as a scene's robot is)."""
    parsed = urlparse(uri)
    if parsed.scheme not in ("", "file"):
        return None
    path = Path(unquote(parsed.path) if parsed.scheme == "file" else uri).expanduser()
    return path if path.suffix.lower() in (".urdf", ".xacro") else None


def read_uri(uri: str) -> tuple[str, str]:
    """The YAML text and its source name for a ``uri`` (a path or ``file://`` URI of a .yaml file, read as every
    user file is: :func:`cgp_core.user_input.read_user_text`, a regular file only, size-capped); raises a
    :class:`Refused` otherwise.  The message names the uri, never the file's content."""
    from cgp_core.user_input import UserInputError, read_user_text

    parsed = urlparse(uri)
    if parsed.scheme not in ("", "file"):
        raise Refused("unsupported_format", f"uri {brief(uri)}: only local files are spawned (a path or file:// "
                                             f"URI; spawn_formats: {', '.join(SPAWN_FORMATS)})")
    path = Path(unquote(parsed.path) if parsed.scheme == "file" else uri).expanduser()
    if path.suffix.lower() not in (".yaml", ".yml"):
        raise Refused("unsupported_format", f"uri {brief(uri)}: not a .yaml, .stl, .obj, .urdf or .xacro file; "
                                             f"cgp_sim spawns YAML, a mesh as a convex body or a robot's URDF "
                                             f"(spawn_formats: "
                                             f"{', '.join(SPAWN_FORMATS)})")
    try:
        return read_user_text(path), str(path)
    except UserInputError as exc:
        raise Refused("parse_error", f"uri {brief(uri)}: {exc}") from None


def brief(text: str, limit: int = 200) -> str:
    """repr of a request's string field, cut to ``limit`` characters (a field may be megabytes long)."""
    return repr(text) if len(text) <= limit else repr(text[:limit]) + f"... ({len(text)} characters)"


def warm_up() -> None:
    """Run in every new worker before its first job: one of each kind of entity, prepared and drawn and thrown
    away, so that the compiled kernels (the BVH build, the hull queries) are loaded from numba's cache and the
    mesh reader imported before a request waits for them."""
    from cgp_core.scene import WorldSpec

    world = WorldSpec()
    for entry in ({"body": {"shape": "mesh", "mesh": "rock.stl", "fixed": True}},
                  {"body": {"shape": "convex", "mesh": "rock.stl"}},
                  {"body": {"shape": "compound", "parts": [{"shape": "box", "size": [1, 1, 1]},
                                                           {"shape": "convex", "mesh": "rock.stl"}]}},
                  {"flock": {"count": 10}},
                  {"robot": {"urdf": "arm.urdf"}}):
        _prepare_entry(entry, world)


def _prepare_entry(entry: dict, world) -> None:
    from cgp_core.world import prepare_spawn

    from .drawing.bodies import model_drawings
    from .drawing.robots import visual_drawings

    try:
        prepared = prepare_spawn(entry, world, name="warm_up", taken=set(), position=(0.0, 0.0, 10.0),
                                 source="<warm-up>")
    except Exception:  # noqa: BLE001 - a warm-up that fails leaves the loading to the first request
        return
    if prepared.model is not None:
        model_drawings(prepared.model)
    if prepared.robot is not None:
        visual_drawings(prepared.robot.model)

"""A ``load_world`` request's expensive part, as a job for the node's worker process (:mod:`cgp_sim_ros.workers`),
as :mod:`cgp_sim_ros.spawning` is for a spawn: find the scene (a built-in name, a ``.yaml`` path or ``file://``
URI) or take its text (``resource_string``), read it bounded, parse and validate it (meshes read and their hulls
and BVHs built, URDFs parsed: :func:`cgp_core.scene.load_scene`) and draw its hulls and meshes.  The answer is a
:class:`LoadedScene` (the validated :class:`~cgp_core.scene.Scene` and the drawings, pickled together so that
the drawings stay keyed on the scene's own shape objects) or a :class:`~cgp_sim_ros.spawning.Refusal`.  The node
then builds the world from the scene between two ticks (:meth:`cgp_core.world.World.load`: milliseconds once
the kernels are loaded) — the old world keeps ticking until then, and stays if anything is refused.

ROS-free: the worker never imports rclpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote, urlparse

from .spawning import Refusal, brief

#: the formats load_world takes: cgp_sim's own scene files
WORLD_FORMATS = ("yaml",)


@dataclass(frozen=True)
class WorldRequest:
    uri: str  # a built-in scene name, a .yaml path or file:// URI; "" for resource
    resource: str  # the scene as YAML text (the request's resource_string)


@dataclass
class LoadedScene:
    """A validated scene, what its bodies' shapes are (``shapes``: the ``BodyModel.shape`` codes, for the kernels
    the node loads first) and their drawings (``(shape, drawing)`` pairs)."""

    scene: object
    shapes: object
    drawings: list = field(default_factory=list)


def scene_path(uri: str) -> str | Refusal:
    """What :func:`cgp_core.scene.load_scene` takes for a ``uri``: a built-in name as it is, a path or ``file://``
    URI as a path; a :class:`Refusal` (``unsupported_format``) for another scheme or another kind of file."""
    parsed = urlparse(uri)
    if parsed.scheme not in ("", "file"):
        return Refusal("unsupported_format", f"uri {brief(uri)}: worlds are loaded from local files (a path or "
                                             "file:// URI) or by a built-in scene's name")
    path = unquote(parsed.path) if parsed.scheme == "file" else uri
    suffix = Path(path).suffix.lower()
    if suffix and suffix not in (".yaml", ".yml"):
        return Refusal("unsupported_format", f"uri {brief(uri)}: a {suffix} file; cgp_sim loads its own YAML scene "
                                             "files (docs/scenes.md), not SDF, USD or MJCF")
    return path


def prepare_world(request: WorldRequest) -> LoadedScene | Refusal:
    """The worker's job (see the module docstring).  Refusal kinds: ``not_found`` (no such file or built-in
    scene), ``unsupported_format``, ``parse_error`` (reading, parsing or validating it: every problem named)."""
    from cgp_core.scene import SceneError, load_scene, parse_scene, resolve_scene

    from .drawing.bodies import model_drawings

    try:
        if request.uri:
            path = scene_path(request.uri)
            if isinstance(path, Refusal):
                return path
            try:
                resolved = resolve_scene(path)
            except SceneError as exc:
                return Refusal("not_found", str(exc))
            scene = load_scene(resolved)
        else:
            scene = parse_scene(request.resource, "resource_string")
    except SceneError as exc:
        return Refusal("parse_error", str(exc))
    model, _ = scene.build_bodies()
    return LoadedScene(scene, model.shape.copy(), model_drawings(model))

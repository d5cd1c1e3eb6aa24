"""What a robot's marker shows: its URDF ``<visual>`` geometry with the URDF's colours (issue 36).

Each visual (a :class:`cgp_core.robots.model.Geometry`, :meth:`cgp_core.robots.world.Robots.visuals`) becomes one
marker of namespace ``robots/<robot>``, drawn in ``world`` at the visual's pose (the link's forward kinematics
composed with the visual's ``<origin>``, :meth:`~cgp_core.robots.world.Robots.visual_poses`):

- ``box`` → CUBE, scale = its size; ``sphere`` → SPHERE, scale = its diameter; ``cylinder`` → CYLINDER, scale =
  (2 r, 2 r, length) (both URDF and the marker have the axis along z);
- ``mesh`` of a file cgp_sim reads (STL, OBJ: :func:`cgp_core.collision.meshfile.load_mesh`, a regular file
  read bounded) → TRIANGLE_LIST of the file's triangles in the visual's frame, the URDF's ``scale`` applied to
  the vertices (a mirroring scale reverses the winding, so the front stays outside), at most
  :data:`VISUAL_MESH_TRIANGLES` (vertex clustering, :func:`cgp_sim_ros.drawing.bodies.cluster_vertices`: a view
  only) in ``full`` detail and :data:`LOW_VISUAL_TRIANGLES` in ``low``.  Why TRIANGLE_LIST rather than
  MESH_RESOURCE: RViz and Foxglove both draw it with no setup, it is in the bag (a recording replays anywhere,
  ``cgp-sim-render`` draws it), while a MESH_RESOURCE URI must be readable by the viewer (``file://`` only on
  the machine that has the file, and not by Foxglove in a browser);
- ``mesh`` of a COLLADA ``.dae`` or binary glTF ``.glb`` file (the visual meshes of most ROS robot packages: UR,
  Panda ...): TRIANGLE_LIST the same way, the file read bounded (:func:`cgp_core.user_input.read_user_file`) and
  parsed by trimesh (pycollada for COLLADA), its scene graph's transforms applied, drawn in the URDF's colour
  (the file's own materials are not used).  A COLLADA file is XML from wherever a URDF pointed: one with a
  ``<!DOCTYPE`` or ``<!ENTITY`` is refused unparsed (COLLADA needs neither; lxml would resolve an external
  entity — a ``file:///etc/shadow`` — into the document);
- ``mesh`` of another format (``.3ds``, ``.gltf`` with external buffers ...): MESH_RESOURCE with the resolved
  file's ``file://`` URI and the URDF's ``scale`` (RViz reads it through assimp; Foxglove's desktop app reads
  ``file://``; a browser and ``cgp-sim-render`` do not draw it);
- a mesh file that cannot be read (missing, not a regular file, too big, malformed): nothing is drawn for that
  visual, and :attr:`VisualDrawing.problem` says why (the node logs it).

Colour: the visual's ``<material>`` (its own ``<color>``, or a material named in the robot), else
:data:`~cgp_core.robots.links.LINK_COLOR` (grey).  ROS-free, numpy.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cgp_core.robots.links import LINK_COLOR

from .bodies import cluster_vertices, triangle_points

#: a visual mesh's TRIANGLE_LIST has at most this many triangles in full detail (1.44 MB: it is re-sent with the
#: link's pose whenever the robot is drawn)
VISUAL_MESH_TRIANGLES = 20_000
#: ... and in low detail (the level of detail's rule 4, as the hulls': cgp_sim_ros/drawing/detail.py)
LOW_VISUAL_TRIANGLES = 500
#: the kinds of :class:`VisualDrawing`
KINDS = ("box", "sphere", "cylinder", "triangles", "mesh_resource", "none")
_NO_POINTS = np.zeros((0, 3))
#: the mesh formats read through trimesh (self-contained files only): suffix -> trimesh's file type
TRIMESH_TYPES = {".dae": "dae", ".glb": "glb"}


@dataclass
class VisualDrawing:
    """One visual's marker, in the visual's frame.

    kind:   one of :data:`KINDS` (``"none"``: not drawn, see ``problem``).
    scale:  (3,) the marker's scale [m]: a box's size, a sphere's diameter (x3), a cylinder's (2 r, 2 r, length);
            ones for triangles (the URDF scale is in the points); a MESH_RESOURCE's URDF scale.
    color:  (4,) RGBA in [0, 1].
    full, low: (3t, 3) [m] TRIANGLE_LIST points at both details (empty but for ``triangles``).
    uri:    a MESH_RESOURCE's ``file://`` URI ('' otherwise).
    triangles, of: the triangles drawn in full detail and the file's (fewer drawn when clustered).
    problem: why nothing is drawn ('' otherwise).
    """

    kind: str
    scale: np.ndarray
    color: np.ndarray
    full: np.ndarray
    low: np.ndarray
    uri: str = ""
    triangles: int = 0
    of: int = 0
    problem: str = ""

    def points(self, detail: str) -> np.ndarray:
        return self.low if detail == "low" else self.full


def visual_color(geometry) -> np.ndarray:
    """(4,) the visual's URDF colour, or the grey of a link without one."""
    rgba = geometry.rgba if geometry.rgba is not None else LINK_COLOR
    return np.asarray(rgba, dtype=float).copy()


def visual_drawing(geometry) -> VisualDrawing:
    """The :class:`VisualDrawing` of one URDF visual (module docstring)."""
    from cgp_core.collision.meshfile import FILE_TYPES

    color = visual_color(geometry)
    size = np.asarray(geometry.size, dtype=float).ravel()
    if geometry.kind == "box":
        return VisualDrawing("box", size[:3].copy(), color, _NO_POINTS, _NO_POINTS)
    if geometry.kind == "sphere":
        return VisualDrawing("sphere", np.full(3, 2.0 * size[0]), color, _NO_POINTS, _NO_POINTS)
    if geometry.kind == "cylinder":
        return VisualDrawing("cylinder", np.array([2.0 * size[0], 2.0 * size[0], size[1]]), color, _NO_POINTS,
                             _NO_POINTS)
    scale = np.asarray(geometry.mesh_scale, dtype=float)
    path = geometry.mesh_path
    if path is None:
        return VisualDrawing("none", np.ones(3), color, _NO_POINTS, _NO_POINTS,
                             problem=f"link {geometry.link}: a mesh visual without a file")
    suffix = Path(path).suffix.lower()
    if suffix not in FILE_TYPES and suffix not in TRIMESH_TYPES:
        return VisualDrawing("mesh_resource", scale.copy(), color, _NO_POINTS, _NO_POINTS,
                             uri=Path(path).absolute().as_uri())
    return _mesh_drawing(geometry.link, path, scale, color)


def read_trimesh_file(path: str) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (V, 3), triangles (T, 3))`` of a COLLADA or binary glTF file (:data:`TRIMESH_TYPES`), every
    geometry of its scene at its scene-graph pose.  Raises :class:`~cgp_core.collision.meshfile.MeshFileError`
    naming the file and the reason: not a regular file, too big, a DTD or entity in a COLLADA file, a file
    trimesh cannot parse, no triangles, too many."""
    import io

    from cgp_core.collision.meshfile import MeshFileError
    from cgp_core.limits import MAX_MESH_FILE_BYTES, MAX_MESH_TRIANGLES, MAX_MESH_VERTICES
    from cgp_core.user_input import UserInputError, read_user_file

    file_type = TRIMESH_TYPES[Path(path).suffix.lower()]
    try:
        data = read_user_file(path, max_bytes=MAX_MESH_FILE_BYTES)
    except UserInputError as exc:
        raise MeshFileError(f"mesh file {path}: {exc}") from None
    head = data.lower()
    if file_type == "dae" and (b"<!doctype" in head or b"<!entity" in head):
        raise MeshFileError(f"mesh file {path}: a COLLADA file with a <!DOCTYPE> or <!ENTITY> is refused "
                            "(COLLADA needs neither; an entity could pull another file into the document)")
    try:
        import trimesh

        mesh = trimesh.load(io.BytesIO(data), file_type=file_type, force="mesh", process=False)
        vertices = np.asarray(mesh.vertices, dtype=float)
        triangles = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    except Exception as exc:  # noqa: BLE001 - any parser failure is the file's: named, never raised on
        raise MeshFileError(f"mesh file {path}: trimesh could not read it as {file_type} "
                            f"({type(exc).__name__})") from None
    if not len(triangles):
        raise MeshFileError(f"mesh file {path}: no triangles")
    if len(triangles) > MAX_MESH_TRIANGLES or len(vertices) > MAX_MESH_VERTICES:
        raise MeshFileError(f"mesh file {path}: {len(triangles)} triangles and {len(vertices)} vertices, more "
                            f"than the {MAX_MESH_TRIANGLES} / {MAX_MESH_VERTICES} allowed")
    if not np.isfinite(vertices).all():
        raise MeshFileError(f"mesh file {path}: vertices that are not finite numbers")
    return vertices, triangles


def _mesh_drawing(link: str, path: str, scale: np.ndarray, color: np.ndarray) -> VisualDrawing:
    from cgp_core.collision.meshfile import MeshFileError, load_mesh

    try:
        if Path(path).suffix.lower() in TRIMESH_TYPES:
            vertices, triangles = read_trimesh_file(path)
        else:
            vertices, triangles = load_mesh(path)  # a regular file only, read bounded (cgp_core.user_input)
    except MeshFileError as exc:
        return VisualDrawing("none", np.ones(3), color, _NO_POINTS, _NO_POINTS,
                             problem=f"link {link}: visual not drawn: {exc}")
    vertices = np.asarray(vertices, dtype=float) * scale
    triangles = np.asarray(triangles, dtype=np.int64)
    if np.prod(np.sign(scale)) < 0:  # a mirror turns counter-clockwise into clockwise: wind the other way
        triangles = triangles[:, ::-1]
    count = len(triangles)
    full = _at_most(vertices, triangles, VISUAL_MESH_TRIANGLES)
    low = full if len(full) // 3 <= LOW_VISUAL_TRIANGLES else _at_most(vertices, triangles, LOW_VISUAL_TRIANGLES)
    return VisualDrawing("triangles", np.ones(3), color, full, low, triangles=len(full) // 3, of=count)


def _at_most(vertices: np.ndarray, triangles: np.ndarray, limit: int) -> np.ndarray:
    """(3t, 3) TRIANGLE_LIST points of the mesh, clustered to at most ``limit`` triangles if it has more."""
    if len(triangles) > limit:
        vertices, triangles = cluster_vertices(vertices, triangles, limit)
    return triangle_points(vertices, triangles)


def robot_geometries(robots) -> list:
    """Every visual :class:`~cgp_core.robots.model.Geometry` of a world's robots (``World.robots``, None: none)."""
    if robots is None:
        return []
    return [g for name in robots.names() for g in robots.visuals(name)]


def visual_drawings(model) -> list[tuple[object, VisualDrawing]]:
    """``(geometry, drawing)`` of every visual of a :class:`~cgp_core.robots.model.RobotModel`: what the spawn
    worker sends with a spawned robot (:class:`~cgp_sim_ros.drawing.bodies.Drawings` keeps them)."""
    return [(g, visual_drawing(g)) for per_body in model.visuals for g in per_body]

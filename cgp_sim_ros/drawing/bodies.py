"""What a body's marker shows of its shape: the triangles of hulls and static meshes, at a bounded size (issue 38).

A convex hull is drawn as a TRIANGLE_LIST of its triangles (in the body's or the part's frame), 72 bytes per
triangle, on every tick the body is drawn: 300 bodies with 1,000-vertex hulls made ``~/markers`` 43 MB per tick.
A static mesh is drawn once (``~/static_markers``, latched), but a 500,000-triangle mesh is 36 MB.  So each shape
is drawn at a *level of detail* chosen by :mod:`cgp_sim_ros.drawing.detail`, from the versions made here:

- a hull: ``full`` (its own triangles) or ``low``: the hull of its extreme vertices in the 26 directions of
  :data:`LOW_HULL_DIRECTIONS` (the faces, edges and corners of a cube), at most 48 triangles — the same outline
  seen along the axes and diagonals, inside the true hull;
- a static mesh: at most :data:`STATIC_MESH_TRIANGLES` triangles, by vertex clustering (Rossignac and Borrel
  1993: vertices in one cell of a grid merged into their mean, the triangles that collapse dropped, the grid
  made coarser until the mesh fits) — a view only: contacts use the mesh itself.

These are made where the shape is made: in the spawn worker process for a spawned body
(:func:`model_drawings`, :mod:`cgp_sim_ros.spawning`), and at start-up for the scene's bodies; :class:`Drawings`
keeps them by shape object for the node's marker serializers.  ROS-free, numpy (and qhull through
:func:`cgp_core.collision.convex.convex_hull`).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from cgp_core.bodies import Shape

#: the directions whose extreme vertices make a hull's ``low`` version: the 26 neighbours of a cell in a 3 x 3 x 3
#: grid (unit vectors)
LOW_HULL_DIRECTIONS = np.array([d for d in itertools.product((-1.0, 0.0, 1.0), repeat=3) if any(d)])
LOW_HULL_DIRECTIONS /= np.linalg.norm(LOW_HULL_DIRECTIONS, axis=1)[:, None]
#: a static mesh's marker has at most this many triangles (7.2 MB)
STATIC_MESH_TRIANGLES = 100_000
#: the clustering grid grows by this factor per try until the mesh fits (at most MAX_CLUSTER_TRIES tries; then
#: every k-th triangle is kept)
CLUSTER_GROWTH = 1.3
MAX_CLUSTER_TRIES = 24


@dataclass
class HullDrawing:
    """A hull's TRIANGLE_LIST points, counter-clockwise seen from outside, in the hull's frame.

    full: (3t, 3) float — its own triangles.
    low:  (3l, 3) float — the hull of its extreme vertices in LOW_HULL_DIRECTIONS (``full`` itself when that is
          no larger).
    """

    full: np.ndarray
    low: np.ndarray

    def points(self, detail: str) -> np.ndarray:
        return self.low if detail == "low" else self.full


@dataclass
class MeshDrawing:
    """A static mesh's marker: ``points`` (3t, 3) float, TRIANGLE_LIST in the mesh's frame, ``triangles`` = t of
    the mesh's ``of`` (fewer when clustered)."""

    points: np.ndarray
    triangles: int
    of: int


def triangle_points(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(3t, 3) the triangles as TRIANGLE_LIST points (their winding kept)."""
    return np.ascontiguousarray(np.asarray(vertices, dtype=float)[np.asarray(triangles)].reshape(-1, 3))


def hull_drawing(hull) -> HullDrawing:
    """Both versions of a :class:`~cgp_core.collision.convex.ConvexPolyhedron`'s marker."""
    from cgp_core.collision.convex import HullError, convex_hull

    full = triangle_points(hull.vertices, hull.triangles)
    if len(hull.triangles) <= 2 * len(LOW_HULL_DIRECTIONS) - 4:
        return HullDrawing(full, full)
    extreme = np.unique(np.argmax(hull.vertices @ LOW_HULL_DIRECTIONS.T, axis=0))
    try:
        low = convex_hull(hull.vertices[extreme], what="the low-detail hull")
    except HullError:  # (a very flat hull: its extreme points may not span a volume) drawn in full
        return HullDrawing(full, full)
    return HullDrawing(full, triangle_points(low.vertices, low.triangles))


def mesh_drawing(mesh, max_triangles: int = STATIC_MESH_TRIANGLES) -> MeshDrawing:
    """A :class:`~cgp_core.collision.bvh.StaticMesh`'s marker with at most ``max_triangles`` triangles."""
    vertices, triangles = np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.triangles)
    count = len(triangles)
    if count <= max_triangles:
        return MeshDrawing(triangle_points(vertices, triangles), count, count)
    clustered = cluster_vertices(vertices, triangles, max_triangles)
    return MeshDrawing(triangle_points(*clustered), len(clustered[1]), count)


def cluster_vertices(vertices: np.ndarray, triangles: np.ndarray, max_triangles: int) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices, triangles)`` of a mesh simplified to at most ``max_triangles`` triangles by vertex clustering
    (see the module docstring): the first grid's cell is the edge of an equilateral triangle of the mesh's mean
    area per allowed triangle, grown by CLUSTER_GROWTH until the result fits."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    area = 0.5 * float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    extent = float(np.max(high - low))
    cell = max(np.sqrt(4.0 * area / (np.sqrt(3.0) * max_triangles)), extent * 1e-6, 1e-12)
    for _ in range(MAX_CLUSTER_TRIES):
        merged_vertices, merged = _cluster(vertices, triangles, low, cell)
        if len(merged) <= max_triangles:
            return merged_vertices, merged
        cell *= CLUSTER_GROWTH
    stride = -(-len(merged) // max_triangles)  # (a mesh the grid cannot reduce: every k-th triangle)
    return merged_vertices, merged[::stride]


def _cluster(vertices, triangles, origin, cell) -> tuple[np.ndarray, np.ndarray]:
    keys = np.floor((vertices - origin) / cell).astype(np.int64)
    _, index, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    index = index.reshape(-1)
    merged_vertices = np.stack([np.bincount(index, weights=vertices[:, k], minlength=len(counts)) for k in range(3)],
                               axis=1) / counts[:, None]
    merged = index[triangles]
    kept = (merged[:, 0] != merged[:, 1]) & (merged[:, 1] != merged[:, 2]) & (merged[:, 0] != merged[:, 2])
    merged = merged[kept]
    _, first = np.unique(np.sort(merged, axis=1), axis=0, return_index=True)  # a triangle twice: once
    return merged_vertices, merged[np.sort(first)]


def model_shapes(model):
    """Every hull (a convex body's, a compound part's) and static mesh of a :class:`~cgp_core.bodies.BodyModel`,
    as ``(kind, shape object)``: ``"hull"`` or ``"mesh"``."""
    for i in range(model.count):
        shape = int(model.shape[i])
        if shape == Shape.CONVEX and model.hulls[i] is not None:
            yield "hull", model.hulls[i]
        elif shape == Shape.COMPOUND and model.parts[i] is not None:
            yield from (("hull", hull) for hull in model.parts[i].hulls if hull is not None)
        elif shape == Shape.MESH and model.meshes[i] is not None:
            yield "mesh", model.meshes[i]


def model_drawings(model) -> list[tuple[object, object]]:
    """``(shape object, drawing)`` for every shape of :func:`model_shapes`: what :class:`Drawings` keeps."""
    return [(shape, hull_drawing(shape) if kind == "hull" else mesh_drawing(shape))
            for kind, shape in model_shapes(model)]


class Drawings:
    """The drawings of the shapes a world holds, by shape object (a hull or mesh object — or a robot's visual
    geometry — is shared by the model, its copies and resets: its drawing is made once).  A shape without one
    gets it made on first use (on the calling thread: the scene's bodies at start-up); spawned bodies bring
    theirs from the worker."""

    def __init__(self):
        self._by_id: dict[int, tuple[object, object]] = {}  # id(shape) -> (shape: kept alive, drawing)

    def add(self, pairs) -> None:
        for shape, drawing in pairs:
            self._by_id[id(shape)] = (shape, drawing)

    def hull(self, hull) -> HullDrawing:
        entry = self._by_id.get(id(hull))
        if entry is None:
            entry = self._by_id[id(hull)] = (hull, hull_drawing(hull))
        return entry[1]

    def mesh(self, mesh) -> MeshDrawing:
        entry = self._by_id.get(id(mesh))
        if entry is None:
            entry = self._by_id[id(mesh)] = (mesh, mesh_drawing(mesh))
        return entry[1]

    def of(self, shape, make):
        """The drawing of any other shape object — a robot's visual geometry, ``make`` =
        :func:`cgp_sim_ros.drawing.robots.visual_drawing` —, made by ``make(shape)`` on first use (a visual's mesh
        file read then: the scene's robots at start-up; spawned ones bring theirs from the worker)."""
        entry = self._by_id.get(id(shape))
        if entry is None:
            entry = self._by_id[id(shape)] = (shape, make(shape))
        return entry[1]

    def keep(self, shapes) -> None:
        """Forget the drawings of every shape not in ``shapes`` (those of deleted bodies)."""
        alive = {id(shape) for shape in shapes}
        self._by_id = {k: v for k, v in self._by_id.items() if k in alive}

    def __len__(self) -> int:
        return len(self._by_id)

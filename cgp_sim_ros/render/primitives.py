"""From markers to what the rasterizer draws: triangles and spheres in the world frame.

:class:`MarkerSet` keeps the markers a viewer would show at a given time (RViz's rules: a marker is keyed by
``(ns, id)``; ADD/MODIFY replace it, DELETE removes it, DELETEALL removes every marker — or those of its
``ns`` when given, as ``visualization_msgs/Marker`` documents); ``lifetime`` is not applied (the node's markers
never expire).  :class:`Transforms` holds the bag's TF (``/tf``, ``/tf_static``) as a viewer's TF buffer would, and
:meth:`Transforms.place` puts a marker whose frame is a TF child frame — the node draws every body once, in its own
frame, ``frame_locked`` (issue 37) — into the root frame (``world``) with the latest transform, as RViz and Foxglove
do for frame-locked markers; a marker in a frame TF has not given yet is not drawn (a viewer cannot place it
either); the others are taken to be in the root frame.

:func:`primitives` turns the set into :class:`Primitives`:

- SPHERE, SPHERE_LIST → spheres (drawn as exact shaded spheres by the rasterizer, not tessellated);
- CUBE, CUBE_LIST → 12 triangles per box; a face larger than :data:`TILE` m is cut into a checkerboard of
  TILE-sized tiles (the ground: it shows scale and motion, and near-plane clipping then loses one tile, not
  the whole face);
- CYLINDER → :data:`CYLINDER_SEGMENTS` side quads and two caps (the node's capsules are a CYLINDER and two
  SPHEREs);
- TRIANGLE_LIST → its triangles (the fish), coloured per triangle, per vertex (the first vertex's) or by the
  marker colour;
- ARROW → a shaft (:data:`ARROW_SEGMENTS` side quads) and a cone, as RViz draws it: from ``points[0]`` to
  ``points[1]`` with shaft diameter ``scale.x``, head diameter ``scale.y`` and head length ``scale.z`` (the contact
  force arrows); without points, along the pose's x axis, ``scale.x`` long and ``scale.y`` wide.

Other types (lines, points, text, meshes) are not drawn; :attr:`Primitives.skipped` names them.
A marker with alpha 0 is invisible; other alphas are drawn opaque.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from cgp_core.rotation import quat_multiply, quat_rotate, quat_to_matrix

from ..wire import cdr

#: the namespace of the node's ground marker: drawn (as a checkerboard), but not framed by the default camera
BACKDROP_NS = "ground"
#: edge [m] of the checkerboard tiles large box faces are cut into
TILE = 2.0
#: how much lighter / darker the two tile colours are (the ground's checkerboard)
CHECKER_CONTRAST = 0.06
CYLINDER_SEGMENTS = 24
ARROW_SEGMENTS = 12
#: head length / arrow length where the marker does not give it (RViz's proportion for pose arrows)
ARROW_HEAD_SHARE = 0.23
TYPE_NAMES = {0: "ARROW", 1: "CUBE", 2: "SPHERE", 3: "CYLINDER", 4: "LINE_STRIP", 5: "LINE_LIST", 6: "CUBE_LIST",
              7: "SPHERE_LIST", 8: "POINTS", 9: "TEXT_VIEW_FACING", 10: "MESH_RESOURCE", 11: "TRIANGLE_LIST",
              12: "ARROW_STRIP"}


class MarkerSet:
    """The markers on display, keyed by ``(ns, id)`` in the order they were first added."""

    def __init__(self) -> None:
        self.markers: dict[tuple[str, int], cdr.MarkerData] = {}

    def apply(self, markers: list[cdr.MarkerData]) -> None:
        for m in markers:
            if m.action == cdr.DELETEALL:
                if m.ns:
                    for key in [k for k in self.markers if k[0] == m.ns]:
                        del self.markers[key]
                else:
                    self.markers.clear()
            elif m.action == cdr.DELETE:
                self.markers.pop((m.ns, m.id), None)
            else:  # ADD / MODIFY
                self.markers[(m.ns, m.id)] = m

    def __len__(self) -> int:
        return len(self.markers)


class Transforms:
    """The latest transform of every TF child frame (``child -> cdr.TransformData``), from TFMessages applied in
    log-time order."""

    #: the longest chain of parent frames followed (a cycle in a damaged bag ends there)
    MAX_DEPTH = 64

    def __init__(self) -> None:
        self.frames: dict[str, cdr.TransformData] = {}

    def apply(self, transforms: list[cdr.TransformData]) -> None:
        for t in transforms:
            self.frames[t.child] = t

    def place(self, markers) -> list[cdr.MarkerData]:
        """``markers`` with those in a TF child frame moved into its root frame; those in a frame TF has not given
        (frame_locked ones: the node's bodies before their first transform) left out."""
        out = []
        for m in markers:
            if m.frame_id not in self.frames:
                if not m.frame_locked:
                    out.append(m)
                continue
            position, orientation = np.asarray(m.position, dtype=float), np.asarray(m.orientation, dtype=float)
            if not np.any(orientation):
                orientation = np.array([0.0, 0.0, 0.0, 1.0])
            frame = m.frame_id
            for _ in range(self.MAX_DEPTH):
                t = self.frames.get(frame)
                if t is None:
                    break
                q = t.rotation / (np.linalg.norm(t.rotation) or 1.0)
                position = quat_rotate(q, position) + t.translation
                orientation = quat_multiply(q, orientation)
                frame = t.parent
            out.append(replace(m, frame_id=frame, position=position, orientation=orientation))
        return out


@dataclass
class Primitives:
    """World-frame geometry of one frame.

    triangles: (T, 3, 3) vertices; triangle_colors: (T, 3) RGB in [0, 1].
    sphere_centers: (S, 3); sphere_radii: (S,); sphere_colors: (S, 3).
    closed: (T,) bool, triangles of closed surfaces wound counter-clockwise seen from outside (boxes,
        cylinders), which the rasterizer may cull when they face away from the camera.
    skipped: names of marker types present but not drawn.
    """

    triangles: np.ndarray
    triangle_colors: np.ndarray
    sphere_centers: np.ndarray
    sphere_radii: np.ndarray
    sphere_colors: np.ndarray
    closed: np.ndarray
    skipped: set[str] = field(default_factory=set)


def _rgb(color: np.ndarray, n: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(color, dtype=np.float64)[:3], (n, 3))


#: tiles along one side of a box face at most: a face longer than this many ``tile`` gets larger tiles (a marker's
#: scale comes from a bag, any float: make fuzz found a 2³² m cube asking for 4·10⁹ tiles)
MAX_TILES_PER_SIDE = 64


def _tiles(extent: float, tile: float) -> int:
    """How many tiles a face side of length ``extent`` is cut into: ⌈extent / tile⌉, 1 for a side no longer than a
    tile or not finite, at most :data:`MAX_TILES_PER_SIDE`."""
    if not (np.isfinite(extent) and extent > tile):
        return 1
    return int(min(MAX_TILES_PER_SIDE, np.ceil(extent / tile)))


def _box_triangles(half: np.ndarray, tile: float) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of an axis-aligned box of half extents ``half`` about the origin, wound counter-clockwise
    seen from outside, and a per-triangle checker sign (+1 / -1; 0 where the face is one tile).  Faces are cut
    into tiles when larger than ``tile`` (:func:`_tiles`)."""
    tris, signs = [], []
    for axis in range(3):
        u, v = (axis + 1) % 3, (axis + 2) % 3
        nu, nv = _tiles(2 * half[u], tile), _tiles(2 * half[v], tile)
        gu = np.linspace(-half[u], half[u], nu + 1)
        gv = np.linspace(-half[v], half[v], nv + 1)
        iu, iv = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
        iu, iv = iu.ravel(), iv.ravel()
        checker = np.where((iu + iv) % 2 == 0, 1.0, -1.0) if nu * nv > 1 else np.zeros(len(iu))
        for side in (-1.0, 1.0):
            corners = np.zeros((len(iu), 4, 3))
            corners[:, :, axis] = side * half[axis]
            corners[:, 0, u], corners[:, 0, v] = gu[iu], gv[iv]
            corners[:, 1, u], corners[:, 1, v] = gu[iu + 1], gv[iv]
            corners[:, 2, u], corners[:, 2, v] = gu[iu + 1], gv[iv + 1]
            corners[:, 3, u], corners[:, 3, v] = gu[iu], gv[iv + 1]
            # (u, v, axis) is right-handed: 0-1-2 is counter-clockwise seen from +axis; reversed on the - side
            order = ([0, 1, 2], [0, 2, 3]) if side > 0 else ([0, 2, 1], [0, 3, 2])
            tris.append(corners[:, order[0]])
            tris.append(corners[:, order[1]])
            signs += [checker, checker]
    return np.concatenate(tris), np.concatenate(signs)


def _cylinder_triangles(rx: float, ry: float, half_h: float, segments: int) -> np.ndarray:
    angle = np.linspace(0.0, 2 * np.pi, segments + 1)
    ring = np.stack([rx * np.cos(angle), ry * np.sin(angle)], axis=1)  # (segments + 1, 2)
    a, b = ring[:-1], ring[1:]
    lo = lambda p: np.column_stack([p, np.full(len(p), -half_h)])  # noqa: E731
    hi = lambda p: np.column_stack([p, np.full(len(p), half_h)])  # noqa: E731
    side1 = np.stack([lo(a), lo(b), hi(b)], axis=1)
    side2 = np.stack([lo(a), hi(b), hi(a)], axis=1)
    zeros = np.zeros((segments, 2))
    top = np.stack([hi(zeros), hi(a), hi(b)], axis=1)
    bottom = np.stack([lo(zeros), lo(b), lo(a)], axis=1)
    return np.concatenate([side1, side2, top, bottom])


def _arrow_triangles(start: np.ndarray, end: np.ndarray, shaft: float, head: float, head_length: float,
                     segments: int) -> np.ndarray:
    """An arrow from ``start`` to ``end`` (3,): a shaft of diameter ``shaft`` and a cone of diameter ``head`` and
    length ``head_length`` (at most the arrow's), as triangles (T, 3, 3); none for a zero-length arrow."""
    axis = end - start
    length = float(np.linalg.norm(axis))
    if length <= 0.0:
        return np.zeros((0, 3, 3))
    z = axis / length
    x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    cone = min(head_length, length)
    angle = np.linspace(0.0, 2 * np.pi, segments + 1)
    ring = np.outer(np.cos(angle), x) + np.outer(np.sin(angle), y)  # (segments + 1, 3) unit ring
    base, neck = start, start + (length - cone) * z
    s0, s1 = base + 0.5 * shaft * ring, neck + 0.5 * shaft * ring
    c0 = neck + 0.5 * head * ring
    a, b = slice(0, segments), slice(1, segments + 1)
    rep = lambda p: np.broadcast_to(p, (segments, 3))  # noqa: E731
    return np.concatenate([np.stack([s0[a], s0[b], s1[b]], 1), np.stack([s0[a], s1[b], s1[a]], 1),  # shaft
                           np.stack([rep(base), s0[b], s0[a]], 1),  # its end
                           np.stack([c0[a], c0[b], rep(end)], 1), np.stack([rep(neck), c0[b], c0[a]], 1)])  # cone


def _to_world(m: cdr.MarkerData, local: np.ndarray) -> np.ndarray:
    """Marker-frame points (..., 3) to the world: p + R(q) local."""
    q = m.orientation
    R = quat_to_matrix(q / np.linalg.norm(q)) if np.any(q) else np.eye(3)
    return local @ R.T + m.position


#: point lists longer than this are framed by the box of their FRAMING_QUANTILE .. 1 - FRAMING_QUANTILE
#: quantiles (so that one boid far from its flock does not shrink everything else)
FRAMING_MANY_POINTS = 50
FRAMING_QUANTILE = 0.02


def extent_points(markers: MarkerSet | list[cdr.MarkerData]) -> np.ndarray:
    """(n, 3) world points whose bounding box the default camera fits: the corners of each marker's box —
    for long point lists (flocks) the box of the central 96 % of the points; markers of the backdrop
    namespace (the ground) and invisible ones left out."""
    items = markers.markers.values() if isinstance(markers, MarkerSet) else markers
    out = [np.zeros((0, 3))]
    for m in items:
        if m.ns == BACKDROP_NS or m.action != cdr.ADD or (m.color[3] <= 0.0 and not len(m.colors)):
            continue
        half = 0.5 * np.abs(np.asarray(m.scale, dtype=float))
        if m.type in (cdr.SPHERE, cdr.CUBE, cdr.CYLINDER):
            local = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half
            out.append(_to_world(m, local))
        elif len(m.points) and m.type in (cdr.SPHERE_LIST, cdr.CUBE_LIST, cdr.TRIANGLE_LIST, cdr.POINTS):
            world = _to_world(m, m.points)
            if len(world) > FRAMING_MANY_POINTS:
                lo, hi = np.quantile(world, [FRAMING_QUANTILE, 1 - FRAMING_QUANTILE], axis=0)
            else:
                lo, hi = world.min(axis=0), world.max(axis=0)
            pad = half if m.type != cdr.TRIANGLE_LIST else 0.0
            out.append(np.array([lo - pad, hi + pad]))
    return np.concatenate(out)


def primitives(markers: MarkerSet | list[cdr.MarkerData], tile: float = TILE) -> Primitives:
    """The triangles and spheres of the markers on display (see the module docstring)."""
    items = markers.markers.values() if isinstance(markers, MarkerSet) else markers
    tris, tri_colors, centers, radii, sphere_colors, closed = [], [], [], [], [], []
    skipped: set[str] = set()
    for m in items:
        if m.color[3] <= 0.0 and not len(m.colors):
            continue
        kind = m.type
        if kind == cdr.SPHERE:
            centers.append(m.position[None, :])
            radii.append(np.array([0.5 * float(np.mean(m.scale))]))
            sphere_colors.append(_rgb(m.color, 1))
        elif kind == cdr.SPHERE_LIST:
            n = len(m.points)
            centers.append(_to_world(m, m.points))
            radii.append(np.full(n, 0.5 * float(np.mean(m.scale))))
            sphere_colors.append(m.colors[:, :3].astype(np.float64) if len(m.colors) == n else _rgb(m.color, n))
        elif kind in (cdr.CUBE, cdr.CUBE_LIST):
            local, checker = _box_triangles(0.5 * np.asarray(m.scale, dtype=float), tile)
            if kind == cdr.CUBE:
                tris.append(_to_world(m, local))
                shade = 1.0 + CHECKER_CONTRAST * checker[:, None] * (m.ns == BACKDROP_NS)
                tri_colors.append(np.clip(_rgb(m.color, len(local)) * shade, 0.0, 1.0))
            else:
                n = len(m.points)
                boxes = _to_world(m, m.points[:, None, None, :] + local[None])  # (n, T, 3, 3)
                tris.append(boxes.reshape(-1, 3, 3))
                per_box = m.colors[:, :3].astype(np.float64) if len(m.colors) == n else _rgb(m.color, n)
                tri_colors.append(np.repeat(per_box, len(local), axis=0))
        elif kind == cdr.CYLINDER:
            local = _cylinder_triangles(0.5 * m.scale[0], 0.5 * m.scale[1], 0.5 * m.scale[2], CYLINDER_SEGMENTS)
            tris.append(_to_world(m, local))
            tri_colors.append(_rgb(m.color, len(local)))
        elif kind == cdr.TRIANGLE_LIST:
            n = len(m.points) // 3
            tris.append(_to_world(m, m.points[: 3 * n]).reshape(n, 3, 3))
            if len(m.colors) == 3 * n:
                tri_colors.append(m.colors[::3, :3].astype(np.float64))
            elif len(m.colors) == n:
                tri_colors.append(m.colors[:, :3].astype(np.float64))
            else:
                tri_colors.append(_rgb(m.color, n))
        elif kind == cdr.ARROW:
            sx, sy, sz = (float(v) for v in m.scale)
            if len(m.points) >= 2:
                start, end = _to_world(m, m.points[:2])
                local = _arrow_triangles(start, end, sx, sy, sz, ARROW_SEGMENTS)
            else:
                start, end = _to_world(m, np.array([[0.0, 0.0, 0.0], [sx, 0.0, 0.0]]))
                local = _arrow_triangles(start, end, sy, 2.0 * sy, ARROW_HEAD_SHARE * sx, ARROW_SEGMENTS)
            tris.append(local)
            tri_colors.append(_rgb(m.color, len(local)))
        else:
            skipped.add(TYPE_NAMES.get(kind, str(kind)))
        drawn = sum(len(t) for t in tris) - sum(len(c) for c in closed)
        if drawn:
            closed.append(np.full(drawn, kind in (cdr.CUBE, cdr.CUBE_LIST, cdr.CYLINDER)))
    cat = lambda parts, shape: np.concatenate(parts) if parts else np.zeros(shape)  # noqa: E731
    return Primitives(
        triangles=cat(tris, (0, 3, 3)), triangle_colors=cat(tri_colors, (0, 3)),
        sphere_centers=cat(centers, (0, 3)), sphere_radii=cat(radii, (0,)), sphere_colors=cat(sphere_colors, (0, 3)),
        closed=cat(closed, (0,)).astype(bool), skipped=skipped)

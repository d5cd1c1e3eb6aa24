"""A bounding-volume hierarchy over the triangles of a static mesh (Ericson ch. 6: an AABB tree), and the mesh
data the narrow phase needs.

**Build** (:func:`build_bvh`, compiled): top-down (Ericson 6.2.1).  A node's triangles are split in two by the
*binned surface-area heuristic* (Wald, "On fast Construction of SAH-based Bounding Volume Hierarchies", 2007;
Ericson 6.2.1.2's cost model): their centroids are dropped into :data:`SAH_BINS` bins along the longest axis of the
centroids' bounds, and the split between bins that minimizes area(left)·count(left) + area(right)·count(right) is
taken — the expected cost of a query that reaches the node.  Where the centroids coincide along that axis or SAH
puts all triangles on one side, the node is split at the median instead (Ericson 6.2.1.1).  A node of at most
:data:`LEAF_SIZE` triangles is a leaf.  Why SAH rather than the median alone: on a terrain with triangles of equal
size both give similar trees, but for meshes with triangles of very different sizes (a detailed object on a
plain) SAH's boxes are much tighter, and the build stays O(T log T).

**Layout** (flattened; node 0 is the root; children are allocated in pairs, so the right child of ``c`` is
``c + 1``):

    node_lo, node_hi       (N, 3)  float — the node's box
    node_child_or_first    (N,)    int64 — internal node: its left child; leaf: first slot in ``triangle_order``
    node_count             (N,)    int64 — leaf: its number of triangles (≥ 1); internal node: 0
    triangle_order         (T,)    int64 — slot → triangle index (a leaf's triangles are consecutive slots)
    triangle_lo, triangle_hi (T, 3) float — every triangle's own box (by triangle index)

**Queries** (compiled, traversal with an explicit stack, Ericson 6.3): :func:`bvh_overlap` (the triangles whose
boxes overlap a box: what the narrow phase asks for a body's bounds), :func:`bvh_closest_point` (the closest
point of the mesh to a point: sphere–mesh, boids avoiding a mesh; nearest child first, pruned by the box
distance), :func:`bvh_raycast` (the first hit of a segment: slab test for the boxes, Ericson 5.3.3; Möller–Trumbore
for the triangles).

**Active edges** (:func:`active_edges`): a triangle's edge is *active* if it is a boundary edge or a convex edge
whose two triangles' normals differ by more than :data:`.manifold.ACTIVE_EDGE_ANGLE`; a flat or concave edge is
inactive (nothing can touch it without touching a face first), and the manifold uses the face normal for
contacts on it (internal-edge "ghost" collisions; Jolt's active edges).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..jit import njit
from .gjk import closest_on_triangle
from .manifold import ACTIVE_EDGE_ANGLE

#: triangles in a leaf (at most)
LEAF_SIZE = 4
#: SAH bins along the split axis
SAH_BINS = 16
#: nodes deeper than this are split at the median, never by SAH: SAH may cut one triangle off a node per level (a
#: mesh whose triangles sit at geometrically growing coordinates made a tree 327 levels deep, issue 38), the
#: median halves the node, so a tree is at most SAH_DEPTH + log2(T / LEAF_SIZE) levels deep
SAH_DEPTH = 40
#: the deepest a tree can be (root: depth 0), for any T < 2^63: the bound by construction of :func:`build_bvh`
MAX_DEPTH = SAH_DEPTH + 61
#: a depth-first traversal that pops one node and pushes its two children holds at most one pending node per
#: level above the current one, plus the two just pushed: at most MAX_DEPTH + 1 nodes
STACK_DEPTH = MAX_DEPTH + 1


class BvhTree(NamedTuple):
    """The tree :func:`build_bvh` gives (see the module docstring's layout)."""

    node_lo: np.ndarray              # (N, 3) the node's box, lower corner
    node_hi: np.ndarray              # (N, 3) upper corner
    node_child_or_first: np.ndarray  # (N,) int64 internal: left child (right = left + 1); leaf: first slot
    node_count: np.ndarray           # (N,) int64 leaf: its triangles (≥ 1); internal: 0
    triangle_order: np.ndarray       # (T,) int64 slot → triangle
    triangle_lo: np.ndarray          # (T, 3) each triangle's own box, by triangle index
    triangle_hi: np.ndarray          # (T, 3)


class TriangleMesh(NamedTuple):
    """A static mesh with its tree, as the queries and the mesh contacts take it (:attr:`StaticMesh.arrays`; from
    Python the queries also take it as a plain tuple, see "Bundles" in :mod:`cgp_core.jit`)."""

    vertices: np.ndarray             # (V, 3) in the mesh's frame
    triangles: np.ndarray            # (T, 3) int64 vertex indices, counter-clockwise seen from the front
    active_edges: np.ndarray         # (T,) uint8 bit e: edge (v_e, v_(e+1)%3) is active (:func:`active_edges`)
    node_lo: np.ndarray              # (N, 3) — the :class:`BvhTree`'s fields
    node_hi: np.ndarray              # (N, 3)
    node_child_or_first: np.ndarray  # (N,) int64
    node_count: np.ndarray           # (N,) int64
    triangle_order: np.ndarray       # (T,) int64
    triangle_lo: np.ndarray          # (T, 3)
    triangle_hi: np.ndarray          # (T, 3)


class ClosestPoint(NamedTuple):
    """What :func:`bvh_closest_point` gives."""

    triangle: int     # the closest triangle, −1 if none is within the distance asked
    distance: float   # to it (inf if none)
    x: float          # the closest point, mesh frame
    y: float
    z: float


@njit
def _triangle_boxes(vertices, triangles):
    t = len(triangles)
    lo, hi, centroid = np.empty((t, 3)), np.empty((t, 3)), np.empty((t, 3))
    for i in range(t):
        for r in range(3):
            a, b, c = vertices[triangles[i, 0], r], vertices[triangles[i, 1], r], vertices[triangles[i, 2], r]
            lo[i, r] = min(a, b, c)
            hi[i, r] = max(a, b, c)
            centroid[i, r] = (a + b + c) / 3.0
    return lo, hi, centroid


@njit
def _bin(centroid, low, scale):
    """The SAH bin of a centroid coordinate: in [0, SAH_BINS) for any float (a NaN or a non-finite product from
    a degenerate extent goes to an end bin: never an index out of bounds)."""
    f = (centroid - low) * scale
    if f >= SAH_BINS:
        return SAH_BINS - 1
    if f >= 0.0:
        return int(f)
    return 0


@njit
def _area(lx, ly, lz, hx, hy, hz):
    dx, dy, dz = hx - lx, hy - ly, hz - lz
    return dx * dy + dy * dz + dz * dx  # half the surface area: only ratios matter


@njit
def build_bvh(vertices, triangles):
    """Build the tree (see the module docstring) over ``triangles (T, 3)`` of ``vertices (V, 3)``, T ≥ 1.

    Returns a :class:`BvhTree`.
    """
    t = len(triangles)
    tri_lo, tri_hi, centroid = _triangle_boxes(vertices, triangles)
    capacity = max(2 * t, 1)
    node_lo, node_hi = np.empty((capacity, 3)), np.empty((capacity, 3))
    child, count = np.zeros(capacity, np.int64), np.zeros(capacity, np.int64)
    order = np.arange(t)
    stack_node = np.empty(STACK_DEPTH, np.int64)
    stack_start = np.empty(STACK_DEPTH, np.int64)
    stack_end = np.empty(STACK_DEPTH, np.int64)
    stack_depth = np.empty(STACK_DEPTH, np.int64)
    stack_node[0], stack_start[0], stack_end[0], stack_depth[0] = 0, 0, t, 0
    top = 1
    nodes = 1
    bin_count = np.zeros(SAH_BINS, np.int64)
    bin_lo, bin_hi = np.empty((SAH_BINS, 3)), np.empty((SAH_BINS, 3))
    right_area, right_count = np.empty(SAH_BINS), np.zeros(SAH_BINS, np.int64)
    while top > 0:
        top -= 1
        node, start, end, depth = stack_node[top], stack_start[top], stack_end[top], stack_depth[top]
        n = end - start
        clo = np.full(3, np.inf)
        chi = np.full(3, -np.inf)
        for r in range(3):
            node_lo[node, r], node_hi[node, r] = np.inf, -np.inf
        for s in range(start, end):
            i = order[s]
            for r in range(3):
                node_lo[node, r] = min(node_lo[node, r], tri_lo[i, r])
                node_hi[node, r] = max(node_hi[node, r], tri_hi[i, r])
                clo[r] = min(clo[r], centroid[i, r])
                chi[r] = max(chi[r], centroid[i, r])
        if n <= LEAF_SIZE:
            child[node], count[node] = start, n
            continue
        axis = 0
        for r in range(1, 3):
            if chi[r] - clo[r] > chi[axis] - clo[axis]:
                axis = r
        extent = chi[axis] - clo[axis]
        mid = start
        if extent > 0.0 and depth < SAH_DEPTH:
            # binned SAH along the axis
            bin_count[:] = 0
            bin_lo[:, :] = np.inf
            bin_hi[:, :] = -np.inf
            scale = SAH_BINS * (1.0 - 1e-9) / extent
            for s in range(start, end):
                i = order[s]
                b = _bin(centroid[i, axis], clo[axis], scale)
                bin_count[b] += 1
                for r in range(3):
                    bin_lo[b, r] = min(bin_lo[b, r], tri_lo[i, r])
                    bin_hi[b, r] = max(bin_hi[b, r], tri_hi[i, r])
            # sweep from the right: area and count of bins b.. end
            lx = ly = lz = np.inf
            hx = hy = hz = -np.inf
            acc = 0
            for b in range(SAH_BINS - 1, 0, -1):
                if bin_count[b] > 0:
                    lx, ly, lz = min(lx, bin_lo[b, 0]), min(ly, bin_lo[b, 1]), min(lz, bin_lo[b, 2])
                    hx, hy, hz = max(hx, bin_hi[b, 0]), max(hy, bin_hi[b, 1]), max(hz, bin_hi[b, 2])
                acc += bin_count[b]
                right_count[b] = acc
                right_area[b] = _area(lx, ly, lz, hx, hy, hz) if acc > 0 else 0.0
            lx = ly = lz = np.inf
            hx = hy = hz = -np.inf
            acc = 0
            best_cost, best_split = np.inf, -1
            for b in range(SAH_BINS - 1):  # split between bin b and b + 1
                if bin_count[b] > 0:
                    lx, ly, lz = min(lx, bin_lo[b, 0]), min(ly, bin_lo[b, 1]), min(lz, bin_lo[b, 2])
                    hx, hy, hz = max(hx, bin_hi[b, 0]), max(hy, bin_hi[b, 1]), max(hz, bin_hi[b, 2])
                acc += bin_count[b]
                if acc == 0 or right_count[b + 1] == 0:
                    continue
                cost = _area(lx, ly, lz, hx, hy, hz) * acc + right_area[b + 1] * right_count[b + 1]
                if cost < best_cost:
                    best_cost, best_split = cost, b
            if best_split >= 0:
                # partition order[start:end]: bins ≤ best_split first
                lo_s, hi_s = start, end - 1
                while lo_s <= hi_s:
                    i = order[lo_s]
                    if _bin(centroid[i, axis], clo[axis], scale) <= best_split:
                        lo_s += 1
                    else:
                        order[lo_s], order[hi_s] = order[hi_s], order[lo_s]
                        hi_s -= 1
                mid = lo_s
        if mid <= start or mid >= end:
            # the median (Ericson 6.2.1.1): sort the node's triangles by centroid along the axis
            keys = np.empty(n)
            for s in range(n):
                keys[s] = centroid[order[start + s], axis]
            sorted_slots = np.argsort(keys, kind="mergesort")
            chunk = order[start:end].copy()
            for s in range(n):
                order[start + s] = chunk[sorted_slots[s]]
            mid = start + n // 2
        left = nodes
        nodes += 2
        child[node], count[node] = left, 0
        # (depth + 1 <= MAX_DEPTH, and the stack holds at most one pending node per level: it cannot overflow)
        stack_node[top], stack_start[top], stack_end[top], stack_depth[top] = left, start, mid, depth + 1
        stack_node[top + 1], stack_start[top + 1], stack_end[top + 1], stack_depth[top + 1] = left + 1, mid, end, \
            depth + 1
        top += 2
    return BvhTree(node_lo[:nodes].copy(), node_hi[:nodes].copy(), child[:nodes].copy(), count[:nodes].copy(), order,
                   tri_lo, tri_hi)


# ---- queries ------------------------------------------------------------------------------------------

@njit
def _boxes_overlap(alo, ahi, k, lo, hi):
    return (alo[k, 0] <= hi[0] and ahi[k, 0] >= lo[0] and alo[k, 1] <= hi[1] and ahi[k, 1] >= lo[1]
            and alo[k, 2] <= hi[2] and ahi[k, 2] >= lo[2])


@njit
def bvh_overlap(mesh, lo, hi, out):
    """Triangles of the :class:`TriangleMesh` ``mesh`` whose boxes overlap the box ``lo, hi (3,)`` (touching counts),
    written into ``out (cap,)`` in tree order; returns how many there are (may exceed ``cap``: then only the first
    ``cap`` were written — call again with a bigger buffer)."""
    mesh = TriangleMesh(*mesh)
    node_lo, node_hi, node_child_or_first, node_count = mesh.node_lo, mesh.node_hi, mesh.node_child_or_first, \
        mesh.node_count
    triangle_order, triangle_lo, triangle_hi = mesh.triangle_order, mesh.triangle_lo, mesh.triangle_hi
    found = 0
    stack = np.empty(STACK_DEPTH, np.int64)
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        node = stack[top]
        if not _boxes_overlap(node_lo, node_hi, node, lo, hi):
            continue
        if node_count[node] > 0:
            first = node_child_or_first[node]
            for s in range(first, first + node_count[node]):
                i = triangle_order[s]
                if _boxes_overlap(triangle_lo, triangle_hi, i, lo, hi):
                    if found < len(out):
                        out[found] = i
                    found += 1
        else:
            stack[top] = node_child_or_first[node] + 1
            stack[top + 1] = node_child_or_first[node]
            top += 2
    return found


@njit
def _box_distance2(node_lo, node_hi, k, px, py, pz):
    """Squared distance from a point to box k (0 inside; Ericson 5.1.3.1)."""
    d = 0.0
    for r in range(3):
        p = px if r == 0 else (py if r == 1 else pz)
        if p < node_lo[k, r]:
            d += (node_lo[k, r] - p) ** 2
        elif p > node_hi[k, r]:
            d += (p - node_hi[k, r]) ** 2
    return d


@njit
def closest_point_on_triangle(vertices, triangles, i, px, py, pz):
    """The point of triangle i closest to p (Ericson 5.1.5, via :func:`.gjk.closest_on_triangle` in p's frame)."""
    a, b, c = triangles[i, 0], triangles[i, 1], triangles[i, 2]
    u, v, w = closest_on_triangle(vertices[a, 0] - px, vertices[a, 1] - py, vertices[a, 2] - pz,
                                  vertices[b, 0] - px, vertices[b, 1] - py, vertices[b, 2] - pz,
                                  vertices[c, 0] - px, vertices[c, 1] - py, vertices[c, 2] - pz)
    return (u * vertices[a, 0] + v * vertices[b, 0] + w * vertices[c, 0],
            u * vertices[a, 1] + v * vertices[b, 1] + w * vertices[c, 1],
            u * vertices[a, 2] + v * vertices[b, 2] + w * vertices[c, 2])


@njit
def bvh_closest_point(mesh, point, max_distance):
    """The point of the :class:`TriangleMesh` ``mesh`` closest to ``point (3,)`` within ``max_distance`` (inf:
    anywhere): a :class:`ClosestPoint`, triangle −1 if none is that close.  Nearest child first; a node farther
    than the best so far is skipped (Ericson 6.3)."""
    mesh = TriangleMesh(*mesh)
    node_lo, node_hi, node_child_or_first, node_count = mesh.node_lo, mesh.node_hi, mesh.node_child_or_first, \
        mesh.node_count
    triangle_order, vertices, triangles = mesh.triangle_order, mesh.vertices, mesh.triangles
    px, py, pz = point[0], point[1], point[2]
    best_d2 = max_distance * max_distance if max_distance < np.inf else np.inf
    best_t = -1
    bx = by = bz = 0.0
    stack = np.empty(STACK_DEPTH, np.int64)
    stack_d2 = np.empty(STACK_DEPTH)
    stack[0], stack_d2[0] = 0, _box_distance2(node_lo, node_hi, 0, px, py, pz)
    top = 1
    while top > 0:
        top -= 1
        node = stack[top]
        if stack_d2[top] > best_d2:
            continue
        if node_count[node] > 0:
            first = node_child_or_first[node]
            for s in range(first, first + node_count[node]):
                i = triangle_order[s]
                cx, cy, cz = closest_point_on_triangle(vertices, triangles, i, px, py, pz)
                d2 = (cx - px) ** 2 + (cy - py) ** 2 + (cz - pz) ** 2
                if d2 < best_d2 or (d2 == best_d2 and best_t >= 0 and i < best_t):
                    best_d2, best_t, bx, by, bz = d2, i, cx, cy, cz
        else:
            left = node_child_or_first[node]
            dl = _box_distance2(node_lo, node_hi, left, px, py, pz)
            dr = _box_distance2(node_lo, node_hi, left + 1, px, py, pz)
            if dl <= dr:  # push the farther first: the nearer is popped first
                stack[top], stack_d2[top] = left + 1, dr
                stack[top + 1], stack_d2[top + 1] = left, dl
            else:
                stack[top], stack_d2[top] = left, dl
                stack[top + 1], stack_d2[top + 1] = left + 1, dr
            top += 2
    return ClosestPoint(best_t, math.sqrt(best_d2) if best_t >= 0 else np.inf, bx, by, bz)


@njit
def ray_triangle(vertices, triangles, i, ox, oy, oz, dx, dy, dz):
    """Möller–Trumbore (1997): the ray o + t d meets triangle i at ``(t, u, v)`` (barycentric u, v of vertices 1,
    2), or t = inf.  Both sides count."""
    a, b, c = triangles[i, 0], triangles[i, 1], triangles[i, 2]
    e1x, e1y, e1z = vertices[b, 0] - vertices[a, 0], vertices[b, 1] - vertices[a, 1], vertices[b, 2] - vertices[a, 2]
    e2x, e2y, e2z = vertices[c, 0] - vertices[a, 0], vertices[c, 1] - vertices[a, 1], vertices[c, 2] - vertices[a, 2]
    px, py, pz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    if det == 0.0:
        return np.inf, 0.0, 0.0
    inv = 1.0 / det
    sx, sy, sz = ox - vertices[a, 0], oy - vertices[a, 1], oz - vertices[a, 2]
    u = (sx * px + sy * py + sz * pz) * inv
    if u < 0.0 or u > 1.0:
        return np.inf, 0.0, 0.0
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    if v < 0.0 or u + v > 1.0:
        return np.inf, 0.0, 0.0
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    return t, u, v


@njit
def _slab(node_lo, node_hi, k, ox, oy, oz, ix, iy, iz, t_max):
    """Entry parameter of the ray into box k within [0, t_max], or inf (Ericson 5.3.3, with the inverse
    direction; a zero component gives ±inf, which the comparisons handle)."""
    t0, t1 = 0.0, t_max
    for r in range(3):
        o = ox if r == 0 else (oy if r == 1 else oz)
        inv = ix if r == 0 else (iy if r == 1 else iz)
        if inv == np.inf or inv == -np.inf:  # parallel to this slab: inside or miss
            if o < node_lo[k, r] or o > node_hi[k, r]:
                return np.inf
            continue
        ta = (node_lo[k, r] - o) * inv
        tb = (node_hi[k, r] - o) * inv
        if ta > tb:
            ta, tb = tb, ta
        t0 = max(t0, ta)
        t1 = min(t1, tb)
        if t0 > t1:
            return np.inf
    return t0


@njit
def bvh_raycast(mesh, origin, direction, max_t):
    """First hit on the :class:`TriangleMesh` ``mesh`` of the segment ``origin + t direction``, 0 ≤ t ≤ ``max_t``:
    ``(triangle, t, u, v)``, triangle −1 if none (ties: the lowest triangle index)."""
    mesh = TriangleMesh(*mesh)
    node_lo, node_hi, node_child_or_first, node_count = mesh.node_lo, mesh.node_hi, mesh.node_child_or_first, \
        mesh.node_count
    triangle_order, vertices, triangles = mesh.triangle_order, mesh.vertices, mesh.triangles
    ox, oy, oz = origin[0], origin[1], origin[2]
    dx, dy, dz = direction[0], direction[1], direction[2]
    ix = 1.0 / dx if dx != 0.0 else np.inf
    iy = 1.0 / dy if dy != 0.0 else np.inf
    iz = 1.0 / dz if dz != 0.0 else np.inf
    best_t, best_i, best_u, best_v = max_t, -1, 0.0, 0.0
    stack = np.empty(STACK_DEPTH, np.int64)
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        node = stack[top]
        if _slab(node_lo, node_hi, node, ox, oy, oz, ix, iy, iz, best_t) == np.inf:
            continue
        if node_count[node] > 0:
            first = node_child_or_first[node]
            for s in range(first, first + node_count[node]):
                i = triangle_order[s]
                t, u, v = ray_triangle(vertices, triangles, i, ox, oy, oz, dx, dy, dz)
                if 0.0 <= t and (t < best_t or (t == best_t and (best_i < 0 or i < best_i))):
                    best_t, best_i, best_u, best_v = t, i, u, v
        else:
            stack[top] = node_child_or_first[node] + 1
            stack[top + 1] = node_child_or_first[node]
            top += 2
    return best_i, best_t if best_i >= 0 else np.inf, best_u, best_v


# ---- the static mesh ------------------------------------------------------------------------------------

def active_edges(vertices: np.ndarray, triangles: np.ndarray, angle: float = ACTIVE_EDGE_ANGLE) -> np.ndarray:
    """(T,) uint8: bit e of triangle i set if its edge (v_e, v_(e+1)%3) is active (see the module docstring):
    a boundary edge, an edge shared by more than two triangles, or a convex edge whose triangles' normals are
    more than ``angle`` apart.

    Vectorized over the 3T edges (issue 38: a loop over a dict of edges took 55 s for 500,000 triangles; this,
    ~0.5 s): the edges sorted by their vertex pair (stably, so an edge's two uses are in triangle order), the
    pairs of uses compared at once."""
    t = len(triangles)
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    normal = np.cross(b - a, c - a)
    length = np.linalg.norm(normal, axis=1)
    normal = normal / np.where(length > 0.0, length, 1.0)[:, None]
    # the 3T edge uses (triangle i, edge e), sorted by their undirected vertex pair
    start = triangles.reshape(-1)
    end = triangles[:, [1, 2, 0]].reshape(-1)
    low, high = np.minimum(start, end), np.maximum(start, end)
    order = np.lexsort((high, low))
    low, high = low[order], high[order]
    first = np.ones(len(order), bool)  # the first use of each edge
    first[1:] = (low[1:] != low[:-1]) | (high[1:] != high[:-1])
    group = np.cumsum(first) - 1
    uses = np.bincount(group)[group]  # per sorted use: how many uses its edge has
    active = np.zeros(3 * t, bool)
    active[order[uses != 2]] = True  # boundary or non-manifold: always active
    pair = np.flatnonzero(first & (uses == 2))
    ui, uj = order[pair], order[pair + 1]  # the two uses, in triangle order
    n1, n2 = normal[ui // 3], normal[uj // 3]
    direction = vertices[end[ui]] - vertices[start[ui]]  # the edge as triangle i runs it
    # convex: the second triangle turns away from the first's front (n1 × n2 along the edge as triangle i runs
    # it); concave edges are inactive
    turn = np.cross(n1, n2)
    convex = turn[:, 0] * direction[:, 0] + turn[:, 1] * direction[:, 1] + turn[:, 2] * direction[:, 2] > 0.0
    cosine = n1[:, 0] * n2[:, 0] + n1[:, 1] * n2[:, 1] + n1[:, 2] * n2[:, 2]
    sharp = convex & (cosine < math.cos(angle))
    active[ui[sharp]] = True
    active[uj[sharp]] = True
    bits = active.reshape(t, 3).astype(np.uint8)
    return (bits[:, 0] | (bits[:, 1] << 1) | (bits[:, 2] << 2)).astype(np.uint8)


@dataclass
class StaticMesh:
    """A triangle mesh for fixed bodies, with its BVH.

    Attributes (shapes):
        vertices:            (V, 3) float — in the body's frame.
        triangles:           (T, 3) int64 — counter-clockwise seen from the front (outside, for a closed mesh).
        active_edges:        (T,) uint8 — see :func:`active_edges`.
        node_lo, node_hi, node_child_or_first, node_count, triangle_order, triangle_lo, triangle_hi: the BVH
                             (see the module docstring).
        build_seconds:       the BVH build's wall time (the first build in a process includes no compilation if
                             the cache is warm).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    active_edges: np.ndarray
    node_lo: np.ndarray
    node_hi: np.ndarray
    node_child_or_first: np.ndarray
    node_count: np.ndarray
    triangle_order: np.ndarray
    triangle_lo: np.ndarray
    triangle_hi: np.ndarray
    build_seconds: float

    @classmethod
    def build(cls, vertices, triangles) -> StaticMesh:
        vertices = np.ascontiguousarray(vertices, dtype=float)
        triangles = np.ascontiguousarray(triangles, dtype=np.int64)
        if len(triangles) == 0:
            raise ValueError("a static mesh needs at least one triangle")
        start = time.perf_counter()
        tree = build_bvh(vertices, triangles)
        seconds = time.perf_counter() - start
        return cls(vertices, triangles, active_edges(vertices, triangles), *tree, build_seconds=seconds)

    @property
    def arrays(self) -> TriangleMesh:
        """The mesh and its tree as the queries take them."""
        return TriangleMesh(self.vertices, self.triangles, self.active_edges, self.node_lo, self.node_hi,
                            self.node_child_or_first, self.node_count, self.triangle_order, self.triangle_lo,
                            self.triangle_hi)

    @property
    def nbytes(self) -> int:
        """Memory of the mesh and its tree (the arrays above)."""
        return sum(a.nbytes for a in (self.vertices, self.triangles, self.active_edges, self.node_lo, self.node_hi,
                                      self.node_child_or_first, self.node_count, self.triangle_order,
                                      self.triangle_lo, self.triangle_hi))

    @property
    def bvh_nbytes(self) -> int:
        """Memory of the tree alone (nodes, order, triangle boxes)."""
        return sum(a.nbytes for a in (self.node_lo, self.node_hi, self.node_child_or_first, self.node_count,
                                      self.triangle_order, self.triangle_lo, self.triangle_hi))

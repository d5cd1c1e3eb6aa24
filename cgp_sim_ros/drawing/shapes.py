"""Geometry for markers that has no ROS in it: the fish drawn for ``model: fish`` flocks.

The fish is a TRIANGLE_LIST built per flock (one marker for the whole flock, not one per boid): RViz and
Foxglove both render TRIANGLE_LIST natively (double-sided: rviz2 turns culling off for it, Foxglove uses a
double-sided material), and no mesh file has to be found through a package:// URL.  It is drawn in the boid
frame (x = heading, z = the frame's up/banked side) so the PoseArray orientation and the drawing always agree.

Two levels of detail, both ``boid_size`` long (unit templates below, scaled):

- ``full``: an elongated double pyramid (the body: snout at +x, widest at x = 0.1) and a vertical tail fin,
  10 triangles, 30 vertices per fish.  The fin is listed twice (both windings), as the original template
  has it, for viewers that cull back faces.
- ``low``: the full fish's top-view silhouette — its body as a flat rhombus (snout, widest points, tail) —
  and its tail fin, 3 triangles, 9 vertices per fish.  Seen from above it is the full fish's outline; from the
  side, the fin.  At 15,000 fish it is 3.2 MB per marker instead of 10.8 MB.

Vertices are rounded to multiples of :data:`VERTEX_QUANTUM` (1/1024 m, under a millimetre): nothing a viewer
can show, and it leaves the low bytes of every float64 zero, so the bag's lz4 chunks store markers in ~40 % of
their size (the 15k-fish run of ``benchmarks/bench_tick.py``; unrounded float64 hardly compress).  The poses
(``~/flocks/<flock>/poses``, the data) are never rounded.

The vertices are computed by a compiled kernel, one fish per iteration of a parallel loop, straight into the
buffer the marker is serialized from.
"""

from __future__ import annotations

import math

import numpy as np

from cgp_core.jit import njit, prange, threads_for

_SNOUT = (0.5, 0.0, 0.0)
_TOP = (0.1, 0.0, 0.14)
_BOTTOM = (0.1, 0.0, -0.12)
_LEFT = (0.1, 0.07, 0.0)
_RIGHT = (0.1, -0.07, 0.0)
_TAIL = (-0.28, 0.0, 0.0)
_FIN_TOP = (-0.5, 0.0, 0.13)
_FIN_BOTTOM = (-0.5, 0.0, -0.13)

FISH_TEMPLATE = np.array(
    [
        # front half (snout): counter-clockwise seen from outside
        _SNOUT, _LEFT, _TOP,
        _SNOUT, _BOTTOM, _LEFT,
        _SNOUT, _RIGHT, _BOTTOM,
        _SNOUT, _TOP, _RIGHT,
        # back half (towards the tail)
        _TAIL, _TOP, _LEFT,
        _TAIL, _LEFT, _BOTTOM,
        _TAIL, _BOTTOM, _RIGHT,
        _TAIL, _RIGHT, _TOP,
        # tail fin, both sides
        _TAIL, _FIN_TOP, _FIN_BOTTOM,
        _TAIL, _FIN_BOTTOM, _FIN_TOP,
    ],
    dtype=float,
)
FISH_VERTICES_PER_BOID = len(FISH_TEMPLATE)

FISH_LOW_TEMPLATE = np.array(
    [
        # the body seen from above: a flat rhombus, counter-clockwise seen from above
        _SNOUT, _LEFT, _TAIL,
        _SNOUT, _TAIL, _RIGHT,
        # tail fin
        _TAIL, _FIN_TOP, _FIN_BOTTOM,
    ],
    dtype=float,
)

#: the fish templates by level of detail (unit length; vertices per fish = rows)
FISH_DETAILS = {"full": FISH_TEMPLATE, "low": FISH_LOW_TEMPLATE}

#: marker vertices are rounded to multiples of this [m] (a power of two: the rounding is exact)
VERTEX_QUANTUM = 1.0 / 1024.0


@njit
def _quantized(value: float, quantum: float) -> float:
    return math.floor(value / quantum + 0.5) * quantum if quantum > 0.0 else value


@njit(parallel=True)
def _fish_vertices(positions, orientations, template, quantum, out):
    """out[V i + v] = p_i + R(q_i) template[v], rounded to ``quantum``; one fish per iteration."""
    per_fish = template.shape[0]
    for i in prange(positions.shape[0]):
        x, y, z, w = orientations[i, 0], orientations[i, 1], orientations[i, 2], orientations[i, 3]
        # rotation matrix of the unit quaternion (x, y, z, w), rows r0, r1, r2
        r00, r01, r02 = 1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)
        r10, r11, r12 = 2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)
        r20, r21, r22 = 2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)
        for v in range(per_fish):
            tx, ty, tz = template[v, 0], template[v, 1], template[v, 2]
            k = per_fish * i + v
            out[k, 0] = _quantized(positions[i, 0] + r00 * tx + r01 * ty + r02 * tz, quantum)
            out[k, 1] = _quantized(positions[i, 1] + r10 * tx + r11 * ty + r12 * tz, quantum)
            out[k, 2] = _quantized(positions[i, 2] + r20 * tx + r21 * ty + r22 * tz, quantum)


@njit(parallel=True)
def _quantize_rows(points, quantum, out):
    for i in prange(points.shape[0]):
        for c in range(3):
            out[i, c] = _quantized(points[i, c], quantum)


def fish_triangles(positions: np.ndarray, orientations: np.ndarray, length: float, detail: str = "full",
                   quantum: float = VERTEX_QUANTUM, out: np.ndarray | None = None) -> np.ndarray:
    """World vertices of every fish, ``(N · V, 3)`` (V = 30 for ``full``, 9 for ``low``): p + R(q) (length ·
    template), rounded to ``quantum`` (0: not rounded); written into ``out`` if given (an (N · V, 3) float64
    array, e.g. a view of a marker's serialization buffer)."""
    template = np.ascontiguousarray(FISH_DETAILS[detail] * float(length))
    positions = np.ascontiguousarray(positions, dtype=np.float64)
    orientations = np.ascontiguousarray(orientations, dtype=np.float64)
    if out is None:
        out = np.empty((len(positions) * len(template), 3))
    with threads_for(len(positions)):
        _fish_vertices(positions, orientations, template, float(quantum), out)
    return out


def quantized_points(points: np.ndarray, quantum: float = VERTEX_QUANTUM, out: np.ndarray | None = None):
    """``points (N, 3)`` rounded to multiples of ``quantum`` (into ``out`` if given)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    if out is None:
        out = np.empty_like(points)
    with threads_for(len(points)):
        _quantize_rows(points, float(quantum), out)
    return out

"""Geometry for markers that has no ROS in it: the fish drawn for ``model: fish`` flocks.

The fish is a TRIANGLE_LIST built per flock (one marker for the whole flock, not one per boid): RViz and
Foxglove both render TRIANGLE_LIST natively, and no mesh file has to be found through a package:// URL.
It is drawn in the boid frame (x = heading, z = the frame's up/binormal side) so the PoseArray orientation and
the drawing always agree.

Body frame template, unit length (scaled by the flock's ``boid_size``): an elongated double pyramid (the body:
snout at +x, widest at x = 0.1) and a vertical tail fin, 10 triangles, 30 vertices per fish.  Every triangle is
listed with outward winding; the fin is listed twice (both windings) because it has no inside.
"""

from __future__ import annotations

import numpy as np

from cgp_core.rotation import quat_to_matrix

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


def fish_triangles(positions: np.ndarray, orientations: np.ndarray, length: float) -> np.ndarray:
    """World vertices of every fish, ``(N * 30, 3)``: p + R(q) (length · template)."""
    R = quat_to_matrix(orientations)  # (N, 3, 3)
    local = FISH_TEMPLATE * length  # (30, 3)
    vertices = np.einsum("nij,vj->nvi", R, local) + positions[:, None, :]
    return vertices.reshape(-1, 3)

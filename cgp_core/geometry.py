"""Signed distance from points to the primitive shapes (Ericson, *Real-Time Collision Detection*, ch. 5:
closest-point computations), vectorized as points × shapes.

Every function takes ``points (m, 3)`` and ``k`` shapes and returns ``distance (m, k)`` (negative inside) and
``normal (m, k, 3)``: the unit outward direction of steepest distance increase at the point, i.e. the direction
to push a point out of (or away from) the shape.  Used by the boids (obstacle avoidance and the no-entry
projection) and by the narrow phase for sphere-vs-shape contacts.
"""

from __future__ import annotations

import numpy as np

_TINY = 1e-12


def _unit(v: np.ndarray, fallback: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalize along the last axis; where the length is ~0 use ``fallback`` (already unit)."""
    length = np.linalg.norm(v, axis=-1)
    degenerate = length < _TINY
    unit = v / np.where(degenerate, 1.0, length)[..., None]
    unit = np.where(degenerate[..., None], fallback, unit)
    return unit, length


def sphere_distance(points: np.ndarray, centers: np.ndarray, radii: np.ndarray):
    """Points vs spheres ``centers (k, 3)``, ``radii (k,)``."""
    d = points[:, None, :] - centers[None, :, :]
    normal, length = _unit(d, np.array([0.0, 0.0, 1.0]))
    return length - radii[None, :], normal


def box_distance(points: np.ndarray, centers: np.ndarray, rotations: np.ndarray, half_extents: np.ndarray):
    """Points vs oriented boxes ``centers (k, 3)``, ``rotations (k, 3, 3)`` (columns = box axes in world),
    ``half_extents (k, 3)``.  Inside, the normal is the face axis of least penetration."""
    d = points[:, None, :] - centers[None, :, :]  # (m, k, 3) world offsets
    local = np.einsum("kji,mkj->mki", rotations, d)  # Rᵀ d
    q = np.abs(local) - half_extents[None, :, :]  # per-axis distance outside the slab
    outside = np.maximum(q, 0.0)
    out_len = np.linalg.norm(outside, axis=-1)
    inside_depth = np.max(q, axis=-1)  # <= 0 when inside
    distance = np.where(out_len > 0.0, out_len, inside_depth)

    sign = np.where(local >= 0.0, 1.0, -1.0)
    # outside: direction from the closest point on the box to the point
    n_out_local = sign * outside / np.where(out_len > 0.0, out_len, 1.0)[..., None]
    # inside: the face whose plane is nearest
    axis = np.argmax(q, axis=-1)
    n_in_local = np.zeros_like(local)
    np.put_along_axis(n_in_local, axis[..., None], np.take_along_axis(sign, axis[..., None], axis=-1), axis=-1)
    n_local = np.where((out_len > 0.0)[..., None], n_out_local, n_in_local)
    normal = np.einsum("kij,mkj->mki", rotations, n_local)
    return distance, normal


def segment_closest_parameter(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Parameter t in [0, 1] of the point on segments ``a (k,3)``–``b (k,3)`` closest to each point; (m, k)."""
    ab = b - a
    denom = np.einsum("ki,ki->k", ab, ab)
    t = np.einsum("mki,ki->mk", points[:, None, :] - a[None, :, :], ab) / np.where(denom > _TINY, denom, 1.0)
    return np.clip(t, 0.0, 1.0)


def capsule_distance(points: np.ndarray, centers: np.ndarray, axes: np.ndarray, half_lengths: np.ndarray,
                     radii: np.ndarray):
    """Points vs capsules: segment ``center ± half_length * axis`` (``axes (k, 3)`` unit) swept by ``radii``."""
    a = centers - axes * half_lengths[:, None]
    b = centers + axes * half_lengths[:, None]
    t = segment_closest_parameter(points, a, b)
    closest = a[None, :, :] + t[..., None] * (b - a)[None, :, :]
    d = points[:, None, :] - closest
    # on the axis itself any direction perpendicular to it is steepest: pick one
    perpendicular = np.cross(axes, np.where(np.abs(axes[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    perpendicular /= np.linalg.norm(perpendicular, axis=-1, keepdims=True)
    normal, length = _unit(d, perpendicular[None, :, :])
    return length - radii[None, :], normal

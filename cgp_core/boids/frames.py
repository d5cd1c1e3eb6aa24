"""Body frames of boids (the lecture's fish-model exercise): x along the velocity, z the dorsal ("up") axis.

The lecture's moving frame of a particle is the Frenet frame: tangent ``T = v / |v|``, normal N from the
change of T (``dT/ds = κ N``), binormal ``B = T × N``, ``R = [T N B]``.  Used raw on a boid it fails twice:
on a straight path ``dT/ds = 0`` and N is undefined, and whenever a turn changes side N jumps across T, so B
(and the drawn fish) rolls by 180°.  This module keeps T and the lecture's curvature vector ``κN`` and builds
a frame that is defined everywhere and continuous:

- x axis = T (so PoseArray orientations point along the velocity);
- z axis (dorsal) = the apparent "up" of a coordinated turn, ``u = g ẑ + bank_gain · |v|² κN`` (−gravity plus
  the centripetal acceleration): level on a straight path (the fallback is world up), banked into the turn by
  ``atan(bank_gain · |v|² κ / g)``.  Turning the other way tilts it the other way, continuously — no flip;
- the dorsal axis follows that target through a first-order low-pass (time constant τ) and is carried along
  with the heading (projected perpendicular to the new T: parallel transport to first order), so it never
  jumps; in vertical flight (u ∥ T) the low-pass keeps the previous roll;
- y = z × x (right-handed).

The discrete curvature: ``κN ≈ (T_new − T_old)_⊥ / (|v| dt)`` (the change of the unit tangent per arc length,
its component perpendicular to T_new), so the centripetal acceleration is ``|v| (T_new − T_old)_⊥ / dt``.

Arrays are component-major ``(3, N)`` float64 (rows x, y, z), quaternions ``(4, N)`` (x, y, z, w).
"""

from __future__ import annotations

import math

import numpy as np

GRAVITY = 9.81  # m/s², the g in the banking target
_TINY = 1e-12


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack((a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]))


def _project_unit(v: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Component of ``v`` perpendicular to the unit ``axis``, normalized; also its length before normalizing."""
    p = v - _dot(v, axis) * axis
    length = np.sqrt(_dot(p, p))
    p /= np.maximum(length, _TINY)
    return p, length


def unit_headings(velocities: np.ndarray, previous: np.ndarray | None = None) -> np.ndarray:
    """T = v / |v| (3, N); where |v| is ~0, the previous heading (or world x)."""
    speed = np.sqrt(_dot(velocities, velocities))
    heading = velocities / np.maximum(speed, _TINY)
    still = speed < 1e-9
    if np.any(still):
        fallback = previous if previous is not None else np.array([[1.0], [0.0], [0.0]])
        heading[:, still] = np.broadcast_to(fallback, heading.shape)[:, still]
    return heading


def initial_dorsal(headings: np.ndarray) -> np.ndarray:
    """Level dorsal axes for a start: world up projected perpendicular to T (world y where T is vertical)."""
    up = np.zeros_like(headings)
    up[2] = 1.0
    dorsal, length = _project_unit(up, headings)
    vertical = length < 1e-6
    if np.any(vertical):
        side = np.zeros_like(headings[:, vertical])
        side[1] = 1.0
        dorsal[:, vertical] = _project_unit(side, headings[:, vertical])[0]
    return dorsal


def parallel_transport(vectors: np.ndarray, old: np.ndarray, new: np.ndarray) -> np.ndarray:
    """Rotate ``vectors`` by the minimal rotation taking unit ``old`` to unit ``new`` (all (3, N)).

    Rodrigues with axis·sin = old × new and cos = old·new: ``v' = c v + k × v + k (k·v) / (1 + c)``.  For an
    exact reversal (c = −1, no unique minimal rotation) the vectors are returned unchanged."""
    k = _cross(old, new)
    c = _dot(old, new)
    out = c * vectors + _cross(k, vectors)
    safe = c > -1.0 + 1e-9
    out += k * (_dot(k, vectors) / np.where(safe, 1.0 + c, 1.0))
    return np.where(safe, out, vectors)


def update_frames(heading_old: np.ndarray, dorsal_old: np.ndarray, velocities: np.ndarray, dt: float,
                  bank_gain: float, time_constant: float) -> tuple[np.ndarray, np.ndarray]:
    """Advance the frames by one step of ``dt`` to the new ``velocities (3, N)``.

    Returns ``(heading (3, N), dorsal (3, N))``, unit, orthogonal.  See the module docstring for the model.
    The old dorsal axis is carried to the new heading by projecting it perpendicular to it (first-order
    parallel transport, exact enough for the few degrees a boid turns per tick); only if that projection
    degenerates (a turn of ~90° in one tick) is the exact transport used."""
    speed = np.sqrt(_dot(velocities, velocities))
    heading = velocities / np.maximum(speed, _TINY)
    still = speed < 1e-9
    if np.any(still):
        heading[:, still] = heading_old[:, still]
    # the lecture's dT/ds = κN, discretely (T_new − T_old)⊥ / (|v| dt); times |v|² the centripetal acceleration
    target = heading - heading_old
    target -= _dot(target, heading) * heading
    target *= (bank_gain / dt) * speed
    target[2] += GRAVITY  # apparent up = −gravity + bank_gain · centripetal acceleration
    target_length = np.sqrt(_dot(target, target))
    has_target = target_length > _TINY
    target /= np.where(has_target, target_length, 1.0)
    if not np.all(has_target):
        target[:, ~has_target] = dorsal_old[:, ~has_target]
    blend = 1.0 if time_constant <= 0.0 else -math.expm1(-dt / time_constant)
    # low-pass towards the target, then make it perpendicular to the new heading
    dorsal = dorsal_old * (1.0 - blend)
    dorsal += blend * target
    dorsal, length = _project_unit(dorsal, heading)
    degenerate = length < 1e-6
    if np.any(degenerate):
        carried = parallel_transport(dorsal_old[:, degenerate], heading_old[:, degenerate], heading[:, degenerate])
        dorsal[:, degenerate] = _project_unit(carried, heading[:, degenerate])[0]
    return heading, dorsal


def frames_to_quaternions(heading: np.ndarray, dorsal: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Quaternions (4, N) (x, y, z, w), ``w >= 0``, of the rotations R = [x y z] with x = heading, z = dorsal,
    y = z × x (both unit and orthogonal).

    Branch-free: each component's magnitude from the diagonal (``4w² = 1 + m00 + m11 + m22``, ``4x² = 1 + m00
    − m11 − m22``, …) and the signs of x, y, z relative to w from the antisymmetric part (``4wx = m21 − m12``,
    …).  Where w is ~0 (turns by ~180°) those signs are undetermined and are taken from the symmetric part
    instead (``4xy = m01 + m10``, ``4xz = m02 + m20``).  Accurate to ~1e-8 (square roots of differences),
    plenty for poses; ``rotation.matrix_to_quat`` (Shepperd) is the reference in the tests.  Several times
    cheaper than a branching Shepperd on component rows, which matters at 10⁵ boids per tick."""
    x_axis = heading
    z_axis = dorsal
    y_axis = _cross(z_axis, x_axis)
    m00, m10, m20 = x_axis  # R[row, column]: column 0 is the x axis
    m01, m11, m21 = y_axis
    m02, m12, m22 = z_axis
    n = heading.shape[1]
    q = np.empty((4, n)) if out is None else out
    q[3] = 1.0 + m00 + m11 + m22
    q[0] = 1.0 + m00 - m11 - m22
    q[1] = 1.0 - m00 + m11 - m22
    q[2] = 1.0 - m00 - m11 + m22
    np.maximum(q, 0.0, out=q)
    np.sqrt(q, out=q)
    q *= 0.5
    # signs relative to w (w >= 0)
    np.copysign(q[0], m21 - m12, out=q[0])
    np.copysign(q[1], m02 - m20, out=q[1])
    np.copysign(q[2], m10 - m01, out=q[2])
    small_w = q[3] < 1e-3
    if np.any(small_w):
        # w ~ 0: the rotation is a half turn about (x, y, z); fix y and z relative to the largest of them
        qs = q[:, small_w]
        xy = (m01 + m10)[small_w]
        xz = (m02 + m20)[small_w]
        yz = (m12 + m21)[small_w]
        ax, ay, az = np.abs(qs[0]), np.abs(qs[1]), np.abs(qs[2])
        x_big = (ax >= ay) & (ax >= az)
        y_big = ~x_big & (ay >= az)
        z_big = ~x_big & ~y_big
        sx = np.where(x_big, 1.0, np.where(y_big, np.sign(xy), np.sign(xz)))
        sy = np.where(y_big, 1.0, np.where(x_big, np.sign(xy), np.sign(yz)))
        sz = np.where(z_big, 1.0, np.where(x_big, np.sign(xz), np.sign(yz)))
        qs[0] = ax * np.where(sx == 0.0, 1.0, sx)
        qs[1] = ay * np.where(sy == 0.0, 1.0, sy)
        qs[2] = az * np.where(sz == 0.0, 1.0, sz)
        # with w > 0 the sign of the largest component follows from the antisymmetric part
        big = np.where(x_big, qs[0], np.where(y_big, qs[1], qs[2]))
        anti = np.where(x_big, (m21 - m12)[small_w], np.where(y_big, (m02 - m20)[small_w], (m10 - m01)[small_w]))
        flip = (anti * big) < 0.0
        qs[:3, flip] *= -1.0
        q[:, small_w] = qs
    return q

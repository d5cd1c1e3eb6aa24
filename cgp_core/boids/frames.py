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

The per-boid formulas are compiled (numba, :func:`update_frames_rows` / :func:`quaternions_rows`: one boid per
iteration of a parallel loop, on ``(N, 3)`` rows as the flock stores them).  The functions without ``_rows``
take component-major ``(3, N)`` arrays (rows x, y, z; quaternions ``(4, N)`` as x, y, z, w) and call the same
kernels: they are the API the tests and the initial state use.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import njit, prange

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


@njit
def _frame(h_old, d_old, velocity, dt, bank_gain, blend, heading, dorsal):
    """One boid's frame after a step: ``heading`` and ``dorsal`` (3,) written from the old frame and the new
    velocity (see :func:`update_frames`)."""
    vx, vy, vz = velocity[0], velocity[1], velocity[2]
    speed = math.sqrt(vx * vx + vy * vy + vz * vz)
    scale = 1.0 / max(speed, _TINY)
    hx, hy, hz = vx * scale, vy * scale, vz * scale
    if speed < 1e-9:
        hx, hy, hz = h_old[0], h_old[1], h_old[2]
    # the lecture's dT/ds = κN, discretely (T_new − T_old)⊥ / (|v| dt); times |v|² the centripetal acceleration
    tx, ty, tz = hx - h_old[0], hy - h_old[1], hz - h_old[2]
    along = tx * hx + ty * hy + tz * hz
    factor = (bank_gain / dt) * speed
    tx, ty, tz = (tx - along * hx) * factor, (ty - along * hy) * factor, (tz - along * hz) * factor
    tz += GRAVITY  # apparent up = −gravity + bank_gain · centripetal acceleration
    length = math.sqrt(tx * tx + ty * ty + tz * tz)
    if length > _TINY:
        tx, ty, tz = tx / length, ty / length, tz / length
    else:
        tx, ty, tz = d_old[0], d_old[1], d_old[2]
    # low-pass towards the target, then perpendicular to the new heading
    dx = d_old[0] * (1.0 - blend) + blend * tx
    dy = d_old[1] * (1.0 - blend) + blend * ty
    dz = d_old[2] * (1.0 - blend) + blend * tz
    along = dx * hx + dy * hy + dz * hz
    dx, dy, dz = dx - along * hx, dy - along * hy, dz - along * hz
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    if length < 1e-6:
        # a turn of ~90° in one tick: carry the old dorsal axis exactly (parallel transport), then project
        dx, dy, dz = _transported(d_old[0], d_old[1], d_old[2], h_old[0], h_old[1], h_old[2], hx, hy, hz)
        along = dx * hx + dy * hy + dz * hz
        dx, dy, dz = dx - along * hx, dy - along * hy, dz - along * hz
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
    length = max(length, _TINY)
    heading[0], heading[1], heading[2] = hx, hy, hz
    dorsal[0], dorsal[1], dorsal[2] = dx / length, dy / length, dz / length


@njit
def _transported(vx, vy, vz, ox, oy, oz, nx, ny, nz):
    """(vx, vy, vz) rotated by the minimal rotation taking unit ``o`` to unit ``n`` (Rodrigues, see
    :func:`parallel_transport`); unchanged for an exact reversal."""
    kx, ky, kz = oy * nz - oz * ny, oz * nx - ox * nz, ox * ny - oy * nx
    c = ox * nx + oy * ny + oz * nz
    if c <= -1.0 + 1e-9:
        return vx, vy, vz
    kv = (kx * vx + ky * vy + kz * vz) / (1.0 + c)
    return (c * vx + (ky * vz - kz * vy) + kx * kv, c * vy + (kz * vx - kx * vz) + ky * kv,
            c * vz + (kx * vy - ky * vx) + kz * kv)


@njit(parallel=True)
def update_frames_rows(headings, dorsals, velocities, dt, bank_gain, blend):
    """:func:`update_frames` in place on ``(N, 3)`` rows, one boid per iteration (``blend`` = the low-pass
    weight of one step, ``1 − exp(−dt / τ)``)."""
    for i in prange(headings.shape[0]):
        _frame(headings[i], dorsals[i], velocities[i], dt, bank_gain, blend, headings[i], dorsals[i])


def low_pass_weight(dt: float, time_constant: float) -> float:
    """Weight of the new target in one step of the dorsal axis' first-order low-pass: 1 − exp(−dt / τ)."""
    return 1.0 if time_constant <= 0.0 else -math.expm1(-dt / time_constant)


def update_frames(heading_old: np.ndarray, dorsal_old: np.ndarray, velocities: np.ndarray, dt: float,
                  bank_gain: float, time_constant: float) -> tuple[np.ndarray, np.ndarray]:
    """Advance the frames by one step of ``dt`` to the new ``velocities (3, N)``.

    Returns ``(heading (3, N), dorsal (3, N))``, unit, orthogonal.  See the module docstring for the model.
    The old dorsal axis is carried to the new heading by projecting it perpendicular to it (first-order
    parallel transport, exact enough for the few degrees a boid turns per tick); only if that projection
    degenerates (a turn of ~90° in one tick) is the exact transport used."""
    heading = np.ascontiguousarray(np.asarray(heading_old, dtype=float).T)
    dorsal = np.ascontiguousarray(np.asarray(dorsal_old, dtype=float).T)
    update_frames_rows(heading, dorsal, np.ascontiguousarray(np.asarray(velocities, dtype=float).T), float(dt),
                       float(bank_gain), low_pass_weight(dt, time_constant))
    return heading.T, dorsal.T


@njit
def _quaternion(x_axis, z_axis, q):
    """The unit quaternion (x, y, z, w), w >= 0, of R = [x y z], y = z × x (see :func:`frames_to_quaternions`)."""
    m00, m10, m20 = x_axis[0], x_axis[1], x_axis[2]  # R[row, column]: column 0 is the x axis
    m02, m12, m22 = z_axis[0], z_axis[1], z_axis[2]
    m01, m11, m21 = m12 * m20 - m22 * m10, m22 * m00 - m02 * m20, m02 * m10 - m12 * m00  # y = z × x
    w = 0.5 * math.sqrt(max(1.0 + m00 + m11 + m22, 0.0))
    x = 0.5 * math.sqrt(max(1.0 + m00 - m11 - m22, 0.0))
    y = 0.5 * math.sqrt(max(1.0 - m00 + m11 - m22, 0.0))
    z = 0.5 * math.sqrt(max(1.0 - m00 - m11 + m22, 0.0))
    if w >= 1e-3:
        # signs relative to w (w >= 0) from the antisymmetric part
        x = math.copysign(x, m21 - m12)
        y = math.copysign(y, m02 - m20)
        z = math.copysign(z, m10 - m01)
    else:
        # w ~ 0: a half turn about (x, y, z); signs of the two smaller components relative to the largest from
        # the symmetric part, then the largest's sign (w > 0) from the antisymmetric part
        xy, xz, yz = m01 + m10, m02 + m20, m12 + m21
        if x >= y and x >= z:
            y = math.copysign(y, xy) if xy != 0.0 else y
            z = math.copysign(z, xz) if xz != 0.0 else z
            if (m21 - m12) < 0.0:
                x, y, z = -x, -y, -z
        elif y >= z:
            x = math.copysign(x, xy) if xy != 0.0 else x
            z = math.copysign(z, yz) if yz != 0.0 else z
            if (m02 - m20) < 0.0:
                x, y, z = -x, -y, -z
        else:
            x = math.copysign(x, xz) if xz != 0.0 else x
            y = math.copysign(y, yz) if yz != 0.0 else y
            if (m10 - m01) < 0.0:
                x, y, z = -x, -y, -z
    q[0], q[1], q[2], q[3] = x, y, z, w


@njit(parallel=True)
def quaternions_rows(headings, dorsals, out):
    """:func:`frames_to_quaternions` on ``(N, 3)`` rows into ``out (N, 4)``, one boid per iteration."""
    for i in prange(headings.shape[0]):
        _quaternion(headings[i], dorsals[i], out[i])


def frames_to_quaternions(heading: np.ndarray, dorsal: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Quaternions (4, N) (x, y, z, w), ``w >= 0``, of the rotations R = [x y z] with x = heading, z = dorsal,
    y = z × x (both unit and orthogonal).

    Each component's magnitude from the diagonal (``4w² = 1 + m00 + m11 + m22``, ``4x² = 1 + m00 − m11 − m22``,
    …) and the signs of x, y, z relative to w from the antisymmetric part (``4wx = m21 − m12``, …).  Where w is
    ~0 (turns by ~180°) those signs are undetermined and are taken from the symmetric part instead
    (``4xy = m01 + m10``, ``4xz = m02 + m20``).  Accurate to ~1e-8 (square roots of differences), plenty for
    poses; ``rotation.matrix_to_quat`` (Shepperd) is the reference in the tests."""
    rows = np.empty((heading.shape[1], 4))
    quaternions_rows(np.ascontiguousarray(np.asarray(heading, dtype=float).T),
                     np.ascontiguousarray(np.asarray(dorsal, dtype=float).T), rows)
    if out is None:
        return rows.T
    out[...] = rows.T
    return out

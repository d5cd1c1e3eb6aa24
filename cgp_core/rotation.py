"""Rotations, vectorized over a leading batch axis.

Quaternions are stored as ``(x, y, z, w)`` — the order of ROS ``geometry_msgs/Quaternion`` and
scipy.spatial.transform — so state arrays go to messages without shuffling.  All functions accept a single
quaternion ``(4,)`` or a batch ``(N, 4)`` (vectors ``(3,)`` / ``(N, 3)``, matrices ``(3, 3)`` / ``(N, 3, 3)``) and
return the same rank.

scipy's ``Rotation`` is not used in the hot paths: building a ``Rotation`` object costs more than the
handful of multiply-adds below for the batch sizes of a scene, and we need the raw arrays anyway.
"""

from __future__ import annotations

import math

import numpy as np

IDENTITY_QUAT = np.array([0.0, 0.0, 0.0, 1.0])


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix ``[v]x`` with ``skew(v) @ u == cross(v, u)``; ``(..., 3) -> (..., 3, 3)``."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def norms(v: np.ndarray, keepdims: bool = False) -> np.ndarray:
    """Euclidean norms along the last axis: ``np.linalg.norm(v, axis=-1)``, the same arithmetic without its
    argument handling (which costs more than the sum itself for the few bodies of a scene)."""
    return np.sqrt(np.add.reduce(v * v, axis=-1, keepdims=keepdims))


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b for float (..., 3) arrays: the same products as ``np.cross``, which is general (any axis) and costs
    several times more than these few elementwise operations at both n = 1 and n = 1000 (this runs in the
    integrators' inner loop and the contact pipeline)."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(a.shape if a.shape == b.shape else np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = ay * bz - az * by
    out[..., 1] = az * bx - ax * bz
    out[..., 2] = ax * by - ay * bx
    return out


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternion(s) with ``w >= 0`` (the same rotation; the sign is fixed so outputs are canonical)."""
    q = np.asarray(q, dtype=float)
    q = q / norms(q, keepdims=True)
    return np.where(q[..., 3:4] < 0.0, -q, q)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` (apply ``b`` first, then ``a``)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = aw * bx + ax * bw + ay * bz - az * by
    out[..., 1] = aw * by - ax * bz + ay * bw + az * bx
    out[..., 2] = aw * bz + ax * by - ay * bx + az * bw
    out[..., 3] = aw * bw - ax * bx - ay * by - az * bz
    return out


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Inverse rotation of a unit quaternion."""
    q = np.array(q, dtype=float)
    q[..., :3] *= -1.0
    return q


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix ``R`` (columns = body axes in world coordinates) of unit quaternion(s) of any shape
    ``(..., 4)``: ``(..., 3, 3)``.  The formula's one home is :func:`quat_to_matrices`."""
    q = np.asarray(q, dtype=float)
    rows = np.ascontiguousarray(q.reshape(-1, 4))
    return quat_to_matrices(rows).reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion(s) of rotation matrix(es) (Shepperd's method: branch on the largest diagonal term so
    the square root never takes a small argument).  For a slightly non-orthogonal ``R`` (e.g. the lecture's
    explicit Euler update) this returns a quaternion close to its nearest rotation, normalized."""
    R = np.asarray(R, dtype=float)
    single = R.ndim == 2
    R = R.reshape(-1, 3, 3)
    m00, m11, m22 = R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]
    trace = m00 + m11 + m22
    q = np.empty((R.shape[0], 4))
    # candidates 4*w^2, 4*x^2, 4*y^2, 4*z^2 -> pick the largest per matrix
    cand = np.stack((1.0 + trace, 1.0 + m00 - m11 - m22, 1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22), axis=1)
    k = np.argmax(cand, axis=1)
    s = 2.0 * np.sqrt(np.maximum(cand[np.arange(len(k)), k], 1e-300))
    r21_m_r12 = R[:, 2, 1] - R[:, 1, 2]
    r02_m_r20 = R[:, 0, 2] - R[:, 2, 0]
    r10_m_r01 = R[:, 1, 0] - R[:, 0, 1]
    r01_p_r10 = R[:, 0, 1] + R[:, 1, 0]
    r02_p_r20 = R[:, 0, 2] + R[:, 2, 0]
    r12_p_r21 = R[:, 1, 2] + R[:, 2, 1]
    w_case = k == 0
    q[w_case] = np.stack((r21_m_r12, r02_m_r20, r10_m_r01, 0.25 * s * s), axis=1)[w_case] / s[w_case, None]
    x_case = k == 1
    q[x_case] = np.stack((0.25 * s * s, r01_p_r10, r02_p_r20, r21_m_r12), axis=1)[x_case] / s[x_case, None]
    y_case = k == 2
    q[y_case] = np.stack((r01_p_r10, 0.25 * s * s, r12_p_r21, r02_m_r20), axis=1)[y_case] / s[y_case, None]
    z_case = k == 3
    q[z_case] = np.stack((r02_p_r20, r12_p_r21, 0.25 * s * s, r10_m_r01), axis=1)[z_case] / s[z_case, None]
    q = quat_normalize(q)
    return q[0] if single else q


def quat_from_rotvec(phi: np.ndarray) -> np.ndarray:
    """Exponential map: the rotation by angle ``|phi|`` about ``phi/|phi|`` (a series near zero, no 0/0)."""
    phi = np.asarray(phi, dtype=float)
    angle = norms(phi, keepdims=True)
    half = 0.5 * angle
    small = angle < 1e-8
    # sin(a/2)/a ~ 1/2 - a^2/48 for small a
    safe = np.where(small, 1.0, angle)
    sinc_half = np.where(small, 0.5 - angle * angle / 48.0, np.sin(half) / safe)
    return np.concatenate((phi * sinc_half, np.cos(half)), axis=-1)


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Logarithm map (inverse of :func:`quat_from_rotvec`), angle in ``[0, pi]``."""
    q = quat_normalize(q)
    v = q[..., :3]
    s = norms(v, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., 3:4])
    small = s < 1e-12
    scale = np.where(small, 2.0, angle / np.where(small, 1.0, s))
    return v * scale


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vector(s) ``v`` by unit quaternion(s) ``q`` (``R(q) @ v`` without building ``R``)."""
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    u = q[..., :3]
    w = q[..., 3:4]
    t = 2.0 * cross3(u, v)
    return v + w * t + cross3(u, t)


def quat_from_euler(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Quaternion of fixed-axis roll (x), pitch (y), yaw (z), applied in that order (REP-103 RPY)."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.array(
        [
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ]
    )


# ---- one quaternion at a time, for the compiled kernels (cgp_core.jit) -------------------------------------
# The same formulas as quat_from_rotvec / quat_to_rotvec / quat_multiply / quat_rotate above, written for one
# quaternion with scalar arithmetic, so compiled loops call them without allocating.

from .jit import njit  # noqa: E402  (kept next to its only users)


@njit
def rotvec_to_quat_scalar(px, py, pz):
    """Exponential map of one rotation vector: ``(x, y, z, w)`` (a series near zero, no 0/0)."""
    angle = math.sqrt(px * px + py * py + pz * pz)
    if angle < 1e-8:
        sinc_half = 0.5 - angle * angle / 48.0  # sin(a/2)/a ~ 1/2 - a^2/48
    else:
        sinc_half = math.sin(0.5 * angle) / angle
    return px * sinc_half, py * sinc_half, pz * sinc_half, math.cos(0.5 * angle)


@njit
def quat_to_rotvec_scalar(x, y, z, w):
    """Logarithm map of one quaternion (normalized here, w >= 0 taken), angle in [0, pi]."""
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    s = math.sqrt(x * x + y * y + z * z)
    scale = 2.0 if s < 1e-12 else 2.0 * math.atan2(s, w) / s
    return x * scale, y * scale, z * scale


@njit
def quat_multiply_scalar(ax, ay, az, aw, bx, by, bz, bw):
    """Hamilton product ``a ⊗ b`` of two quaternions given by components."""
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


@njit
def quat_rotate_scalar(qx, qy, qz, qw, vx, vy, vz):
    """``R(q) v`` for one unit quaternion: v + w t + u × t with t = 2 u × v."""
    tx = 2.0 * (qy * vz - qz * vy)
    ty = 2.0 * (qz * vx - qx * vz)
    tz = 2.0 * (qx * vy - qy * vx)
    return (vx + qw * tx + (qy * tz - qz * ty),
            vy + qw * ty + (qz * tx - qx * tz),
            vz + qw * tz + (qx * ty - qy * tx))


@njit
def quat_to_matrices(q):
    """Rotation matrices ``R`` (columns = body axes in world coordinates) of ``(n, 4)`` unit quaternions
    ``(x, y, z, w)``, one compiled loop: ``(n, 3, 3)``.  :func:`quat_to_matrix` takes any shape."""
    R = np.empty((len(q), 3, 3))
    for i in range(len(q)):
        x, y, z, w = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
        xx, yy, zz = x * x, y * y, z * z
        xy, xz, yz = x * y, x * z, y * z
        wx, wy, wz = w * x, w * y, w * z
        R[i, 0, 0] = 1.0 - 2.0 * (yy + zz)
        R[i, 0, 1] = 2.0 * (xy - wz)
        R[i, 0, 2] = 2.0 * (xz + wy)
        R[i, 1, 0] = 2.0 * (xy + wz)
        R[i, 1, 1] = 1.0 - 2.0 * (xx + zz)
        R[i, 1, 2] = 2.0 * (yz - wx)
        R[i, 2, 0] = 2.0 * (xz - wy)
        R[i, 2, 1] = 2.0 * (yz + wx)
        R[i, 2, 2] = 1.0 - 2.0 * (xx + yy)
    return R

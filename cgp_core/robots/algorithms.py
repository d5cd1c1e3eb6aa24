"""The recursive algorithms of a robot's tree (Featherstone, *Rigid Body Dynamics Algorithms*, 2008), compiled.

Each is a plain loop over the bodies, parent before child (or the reverse), in the style of MuJoCo's
``engine_core_smooth.c`` (``mj_kinematics``, ``mj_crb``, ``mj_rne``), reading the ``RobotArrays`` bundle of a
:class:`~cgp_core.robots.model.RobotModel` (``model.arrays``).  Joint conventions (what ``q`` and ``qd`` mean,
the floating root's world-frame velocity) are in :mod:`cgp_core.robots.model`.

Coordinates: spatial vectors in world coordinates at the world origin.  Featherstone writes the recursions in
each body's own coordinates, with a 6×6 Plücker transform ``X`` from parent to child at every step.  Here, as in
MuJoCo, every spatial quantity is expressed once in one frame — the world's axes, about the world origin — so the
recursions add vectors without transforming them; only the joint's motion subspace and the body's inertia are
put into world coordinates, from the poses forward kinematics computed.  The conventions:

- a motion vector (spatial velocity, acceleration, a joint's motion-subspace column) is ``(ω, v_O)`` (6,): the
  angular velocity and the velocity of the body point that passes through the world origin [rad/s, m/s]; the
  velocity of a point ``p`` fixed to the body is ``v_O + ω × p``;
- a force vector is ``(n_O, f)``: the torque about the world origin and the force [N m, N];
- a body's spatial inertia (mass ``m``, world COM ``c``, world inertia about the COM ``I_c = R I Rᵀ``) is
  ``[[I_c + m [c]×[c]×ᵀ, m [c]×], [m [c]×ᵀ, m 1]]`` — the parallel-axis theorem and the momentum ``m (v_O + ω × c)``
  in one matrix;
- cross products ``(ω, v) ×ₘ (a, b) = (ω × a, ω × b + v × a)`` and ``(ω, v) ×_f (n, f) = (ω × n + v × f, ω × f)``.

The lecture (Eberly, *Game Physics*; the seed slides) integrates free rigid bodies in world coordinates about
their COM with ``L = I_world ω``; for a single free body the equations below reduce to the same Newton–Euler
equations written about the world origin instead of the COM (the parallel-axis term moves them).  Accelerations
here are *spatial* accelerations (the derivative of ``(ω, v_O)``), not the classical acceleration of a point;
gravity enters as an acceleration of the base, ``a_0 = (0, −g)`` (Featherstone §5.3), so it acts on every body
through the recursion.

Functions (n bodies, f frames, n_dofs velocities, n_q positions; world frame, SI units):

- :func:`forward_kinematics`, :func:`frame_poses` — poses;
- :func:`motion_subspace` — every dof's world motion vector (MuJoCo's ``cdof``);
- :func:`body_velocities`, :func:`point_jacobian`, :func:`angular_jacobian`;
- :func:`mass_matrix` — composite rigid bodies, ``M(q)`` (n_dofs, n_dofs);
- :func:`inverse_dynamics` — recursive Newton–Euler, ``τ = M(q) q̈ + b(q, q̇) − Σ Jᵀ f_ext``; :func:`bias_forces`;
- :func:`forward_dynamics` — ``q̈ = M⁻¹ (τ − b)`` by a dense Cholesky factorization (not ABA: the solver needs
  ``M`` and its factor anyway, and for the tens of dofs of an arm the O(n³) is microseconds);
- :func:`integrate_positions` — ``q ← q ⊕ h q̇`` (the floating root's quaternion by the exponential map).

Each takes the bundle as it is or as a plain tuple (``tuple(model.arrays)``, named again first thing): the rule of
:mod:`cgp_core.jit` for kernels Python calls every sub-step (numba's dispatcher types a plain tuple faster: 6.0 µs
against 7.4 µs per ``mass_matrix`` call of a 3-dof arm, measured).  The world calls them with the plain tuple
only, and they hand it on to each other as one again (``arrays[:]``: a namedtuple's fields as a plain tuple):
numba compiles a function once per argument type, and the namedtuple was a second compile of each function called
both ways (~1-2 s of CPU each, issue 34).  All run as plain Python under ``NUMBA_DISABLE_JIT=1`` with the same
results.

The lecture's rigid body keeps momenta in its state (``P``, ``L``; ``ω = J⁻¹ L``); a tree's state here is ``(q,
qd)`` and its momentum ``M(q) qd`` is not integrated directly: forward dynamics solves ``M qdd = τ − b`` each
time, the joint-space form of ``dL/dt = τ`` with ``b`` holding the ``ω × L`` terms.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit import njit
from ..rotation import quat_multiply_scalar, rotvec_to_quat_scalar
from .model import (
    JOINT_BALL,
    JOINT_FLOATING,
    JOINT_PLANAR,
    JOINT_PRISMATIC,
    JOINT_REVOLUTE,
    RobotArrays,
    RobotStarts,
)

__all__ = ["forward_kinematics", "frame_poses", "motion_subspace", "body_velocities", "point_jacobian",
           "angular_jacobian", "spatial_inertias", "mass_matrix", "inverse_dynamics", "bias_forces",
           "forward_dynamics", "integrate_positions", "cholesky_solve", "joint_space_terms", "advance", "robot_view",
           "advance_all"]


# ---- small 3-vector helpers ---------------------------------------------------------------------------------
#
# Those the recursions call per body write into an output the caller allocated once (``out``): in compiled code
# each small array a helper allocates costs a heap allocation and its reference counting, ~10× the arithmetic of
# a 3 × 3 product (measured: ~200 against ~12 ns per call on this 2-core machine under load).
#
# Rows of the per-body arrays (``rotation[i]``, ``S[d]``, ``inertias[i]``) are read in place, by index, not as
# views: in compiled code a view is an array of its own, with a reference-count update when made and one when
# dropped, and the recursions made ~20 per body (measured on a KUKA iiwa's 8 bodies: forward kinematics 1.5 µs
# with views, 0.5 µs reading in place; the same products in the same order, the same bits).  Hence the ``_at``
# helpers, which take a stack and a row.

@njit
def _mat_mul(A, B, out):
    """``out = A B`` (3, 3); ``out`` must not be ``A`` or ``B``."""
    for r in range(3):
        for c in range(3):
            out[r, c] = A[r, 0] * B[0, c] + A[r, 1] * B[1, c] + A[r, 2] * B[2, c]


@njit
def _mat_vec(A, v, out):
    """``out = A v`` (3,); ``out`` must not be ``v``."""
    for r in range(3):
        out[r] = A[r, 0] * v[0] + A[r, 1] * v[1] + A[r, 2] * v[2]


@njit
def _mat_mul_at(A, a, B, b, out):
    """``out = A[a] B[b]`` (3, 3): rows ``a`` of ``A`` (k, 3, 3) and ``b`` of ``B`` (m, 3, 3), read in place."""
    for r in range(3):
        for c in range(3):
            out[r, c] = A[a, r, 0] * B[b, 0, c] + A[a, r, 1] * B[b, 1, c] + A[a, r, 2] * B[b, 2, c]


@njit
def _mat_vec_at(A, a, v, b, out):
    """``out = A[a] v[b]`` (3,): rows ``a`` of ``A`` (k, 3, 3) and ``b`` of ``v`` (m, 3), read in place."""
    for r in range(3):
        out[r] = A[a, r, 0] * v[b, 0] + A[a, r, 1] * v[b, 1] + A[a, r, 2] * v[b, 2]


@njit
def _cross(a, b):
    out = np.empty(3)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


@njit
def _axis_rotation(axis, angle, R):
    """Rodrigues: ``R`` (3, 3) = the rotation by ``angle`` [rad] about the unit ``axis`` (3,)."""
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 - c
    x, y, z = axis[0], axis[1], axis[2]
    R[0, 0] = t * x * x + c
    R[0, 1] = t * x * y - s * z
    R[0, 2] = t * x * z + s * y
    R[1, 0] = t * x * y + s * z
    R[1, 1] = t * y * y + c
    R[1, 2] = t * y * z - s * x
    R[2, 0] = t * x * z - s * y
    R[2, 1] = t * y * z + s * x
    R[2, 2] = t * z * z + c


@njit
def _quat_matrix(x, y, z, w, R):
    """``R`` (3, 3) = the rotation matrix of the quaternion (x, y, z, w), normalized first."""
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    R[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R[0, 1] = 2.0 * (x * y - w * z)
    R[0, 2] = 2.0 * (x * z + w * y)
    R[1, 0] = 2.0 * (x * y + w * z)
    R[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R[1, 2] = 2.0 * (y * z - w * x)
    R[2, 0] = 2.0 * (x * z - w * y)
    R[2, 1] = 2.0 * (y * z + w * x)
    R[2, 2] = 1.0 - 2.0 * (x * x + y * y)


# (inlined: its callers pass literal offsets, and numba compiled a separate function for each combination of them)
@njit(inline="always")
def _cross_into(a, i, b, j, out, k):
    """``out[k:k+3] = a[i:i+3] × b[j:j+3]`` (no temporaries: see :func:`_rnea`)."""
    out[k] = a[i + 1] * b[j + 2] - a[i + 2] * b[j + 1]
    out[k + 1] = a[i + 2] * b[j] - a[i] * b[j + 2]
    out[k + 2] = a[i] * b[j + 1] - a[i + 1] * b[j]


@njit
def _motion_cross(V, S, out, scratch):
    """``out = V ×ₘ S`` of two motion vectors (6,) (ω × S_ω, ω × S_v + v × S_ω); ``scratch`` (3,)."""
    _cross_into(V, 0, S, 0, out, 0)
    _cross_into(V, 0, S, 3, out, 3)
    _cross_into(V, 3, S, 0, scratch, 0)
    for k in range(3):
        out[3 + k] += scratch[k]


@njit
def _force_cross(V, F, out, scratch):
    """``out = V ×_f F`` of a motion vector and a force vector (6,) (ω × n + v × f, ω × f); ``scratch`` (3,)."""
    _cross_into(V, 0, F, 0, out, 0)
    _cross_into(V, 3, F, 3, scratch, 0)
    for k in range(3):
        out[k] += scratch[k]
    _cross_into(V, 0, F, 3, out, 3)


@njit
def _joint_frame(parent, joint_rotation, joint_position, rotation, position, i, frame_rotation, frame_origin):
    """Body ``i``'s joint frame in the world, written into ``frame_rotation`` (3, 3) and ``frame_origin`` (3,):
    its parent's pose times the joint frame's pose in the parent (the world's for the root).  Takes the
    RobotArrays fields it reads, not the bundle: a bundle handed to a compiled helper costs a reference-count
    update per array per call (~20 arrays: more than this helper's arithmetic, measured)."""
    p = parent[i]
    if p < 0:
        for r in range(3):
            frame_origin[r] = joint_position[i, r]
            for c in range(3):
                frame_rotation[r, c] = joint_rotation[i, r, c]
        return
    _mat_mul_at(rotation, p, joint_rotation, i, frame_rotation)
    _mat_vec_at(rotation, p, joint_position, i, frame_origin)
    for k in range(3):
        frame_origin[k] += position[p, k]


# ---- kinematics ------------------------------------------------------------------------------------------------

@njit
def forward_kinematics(arrays, q):
    """World pose of every body frame: ``R_i = R_p R_J,i R_q,i(q)``, ``x_i = x_p + R_p p_J,i + R_J,i t_q,i(q)``
    (parent before child; ``R_J``, ``p_J``: the joint frame in the parent; ``R_q``, ``t_q``: the joint's motion,
    see :mod:`~cgp_core.robots.model`).

    Args: arrays: :class:`RobotArrays`; q: (n_q,) joint positions [rad, m; quaternion for a floating root].
    Returns: ``(rotation (n, 3, 3), position (n, 3) [m])``, world frame.
    """
    arrays = RobotArrays(*arrays)
    n = len(arrays.parent)
    rotation = np.empty((n, 3, 3))
    position = np.empty((n, 3))
    Rj, xj = np.empty((3, 3)), np.empty(3)        # the joint frame in the world
    turn, slide = np.empty((3, 3)), np.empty(3)   # the joint's motion in it (work space, see the helpers)
    moved, turned = np.empty(3), np.empty((3, 3))
    for i in range(n):
        # the joint frame in the world (:func:`_joint_frame`, written out: a call per body with its seven arrays
        # cost more than its products, measured ~80 ns)
        p = arrays.parent[i]
        if p < 0:
            for r in range(3):
                xj[r] = arrays.joint_position[i, r]
                for c in range(3):
                    Rj[r, c] = arrays.joint_rotation[i, r, c]
        else:
            _mat_mul_at(rotation, p, arrays.joint_rotation, i, Rj)
            _mat_vec_at(rotation, p, arrays.joint_position, i, xj)
            for k in range(3):
                xj[k] += position[p, k]
        kind = arrays.joint_type[i]
        s = arrays.q_start[i]
        if kind == JOINT_REVOLUTE or kind == JOINT_PLANAR or kind == JOINT_FLOATING or kind == JOINT_BALL:
            if kind == JOINT_REVOLUTE or kind == JOINT_PLANAR:
                _axis_rotation(arrays.joint_axis[i], q[s] if kind == JOINT_REVOLUTE else q[s + 2], turn)
            elif kind == JOINT_FLOATING:
                _quat_matrix(q[s + 3], q[s + 4], q[s + 5], q[s + 6], turn)
            else:  # a ball: turned about the joint frame's origin (the ball's centre)
                _quat_matrix(q[s], q[s + 1], q[s + 2], q[s + 3], turn)
            _mat_mul(Rj, turn, turned)
            for r in range(3):
                for c in range(3):
                    rotation[i, r, c] = turned[r, c]
        else:
            for r in range(3):
                for c in range(3):
                    rotation[i, r, c] = Rj[r, c]
        for k in range(3):
            position[i, k] = xj[k]
        if kind == JOINT_PRISMATIC or kind == JOINT_PLANAR or kind == JOINT_FLOATING:
            for k in range(3):  # the translation in the joint frame
                if kind == JOINT_PRISMATIC:
                    slide[k] = arrays.joint_axis[i, k] * q[s]
                elif kind == JOINT_PLANAR:
                    slide[k] = arrays.plane_u[i, k] * q[s] + arrays.plane_v[i, k] * q[s + 1]
                else:
                    slide[k] = q[s + k]
            _mat_vec(Rj, slide, moved)
            for k in range(3):
                position[i, k] = xj[k] + moved[k]
    return rotation, position


@njit
def frame_poses(arrays, rotation, position):
    """World pose of every frame (every URDF link): ``R_f = R_b R_f,b``, ``x_f = x_b + R_b p_f,b`` with ``b`` its
    body.  Args: the body poses from :func:`forward_kinematics`.  Returns ``(rotation (f, 3, 3), position (f, 3))``."""
    arrays = RobotArrays(*arrays)
    f = len(arrays.frame_body)
    out_r = np.empty((f, 3, 3))
    out_x = np.empty((f, 3))
    moved = np.empty(3)
    for k in range(f):
        b = arrays.frame_body[k]
        _mat_mul(rotation[b], arrays.frame_rotation[k], out_r[k])
        _mat_vec(rotation[b], arrays.frame_position[k], moved)
        for r in range(3):
            out_x[k, r] = position[b, r] + moved[r]
    return out_r, out_x


@njit
def motion_subspace(arrays, rotation, position):
    """Every dof's motion vector ``S_d = (ω, v_O)`` (world axes, about the world origin; MuJoCo's ``cdof``): the
    spatial velocity of its body per unit of ``qd[d]`` with every other velocity zero.  Revolute: ``(a, x × a)``
    with ``a`` the world axis and ``x`` the body origin (on the axis); prismatic: ``(0, a)``; planar: ``(0, u)``,
    ``(0, v)``, ``(a, x × a)``; floating: ``(0, e_k)`` and ``(e_k, x × e_k)``; ball: ``(a_k, x × a_k)`` with
    ``a_k`` the joint frame's k-th axis in the world (three revolute columns through the ball's centre ``x``).

    Returns S (n_dofs, 6)."""
    arrays = RobotArrays(*arrays)
    S = np.zeros((arrays.n_dofs, 6))
    a, Rj, xj = np.empty(3), np.empty((3, 3)), np.empty(3)  # an axis in the world, a joint frame (work space)
    for i in range(len(arrays.parent)):
        kind = arrays.joint_type[i]
        d = arrays.dof_start[i]
        if kind == JOINT_REVOLUTE:  # (a, x × a), in place (the helpers' note on views)
            _mat_vec_at(rotation, i, arrays.joint_axis, i, a)
            for k in range(3):
                S[d, k] = a[k]
            S[d, 3] = position[i, 1] * a[2] - position[i, 2] * a[1]
            S[d, 4] = position[i, 2] * a[0] - position[i, 0] * a[2]
            S[d, 5] = position[i, 0] * a[1] - position[i, 1] * a[0]
            continue
        x = position[i]
        if kind == JOINT_PRISMATIC:
            _mat_vec(rotation[i], arrays.joint_axis[i], a)
            S[d, 3:6] = a
        elif kind == JOINT_PLANAR:
            _joint_frame(arrays.parent, arrays.joint_rotation, arrays.joint_position, rotation, position, i, Rj, xj)
            _mat_vec(Rj, arrays.plane_u[i], a)
            S[d, 3:6] = a
            _mat_vec(Rj, arrays.plane_v[i], a)
            S[d + 1, 3:6] = a
            _mat_vec(rotation[i], arrays.joint_axis[i], a)
            S[d + 2, 0:3] = a
            _cross_into(x, 0, a, 0, S[d + 2], 3)
        elif kind == JOINT_FLOATING:
            for k in range(3):
                S[d + k, 3 + k] = 1.0
                a[:] = 0.0
                a[k] = 1.0
                S[d + 3 + k, 0:3] = a
                _cross_into(x, 0, a, 0, S[d + 3 + k], 3)
        elif kind == JOINT_BALL:
            _joint_frame(arrays.parent, arrays.joint_rotation, arrays.joint_position, rotation, position, i, Rj, xj)
            for k in range(3):
                for r in range(3):
                    a[r] = Rj[r, k]
                S[d + k, 0:3] = a
                _cross_into(x, 0, a, 0, S[d + k], 3)
    return S


@njit
def _spatial_velocities(arrays, S, qd):
    """(n, 6) every body's spatial velocity ``V_i = V_p + Σ_d S_d qd_d``."""
    n = len(arrays.parent)
    V = np.zeros((n, 6))
    for i in range(n):
        p = arrays.parent[i]
        if p >= 0:
            for k in range(6):
                V[i, k] = V[p, k]
        for d in range(arrays.dof_start[i], arrays.dof_start[i] + arrays.dof_count[i]):
            for k in range(6):
                V[i, k] += S[d, k] * qd[d]
    return V


@njit
def body_velocities(arrays, q, qd, rotation, position):
    """World velocity of every body frame's origin and every body's angular velocity: ``v_i = v_O,i + ω_i × x_i``
    from the spatial velocity ``(ω_i, v_O,i) = Σ_{d ∈ ancestors(i)} S_d qd_d``.

    Args: q (n_q,) (unused: the poses carry it; kept for the signature), qd (n_dofs,), the body poses from
    :func:`forward_kinematics`.  Returns ``(linear (n, 3) [m/s], angular (n, 3) [rad/s])``."""
    arrays = RobotArrays(*arrays)
    S = motion_subspace(arrays, rotation, position)
    V = _spatial_velocities(arrays, S, qd)
    n = len(arrays.parent)
    linear = np.empty((n, 3))
    angular = np.empty((n, 3))
    turning = np.empty(3)  # ω_i × x_i (work space)
    for i in range(n):
        turning[0] = V[i, 1] * position[i, 2] - V[i, 2] * position[i, 1]
        turning[1] = V[i, 2] * position[i, 0] - V[i, 0] * position[i, 2]
        turning[2] = V[i, 0] * position[i, 1] - V[i, 1] * position[i, 0]
        for k in range(3):
            angular[i, k] = V[i, k]
            linear[i, k] = V[i, 3 + k] + turning[k]
    return linear, angular


@njit
def point_jacobian(arrays, rotation, position, body, point):
    """``J`` (3, n_dofs) with ``J qd`` the world velocity [m/s] of the world point ``point`` (3,) [m] moving with
    ``body``: column ``d`` is ``v_O,d + ω_d × point`` for the dofs of ``body`` and its ancestors, zero elsewhere."""
    arrays = RobotArrays(*arrays)
    S = motion_subspace(arrays, rotation, position)
    J = np.zeros((3, arrays.n_dofs))
    i = body
    while i >= 0:
        for d in range(arrays.dof_start[i], arrays.dof_start[i] + arrays.dof_count[i]):
            J[:, d] = S[d, 3:6] + _cross(S[d, 0:3], point)
        i = arrays.parent[i]
    return J


@njit
def angular_jacobian(arrays, rotation, position, body):
    """``J`` (3, n_dofs) with ``J qd`` the world angular velocity [rad/s] of ``body``."""
    arrays = RobotArrays(*arrays)
    S = motion_subspace(arrays, rotation, position)
    J = np.zeros((3, arrays.n_dofs))
    i = body
    while i >= 0:
        for d in range(arrays.dof_start[i], arrays.dof_start[i] + arrays.dof_count[i]):
            J[:, d] = S[d, 0:3]
        i = arrays.parent[i]
    return J


# ---- dynamics --------------------------------------------------------------------------------------------------

@njit
def spatial_inertias(arrays, rotation, position):
    """(n, 6, 6) every body's spatial inertia in world coordinates about the world origin (module docstring):
    ``[[I_c + m [c]×[c]×ᵀ, m [c]×], [m [c]×ᵀ, m 1]]``, ``c = x + R com``, ``I_c = R I Rᵀ`` [kg m², kg m, kg]."""
    arrays = RobotArrays(*arrays)
    n = len(arrays.parent)
    out = np.zeros((n, 6, 6))
    c, RI, RT, Ic = np.empty(3), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))  # work space
    for i in range(n):
        m = arrays.mass[i]
        _mat_vec_at(rotation, i, arrays.com, i, c)
        for k in range(3):
            c[k] += position[i, k]
            for r in range(3):
                RT[r, k] = rotation[i, k, r]
        _mat_mul_at(rotation, i, arrays.inertia, i, RI)
        _mat_mul(RI, RT, Ic)
        cc = c[0] * c[0] + c[1] * c[1] + c[2] * c[2]
        for r in range(3):
            for k in range(3):
                out[i, r, k] = Ic[r, k] + m * ((cc if r == k else 0.0) - c[r] * c[k])
            out[i, 3 + r, 3 + r] = m
        # m [c]× in the upper right, its transpose in the lower left
        out[i, 0, 4], out[i, 0, 5] = -m * c[2], m * c[1]
        out[i, 1, 3], out[i, 1, 5] = m * c[2], -m * c[0]
        out[i, 2, 3], out[i, 2, 4] = -m * c[1], m * c[0]
        for r in range(3):
            for k in range(3):
                out[i, 3 + k, r] = out[i, r, 3 + k]
    return out


@njit
def _spatial_times_at(A, i, v, d, out):
    """``out = A[i] v[d]`` (6,) of a 6 × 6 matrix (row ``i`` of ``A`` (k, 6, 6)) and a 6-vector (row ``d`` of ``v``
    (m, 6)), read in place, as a plain loop (numba's ``@`` calls BLAS, whose call costs more than these 36
    products; and the sum order is the same compiled and in plain Python)."""
    for r in range(6):
        s = 0.0
        for c in range(6):
            s += A[i, r, c] * v[d, c]
        out[r] = s


@njit
def _dot6_at(a, B, e):
    """``a · B[e]`` of a 6-vector and row ``e`` of ``B`` (m, 6), read in place (a plain loop: see
    :func:`_spatial_times_at`)."""
    s = 0.0
    for c in range(6):
        s += a[c] * B[e, c]
    return s


@njit
def _mass_matrix(arrays, S, inertias):
    """Composite rigid bodies: ``I^c_i = I_i + Σ_children I^c_j`` (all in one frame: plain sums), then
    ``M[d, e] = S_dᵀ I^c_{body(d)} S_e`` for ``e`` a dof of ``body(d)`` or an ancestor (Featherstone §6.2)."""
    n = len(arrays.parent)
    composite = inertias.copy()
    for i in range(n - 1, 0, -1):
        p = arrays.parent[i]
        if p >= 0:
            for r in range(6):
                for c in range(6):
                    composite[p, r, c] += composite[i, r, c]
    M = np.zeros((arrays.n_dofs, arrays.n_dofs))
    F = np.empty(6)
    for i in range(n):
        for d in range(arrays.dof_start[i], arrays.dof_start[i] + arrays.dof_count[i]):
            _spatial_times_at(composite, i, S, d, F)
            j = i
            while j >= 0:
                for e in range(arrays.dof_start[j], arrays.dof_start[j] + arrays.dof_count[j]):
                    value = _dot6_at(F, S, e)
                    M[d, e] = value
                    M[e, d] = value
                j = arrays.parent[j]
    return M


@njit
def mass_matrix(arrays, q):
    """The joint-space mass matrix ``M(q)`` (n_dofs, n_dofs), symmetric positive definite (kinetic energy
    ``½ qdᵀ M qd``), by the composite-rigid-body algorithm (Featherstone §6.2; MuJoCo ``mj_crb``).  Units: kg m²
    on revolute rows/columns, kg on prismatic ones, kg m mixed."""
    arrays = RobotArrays(*arrays)
    rotation, position = forward_kinematics(arrays[:], q)
    S = motion_subspace(arrays, rotation, position)
    return _mass_matrix(arrays, S, spatial_inertias(arrays, rotation, position))


@njit
def _joint_bias(kind, d, i, S, qd, V, parent_velocity, out, column, scratch):
    """``out = Ṡ qd`` of body ``i``'s joint (6,): the acceleration its subspace's own motion adds.  A column fixed
    in a body moving with spatial velocity ``W`` changes as ``W ×ₘ S``: revolute, prismatic, ball (its columns are
    the joint frame's axes, fixed in the parent) and the planar translations are fixed in the parent, the planar
    rotation in the child; the floating root's rotation columns move with its origin (``W = (0, v)``), giving
    ``(0, v × ω)``.  (``kind``, ``d``: body ``i``'s joint type and first dof: numbers, not the bundle, see
    :func:`_joint_frame`; ``column`` (6,) and ``scratch`` (3,): work space, see :func:`_rnea`.)"""
    out[:] = 0.0
    if kind == JOINT_REVOLUTE or kind == JOINT_PRISMATIC or kind == JOINT_BALL or kind == JOINT_PLANAR:
        moved = 3 if kind == JOINT_BALL else 2 if kind == JOINT_PLANAR else 1  # columns fixed in the parent
        for k in range(6):  # Σ S_d qd_d over them
            column[k] = S[d, k] * qd[d]
            for e in range(d + 1, d + moved):
                column[k] += S[e, k] * qd[e]
        _motion_cross(parent_velocity, column, out, scratch)
        if kind == JOINT_PLANAR:  # its rotation column, fixed in the child
            for k in range(6):
                column[k] = S[d + 2, k] * qd[d + 2]
            rotation = np.empty(6)
            _motion_cross(V[i], column, rotation, scratch)
            for k in range(6):
                out[k] += rotation[k]
    elif kind == JOINT_FLOATING:
        _cross_into(qd, d, qd, d + 3, out, 3)


@njit
def _rnea(arrays, S, inertias, qd, qdd, gravity, f_ext):
    """The two passes of the recursive Newton–Euler algorithm (Featherstone §5.3; MuJoCo ``mj_rne``).  Per body,
    in vector form: ``V_i = V_p + Σ S_d qd_d``, ``A_i = A_p + Σ S_d qdd_d + Ṡ qd``, ``F_i = I_i A_i + V_i ×_f I_i
    V_i − f_ext,i``; then ``τ_d = S_d · F_i`` and ``F_p += F_i`` from the leaves.  Written as loops over
    preallocated 6-vectors: a small array allocated per body and operation (~25 per body) cost more than the
    arithmetic (measured on a KUKA iiwa's 8 bodies: from 3.0× to 0.6× the time of its forward kinematics)."""
    n = len(arrays.parent)
    V = np.zeros((n, 6))
    A = np.zeros((n, 6))
    F = np.zeros((n, 6))
    base = np.zeros(6)
    base[3:6] = -gravity
    # work 6-vectors: the parent's V and A (the base's for the root), this body's V, the joint's velocity and
    # acceleration, Ṡ qd, I A, I V, V ×_f I V, a column of S, this body's F; copies of rows, not views (the
    # helpers' note)
    Vp, Ap, Vi, vJ, aJ, bias, IA, IV, fc, column, Fi = (np.empty(6), np.empty(6), np.empty(6), np.empty(6),
                                                        np.empty(6), np.empty(6), np.empty(6), np.empty(6),
                                                        np.empty(6), np.empty(6), np.empty(6))
    scratch = np.empty(3)
    for i in range(n):
        p = arrays.parent[i]
        for k in range(6):
            Vp[k] = V[p, k] if p >= 0 else 0.0
            Ap[k] = A[p, k] if p >= 0 else base[k]
            vJ[k] = 0.0
            aJ[k] = 0.0
        for d in range(arrays.dof_start[i], arrays.dof_start[i] + arrays.dof_count[i]):
            for k in range(6):
                vJ[k] += S[d, k] * qd[d]
                aJ[k] += S[d, k] * qdd[d]
        for k in range(6):
            V[i, k] = Vp[k] + vJ[k]
            Vi[k] = V[i, k]
        kind = arrays.joint_type[i]
        if kind == JOINT_REVOLUTE or kind == JOINT_PRISMATIC:
            # Ṡ qd = V_p ×ₘ (S_d qd_d), the axis fixed in the parent: :func:`_joint_bias`'s first case written out
            # (the call, with its seven arrays, cost more than these products: ~50 ns a body)
            d = arrays.dof_start[i]
            for k in range(6):
                column[k] = S[d, k] * qd[d]
            _motion_cross(Vp, column, bias, scratch)
        else:
            _joint_bias(kind, arrays.dof_start[i], i, S, qd, V, Vp, bias, column, scratch)
        for k in range(6):
            A[i, k] = Ap[k] + aJ[k] + bias[k]
        _spatial_times_at(inertias, i, A, i, IA)
        _spatial_times_at(inertias, i, V, i, IV)
        _force_cross(Vi, IV, fc, scratch)
        for k in range(6):
            F[i, k] = IA[k] + fc[k] - f_ext[i, k]
    tau = np.zeros(arrays.n_dofs)
    for i in range(n - 1, -1, -1):
        for k in range(6):
            Fi[k] = F[i, k]
        for d in range(arrays.dof_start[i], arrays.dof_start[i] + arrays.dof_count[i]):
            tau[d] = _dot6_at(Fi, S, d)
        p = arrays.parent[i]
        if p >= 0:
            for k in range(6):
                F[p, k] += F[i, k]
    return tau


@njit
def _external_forces(arrays, rotation, position, f_ext):
    """(n, 6) spatial forces ``(τ + c × f, f)`` about the world origin of world forces ``f_ext[:, 0:3]`` [N] and
    torques ``f_ext[:, 3:6]`` [N m] given about each body's COM ``c``."""
    n = len(arrays.parent)
    out = np.zeros((n, 6))
    c = np.empty(3)
    for i in range(n):
        _mat_vec(rotation[i], arrays.com[i], c)
        for k in range(3):
            c[k] += position[i, k]
        out[i, 0:3] = f_ext[i, 3:6] + _cross(c, f_ext[i, 0:3])
        out[i, 3:6] = f_ext[i, 0:3]
    return out


@njit
def inverse_dynamics(arrays, q, qd, qdd, gravity, f_ext=None):
    """The joint forces that give ``qdd``: ``τ = M(q) qdd + b(q, qd) − Σ_i J_iᵀ f_ext,i`` by the recursive
    Newton–Euler algorithm (Featherstone §5.3, RNEA; MuJoCo ``mj_rne``): a forward pass of spatial velocities
    ``V_i = V_p + S_i qd_i`` and accelerations ``A_i = A_p + S_i qdd_i + Ṡ_i qd_i`` (``A_0 = (0, −g)``: gravity
    as a base acceleration), the body forces ``F_i = I_i A_i + V_i ×_f I_i V_i − f_ext,i``, then a backward pass
    summing them into the parents, ``τ_d = S_dᵀ F_{body(d)}``.

    Args:
        arrays: :class:`RobotArrays`; q (n_q,); qd, qdd (n_dofs,) [rad/s, rad/s², m/s, m/s²].
        gravity: (3,) [m/s²], e.g. (0, 0, −9.81).
        f_ext: optional (n, 6) world force [N] (columns 0:3) and torque about the body's COM [N m] (3:6) acting on
            each body.
    Returns: τ (n_dofs,) [N m or N; the floating root: world force at its origin and world torque].
    """
    arrays = RobotArrays(*arrays)
    rotation, position = forward_kinematics(arrays[:], q)
    S = motion_subspace(arrays, rotation, position)
    inertias = spatial_inertias(arrays, rotation, position)
    n = len(arrays.parent)
    if f_ext is None:
        external = np.zeros((n, 6))
    else:
        external = _external_forces(arrays, rotation, position, f_ext)
    return _rnea(arrays, S, inertias, qd, qdd, gravity, external)


@njit
def bias_forces(arrays, q, qd, gravity):
    """``b(q, qd)`` (n_dofs,): Coriolis, centrifugal and gravity forces, :func:`inverse_dynamics` with qdd = 0."""
    arrays = RobotArrays(*arrays)
    return inverse_dynamics(arrays[:], q, qd, np.zeros(arrays.n_dofs), gravity)


@njit
def joint_space_terms(arrays, q, qd, gravity):
    """``(M(q), b(q, qd))``: :func:`mass_matrix` and :func:`inverse_dynamics` at qdd = 0 in one call, sharing the
    poses, motion subspaces and spatial inertias the two would each compute (the robot stage needs both every
    sub-step); the same numbers as the two calls."""
    arrays = RobotArrays(*arrays)
    rotation, position = forward_kinematics(arrays[:], q)
    S = motion_subspace(arrays, rotation, position)
    inertias = spatial_inertias(arrays, rotation, position)
    M = _mass_matrix(arrays, S, inertias)
    return M, _rnea(arrays, S, inertias, qd, np.zeros(arrays.n_dofs), gravity, np.zeros((len(arrays.parent), 6)))


class BodyMotion(NamedTuple):
    """The poses and velocities of ``B`` robot bodies (their joint frames) in the world."""

    rotation: np.ndarray  # (B, 3, 3) body-to-world rotation
    position: np.ndarray  # (B, 3) joint-frame origin [m]
    linear: np.ndarray    # (B, 3) velocity of that origin [m/s]
    angular: np.ndarray   # (B, 3) angular velocity [rad/s]


class LinkInertia(NamedTuple):
    """The mass properties of ``k`` link bodies (their world bodies' rows)."""

    com: np.ndarray           # (k, 3) COM in the robot body's frame [m]
    mass: np.ndarray          # (k,) [kg]
    inertia_body: np.ndarray  # (k, 3, 3) about the COM in body axes [kg m²]


class BodyStateArrays(NamedTuple):
    """The world's body state arrays a link body's state is written into (in place)."""

    position: np.ndarray          # (n, 3) COM [m]
    orientation: np.ndarray       # (n, 4) quaternion xyzw
    rotation: np.ndarray          # (n, 3, 3), or (0, 3, 3): none kept
    linear_momentum: np.ndarray   # (n, 3) [kg m/s]
    angular_momentum: np.ndarray  # (n, 3) [kg m²/s]


@njit
def advance(arrays, q, moving, qd, h):
    """The robot stage's end of a sub-step in one call: ``q_new = integrate_positions(q, moving, h)``, the bodies'
    poses there (:func:`forward_kinematics`) and their velocities with ``qd`` (:func:`body_velocities`):
    ``(q_new, BodyMotion)``."""
    arrays = RobotArrays(*arrays)
    q_new = integrate_positions(arrays[:], q, moving, h)
    rotation, position = forward_kinematics(arrays[:], q_new)
    linear, angular = body_velocities(arrays[:], q_new, qd, rotation, position)
    return q_new, BodyMotion(rotation, position, linear, angular)


@njit
def cholesky_solve(M, b):
    """``x = M⁻¹ b`` for a symmetric positive definite ``M`` (k, k) by ``M = L Lᵀ`` (plain loops; a zero or
    negative pivot gives nan, which the caller's blow-up checks see)."""
    k = len(b)
    L = np.zeros((k, k))
    for j in range(k):
        s = M[j, j]
        for m in range(j):
            s -= L[j, m] * L[j, m]
        L[j, j] = math.sqrt(s) if s > 0.0 else math.nan
        for r in range(j + 1, k):
            s = M[r, j]
            for m in range(j):
                s -= L[r, m] * L[j, m]
            L[r, j] = s / L[j, j]
    y = np.zeros(k)
    for r in range(k):
        s = b[r]
        for m in range(r):
            s -= L[r, m] * y[m]
        y[r] = s / L[r, r]
    x = np.zeros(k)
    for r in range(k - 1, -1, -1):
        s = y[r]
        for m in range(r + 1, k):
            s -= L[m, r] * x[m]
        x[r] = s / L[r, r]
    return x


@njit
def forward_dynamics(arrays, q, qd, tau, gravity):
    """The joint accelerations ``qdd = M(q)⁻¹ (τ − b(q, qd))`` (n_dofs,): CRBA for ``M``, RNEA with qdd = 0 for
    ``b``, a dense Cholesky solve (Featherstone §6.1's "method 1"; not the articulated-body algorithm).

    Args: q (n_q,), qd (n_dofs,), tau (n_dofs,) [N m or N], gravity (3,) [m/s²]."""
    arrays = RobotArrays(*arrays)
    rotation, position = forward_kinematics(arrays[:], q)
    S = motion_subspace(arrays, rotation, position)
    inertias = spatial_inertias(arrays, rotation, position)
    M = _mass_matrix(arrays, S, inertias)
    bias = _rnea(arrays, S, inertias, qd, np.zeros(arrays.n_dofs), gravity, np.zeros((len(arrays.parent), 6)))
    return cholesky_solve(M, tau - bias)


@njit
def integrate_positions(arrays, q, qd, h):
    """``q_new`` (n_q,) after moving with ``qd`` for ``h`` [s]: ``q + h qd`` for revolute, prismatic and planar
    coordinates; a floating root's position ``x + h v`` and its orientation ``exp(h ω) ⊗ quat`` (world-frame ω
    multiplies on the left; exponential map of :mod:`cgp_core.rotation`), normalized; a ball joint's quaternion
    likewise, ``exp(h ω) ⊗ quat`` with ω in its joint frame (the frame the quaternion is relative to).  A
    quaternion is kept unit, not sign-unwrapped: q and −q are the same rotation and nothing here reads its sign."""
    arrays = RobotArrays(*arrays)
    out = q.copy()
    for i in range(len(arrays.parent)):
        s = arrays.q_start[i]
        d = arrays.dof_start[i]
        if arrays.joint_type[i] == JOINT_FLOATING:
            for k in range(3):
                out[s + k] = q[s + k] + h * qd[d + k]
            dx, dy, dz, dw = rotvec_to_quat_scalar(h * qd[d + 3], h * qd[d + 4], h * qd[d + 5])
            x, y, z, w = quat_multiply_scalar(dx, dy, dz, dw, q[s + 3], q[s + 4], q[s + 5], q[s + 6])
            norm = math.sqrt(x * x + y * y + z * z + w * w)
            out[s + 3], out[s + 4], out[s + 5], out[s + 6] = x / norm, y / norm, z / norm, w / norm
        elif arrays.joint_type[i] == JOINT_BALL:
            dx, dy, dz, dw = rotvec_to_quat_scalar(h * qd[d], h * qd[d + 1], h * qd[d + 2])
            x, y, z, w = quat_multiply_scalar(dx, dy, dz, dw, q[s], q[s + 1], q[s + 2], q[s + 3])
            norm = math.sqrt(x * x + y * y + z * z + w * w)
            out[s], out[s + 1], out[s + 2], out[s + 3] = x / norm, y / norm, z / norm, w / norm
        else:
            for k in range(arrays.q_count[i]):
                out[s + k] = q[s + k] + h * qd[d + k]
    return out


@njit
def write_link_bodies(rows, body, motion, links, out):
    """Link bodies' world state from their robot bodies' poses and velocities (``k`` links, world rows ``rows``,
    robot bodies ``body`` (k,) int64: their rows in ``motion``, read there rather than copied out first):
    COM ``p + R c``, orientation (Shepperd's method, as :func:`cgp_core.rotation.matrix_to_quat`, w ≥ 0), the
    rotation matrix (``out.rotation`` of shape (0, 3, 3): none kept), P = m (v + ω × R c) and L = R I Rᵀ ω.
    Bundles as plain tuples: ``motion`` :class:`BodyMotion` of all robots' bodies, ``links`` :class:`LinkInertia`,
    ``out`` :class:`BodyStateArrays` (written in place)."""
    rotation, position, linear, angular = motion
    com, mass, inertia_body = links
    out_position, out_orientation, out_rotation, out_linear_momentum, out_angular_momentum = out
    keep_rotation = out_rotation.shape[0] > 0
    c, RI = np.empty(3), np.empty((3, 3))  # R c and R I (work space, overwritten per link)
    for t in range(len(rows)):
        row, u = rows[t], body[t]
        R = rotation[u]
        for i in range(3):
            c[i] = R[i, 0] * com[t, 0] + R[i, 1] * com[t, 1] + R[i, 2] * com[t, 2]
            out_position[row, i] = position[u, i] + c[i]
        m00, m11, m22 = R[0, 0], R[1, 1], R[2, 2]
        trace = m00 + m11 + m22
        cand0, cand1 = 1.0 + trace, 1.0 + m00 - m11 - m22
        cand2, cand3 = 1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22
        k, best = 0, cand0
        if cand1 > best:
            k, best = 1, cand1
        if cand2 > best:
            k, best = 2, cand2
        if cand3 > best:
            k, best = 3, cand3
        s = 2.0 * math.sqrt(max(best, 1e-300))
        if k == 0:
            x, y, z, w = R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1], 0.25 * s * s
        elif k == 1:
            x, y, z, w = 0.25 * s * s, R[0, 1] + R[1, 0], R[0, 2] + R[2, 0], R[2, 1] - R[1, 2]
        elif k == 2:
            x, y, z, w = R[0, 1] + R[1, 0], 0.25 * s * s, R[1, 2] + R[2, 1], R[0, 2] - R[2, 0]
        else:
            x, y, z, w = R[0, 2] + R[2, 0], R[1, 2] + R[2, 1], 0.25 * s * s, R[1, 0] - R[0, 1]
        x, y, z, w = x / s, y / s, z / s, w / s
        norm = math.sqrt(x * x + y * y + z * z + w * w)
        x, y, z, w = x / norm, y / norm, z / norm, w / norm
        if w < 0.0:
            x, y, z, w = -x, -y, -z, -w
        out_orientation[row, 0], out_orientation[row, 1] = x, y
        out_orientation[row, 2], out_orientation[row, 3] = z, w
        if keep_rotation:
            for i in range(3):
                for j in range(3):
                    out_rotation[row, i, j] = R[i, j]
        wx, wy, wz = angular[u, 0], angular[u, 1], angular[u, 2]
        vx = linear[u, 0] + (wy * c[2] - wz * c[1])
        vy = linear[u, 1] + (wz * c[0] - wx * c[2])
        vz = linear[u, 2] + (wx * c[1] - wy * c[0])
        out_linear_momentum[row, 0] = mass[t] * vx
        out_linear_momentum[row, 1] = mass[t] * vy
        out_linear_momentum[row, 2] = mass[t] * vz
        for i in range(3):
            for j in range(3):
                RI[i, j] = R[i, 0] * inertia_body[t, 0, j] + R[i, 1] * inertia_body[t, 1, j] \
                    + R[i, 2] * inertia_body[t, 2, j]
        for i in range(3):
            s_ = 0.0
            for j in range(3):
                iw = RI[i, 0] * R[j, 0] + RI[i, 1] * R[j, 1] + RI[i, 2] * R[j, 2]
                s_ += iw * angular[u, j]
            out_angular_momentum[row, i] = s_


@njit
def robot_view(models, starts, k):
    """Robot ``k``'s :class:`RobotArrays` as views into ``models``, every robot's bundle stacked
    (:func:`~cgp_core.robots.model.stack_robot_arrays`), at its :class:`~cgp_core.robots.model.RobotStarts`
    ``starts`` (slices: nothing copied), a plain tuple (the module docstring)."""
    m = RobotArrays(*models)
    b0, b1 = starts.body[k], starts.body[k + 1]
    f0, f1 = starts.frame[k], starts.frame[k + 1]
    d0, d1 = starts.dof[k], starts.dof[k + 1]
    return RobotArrays(m.parent[b0:b1], m.joint_type[b0:b1], m.joint_rotation[b0:b1], m.joint_position[b0:b1],
                       m.joint_axis[b0:b1], m.plane_u[b0:b1], m.plane_v[b0:b1], m.dof_start[b0:b1],
                       m.dof_count[b0:b1], m.q_start[b0:b1], m.q_count[b0:b1], m.mass[b0:b1], m.com[b0:b1],
                       m.inertia[b0:b1], m.frame_body[f0:f1], m.frame_rotation[f0:f1], m.frame_position[f0:f1],
                       m.dof_body[d0:d1], d1 - d0, starts.q[k + 1] - starts.q[k])[:]


@njit
def advance_all(models, starts, q, moving, qd, h, out):
    """:func:`advance` for every robot in one call: ``models`` every robot's :class:`RobotArrays` stacked
    (:func:`~cgp_core.robots.model.stack_robot_arrays`, a plain tuple), ``starts`` their
    :class:`~cgp_core.robots.model.RobotStarts` (a plain tuple); robot ``k``'s positions at
    ``q[starts.q[k]:starts.q[k + 1]]`` (updated in place), its velocities at ``starts.dof``, and its bodies' poses
    and velocities written at rows ``starts.body[k]`` … of ``out`` (a plain :class:`BodyMotion` tuple of all
    robots' B bodies)."""
    starts = RobotStarts(*starts)
    rotation, position, linear, angular = out
    for k in range(len(starts.body) - 1):
        qs, qe, ds, de, bs = starts.q[k], starts.q[k + 1], starts.dof[k], starts.dof[k + 1], starts.body[k]
        q_new, motion = advance(robot_view(models, starts, k), q[qs:qe], moving[ds:de], qd[ds:de], h)
        R, p, v, w = motion.rotation, motion.position, motion.linear, motion.angular
        for i in range(qe - qs):
            q[qs + i] = q_new[i]
        for b in range(len(R)):
            for i in range(3):
                position[bs + b, i] = p[b, i]
                linear[bs + b, i] = v[b, i]
                angular[bs + b, i] = w[b, i]
                for j in range(3):
                    rotation[bs + b, i, j] = R[b, i, j]

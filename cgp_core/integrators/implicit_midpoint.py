"""Implicit midpoint rule for the free rigid body — the default integrator.

One step of ``h`` is a kick followed by a drift (the same splitting as symplectic Euler):

    kick:   P ← P + h F,   L ← L + h τ                       (exact for constant F, τ)
    drift:  x ← x + h P/m                                     (with the kicked momentum)
            Π_n = Rₙᵀ L,  solve  Π_mid = Π_n + (h/2) Π_mid × Ω_mid,   Ω_mid = I_body⁻¹ Π_mid
            q ← q ⊗ normalize([h Ω_mid / 2, 1])               (Rₙ₊₁ = Rₙ cay(h Ω̂_mid))
            L unchanged                                       (no torque acts during the drift)

Why this is exact where it matters.  The implicit midpoint rule on Euler's equations Π̇ = Π × Ω,
Πₙ₊₁ = Πₙ + h Π_mid × Ω_mid with Π_mid = (Πₙ + Πₙ₊₁)/2, can be rewritten
(I − A/2) Πₙ₊₁ = (I + A/2) Πₙ with A = −h Ω̂_mid, i.e. Πₙ₊₁ = cay(−h Ω̂_mid) Πₙ, where
cay(A) = (I − A/2)⁻¹ (I + A/2) is a rotation for skew A.  Hence

- |Π| is conserved exactly, and the kinetic energy ½ Π·I⁻¹Π too:
  Eₙ₊₁ − Eₙ = (Πₙ₊₁ − Πₙ)·Ω_mid = h (Π_mid × Ω_mid)·Ω_mid = 0 (to the tolerance of the implicit solve);
- moving the body by Rₙ₊₁ = Rₙ cay(h Ω̂_mid) gives Rₙ₊₁ Πₙ₊₁ = Rₙ Πₙ: the world-frame L is unchanged, so it
  can stay the stored state, untouched by the free flight, and the orientation is consistent with it.
  cay(v̂) is the rotation by 2 atan(|v|/2) about v, whose quaternion is [v/2, 1] normalized, so the
  orientation stays a unit quaternion (‖RᵀR − I‖ at round-off);
- it is second order and time-reversible for the free rotation, and stable for fast spin about any axis:
  the gyroscopic term Π × Ω is treated implicitly (the problem Bullet's implicit gyroscopic option addresses,
  there with a dissipative backward-Euler step), so a body spinning near its unstable intermediate axis
  flips with the right period instead of gaining energy (explicit treatments gain 100 % and more in the
  tennis-racket test).

The implicit equation is solved by Newton's method, body by body in a compiled loop, with the full (possibly
non-diagonal, e.g. particle-set) body tensor, to round-off (see :func:`solve_midpoint_momentum`).

Why the default: it is the only scheme here whose free rotation conserves both quadratic invariants
(energy and |L|, with L exactly fixed in the world), which is what a spinning or tumbling body needs to look
right for long runs; it costs one 3×3 inverse and a few cheap fixed-point sweeps per body per step.

Forces enter by a full kick before the drift, not a Strang split (half kick, drift, half kick), on purpose:
the contact solver chooses impulses so that the end-of-step velocity (momentum + h F + impulse) satisfies
non-penetration and friction, and with kick-then-drift that is exactly the velocity that moves the body, so
a body resting on the ground stays put.  (A Strang split would drift with P − hF/2, lifting a resting body by
h² g / 2 every step.)  The price: under a constant force the position is first order, exactly symplectic
Euler's discrete trajectory xₙ = x₀ + n h v₀ + h² g n(n+1)/2, and torques enter to first order; the free
rotation keeps its second order and its invariants.
"""

from __future__ import annotations

import math
import warnings
from typing import ClassVar

import numpy as np

from ..bodies import BodyModel, BodyState
from ..jit import njit
from ..rotation import quat_rotate_scalar
from .base import check_step, inverse3_into

#: Largest value of h |L| ‖I_body⁻¹‖_F one implicit solve is given.  This bounds both h|Ω| (the angle turned
#: in the step) and h‖∂(Π × WΠ)/∂Π‖, how far Newton's Jacobian is from the identity; below ~1 Newton
#: converges from the predictor for any inertia ratio (checked up to 1000:1).  Bodies above it are sub-stepped.
MAX_SPIN_PER_SOLVE = 1.0
#: at most this many sub-steps per step (a body spinning at 1e5 rad/s with h = 1/240 s needs a few hundred)
MAX_SUBSTEPS = 1000

_TINY = float(np.finfo(float).tiny)


class ImplicitMidpoint:
    """Kick, then implicit-midpoint free flight (see the module docstring).  Stateless."""

    name: ClassVar[str] = "implicit_midpoint"

    def step(self, model: BodyModel, state: BodyState, h: float, active: np.ndarray | None = None) -> None:
        h = check_step(h)
        state.rotation = None  # the quaternion is authoritative (a matrix left by explicit_euler is stale)
        movable = model.inv_mass > 0.0
        if active is not None:
            movable = movable & active
        worst = _step_kernel(model.inv_mass, model.inv_inertia_body, movable, state.position, state.orientation,
                             state.linear_momentum, state.angular_momentum, state.force, state.torque, h)
        _warn_unconverged(worst, h)


@njit
def _step_kernel(inv_mass, inv_inertia, movable, position, orientation, linear_momentum, angular_momentum, force,
                 torque, h):
    """The whole step for the ``movable`` bodies, in place: kick (P += h F, L += h τ), drift (x += h P/m), then
    the implicit-midpoint free rotation.  Returns what :func:`_free_rotation_kernel` returns."""
    for i in range(len(position)):
        if movable[i]:
            for k in range(3):
                linear_momentum[i, k] += h * force[i, k]
                angular_momentum[i, k] += h * torque[i, k]
                position[i, k] += h * linear_momentum[i, k] * inv_mass[i]
    return _free_rotation_kernel(inv_inertia, orientation, angular_momentum, h, movable)


def _warn_unconverged(worst: float, h: float) -> None:
    if worst > 0.0:
        warnings.warn(
            f"implicit midpoint: the implicit solve did not converge in {MAX_ITERATIONS} iterations (h = {h:g} s, "
            f"last relative update {worst:.1e}): the step is too large for the bodies' spin; energy is not "
            "conserved exactly this step", RuntimeWarning, stacklevel=3)


def free_rotation(inv_inertia: np.ndarray, orientation: np.ndarray, angular_momentum: np.ndarray, h: float, *,
                  movable: np.ndarray | None = None) -> np.ndarray:
    """Orientations (n, 4) after torque-free motion over ``h`` by the implicit midpoint rule; L is constant.

    Args:
        inv_inertia: (n, 3, 3) I_body⁻¹.
        orientation: (n, 4) unit quaternions at the start (not modified).
        angular_momentum: (n, 3) world L.
        h: step [s].
        movable: (n,) bool; where False the quaternion is returned bit for bit unchanged.

    A body with h |L| ‖I_body⁻¹‖_F > ``MAX_SPIN_PER_SOLVE`` takes the step as that many equal implicit-midpoint
    sub-steps (each one still conserves energy and L exactly).  Each body is solved on its own, so its result
    never depends on which other bodies share the batch.
    """
    n = len(orientation)
    movable = np.ones(n, dtype=bool) if movable is None else np.ascontiguousarray(movable, dtype=bool)
    q = np.ascontiguousarray(orientation, dtype=float).copy()
    worst = _free_rotation_kernel(np.ascontiguousarray(inv_inertia, dtype=float),
                                  q, np.ascontiguousarray(angular_momentum, dtype=float), float(h), movable)
    _warn_unconverged(worst, h)
    return q


#: Newton iterations of the implicit solve at most (2 are typical at h = 1/240 s)
MAX_ITERATIONS = 50
#: the implicit solve stops when the relative update is below this (round-off is ~1e-16)
TOLERANCE = 1e-14


@njit
def _free_rotation_kernel(inv_inertia, q, angular_momentum, h, movable):
    """:func:`free_rotation` in place on ``q``, body by body; returns the largest relative update of a body
    whose solve did not converge (0 if all did)."""
    worst = 0.0
    pi_mid = np.empty(3)
    for i in range(len(q)):
        if not movable[i]:
            continue
        W, L = inv_inertia[i], angular_momentum[i]
        frobenius = 0.0
        for r in range(3):
            for c in range(3):
                frobenius += W[r, c] * W[r, c]
        spin = h * math.sqrt(L[0] * L[0] + L[1] * L[1] + L[2] * L[2]) * math.sqrt(frobenius)
        if not math.isfinite(spin):  # a non-finite body is the World's to reset
            spin = 0.0
        substeps = int(min(max(math.ceil(spin / MAX_SPIN_PER_SOLVE), 1.0), MAX_SUBSTEPS))
        sub_h = h / substeps
        for _ in range(substeps):
            worst = max(worst, _midpoint_rotation(W, q[i], L, sub_h, pi_mid))
    return worst


@njit
def _midpoint_rotation(W, q, L, h, pi_mid):
    """One implicit-midpoint step of the free rotation of one body, ``q`` (4,) updated in place."""
    # Π = Rᵀ L: L rotated by the conjugate quaternion (base.body_angular_momentum, one body)
    w = q[3]
    pi_n = np.empty(3)
    pi_n[0], pi_n[1], pi_n[2] = quat_rotate_scalar(-q[0], -q[1], -q[2], w, L[0], L[1], L[2])
    unconverged = solve_midpoint_momentum(W, pi_n, h, pi_mid)
    # v = h Ω_mid / 2;  q ⊗ [v, 1] = [u + w v + u × v,  w − u·v] for q = [u, w]; normalized, q ⊗ cay(h Ω̂_mid)
    v0 = 0.5 * h * (W[0, 0] * pi_mid[0] + W[0, 1] * pi_mid[1] + W[0, 2] * pi_mid[2])
    v1 = 0.5 * h * (W[1, 0] * pi_mid[0] + W[1, 1] * pi_mid[1] + W[1, 2] * pi_mid[2])
    v2 = 0.5 * h * (W[2, 0] * pi_mid[0] + W[2, 1] * pi_mid[1] + W[2, 2] * pi_mid[2])
    x, y, z = q[0], q[1], q[2]
    nx = x + w * v0 + (y * v2 - z * v1)
    ny = y + w * v1 + (z * v0 - x * v2)
    nz = z + w * v2 + (x * v1 - y * v0)
    nw = w - (x * v0 + y * v1 + z * v2)
    norm = math.sqrt(nx * nx + ny * ny + nz * nz + nw * nw)
    q[0], q[1], q[2], q[3] = nx / norm, ny / norm, nz / norm, nw / norm
    return unconverged


@njit
def solve_midpoint_momentum(W, pi_n, h, pi):
    """Solve Π_mid = Πₙ + (h/2) Π_mid × (W Π_mid) for one body; the answer goes into ``pi`` (3,).

    Newton's method from the explicit predictor Πₙ + (h/2) Πₙ × WΠₙ, already within O((hΩ)²) of the
    answer.  The Jacobian 1 − (h/2)(Π̂ W − (WΠ)^) is re-evaluated only while the updates are large
    (relative size > 1e-3); after that its inverse is kept (the chord method), whose contraction rate is
    then ~ h‖W‖|ΔΠ| ≪ 1, so a further iteration costs two matrix-vector products and a cross product.
    Stops when the relative update is ≤ ``TOLERANCE`` (round-off is ~1e-16): for the tennis-racket case
    at h = 1/240 s that is 2 iterations with one 3×3 inverse.

    Args:
        W: (3, 3) I_body⁻¹ (zeros for fixed bodies, which then give Π_mid = Πₙ).
        pi_n: (3,) Πₙ, body frame.
        h: step [s].

    Returns 0 when converged, else the last relative update: the step built from the last iterate still turns
    the body rigidly and keeps L, so the energy stays bounded, just not exact (not seen below
    ``MAX_SPIN_PER_SOLVE``).  A non-finite body (a blow-up the World will reset) returns 0.
    """
    half_h = 0.5 * h
    omega = np.empty(3)
    residual = np.empty(3)
    jacobian = np.empty((3, 3))
    inverse = np.empty((3, 3))
    for r in range(3):
        omega[r] = W[r, 0] * pi_n[0] + W[r, 1] * pi_n[1] + W[r, 2] * pi_n[2]
    pi[0] = pi_n[0] + half_h * (pi_n[1] * omega[2] - pi_n[2] * omega[1])
    pi[1] = pi_n[1] + half_h * (pi_n[2] * omega[0] - pi_n[0] * omega[2])
    pi[2] = pi_n[2] + half_h * (pi_n[0] * omega[1] - pi_n[1] * omega[0])
    scale = math.sqrt(pi_n[0] * pi_n[0] + pi_n[1] * pi_n[1] + pi_n[2] * pi_n[2]) + _TINY
    largest = np.inf
    fresh = True
    for _ in range(MAX_ITERATIONS):
        for r in range(3):
            omega[r] = W[r, 0] * pi[0] + W[r, 1] * pi[1] + W[r, 2] * pi[2]
        residual[0] = pi[0] - pi_n[0] - half_h * (pi[1] * omega[2] - pi[2] * omega[1])
        residual[1] = pi[1] - pi_n[1] - half_h * (pi[2] * omega[0] - pi[0] * omega[2])
        residual[2] = pi[2] - pi_n[2] - half_h * (pi[0] * omega[1] - pi[1] * omega[0])
        if fresh or largest > 1e-3:
            # 1 − (h/2)(Π̂ W − Ω̂), Π̂ the cross-product matrix of Π
            for c in range(3):
                jacobian[0, c] = -half_h * (-pi[2] * W[1, c] + pi[1] * W[2, c])
                jacobian[1, c] = -half_h * (pi[2] * W[0, c] - pi[0] * W[2, c])
                jacobian[2, c] = -half_h * (-pi[1] * W[0, c] + pi[0] * W[1, c])
            jacobian[0, 1] += half_h * -omega[2]
            jacobian[0, 2] += half_h * omega[1]
            jacobian[1, 0] += half_h * omega[2]
            jacobian[1, 2] += half_h * -omega[0]
            jacobian[2, 0] += half_h * -omega[1]
            jacobian[2, 1] += half_h * omega[0]
            for r in range(3):
                jacobian[r, r] += 1.0
            inverse3_into(jacobian, inverse)
            fresh = False
        largest = 0.0
        for r in range(3):
            update = inverse[r, 0] * residual[0] + inverse[r, 1] * residual[1] + inverse[r, 2] * residual[2]
            pi[r] -= update
            largest = max(largest, abs(update) / scale)
        if not math.isfinite(largest):
            return 0.0
        if largest <= TOLERANCE:
            return 0.0
    return largest

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

The implicit equation is solved by Newton's method on all bodies at once with the full (possibly
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

import warnings
from typing import ClassVar

import numpy as np

from ..bodies import BodyModel, BodyState
from ..rotation import cross3, norms, skew
from .base import apply_inertia, body_angular_momentum, check_step, inverse3, kick


#: Largest value of h |L| ‖I_body⁻¹‖_F one implicit solve is given.  This bounds both h|Ω| (the angle turned
#: in the step) and h‖∂(Π × WΠ)/∂Π‖, how far Newton's Jacobian is from the identity; below ~1 Newton
#: converges from the predictor for any inertia ratio (checked up to 1000:1).  Bodies above it are sub-stepped.
MAX_SPIN_PER_SOLVE = 1.0
#: at most this many sub-steps per step (a body spinning at 1e5 rad/s with h = 1/240 s needs a few hundred)
MAX_SUBSTEPS = 1000

_IDENTITY = np.eye(3)
_TINY = np.finfo(float).tiny


class ImplicitMidpoint:
    """Kick, then implicit-midpoint free flight (see the module docstring).  Stateless."""

    name: ClassVar[str] = "implicit_midpoint"

    def step(self, model: BodyModel, state: BodyState, h: float) -> None:
        h = check_step(h)
        state.rotation = None  # the quaternion is authoritative (a matrix left by explicit_euler is stale)
        kick(model, state, h)
        state.position += h * state.linear_momentum * model.inv_mass[:, None]
        state.orientation[:] = free_rotation(model.inv_inertia_body, state.orientation, state.angular_momentum,
                                             h, movable=model.inv_mass > 0.0)


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
    sub-steps (each one still conserves energy and L exactly).  Only those bodies are sub-stepped, so a
    body's result never depends on which other bodies share the batch.
    """
    # h |L| ‖I_body⁻¹‖_F (the Frobenius norm as np.linalg.norm computes it, without its argument handling)
    spin = h * norms(angular_momentum) * np.sqrt(np.add.reduce(inv_inertia * inv_inertia, axis=(1, 2)))
    spin = np.where(np.isfinite(spin), spin, 0.0)  # a non-finite body is the World's to reset
    solves = np.ceil(spin / MAX_SPIN_PER_SOLVE)
    q = orientation.copy()
    if solves.max(initial=1.0) <= 1.0:  # the common case: one solve for every body
        _midpoint_rotation(inv_inertia, q, angular_momentum, h)
    else:
        substeps = np.clip(solves, 1, MAX_SUBSTEPS).astype(int)
        sub_h = (h / substeps)[:, None]
        for k in range(substeps.max()):  # a loop over sub-steps, vectorized over the bodies that need them
            rows = np.flatnonzero(substeps > k)
            q_rows = q[rows]
            _midpoint_rotation(inv_inertia[rows], q_rows, angular_momentum[rows], sub_h[rows])
            q[rows] = q_rows
    if movable is not None:
        q = np.where(movable[:, None], q, orientation)  # renormalizing could change a fixed body's last digit
    return q


def _midpoint_rotation(inv_inertia: np.ndarray, q: np.ndarray, angular_momentum: np.ndarray, h) -> None:
    """One implicit-midpoint step of the free rotation, ``q`` (n, 4) updated in place; h scalar or (n, 1)."""
    pi_mid = solve_midpoint_momentum(inv_inertia, body_angular_momentum(q, angular_momentum), h)
    v = (0.5 * h) * apply_inertia(inv_inertia, pi_mid)  # h Ω_mid / 2
    # q ⊗ [v, 1] = [u + w v + u × v,  w − u·v] for q = [u, w]; normalized, that is q ⊗ cay(h Ω̂_mid)
    u, w = q[:, :3].copy(), q[:, 3:].copy()
    q[:, :3] = u + w * v + cross3(u, v)
    q[:, 3:] = w - np.einsum("ni,ni->n", u, v)[:, None]
    q /= norms(q, keepdims=True)


def solve_midpoint_momentum(inv_inertia: np.ndarray, body_momentum: np.ndarray, h, *, tol: float = 1e-14,
                            max_iterations: int = 50) -> np.ndarray:
    """Solve Π_mid = Πₙ + (h/2) Π_mid × (W Π_mid) for all bodies at once.

    Newton's method from the explicit predictor Πₙ + (h/2) Πₙ × WΠₙ, already within O((hΩ)²) of the
    answer.  The Jacobian 1 − (h/2)(Π̂ W − (WΠ)^) is re-evaluated only while the updates are large
    (relative size > 1e-3); after that its inverse is kept (the chord method), whose contraction rate is
    then ~ h‖W‖|ΔΠ| ≪ 1, so a further iteration costs two matrix-vector products and a cross product.
    Stops when the largest relative update is ≤ ``tol`` (round-off is ~1e-16): for the tennis-racket case
    at h = 1/240 s that is 2 iterations with one 3×3 inverse per body.

    Args:
        inv_inertia: (n, 3, 3) W = I_body⁻¹ (zeros for fixed bodies, which then give Π_mid = Πₙ).
        body_momentum: (n, 3) Πₙ, body frame.
        h: step [s], a scalar or (n, 1) per body.

    Returns:
        (n, 3) Π_mid.  If some bodies have not converged after ``max_iterations`` (not seen below
        ``MAX_SPIN_PER_SOLVE``) a RuntimeWarning is issued and the last iterate is returned: the step built
        from it still turns the body rigidly and keeps L, so the energy stays bounded, just not exact.
    """
    half_h = 0.5 * np.asarray(h, dtype=float)  # scalar or (n, 1)
    half_h_matrix = half_h[..., None] if half_h.ndim else half_h
    pi = body_momentum + half_h * cross3(body_momentum, apply_inertia(inv_inertia, body_momentum))
    scale = norms(body_momentum) + _TINY
    jacobian_inverse = None
    largest_update = np.inf
    for _ in range(max_iterations):
        omega = apply_inertia(inv_inertia, pi)
        residual = pi - body_momentum - half_h * cross3(pi, omega)
        if jacobian_inverse is None or largest_update > 1e-3:
            jacobian_inverse = inverse3(_IDENTITY - half_h_matrix * (skew(pi) @ inv_inertia - skew(omega)))
        update = apply_inertia(jacobian_inverse, residual)
        pi -= update
        relative = np.abs(update).max(axis=1) / scale
        # bodies already non-finite (a blow-up the World will reset) must not keep the others iterating
        largest_update = relative.max(initial=0.0)
        if not np.isfinite(largest_update):  # (the masked max only when needed: it costs more)
            largest_update = np.max(relative, where=np.isfinite(relative), initial=0.0)
        if largest_update <= tol:
            return pi
    warnings.warn(
        f"implicit midpoint: the implicit solve did not converge in {max_iterations} iterations (h up to "
        f"{np.max(h):g} s, last relative update {largest_update:.1e}): the step is too large for the bodies' "
        "spin; energy is not conserved exactly this step",
        RuntimeWarning,
        stacklevel=2,
    )
    return pi

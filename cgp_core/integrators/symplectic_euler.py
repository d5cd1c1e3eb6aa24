"""Symplectic (semi-implicit) Euler with the rotation advanced on SO(3).

    P ← P + h F,  L ← L + h τ             (kick: momenta first)
    x ← x + h P/m                          (drift with the *new* velocity)
    q ← exp(h ω) ⊗ q,  ω = I_world⁻¹ L     (exponential map: q stays a unit quaternion)

Updating the momenta before the positions is what makes the linear part symplectic (energy error bounded
instead of growing, unlike the lecture's explicit Euler); under constant force the positions follow
xₙ = x₀ + n h v₀ + h² a n(n+1)/2 exactly, and the contact solver's velocity-level impulses are exactly
what moves the bodies.  The rotation, though, uses ω from the start-of-step orientation: that is an
explicit treatment of the gyroscopic term, first order, and it pumps energy into a tumbling body — near the
unstable intermediate axis badly (the tennis-racket test: +148 % kinetic energy in 10 s at h = 1/240 s;
world L and |Π| stay exact).  Fine for slowly turning bodies; use ``implicit_midpoint`` (the default) for
anything that spins.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..bodies import BodyModel, BodyState
from ..rotation import quat_from_rotvec, quat_multiply, quat_normalize, quat_rotate
from .base import apply_inertia, body_angular_momentum, check_step, kick, movable_mask


class SymplecticEuler:
    """Kick, then drift with the exponential map; see the module docstring.  Stateless."""

    name: ClassVar[str] = "symplectic_euler"

    def step(self, model: BodyModel, state: BodyState, h: float, active: np.ndarray | None = None) -> None:
        h = check_step(h)
        state.rotation = None  # the quaternion is authoritative (a matrix left by explicit_euler is stale)
        movable = movable_mask(model, active)
        kick(model, state, h, active)
        state.position += h * state.linear_momentum * (model.inv_mass[:, None] * movable)
        q = state.orientation
        omega_body = apply_inertia(model.inv_inertia_body, body_angular_momentum(q, state.angular_momentum))
        omega = quat_rotate(q, omega_body)  # ω = R I_body⁻¹ Rᵀ L
        q_new = quat_normalize(quat_multiply(quat_from_rotvec(h * omega), q))
        state.orientation[:] = np.where(movable > 0.0, q_new, q)

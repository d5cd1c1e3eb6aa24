"""Symplectic (semi-implicit) Euler with the rotation advanced on SO(3).

    P ← P + h F,  L ← L + h τ             (kick: momenta first)
    x ← x + h P/m                          (drift with the *new* velocity)
    q ← exp(h ω) ⊗ q,  ω = I_world⁻¹ L     (exponential map: q stays a unit quaternion)

Updating the momenta before the positions is what makes the linear part symplectic (energy error bounded
instead of growing, unlike the lecture's explicit Euler).  The rotation uses ω at the start-of-step
orientation, so torque-free tumbling still drifts energy slowly (no gyroscopic treatment): use
``implicit_midpoint`` for spinning bodies.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..bodies import BodyModel, BodyState
from ..rotation import quat_from_rotvec, quat_multiply, quat_normalize


class SymplecticEuler:
    name: ClassVar[str] = "symplectic_euler"

    def step(self, model: BodyModel, state: BodyState, h: float) -> None:
        movable = model.inv_mass > 0.0
        state.linear_momentum[movable] += h * state.force[movable]
        state.angular_momentum[movable] += h * state.torque[movable]
        state.position += h * state.linear_velocity(model)
        omega = state.angular_velocity(model)
        state.orientation[:] = quat_normalize(quat_multiply(quat_from_rotvec(h * omega), state.orientation))

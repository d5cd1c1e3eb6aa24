"""Contact materials: the ground plane, and how two surfaces' coefficients combine into one per contact.

Combination rules (Box2D's defaults, ``b2MixFriction`` / ``b2MixRestitution``):

- friction ``μ = √(μ_a μ_b)`` — the geometric mean: a frictionless surface (μ = 0) makes every contact with
  it frictionless, and equal materials keep their own μ;
- restitution ``e = max(e_a, e_b)`` — a bouncy ball bounces on any floor, so a floor's e = 0 (the ground's
  default) leaves the body's own e in charge.

The ground defaults (``Ground()``: μ = 0.6, e = 0) are the scene defaults ``world.ground_friction`` and
``world.ground_restitution``: 0.6 is the Box2D / "wood or concrete" middle value, and e = 0 lets each
body's restitution decide how it bounces on the ground (by the max rule above).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..jit import njit

DEFAULT_GROUND_FRICTION = 0.6
DEFAULT_GROUND_RESTITUTION = 0.0


@dataclass(frozen=True)
class Ground:
    """The static ground: the plane z = 0 of the world frame, solid below (normal +z), never moving.

    Attributes:
        friction:    Coulomb μ >= 0 of the ground surface.
        restitution: coefficient of restitution e in [0, 1] of the ground surface.
    """

    friction: float = DEFAULT_GROUND_FRICTION
    restitution: float = DEFAULT_GROUND_RESTITUTION

    def __post_init__(self) -> None:
        for name, value, top in (("friction", self.friction, math.inf), ("restitution", self.restitution, 1.0)):
            if not isinstance(value, (int, float)) or not (0.0 <= value <= top) or math.isnan(value):
                raise ValueError(f"ground {name} must be a number in [0, {top:g}], got {value!r}")


@njit
def combine_friction(mu_a, mu_b):
    """Pair friction ``√(μ_a μ_b)`` (numbers or arrays, elementwise; compiled, so the narrow phase calls it)."""
    return np.sqrt(mu_a * mu_b)


@njit
def combine_restitution(e_a, e_b):
    """Pair restitution ``max(e_a, e_b)`` (numbers or arrays, elementwise)."""
    return np.maximum(e_a, e_b)

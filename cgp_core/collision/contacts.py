"""The contact set: every contact point found by the narrow phase in one sub-step, as flat arrays.

Conventions (all contact code follows them):

- A contact is between body ``A`` and body ``B``; ``body_a == GROUND`` (−1) for the static ground plane,
  which is always the A side.  ``body_b`` is always a body.
- ``normal`` is the unit contact normal pointing **from A to B**: pushing B along it separates the pair.
- ``separation`` is the signed gap along the normal: > 0 apart (a *speculative* contact, kept when the gap
  may close within the sub-step), 0 touching, < 0 penetrating by ``-separation``.
- ``point`` is the world point midway between the two surfaces; both bodies' lever arms are taken to this
  same point, so each contact impulse is an exactly equal-and-opposite pair (momentum is conserved to
  round-off, linear and angular).
- ``key`` identifies the contact: the primitive pair (``key // FEATURE_SLOTS``) and the geometric feature
  (vertex, clip point, edge pair ...) that produced it.  It is unique within a contact set, and the solver
  uses its pair part to find the same contact in the previous sub-step (warm starting).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: ``body_a`` value of a contact with the static ground plane z = 0
GROUND = -1

#: features per primitive pair in a contact key (box–box uses up to 296): ``key // FEATURE_SLOTS`` is the
#: primitive pair, which the solver uses to match contacts across sub-steps
FEATURE_SLOTS = 512


class ContactSet(NamedTuple):
    """``m`` contact points (a bundle: compiled kernels take it as it is, see :mod:`cgp_core.jit`)."""

    body_a: np.ndarray       # (m,) intp — body index of side A, or ``GROUND`` (−1)
    body_b: np.ndarray       # (m,) intp — body index of side B
    normal: np.ndarray       # (m, 3) — unit normal from A to B
    separation: np.ndarray   # (m,) — signed gap along ``normal`` [m] (negative = penetration depth)
    point: np.ndarray        # (m, 3) — world contact point, midway between the surfaces
    key: np.ndarray          # (m,) int64 — (primitive pair, feature) identity, see the module docstring
    friction: np.ndarray     # (m,) — combined Coulomb μ of the pair (see :mod:`cgp_core.collision.materials`)
    restitution: np.ndarray  # (m,) — combined coefficient of restitution e of the pair

    @property
    def count(self) -> int:
        return len(self.body_b)

    @staticmethod
    def empty() -> ContactSet:
        return ContactSet(
            body_a=np.zeros(0, dtype=np.intp),
            body_b=np.zeros(0, dtype=np.intp),
            normal=np.zeros((0, 3)),
            separation=np.zeros(0),
            point=np.zeros((0, 3)),
            key=np.zeros(0, dtype=np.int64),
            friction=np.zeros(0),
            restitution=np.zeros(0),
        )

    def select(self, mask_or_index: np.ndarray) -> ContactSet:
        """The subset picked by a boolean mask or an index array."""
        return ContactSet(*(field[mask_or_index] for field in self))

    @staticmethod
    def concatenate(parts: list[ContactSet]) -> ContactSet:
        parts = [p for p in parts if p.count]
        if not parts:
            return ContactSet.empty()
        if len(parts) == 1:
            return parts[0]
        return ContactSet(*(np.concatenate(fields) for fields in zip(*parts)))

    def penetration(self) -> np.ndarray:
        """Penetration depth ``max(−separation, 0)`` per contact, (m,)."""
        return np.maximum(-self.separation, 0.0)

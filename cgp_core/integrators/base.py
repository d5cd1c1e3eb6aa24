"""The one interface every integrator implements, and the few helpers they share.

An integrator advances the free motion of all bodies over one (sub-)step ``h``: positions, orientations and
momenta, with ``state.force`` and ``state.torque`` (world frame, torque about the COM) held constant over the
step.  Contact impulses are not its business: the contact solver applies them to P and L before the
integrator runs (see ARCHITECTURE.md, "The step pipeline").  Fixed bodies (``inv_mass == 0``) never move:
their x, q, P, L are left bit-for-bit unchanged.

State conventions (see :mod:`cgp_core.bodies`): world-frame momenta P and L are the state; the body-frame
angular momentum is Π = Rᵀ L, the body angular velocity Ω = I_body⁻¹ Π and the world one ω = R Ω.
Orientation quaternions map body to world, so a body-frame increment multiplies on the right
(``q ⊗ dq``) and a world-frame one on the left (``dq ⊗ q``).
"""

from __future__ import annotations

from typing import ClassVar, Protocol

import numpy as np

from ..bodies import BodyModel, BodyState
from ..checks import positive
from ..jit import njit
from ..rotation import cross3, quat_conjugate, quat_rotate


class Integrator(Protocol):
    #: the scene key (``world.integrator``) that selects this integrator
    name: ClassVar[str]

    def step(self, model: BodyModel, state: BodyState, h: float, active: np.ndarray | None = None) -> None:
        """Advance ``state`` in place by ``h`` seconds.  ``active`` (n,) bool: the bodies to move (default: all;
        the others — sleeping bodies — are left bit for bit unchanged, like fixed ones)."""
        ...


def check_step(h: float) -> float:
    """``h`` as a float; ``ValueError`` unless it is a positive finite number of seconds."""
    return positive(h, "integrator step h [s]")


def movable_mask(model: BodyModel, active: np.ndarray | None = None) -> np.ndarray:
    """(n, 1) float: 1 for bodies that move (and are ``active``, if given), 0 for fixed (or sleeping) ones —
    multiplies increments so that those bodies get exactly zero without a boolean gather/scatter."""
    movable = model.inv_mass > 0.0
    return (movable if active is None else movable & active).astype(float)[:, None]


def kick(model: BodyModel, state: BodyState, h: float, active: np.ndarray | None = None) -> None:
    """P += h F, L += h τ for the movable bodies (the exact flow of a constant force and torque)."""
    movable = movable_mask(model, active)
    state.linear_momentum += (h * movable) * state.force
    state.angular_momentum += (h * movable) * state.torque


def body_angular_momentum(orientation: np.ndarray, angular_momentum: np.ndarray) -> np.ndarray:
    """Π = Rᵀ L, (n, 3): world angular momentum in body axes (``orientation`` must be unit quaternions) — the
    body-frame side of ω = I_world⁻¹ L (the world-frame side's home is :mod:`cgp_core.bodies`): L rotated by the
    conjugate quaternion, ``rotation.quat_rotate`` (``quat_rotate_scalar`` in the compiled implicit midpoint)."""
    return quat_rotate(quat_conjugate(orientation), angular_momentum)


def apply_inertia(tensor: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """Batched matrix-vector product ``tensor (n, 3, 3) @ vectors (n, 3) -> (n, 3)``."""
    return np.einsum("nij,nj->ni", tensor, vectors)


# Small dense kernels for (n, 3) / (n, 3, 3) batches.  np.cross and np.linalg.solve/inv are general (any
# axis, LAPACK per matrix) and cost several times more than these few elementwise operations at both n = 1
# and n = 1000; they are also the integrators' inner loop.  (cross3 lives in rotation.py, with the other
# small vector kernels.)


def inverse3(matrices: np.ndarray) -> np.ndarray:
    """Inverse of (..., 3, 3) matrices by the adjugate: the columns of A⁻¹ are the cross products of A's
    rows divided by det A.  Never raises: a singular matrix gives inf/nan (with numpy's RuntimeWarning),
    which the World's blow-up guard then catches, where ``np.linalg.inv`` would abort the whole step."""
    # column k of the adjugate is r_{k+1} × r_{k+2} (indices mod 3): all three cross products in one call
    out = np.empty(matrices.shape)
    out[...] = np.swapaxes(cross3(matrices[..., [1, 2, 0], :], matrices[..., [2, 0, 1], :]), -1, -2)
    # det A = r0 · (r1 × r2), read from the column view as before (einsum's rounding depends on the strides)
    inv_det = 1.0 / np.einsum("...i,...i->...", matrices[..., 0, :], out[..., :, 0])
    out *= inv_det[..., None, None]
    return out


@njit
def inverse3_into(A, out):
    """:func:`inverse3` for one 3×3 matrix ``A``, into ``out`` (3, 3), for the compiled integrator loops."""
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3
        out[0, k] = A[i, 1] * A[j, 2] - A[i, 2] * A[j, 1]
        out[1, k] = A[i, 2] * A[j, 0] - A[i, 0] * A[j, 2]
        out[2, k] = A[i, 0] * A[j, 1] - A[i, 1] * A[j, 0]
    inv_det = 1.0 / (A[0, 0] * out[0, 0] + A[0, 1] * out[1, 0] + A[0, 2] * out[2, 0])
    for r in range(3):
        for c in range(3):
            out[r, c] *= inv_det

"""The lecture's explicit Euler, exactly as the slides write it — the teaching baseline.

    x ← x + h v                      v = P/m        (old velocity)
    P ← P + h F                      (v ← v + h a, a = F/m, kept as momentum)
    R ← R + h [ω×T  ω×N  ω×B]        ω = (R J Rᵀ)⁻¹ L, T, N, B = the columns of R
    L ← L + h τ

Every right-hand side is evaluated at the start of the step.  The state keeps momentum P (so "v += dt a"
is P += h F, the same thing for constant mass) and v = P/m.

The rotation *matrix* is integrated, as on the slides, so it leaves SO(3): each step multiplies it by
(1 + h ω̂), whose singular values are 1 and √(1 + h²|ω|²), so ‖RᵀR − I‖ grows like h²|ω|² per step and
the body visibly swells and shears over long runs; and ω is evaluated at the start of the step, so a
tumbling body's energy drifts.  Both are measured in ``tests/test_integrators.py``, not hidden: use this
integrator to see why the others exist.

Slide erratum ("Whole Model - Rotation"): the slide writes ω = J⁻¹ L with the J built from the particles in
the body frame; once the body has turned, L = J_world ω with J_world = R J Rᵀ, so ω = (R J Rᵀ)⁻¹ L — with
the body-frame J the body would spin about the wrong axis as soon as R ≠ 1.  (And the "Whole Model -
Position" slide's v̇ = p/m is v = p/m: a velocity, not an acceleration.)

The drifting matrix is kept in ``state.rotation`` (authoritative while this integrator runs) and
``state.orientation`` is set to the quaternion of its nearest rotation for output: the orthogonal polar
factor U Vᵀ of its SVD U S Vᵀ (``rotation.matrix_to_quat`` alone is only close to that for nearly
orthogonal input; after a few seconds of tumbling this matrix has singular values far from 1).  If anything
else writes ``state.orientation`` between steps (a reset, a teleport, penetration recovery), the quaternion
no longer matches the matrix and the matrix of that body is rebuilt from the new quaternion.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..bodies import BodyModel, BodyState
from ..rotation import matrix_to_quat, quat_to_matrix, skew
from .base import apply_inertia, check_step, inverse3, movable_mask


class ExplicitEuler:
    """The slides' explicit Euler on (x, P, R, L); see the module docstring.

    The only thing an instance remembers is a cache: the matrix array and quaternions it wrote last, so
    that the "did someone else set the orientation?" check costs one comparison instead of a polar
    decomposition.  Any other state (a copy, a reset) takes the full check, so results never depend on it.
    """

    name: ClassVar[str] = "explicit_euler"

    def __init__(self) -> None:
        self._written_rotation: np.ndarray | None = None  # the state.rotation array of the last step
        self._written_orientation: np.ndarray | None = None  # (n, 4) the quaternions that step wrote

    def step(self, model: BodyModel, state: BodyState, h: float, active: np.ndarray | None = None) -> None:
        h = check_step(h)
        R = self._matrices(state)
        movable = movable_mask(model, active)

        # ω = (R J Rᵀ)⁻¹ L = R⁻ᵀ J⁻¹ R⁻¹ L: with the drifting (non-orthogonal) R this is not R J⁻¹ Rᵀ L.
        # Written with J⁻¹ so that fixed bodies (J⁻¹ = 0) get ω = 0 without a special case.
        R_inv = inverse3(R)  # never raises: a degenerate matrix gives inf/nan, caught by the World's guard
        body_l = apply_inertia(R_inv, state.angular_momentum)
        omega = apply_inertia(np.swapaxes(R_inv, -1, -2), apply_inertia(model.inv_inertia_body, body_l))

        state.position += h * state.linear_momentum * (model.inv_mass[:, None] * movable)
        state.linear_momentum += (h * movable) * state.force
        R += h * movable[:, :, None] * (skew(omega) @ R)  # [ω×T ω×N ω×B] = ω̂ R, column by column
        state.angular_momentum += (h * movable) * state.torque

        q_new = nearest_rotation_quat(R)
        state.orientation[:] = np.where(movable > 0.0, q_new, state.orientation)
        self._written_rotation, self._written_orientation = R, state.orientation.copy()

    def _matrices(self, state: BodyState) -> np.ndarray:
        """``state.rotation``, created from the quaternions on first use and rebuilt for any body whose
        quaternion was changed by someone else since this integrator wrote it."""
        if state.rotation is None or state.rotation.shape != (state.count, 3, 3):
            state.rotation = quat_to_matrix(state.orientation)
            return state.rotation
        if state.rotation is self._written_rotation and self._written_orientation.shape == state.orientation.shape:
            written = self._written_orientation  # cached: what this integrator wrote into this very state
        else:
            # nearest_rotation_quat is deterministic, so for a body untouched since its last step this
            # reproduces the quaternion written then bit for bit
            written = nearest_rotation_quat(state.rotation)
        stale = np.any(written != state.orientation, axis=1)
        if stale.any():
            state.rotation[stale] = quat_to_matrix(state.orientation[stale])
        return state.rotation


def nearest_rotation_quat(matrices: np.ndarray) -> np.ndarray:
    """(n, 4) quaternions of the rotations nearest (Frobenius) to ``matrices`` (n, 3, 3) with det > 0: the
    orthogonal polar factor U Vᵀ of the SVD U S Vᵀ.  Non-finite matrices give NaN quaternions (the World's
    blow-up guard resets them)."""
    finite = np.isfinite(matrices).all(axis=(1, 2))
    U, _, Vt = np.linalg.svd(np.where(finite[:, None, None], matrices, np.eye(3)))
    # det(1 + h ω̂) = 1 + h²|ω|² > 0, so R keeps det > 0; this only guards against round-off
    flip = np.linalg.det(U) * np.linalg.det(Vt) < 0.0
    U[flip, :, 2] *= -1.0
    q = matrix_to_quat(U @ Vt)
    q[~finite] = np.nan
    return q

"""Block solve of a contact manifold's normal rows: the ≤ 4 points two bodies touch at, solved together.

The points of one manifold share both bodies, so their normal rows are coupled through the block
A = J M⁻¹ Jᵀ of the Delassus matrix (for 4 coplanar corners it is singular, rank 3: a flat face has three
rigid degrees of freedom against the other body — push, and tilt about two axes — so how the load is shared
between the corners is not determined, only its total and its moments).  Solving the corners one after
another (Gauss–Seidel) favours whichever comes first and converges slowly on exactly the modes that matter
for stacking (tilting); mass-split Jacobi is unbiased but slower still: a flat box landing with
restitution got ~70 % of its bounce after 8 sweeps, and a stack of ten boxes each turned by a few degrees
rocked itself apart.  So each update solves the manifold's normal rows exactly: the linear complementarity
problem

    w = A λ + b,   λ ≥ 0,  w ≥ 0,  λ·w = 0

(λ the new *accumulated* impulses, b = current row velocity − target − A λ_old, w the resulting row
velocity minus its target) by enumerating the active set, as Box2D v2's 2-point block solver does, here for
up to 4 points: for every subset S, λ_S = −A_SS⁺ b_S and λ = 0 elsewhere; the first S (largest first) with
λ ≥ 0 on it and w ≥ 0 off it is the solution.  The pseudo-inverse gives the minimum-norm λ on a singular
face — the load shared as evenly as the geometry allows — and treats singular values below ``RCOND`` of the
largest as zero (a flat face is singular up to round-off; inverting round-off would make impulses explode).
Rows that must end exactly at their target (two-sided rows) only appear in subsets that contain them.

Friction is not solved as a block: projecting a step preconditioned by a full (non-diagonal) block onto the
friction cones is not energy-safe (tried: a stack of turned boxes spun itself up and fell), so the caller
keeps the mass-split Jacobi update for the tangent rows.

The pseudo-inverse of the full set is built once per sub-step (``np.linalg.pinv`` on a stack of ≤ 4 × 4
matrices) — a manifold resting on all its points is solved by it alone — and those of the other subsets
the first time a manifold of the batch needs them; an update is a handful of batched products per batch.
"""

from __future__ import annotations

import itertools

import numpy as np

#: largest manifold solved as a block (box–box and box–plane give ≤ 4 points; bigger groups — a particle
#: body on the ground — keep the mass-split Jacobi update)
MAX_BLOCK = 4

#: relative cut-off of the pseudo-inverses (see the module docstring)
RCOND = 1e-9

_PAD_VELOCITY = 1.0  # a padding row "separates" at 1 m/s: it is never active


def _subsets(P: int) -> np.ndarray:
    """All subsets of P points as masks ``(2**P, P)``, the largest first, the empty one last."""
    masks = []
    for k in range(P, -1, -1):
        for chosen in itertools.combinations(range(P), k):
            m = np.zeros(P, dtype=bool)
            m[list(chosen)] = True
            masks.append(m)
    return np.stack(masks)


_SUBSETS = {P: _subsets(P) for P in range(1, MAX_BLOCK + 1)}


class ManifoldBlocks:
    """The normal-row blocks of ``G`` manifolds (each padded to ``P`` points) of one batch of ``k`` contacts.

    Args:
        group_of:    (k,) manifold of each contact (contacts of a manifold consecutive).
        group_start: (G,) first contact of each manifold.
        Jn, MJn:     (k, 12) normal-row Jacobians and M⁻¹Jᵀ of the contacts.

    Attributes (shapes):
        gather:  (G, P) index of each point's contact, ``k`` for padding (index into an array extended by one).
        A:       (G, P, P) normal-row Delassus blocks (identity on padding).
        inverse_all: (G, P, P) pseudo-inverse of A (all points active).
        inverse: (G, S, P, P) pseudo-inverses of A restricted to each subset (zero outside it), on demand.
        subsets: (S, P) bool, the largest first.
    """

    def __init__(self, group_of: np.ndarray, group_start: np.ndarray, Jn: np.ndarray, MJn: np.ndarray):
        k = len(group_of)
        G = len(group_start)
        within = np.arange(k) - group_start[group_of]
        P = int(within.max()) + 1
        gather = np.full((G, P), k)
        gather[group_of, within] = np.arange(k)
        self.gather = gather
        self.scatter = (group_of, within)
        pad = gather == k
        # A_ij = J_n,i · (M⁻¹ J_n,j)ᵀ: the points of a manifold see the same two bodies
        Jg = np.concatenate((Jn, np.zeros((1, 12))))[gather]
        MJg = np.concatenate((MJn, np.zeros((1, 12))))[gather]
        A = np.einsum("gik,gjk->gij", Jg, MJg)
        A[:, np.arange(P), np.arange(P)] += pad
        self.A = A
        self.pad = pad
        self._velocity = np.empty(k + 1)  # per-contact values extended by the padding value, reused
        self._impulse = np.zeros(k + 1)
        self.subsets = _SUBSETS[P]
        # the full active set is the answer for a manifold resting on all its points — the common case — so
        # its inverse is built now and the other subsets' only when a manifold needs them
        self.inverse_all = np.linalg.pinv(A, rcond=RCOND, hermitian=True)
        self._inverse = None

    @property
    def inverse(self) -> np.ndarray:
        """(G, S, P, P) pseudo-inverses of A restricted to each subset (zero outside it), built on demand."""
        if self._inverse is None:
            G, P, _ = self.A.shape
            S = len(self.subsets)
            on = self.subsets[:, :, None] & self.subsets[:, None, :]
            self._inverse = np.linalg.pinv((self.A[:, None, :, :] * on).reshape(G * S, P, P), rcond=RCOND,
                                           hermitian=True).reshape(G, S, P, P)
        return self._inverse

    def solve_normal(self, velocity, target, lam_old, two_sided=None):
        """The manifold LCP for row velocities ``velocity`` and ``target`` (per contact), from accumulated
        impulses ``lam_old``; ``two_sided`` (k,) bool marks rows that must end exactly at their target (any
        sign).  Returns the new accumulated impulses ``(k,)`` and ``(k,)`` bool: whether the contact's
        manifold found an exact solution (where not, the caller falls back to its Jacobi update)."""
        k = len(velocity)
        np.subtract(velocity, target, out=self._velocity[:k])
        self._velocity[k] = _PAD_VELOCITY
        self._impulse[:k] = lam_old
        b = self._velocity.take(self.gather) - np.einsum("gij,gj->gi", self.A, self._impulse.take(self.gather))
        tol_w = 1e-9 * (np.abs(b).max() + 1e-12)
        must = None if two_sided is None else np.append(two_sided, False)[self.gather]
        pad = self.pad

        # fast path: all (real) points active
        x = -np.einsum("gij,gj->gi", self.inverse_all, np.where(pad, 0.0, b))
        w = np.einsum("gij,gj->gi", self.A, x) + b
        tol_x = 1e-9 * (np.abs(x).max() + 1e-12)
        ok_x = x >= -tol_x if must is None else (x >= -tol_x) | must
        found = np.all(np.where(pad, True, ok_x & (np.abs(w) <= 1e3 * tol_w)), axis=1)

        if not found.all():  # enumerate the active sets of the others
            bad = np.flatnonzero(~found)
            bb = b[bad]
            X = -np.einsum("gsij,gj->gsi", self.inverse[bad], bb)  # (g, S, P): λ per active set, 0 off it
            W = np.einsum("gij,gsj->gsi", self.A[bad], X) + bb[:, None, :]
            tol_x = 1e-9 * (np.abs(X).max() + 1e-12)
            on = self.subsets
            if must is None:
                ok = np.all(np.where(on, (X >= -tol_x) & (np.abs(W) <= 1e3 * tol_w), W >= -tol_w), axis=2)
            else:
                m = must[bad][:, None, :]
                ok = np.all(np.where(on, ((X >= -tol_x) | m) & (np.abs(W) <= 1e3 * tol_w), (W >= -tol_w) & ~m),
                            axis=2)
            x[bad] = X[np.arange(len(bad)), np.argmax(ok, axis=1)]
            found[bad] = ok.any(axis=1)
        x = np.maximum(x, 0.0) if must is None else np.where(must, x, np.maximum(x, 0.0))
        return x[self.scatter], found[self.scatter[0]]

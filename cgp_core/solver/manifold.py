"""Block solve of a contact manifold's normal rows: the ≤ 4 points two bodies touch at, solved together.

The points of one manifold share both bodies, so their normal rows are coupled through the block
A = J M⁻¹ Jᵀ of the Delassus matrix (for 4 coplanar corners it is singular, rank 3: a flat face has three
rigid degrees of freedom against the other body — push, and tilt about two axes — so how the load is shared
between the corners is not determined, only its total and its moments).  Solving the corners one after
another (Gauss–Seidel) favours whichever comes first and converges slowly on exactly the modes that matter
for stacking (tilting): a flat box landing with restitution got ~70 % of its bounce after 8 sweeps, and a
stack of ten boxes each turned by a few degrees rocked itself apart.  So each update solves the manifold's
normal rows exactly: the linear complementarity problem

    w = A λ + b,   λ ≥ 0,  w ≥ 0,  λ·w = 0

(λ the new *accumulated* impulses, b = current row velocity − target − A λ_old, w the resulting row
velocity minus its target) by enumerating the active set, as Box2D v2's 2-point block solver does, here for
up to 4 points: for every subset S, λ_S = −A_SS⁺ b_S and λ = 0 elsewhere; the first S (largest first) with
λ ≥ 0 on it and w ≥ 0 off it is the solution.  The pseudo-inverse gives the minimum-norm λ on a singular
face — the load shared as evenly as the geometry allows — and treats eigenvalues below ``RCOND`` of the
largest as zero (a flat face is singular up to round-off; inverting round-off would make impulses explode).
Rows that must end exactly at their target (two-sided rows) only appear in subsets that contain them.

Friction is not solved as a block: projecting a step preconditioned by a full (non-diagonal) block onto the
friction cones is not energy-safe (tried: a stack of turned boxes spun itself up and fell), so the solver
updates the tangent rows point by point.

The pseudo-inverses come from a cyclic Jacobi eigen-decomposition (:func:`symmetric_pinv`, a few dozen lines
that give the same bits compiled and in plain Python, unlike a LAPACK call).  A manifold's pseudo-inverse for
the full set — the answer for a manifold resting on all its points, the common case — and those of the other
subsets are computed the first time a sub-step needs them and kept in a per-manifold cache for the rest of the
sub-step (the velocity sweeps and the penetration recovery share it).
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from ..jit import njit

#: largest manifold solved as a block (box–box and box–plane give ≤ 4 points; bigger groups — a particle
#: body on the ground — are solved point by point)
MAX_BLOCK = 4

#: relative cut-off of the pseudo-inverses (see the module docstring)
RCOND = 1e-6

#: :func:`solve_manifold_lcp`: a point where the guessed solution's w exceeds this fraction of the largest |b| is in
#: no solution (1e6 times the tolerance of w ≥ 0, 1e3 times that of w = 0 on the active set)
W_PRUNE = 1e-3

#: Jacobi sweeps of the eigen-decomposition (a 4 × 4 converges to round-off in 4–6)
_JACOBI_SWEEPS = 12


def _subset_table() -> np.ndarray:
    """``SUBSETS[P]``: the subsets of P points as bit masks, the largest first (combinations in order), the
    empty one last; padded with −1 to 16 entries."""
    table = np.full((MAX_BLOCK + 1, 1 << MAX_BLOCK), -1, dtype=np.int64)
    for P in range(1, MAX_BLOCK + 1):
        masks = [sum(1 << i for i in chosen)
                 for k in range(P, -1, -1) for chosen in itertools.combinations(range(P), k)]
        table[P, :len(masks)] = masks
    return table


SUBSETS = _subset_table()


@njit
def symmetric_pinv(A, mask, P, out):
    """Pseudo-inverse of the symmetric matrix ``A[:P, :P]`` restricted to the points in the bit ``mask`` (rows
    and columns outside it zero), written into ``out[:P, :P]``; eigenvalues below ``RCOND`` × the largest
    count as zero.  Cyclic Jacobi rotations (Golub & Van Loan 8.5)."""
    idx = np.empty(MAX_BLOCK, np.int64)
    k = 0
    for i in range(P):
        if mask & (1 << i):
            idx[k] = i
            k += 1
    S = np.zeros((MAX_BLOCK, MAX_BLOCK))
    V = np.zeros((MAX_BLOCK, MAX_BLOCK))
    for r in range(k):
        V[r, r] = 1.0
        for c in range(k):
            S[r, c] = A[idx[r], idx[c]]
    for _ in range(_JACOBI_SWEEPS):
        off = 0.0
        for r in range(k):
            for c in range(r + 1, k):
                off += S[r, c] * S[r, c]
        if off == 0.0:
            break
        for p in range(k):
            for q in range(p + 1, k):
                if S[p, q] == 0.0:
                    continue
                theta = (S[q, q] - S[p, p]) / (2.0 * S[p, q])
                t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
                c_ = 1.0 / math.sqrt(t * t + 1.0)
                s_ = t * c_
                for r in range(k):  # S ← S G (columns p, q)
                    sp, sq = S[r, p], S[r, q]
                    S[r, p] = c_ * sp - s_ * sq
                    S[r, q] = s_ * sp + c_ * sq
                for r in range(k):  # S ← Gᵀ S (rows p, q)
                    sp, sq = S[p, r], S[q, r]
                    S[p, r] = c_ * sp - s_ * sq
                    S[q, r] = s_ * sp + c_ * sq
                for r in range(k):  # V ← V G
                    vp, vq = V[r, p], V[r, q]
                    V[r, p] = c_ * vp - s_ * vq
                    V[r, q] = s_ * vp + c_ * vq
    largest = 0.0
    for r in range(k):
        largest = max(largest, abs(S[r, r]))
    cutoff = RCOND * largest
    for r in range(P):
        for c in range(P):
            out[r, c] = 0.0
    for e in range(k):
        lam = S[e, e]
        if abs(lam) <= cutoff:
            continue
        for r in range(k):
            for c in range(k):
                out[idx[r], idx[c]] += V[r, e] * V[c, e] / lam


@njit(inline="always")
def _subset_solves(A, P, b, must, cache, cached, s, tol_w, x):
    """Whether subset ``SUBSETS[P, s]`` solves the LCP (λ = −A_SS⁺ b_S ≥ 0 on it, w ≥ 0 off it, w = 0 on it, up to
    the tolerances; two-sided rows inside it): λ written into ``x`` (unclamped), its pseudo-inverse cached."""
    mask = SUBSETS[P, s]
    for i in range(P):
        if must[i] and not mask & (1 << i):
            return False  # a two-sided row must be in the active set
    if not cached[s]:
        symmetric_pinv(A, mask, P, cache[s])
        cached[s] = True
    inv = cache[s]
    biggest = 0.0
    for i in range(P):
        acc = 0.0
        for j in range(P):
            acc -= inv[i, j] * b[j]
        x[i] = acc
        biggest = max(biggest, abs(acc))
    tol_x = 1e-9 * (biggest + 1e-12)
    ok = True
    for i in range(P):
        w = b[i]
        for j in range(P):
            w += A[i, j] * x[j]
        if mask & (1 << i):
            if not ((x[i] >= -tol_x or must[i]) and abs(w) <= 1e3 * tol_w):
                ok = False
        elif not w >= -tol_w:
            ok = False
    return ok


@njit
def solve_manifold_lcp(A, P, b, must, cache, cached, guess, x):
    """The manifold LCP ``w = A λ + b, λ ≥ 0, w ≥ 0, λ·w = 0`` of ``P`` points (``A (4, 4)``, ``b (4,)``;
    ``must (4,)`` bool marks two-sided rows: any sign, w = 0).  ``cache (16, 4, 4)`` / ``cached (16,)`` bool hold
    the pseudo-inverses of the subsets already computed (in :data:`SUBSETS` order).  Writes λ into ``x`` and
    returns whether an exact solution was found (where not, the caller falls back to one point at a time).

    The answer is the first subset, in :data:`SUBSETS` order, that solves it.  Two guesses are tried first:
    ``guess`` (a bit mask of points: the current impulses' support, i.e. the last update's active set), then the
    points approaching at λ = 0 (b < 0; the position stage starts from λ = 0).  If one solves the LCP, its w tells
    which points can be in *no* solution — A is J M⁻¹ Jᵀ, positive semi-definite, so every solution has the same
    w (that of the guess, up to round-off), and a subset holding a point where w is clearly positive (above
    :data:`W_PRUNE` of the largest |b|) fails — and only the subsets of the other points are enumerated, in
    order.  The answer is the same; what it saves is the pseudo-inverses and tests of the subsets that fail: a
    manifold resting on one of its 4 points (a round hull on the ground: the others speculative, a few mm up)
    reached its answer after 11 failing subsets, computing 12 pseudo-inverses a sub-step (issue 38's 300
    hulls)."""
    tol_w = 0.0
    for i in range(P):
        tol_w = max(tol_w, abs(b[i]))
    scale = tol_w
    tol_w = 1e-9 * (tol_w + 1e-12)
    full = (1 << P) - 1
    forced = 0  # the two-sided rows, in every subset tried
    violated = 0  # the points approaching at λ = 0 (w = b < 0): the second guess
    for i in range(P):
        if must[i]:
            forced |= 1 << i
        if b[i] < 0.0:
            violated |= 1 << i
    allowed = full
    found = -1
    for attempt in range(2):
        mask = ((guess if attempt == 0 else violated) & full) | forced
        if attempt == 1 and mask == (guess & full) | forced:
            break  # the same guess again
        g = 0
        while SUBSETS[P, g] != mask:
            g += 1
        if _subset_solves(A, P, b, must, cache, cached, g, tol_w, x):
            found = g
            allowed = 0
            cut = W_PRUNE * (scale + 1e-12)
            for i in range(P):
                w = b[i]
                for j in range(P):
                    w += A[i, j] * x[j]
                if w <= cut:
                    allowed |= 1 << i
            break
    dirty = False  # whether x was overwritten since the guess that solved it
    for s in range(1 << P):
        mask = SUBSETS[P, s]
        if mask & ~allowed:
            continue  # a point where the solution's w is clearly positive: this subset fails
        if s == found and not dirty:
            ok = True
        else:
            ok = _subset_solves(A, P, b, must, cache, cached, s, tol_w, x)
            dirty = True
        if ok:
            for i in range(P):
                if not must[i]:
                    x[i] = max(x[i], 0.0)
            return True
    return False

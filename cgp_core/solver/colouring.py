"""Graph colouring of the contact graph: batches of contacts that share no dynamic body.

Sequential impulses (Gauss–Seidel) update one contact at a time because each update changes the velocities
the next contact sees.  Two contacts that share no *dynamic* body do not see each other's updates, so they can
be solved at the same time; a colouring of the contacts with "shares a dynamic body" as the conflict relation
splits them into batches that are solved one after another (Gauss–Seidel between batches) with one vectorized
numpy update inside each batch (Jacobi within, which here is exact because nothing in a batch interacts).
Fixed bodies and the ground never change velocity, so they create no conflict (Box2D v3 does the same).

Algorithm: Jones–Plassmann on the conflict graph, vectorized.  Every contact gets a pseudo-random priority
(from its warm-start key, so the order is stable from step to step).  In each round, every uncoloured
contact whose priority is the smallest among the uncoloured contacts at *both* its bodies takes the
smallest colour that neither body has used yet (a 64-bit mask per body).  Contacts coloured in one round
never share a body, so the masks are updated with plain fancy indexing, and one sort up front replaces the
per-round minimum search (see the comment in the code).  The result is a greedy colouring
(at most 2·(max contacts per body) − 1 colours), found in a number of rounds that grows with the contact
count per body, not with the number of contacts.

Colour counts are capped (``max_colours``): a body with very many contacts (a big dynamic plate carrying a
pile) would otherwise produce as many tiny batches as it has contacts.  Contacts that do not fit get the
*overflow* colour ``max_colours``; the solver handles that batch differently (Jacobi with mass splitting).
"""

from __future__ import annotations

import numpy as np

#: Box2D v3 uses 24 graph colours plus an overflow set
DEFAULT_MAX_COLOURS = 24

_MIX = np.uint64(0x9E3779B97F4A7C15)  # Fibonacci hashing: spreads consecutive keys over 64 bits


def contact_priorities(keys: np.ndarray) -> np.ndarray:
    """A permutation rank ``(m,)`` of the contacts, pseudo-random but a pure function of the keys."""
    with np.errstate(over="ignore"):
        mixed = np.asarray(keys).astype(np.uint64) * _MIX
    mixed ^= mixed >> np.uint64(29)
    rank = np.empty(len(keys), dtype=np.int64)
    rank[np.argsort(mixed, kind="stable")] = np.arange(len(keys))
    return rank


def colour_contacts(body_a: np.ndarray, body_b: np.ndarray, dynamic: np.ndarray, priority: np.ndarray,
                    max_colours: int = DEFAULT_MAX_COLOURS, preset: np.ndarray | None = None) -> np.ndarray:
    """Colour ``m`` contacts so that no two contacts of one colour share a dynamic body.

    Args:
        body_a, body_b: (m,) body indices in ``[0, len(dynamic))`` (map the ground to a non-dynamic index).
        dynamic:        (nb,) bool — bodies whose velocity the solver changes.
        priority:       (m,) distinct integers (e.g. :func:`contact_priorities`).
        max_colours:    at most 64; contacts that do not fit get colour ``max_colours`` (overflow).
        preset:         (m,) int or None — colours already fixed (−1: colour this one).  The solver passes
                        last step's colours of the contacts that persist (valid: they were conflict-free
                        then and join the same bodies now), so only new contacts are coloured — the
                        persistent colouring of Box2D v3, and most of a resting pile's colouring is free.

    Returns ``colour (m,)`` int.
    """
    if not 1 <= max_colours <= 64:
        raise ValueError(f"max_colours must be in 1..64, got {max_colours}")
    m = len(body_a)
    nb = len(dynamic)
    colour = np.full(m, max_colours, dtype=np.int64)
    if m == 0:
        return colour
    # a non-dynamic end never conflicts: give it a private node of its own (one per contact end)
    ea = np.where(dynamic[body_a], body_a, nb + np.arange(m))
    eb = np.where(dynamic[body_b], body_b, nb + m + np.arange(m))
    used = np.zeros(nb + 2 * m, dtype=np.uint64)  # colours taken at each end, one bit each
    pending = np.arange(m)
    if preset is not None:
        keep = (preset >= 0) & (preset < max_colours)
        colour[keep] = preset[keep]
        bits = np.left_shift(np.uint64(1), colour[keep].astype(np.uint64))
        np.bitwise_or.at(used, ea[keep], bits)
        np.bitwise_or.at(used, eb[keep], bits)
        pending = np.flatnonzero(~keep)
        if pending.size == 0:
            return colour
    # rank of each pending contact among the pending contacts at the same end, by priority.  A contact wins
    # a round when it is the lowest-priority uncoloured contact at both ends; since each end's contacts are
    # then coloured in rank order, "lowest uncoloured" is simply "rank == number already coloured at that
    # end" (a counter per end, no min-reduction per round).
    k = pending.size
    ends = np.concatenate((ea[pending], eb[pending]))
    order = np.lexsort((np.concatenate((priority[pending], priority[pending])), ends))
    sorted_ends = ends[order]
    rank = np.empty(2 * k, dtype=np.int64)
    rank[order] = np.arange(2 * k) - np.searchsorted(sorted_ends, sorted_ends, side="left")
    rank_a, rank_b = np.zeros(m, np.int64), np.zeros(m, np.int64)
    rank_a[pending], rank_b[pending] = rank[:k], rank[k:]
    done = np.zeros(nb + 2 * m, dtype=np.int64)  # pending contacts coloured so far at each end
    full = np.uint64((1 << max_colours) - 1) if max_colours < 64 else np.uint64(0xFFFFFFFFFFFFFFFF)

    while pending.size:
        pa, pb = ea[pending], eb[pending]
        win = (done[pa] == rank_a[pending]) & (done[pb] == rank_b[pending])
        w, wa, wb = pending[win], pa[win], pb[win]
        free = ~(used[wa] | used[wb]) & full
        fits = free != 0
        # lowest set bit of `free`: free & -free (two's complement), its index via the float exponent
        low = free & (~free + np.uint64(1))
        colour[w] = np.where(fits, np.frexp(low.astype(np.float64))[1] - 1, max_colours)
        bit = np.where(fits, low, np.uint64(0))
        used[wa] |= bit  # winners of one round never share an end: plain fancy assignment is exact
        used[wb] |= bit
        done[wa] += 1
        done[wb] += 1
        pending = pending[~win]
    return colour

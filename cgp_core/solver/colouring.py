"""Colouring the contact graph: manifolds (body pairs) grouped so that no two of one colour share a body that moves.

Gauss–Seidel visits the manifolds one after another, each against the velocities the previous ones left; two
manifolds that share no moving body do not see each other's update, so the manifolds of one colour can be updated
in any order — or at the same time, on several threads — with the same result, bit for bit.  Sweeping colour after
colour is still Gauss–Seidel (each colour sees what the earlier colours did), in another order than the plain one.
This is Box2D v3's constraint graph (``constraint_graph.c``): a greedy colouring in the order the constraints come,
static bodies left out (their velocity never changes: any number of manifolds of one colour may touch the ground),
and an overflow for what does not fit in the colours it keeps.

The colouring depends only on the manifolds and their order — never on the number of threads — so a scene steps
to the same bits on one thread as on many (the solver's sweep over colours: :func:`.sequential_impulse.
solve_contacts`)."""

from __future__ import annotations

import numpy as np

from ..jit import njit

#: colours kept (one bit each of a body's int64 mask of the colours it is in); a manifold whose bodies are in all of
#: them goes to the overflow, updated alone after the colours (Box2D v3 keeps 24 and an overflow too)
MAX_COLOURS = 63


@njit
def colour_manifolds(a, b, group_start, dynamic):
    """Greedy colouring of the ``G`` manifolds (runs ``group_start[g] : group_start[g + 1]`` of the contacts, bodies
    ``a``, ``b`` of their first contact, rows of ``dynamic (n + 1,)``): each manifold, in order, takes the lowest
    colour that neither of its moving bodies is in.  Returns ``order (G,)`` int64, the manifolds colour by colour
    (within a colour in their own order), and ``colour_start (C + 2,)`` int64: colour k is ``order[colour_start[k] :
    colour_start[k + 1]]``; the last run (possibly empty) is the overflow, which must be updated one after another."""
    G = len(group_start) - 1
    used = np.zeros(len(dynamic), np.int64)  # per body row: bit k set = in colour k
    colour = np.empty(G, np.int64)
    count = np.zeros(MAX_COLOURS + 1, np.int64)  # (the last: the overflow)
    colours = 0
    for g in range(G):
        first = group_start[g]
        i, j = a[first], b[first]
        taken = (used[i] if dynamic[i] else 0) | (used[j] if dynamic[j] else 0)
        k = 0
        while k < MAX_COLOURS and (taken >> k) & 1:
            k += 1
        colour[g] = k
        count[k] += 1
        if k < MAX_COLOURS:
            colours = max(colours, k + 1)
            bit = np.int64(1) << k
            if dynamic[i]:
                used[i] |= bit
            if dynamic[j]:
                used[j] |= bit
    colour_start = np.zeros(colours + 2, np.int64)
    for k in range(colours):
        colour_start[k + 1] = colour_start[k] + count[k]
    colour_start[colours + 1] = colour_start[colours] + count[MAX_COLOURS]
    order = np.empty(G, np.int64)
    fill = colour_start[:-1].copy()
    for g in range(G):
        k = colour[g] if colour[g] < MAX_COLOURS else colours
        order[fill[k]] = g
        fill[k] += 1
    return order, colour_start

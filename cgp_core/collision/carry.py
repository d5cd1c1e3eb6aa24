"""Contacts found once per tick and carried through its sub-steps (``world.contact_detection: once_per_tick``).

Box2D v3 finds its contacts once per step and relaxes them over the step's sub-steps: within the step each
contact point is held by both bodies and its separation follows the bodies' motion.  Here each side holds its own
surface point — ``p_A = p₀ − (s₀/2) n`` on A, ``p_B = p₀ + (s₀/2) n`` on B, from the point ``p₀`` found midway
between the surfaces at ``t₀`` — as an *anchor* fixed in its body's frame, ``r = R(t₀)ᵀ (p − x(t₀))``, and

    s(t) = n · ((x_B(t) + R_B(t) r_B) − (x_A(t) + R_A(t) r_A)),

which is ``s₀`` at ``t₀``; the normal ``n`` is kept as found.  (Box2D v3 anchors both sides at the one midway
point, which its 2 cm speculative margin keeps near the surfaces; here a fast body's margin can be metres — the
`bullet` scene's hull is found 1 m before a wall — and a midway anchor carried with it ended up past the wall.)
The point the solver takes both lever arms to (one point: the impulse pair conserves angular momentum, see
:mod:`.contacts`) is midway between the two surface points, or B's moved back by half the gap along the normal
where A does not move (the ground, a fixed body) — there A's lever arm does not matter, and the midpoint would trail
a box sliding over the ground by half its slide.

When they are carried.  The tick's first sub-step detects as every sub-step does by default (margins for one
sub-step's motion).  The others carry its contacts as long as no movable body's surface may have moved since by
more than half the speculative distance — |Δx| + θ · reach — and detect everything again (and carry that) once one
has (:meth:`.detector.CollisionDetector._moved`).  Carrying then misses no contact a detection in every sub-step
would find: each side's margin holds at least the speculative distance (one margin against the ground), and two
bodies that each moved by at most half of it closed their gap by less.  The turn matters as much as the shift: a
hull turning about one point of its manifold brings other points of its surface to the other body — carrying every
contact through the tick unchecked (margins sized for the whole tick), a hull tumbling onto another in the 100-hull
pile sank 69 mm.  So while anything moves, the sub-steps detect as by default (the same contacts, the same bits);
only a world at rest — awake: a sleeping island is not stepped at all — carries its contacts.  (Detecting again only
the pairs of the bodies that moved, and sorting their new contacts in among the carried ones, was tried: in numpy it
cost more than it saved while a pile piled.)

What differs from detecting every sub-step, at rest: a body's points are up to a tick old (its motion within the
tolerance).  Measured: benchmarks/README.md, "Contacts once per tick".

The ground's side (``body_a`` = ``GROUND``) has its anchor in world coordinates (the plane does not move); a fixed
body's pose does not change, so its anchor stays where it was found.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .contacts import GROUND, ContactSet


class CarriedContacts(NamedTuple):
    """The contacts of a tick's first sub-step and each point in both bodies' frames (``m`` contacts)."""

    found: ContactSet        # the contacts as detected (their separations and points at detection)
    anchor_a: np.ndarray     # (m, 3) [m] — the point in A's body frame (world coordinates for the ground)
    anchor_b: np.ndarray     # (m, 3) [m] — the point in B's body frame
    a_still: np.ndarray      # (m,) bool — A does not move (the ground or a fixed body): the point is B's anchor


def carry(contacts: ContactSet, position: np.ndarray, rotation: np.ndarray, fixed: np.ndarray) -> CarriedContacts:
    """The anchors of ``contacts`` at the poses ``position (n, 3)``, ``rotation (n, 3, 3)`` they were found at:
    each side's own surface point, p ∓ (s / 2) n; ``fixed (n,)`` bool: the bodies that never move."""
    a, b, p = contacts.body_a, contacts.body_b, contacts.point
    half_gap = 0.5 * contacts.separation[:, None] * contacts.normal
    # r = Rᵀ (x_surface − x), row by row: rᵀ = (x_surface − x)ᵀ R
    anchor_b = np.einsum("mk,mkj->mj", p + half_gap - position[b], rotation[b])
    on_body = a != GROUND
    anchor_a = p - half_gap
    ia = a[on_body]
    anchor_a[on_body] = np.einsum("mk,mkj->mj", anchor_a[on_body] - position[ia], rotation[ia])
    a_still = ~on_body
    a_still[on_body] = fixed[ia]
    return CarriedContacts(contacts, anchor_a, anchor_b, a_still)


def carried_contacts(carried: CarriedContacts, position: np.ndarray, rotation: np.ndarray) -> ContactSet:
    """The carried contacts at the poses ``position (n, 3)``, ``rotation (n, 3, 3)`` now: each separation the gap
    between the two surface points along the normal, each point midway between them — or, where A does not move,
    B's surface point moved back by half the gap (the module docstring); every other field as found."""
    found = carried.found
    a, b, normal = found.body_a, found.body_b, found.normal
    point_b = position[b] + np.einsum("mkj,mj->mk", rotation[b], carried.anchor_b)
    point_a = carried.anchor_a.copy()
    on_body = a != GROUND
    ia = a[on_body]
    point_a[on_body] = position[ia] + np.einsum("mkj,mj->mk", rotation[ia], carried.anchor_a[on_body])
    separation = np.einsum("mk,mk->m", normal, point_b - point_a)
    point = np.where(carried.a_still[:, None], point_b - 0.5 * separation[:, None] * normal, 0.5 * (point_a + point_b))
    return found._replace(separation=separation, point=point)

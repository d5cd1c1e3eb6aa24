"""Contacts found once per tick and carried through its sub-steps (``world.contact_detection: once_per_tick``).

Box2D v3 finds its contacts once per step and relaxes them over the step's sub-steps: within the step each
contact point is held by both bodies and its separation follows the bodies' motion.  Here each side holds its own
surface point — ``p_A = p₀ − (s₀/2) n`` on A, ``p_B = p₀ + (s₀/2) n`` on B, from the point ``p₀`` found midway
between the surfaces at ``t₀`` — as an *anchor* fixed in its body's frame, ``r = R(t₀)ᵀ (p − x(t₀))``, and

    s(t) = n · ((x_B(t) + R_B(t) r_B) − (x_A(t) + R_A(t) r_A)),

which is ``s₀`` at ``t₀``; the normal ``n`` is kept as found.  (Box2D v3 anchors both sides at the one midway
point, which its 2 cm speculative margin keeps near the surfaces; here a fast body's margin can be metres — the
`bullet` scene's hull is found 1 m before a wall — and a midway anchor carried with it would end up past the wall.)
The point the solver takes both lever arms to (one point: the impulse pair conserves angular momentum, see
:mod:`.contacts`) is midway between the two surface points, or B's moved back by half the gap along the normal
where A does not move (the ground, a fixed body) — there A's lever arm does not matter, and the midpoint would trail
a box sliding over the ground by half its slide.  Detection, ~40 % of a tick of the 100-hull pile, then runs once
per tick instead of once per sub-step, for the bodies that do not turn.

A body that turns changes which of its points touch: a hull turning about one point of its manifold brings other
points of its surface to the other body, points the detection did not report (a hull tumbling onto another in the
100-hull pile sank 69 mm within a tick), and a ball's body-fixed bottom point rises by r (1 − cos θ) as it rolls
by θ.  So a body of the carried contacts that turned since their detection by θ with θ · reach above the detector's
``carry_turn_tolerance`` (5 mm) has its pairs and ground contacts detected again in that sub-step, and carried from
there (:meth:`.detector.CollisionDetector._carry_and_detect`); the others stay carried.  Translation needs no
such check: the margins are sized for the rest of the tick's motion, ``(|v| + |ω| reach)`` times the time left in
it (:mod:`.detector`), and the carry moves the points with the bodies.

What it costs in physics (why it is a choice, not the default): a pair that was not within its margin at the
detection has no contact until the next one, and a body whose velocity grows within the tick (an impact) can outrun
its margin; a point that slides off an edge or a face within the tick keeps its normal and its feature until the
next detection; a sleeping island an awake body reaches within the tick wakes at the next tick (meanwhile it is
static to the awake bodies, its contact holding them off).  A body's own motion within a sub-step is what the
integrator gives, as before.  Measured: benchmarks/README.md, "Contacts once per tick".

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

    def select(self, mask: np.ndarray) -> CarriedContacts:
        """The contacts ``mask (m,)`` picks, with their anchors."""
        return CarriedContacts(self.found.select(mask), self.anchor_a[mask], self.anchor_b[mask], self.a_still[mask])

    def concatenate(self, other: CarriedContacts) -> CarriedContacts:
        """These contacts, then ``other``'s."""
        return CarriedContacts(ContactSet(*(np.concatenate(pair) for pair in zip(self.found, other.found))),
                               *(np.concatenate(pair) for pair in zip(self[1:], other[1:])))


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

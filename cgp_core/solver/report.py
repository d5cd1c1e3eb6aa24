"""The contact report of a tick: every contact point with the impulses the solver gave it, and per body the summed
contact force and torque — what a bumper or a force-torque sensor reports (the node's ``~/contacts``).

**Where it comes from.**  The velocity stage's :func:`~.sequential_impulse.store_impulses` leaves, per contact of
the sub-step, its accumulated normal impulse λₙ and its world-frame friction impulse; :func:`tally_contacts`, run
right after it (only while a report is wanted: :meth:`SequentialImpulseSolver.start_report`), adds them up over
the tick.  It reads only the solver's :class:`~.arrays.Manifolds` (bodies, point, normal, separation, key), the
rows' tangents and the impulses — never a shape — so every shape pair the narrow phase produces is reported
without more work.

**What a tick's report means** (a tick is ``substeps`` sub-steps of h = dt / substeps):

- *contacts*: the contact points of the tick's **last** sub-step (where they are at the end of the tick), each
  with its impulses **summed over the sub-steps of the tick in which it persisted** (the same contact is the
  solver's warm-start match: same primitive pair, nearest point).  A contact that ended before the last sub-step
  is not listed (its impulse is in the body sums).  Listed: the contacts that touch (separation ≤ 0) or took an
  impulse; a speculative contact that stayed apart with no impulse is no contact.
- *per body*: the total contact impulse on the body over the whole tick — every contact of every sub-step,
  rolling resistance included — divided by dt: the **mean contact force** [N] and the **mean contact torque
  about the centre of mass** [N m] over the tick (each sub-step's angular impulse about the COM where it was).
  A box resting on the ground reports m g up and no torque; a body the solver did not touch is not listed.
- Sides: A and B as in :mod:`cgp_core.collision.contacts` — ``body_a`` is ``GROUND`` (−1) for the ground plane,
  else a body index (a fixed body is a body); the normal points **from A to B**; the normal and friction
  impulses are those **on B** (A gets the opposite).  Fixed bodies are listed in the per-body sums too (the
  reaction on them: a force plate).
- Sleeping islands (:mod:`cgp_core.sleep`) are not stepped, so the solver sees none of their contacts; a report
  repeats a sleeping body's last awake contacts and its wrench (:func:`carry_sleeping`), as Box2D keeps a
  sleeping body's contacts — a box asleep on the ground still reports m g.

Cost: nothing while no report is wanted (one ``is None`` test per sub-step); with one, one compiled call per
sub-step, O(m log m) (``benchmarks/bench_contacts.py`` measures it).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..collision.contacts import GROUND
from ..jit import njit
from .arrays import Manifolds, Rows


class ContactTally(NamedTuple):
    """The tick so far (a bundle).  Per contact (``w`` of them) in the order of the solver's warm-start memory of the
    last sub-step (sorted by key), so that the next sub-step's ``Manifolds.previous`` indexes these rows too."""

    body_a: np.ndarray            # (w,) int64 body index of side A, GROUND (−1) for the ground
    body_b: np.ndarray            # (w,) int64 body index of side B
    point: np.ndarray             # (w, 3) world contact point of the last sub-step [m]
    normal: np.ndarray            # (w, 3) unit normal from A to B
    separation: np.ndarray        # (w,) signed gap at the start of the last sub-step [m] (< 0: penetration)
    normal_impulse: np.ndarray    # (w,) Σ λₙ on B over the sub-steps it persisted in [N s]
    friction_impulse: np.ndarray  # (w, 3) Σ friction impulse on B, world frame [N s]
    body_impulse: np.ndarray      # (n + 1, 6) per solver row: Σ contact impulse [N s], Σ angular impulse about the
    #                               COM [N m s] over the tick's sub-steps (row n: the ground)
    touched: np.ndarray           # (n + 1,) bool: the row had a reported contact in some sub-step of the tick

    @staticmethod
    def start(bodies: int, remembered: int) -> ContactTally:
        """An empty tally for ``bodies`` bodies, whose per-contact rows match a warm-start memory of
        ``remembered`` contacts (zero impulses: the sums start at the tick)."""
        w = remembered
        return ContactTally(np.full(w, GROUND, np.int64), np.zeros(w, np.int64), np.zeros((w, 3)), np.zeros((w, 3)),
                            np.zeros(w), np.zeros(w), np.zeros((w, 3)), np.zeros((bodies + 1, 6)),
                            np.zeros(bodies + 1, np.bool_))


class ContactReport(NamedTuple):
    """One tick's contacts (see the module docstring): ``k`` contact points and ``b`` bodies with a contact."""

    body_a: np.ndarray            # (k,) intp body index of side A, GROUND (−1) for the ground plane
    body_b: np.ndarray            # (k,) intp body index of side B
    point: np.ndarray             # (k, 3) world point [m], midway between the surfaces
    normal: np.ndarray            # (k, 3) unit normal from A to B
    separation: np.ndarray        # (k,) signed gap [m] (negative: penetration depth)
    normal_impulse: np.ndarray    # (k,) normal impulse on B over the tick [N s] (≥ 0)
    friction_impulse: np.ndarray  # (k, 3) friction impulse on B over the tick, world frame [N s]
    body: np.ndarray              # (b,) intp the bodies with a contact, ascending
    force: np.ndarray             # (b, 3) mean contact force on each over the tick [N], world frame
    torque: np.ndarray            # (b, 3) mean contact torque about its COM [N m], world frame
    duration: float               # the tick's dt [s] (force = impulse / duration)

    @staticmethod
    def empty(duration: float = 0.0) -> ContactReport:
        i, v, s = np.zeros(0, np.intp), np.zeros((0, 3)), np.zeros(0)
        return ContactReport(i, i.copy(), v, v.copy(), s, s.copy(), v.copy(), i.copy(), v.copy(), v.copy(),
                             float(duration))

    @property
    def count(self) -> int:
        return len(self.body_b)

    def contact_force(self) -> np.ndarray:
        """(k, 3) each contact's mean force on B over the tick [N]: (λₙ n + friction) / dt."""
        return (self.normal_impulse[:, None] * self.normal + self.friction_impulse) / self.duration


@njit(inline="always")
def tally_contacts(manifolds, rows, lam, impulse, tally):
    """The :class:`ContactTally` after one more sub-step: ``manifolds`` / ``rows`` (:class:`~.arrays.Manifolds`,
    :class:`~.arrays.Rows`), ``lam (m, 3)`` the accumulated impulses (normal, t₁, t₂) and ``impulse (n + 1, 6)`` the
    per-row impulses :func:`~.sequential_impulse.apply_impulses` applied; ``tally`` the tick so far.  Bundles as
    plain tuples from Python."""
    manifolds, rows, tally = Manifolds(*manifolds), Rows(*rows), ContactTally(*tally)
    a, b, key, J = manifolds.a, manifolds.b, manifolds.key, rows.J
    m = len(a)
    n = len(impulse) - 1
    by_key = np.argsort(key, kind="mergesort")  # store_impulses' order: the next sub-step's `previous` indexes it
    body_a = np.empty(m, np.int64)
    body_b = np.empty(m, np.int64)
    point = np.empty((m, 3))
    normal = np.empty((m, 3))
    separation = np.empty(m)
    normal_impulse = np.empty(m)
    friction_impulse = np.empty((m, 3))
    touched = tally.touched.copy()
    remembered = len(tally.normal_impulse)
    for q in range(m):
        c = by_key[q]
        body_a[q] = GROUND if a[c] == n else a[c]
        body_b[q] = b[c]
        separation[q] = manifolds.separation[c]
        o = manifolds.previous[c]
        carried = 0 <= o < remembered
        normal_impulse[q] = lam[c, 0] + (tally.normal_impulse[o] if carried else 0.0)
        for k in range(3):
            point[q, k] = manifolds.point[c, k]
            normal[q, k] = manifolds.normal[c, k]
            # J[c, r, 6:9] is row r's direction (B's side): the friction impulse on B
            friction_impulse[q, k] = (lam[c, 1] * J[c, 1, 6 + k] + lam[c, 2] * J[c, 2, 6 + k]
                                      + (tally.friction_impulse[o, k] if carried else 0.0))
        if separation[q] <= 0.0 or lam[c, 0] > 0.0:
            touched[a[c]] = True
            touched[b[c]] = True
    return ContactTally(body_a, body_b, point, normal, separation, normal_impulse, friction_impulse,
                        tally.body_impulse + impulse, touched)


def finish_report(tally: ContactTally, dt: float) -> ContactReport:
    """The :class:`ContactReport` of a tick of ``dt`` seconds from its :class:`ContactTally` (the contacts in the
    solver's order: by primitive pair, then feature)."""
    pick = np.flatnonzero((tally.separation <= 0.0) | (tally.normal_impulse > 0.0))
    rows = np.flatnonzero(tally.touched[:-1])  # row n is the ground: not a body
    sums = tally.body_impulse[rows] * (1.0 / dt)
    return ContactReport(tally.body_a[pick], tally.body_b[pick], tally.point[pick], tally.normal[pick],
                         tally.separation[pick], tally.normal_impulse[pick], tally.friction_impulse[pick], rows,
                         sums[:, :3], sums[:, 3:], float(dt))


def carry_sleeping(report: ContactReport, previous: ContactReport, asleep: np.ndarray, fixed: np.ndarray,
                   position: np.ndarray) -> ContactReport:
    """``report`` with the sleeping bodies' contacts and wrenches of ``previous`` (the tick before, same bodies)
    added: a contact whose movable sides all sleep, a sleeping body's force and torque, and the reaction of such
    contacts on fixed bodies (force −(λₙ n + friction) / dt at the contact point, torque about the fixed body's
    ``position``).  ``asleep``, ``fixed`` (n,) bool; ``position`` (n, 3) the bodies' COMs."""
    if not asleep.any() or (previous.count == 0 and len(previous.body) == 0):
        return report
    a, b = previous.body_a, previous.body_b
    a_index = np.maximum(a, 0)
    at_rest = asleep | fixed
    keep = ((a < 0) | at_rest[a_index]) & at_rest[b] & (asleep[b] | ((a >= 0) & asleep[a_index]))
    scale = report.duration / previous.duration  # the same force over a tick of another length (rate_hz changed)
    carried = ContactReport(*(field[keep] for field in previous[:5]), previous.normal_impulse[keep] * scale,
                            previous.friction_impulse[keep] * scale, *report[7:])
    contacts = [np.concatenate((new, old)) for new, old in zip(report[:7], carried[:7])]
    # per body: this tick's sums, the sleeping bodies' last ones, the fixed bodies' reactions to carried contacts
    n = len(asleep)
    listed = np.zeros(n, bool)
    wrench = np.zeros((n, 6))
    listed[report.body] = True
    wrench[report.body, :3], wrench[report.body, 3:] = report.force, report.torque
    held = previous.body[asleep[previous.body]]
    listed[held] = True
    wrench[held, :3] = previous.force[asleep[previous.body]]
    wrench[held, 3:] = previous.torque[asleep[previous.body]]
    on_b = carried.contact_force()
    for side, sign in ((carried.body_a, -1.0), (carried.body_b, 1.0)):
        hit = np.flatnonzero((side >= 0) & fixed[np.maximum(side, 0)])
        if hit.size:
            body, force = side[hit], sign * on_b[hit]
            listed[body] = True
            np.add.at(wrench, (body, slice(0, 3)), force)
            np.add.at(wrench, (body, slice(3, 6)), np.cross(carried.point[hit] - position[body], force))
    body = np.flatnonzero(listed)
    return ContactReport(*contacts, body, wrench[body, :3], wrench[body, 3:], report.duration)

"""Sleeping bodies, one island at a time (Box2D's islands and ``b2_timeToSleep``).

Bodies at rest on each other cost a full contact solve per sub-step to stay where they are.  A body is
*resting* while the fastest point of its bounding sphere moves slower than :data:`SLEEP_SPEED` [m/s]
(|v| + |ω| r, Box2D v3's measure and threshold); its rest timer counts how long.  An *island* is a connected
component of the contact graph through movable bodies: two movable bodies touching (or within the speculative
margin) in the last sub-step are in one island; fixed bodies and the ground do not connect islands (a pile on
the ground is not one island with a ball rolling elsewhere on the same ground).  Bodies held together by joints
(a robot's moving links, the bodies of a scene's ``joints:`` articulation: ``joined`` pairs of
:meth:`Islands.update`, from :meth:`cgp_core.robots.world.Robots.joined_pairs`) are always in one island, touching
or not: they fall asleep together and wake together (a body hanging on a hinge does not sleep while its partner
moves; waking one wakes the other).  A sleeping robot or articulation is not stepped (its joint velocities zeroed,
its joint positions kept: :meth:`cgp_core.robots.world.Robots.solve`).  When every body of an island
has rested for :data:`SLEEP_TIME` [s], the island sleeps: its momenta are zeroed and its bodies are left out of
the sub-steps (no forces, no contacts among themselves or with static bodies, no integration), so they stay
exactly where they rest.

An island wakes (all its bodies, their rest timers at zero) when

- a wrench command acts on one of its bodies (:class:`cgp_core.world.World` checks before each tick), or a joint
  command on a robot or articulation of it (:meth:`cgp_core.robots.world.Robots.command`),
- an awake body touches one of its bodies (the detector reports the contact, :func:`cgp_core.dynamics.step_bodies`
  wakes the island and detects again in the same sub-step),
- the world is reset, or the caller says a body's state was edited (:meth:`Islands.wake`, e.g. after a
  teleport).

A projectile at its apex is slower than SLEEP_SPEED for a few milliseconds only, far less than SLEEP_TIME.
Everything here is keyed on the body model object: a new model (bodies spawned or deleted) starts every body
awake with fresh timers (see :meth:`Islands.matches`).
"""

from __future__ import annotations

import numpy as np

from .bodies import BodyModel, BodyState
from .jit import njit

SLEEP_SPEED = 0.05
SLEEP_TIME = 0.5


@njit
def island_labels(movable, body_a, body_b):
    """Connected components of the graph whose nodes are the bodies and whose edges are the contacts
    ``body_a[c]–body_b[c]`` between two movable bodies (−1, the ground, and fixed bodies join nothing):
    ``(n,)`` label per body, the smallest body index of its island (−1 for fixed bodies).  Union–find with path
    halving."""
    n = len(movable)
    parent = np.arange(n)
    for c in range(len(body_a)):
        i, j = body_a[c], body_b[c]
        if i < 0 or not movable[i] or not movable[j]:
            continue
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        while parent[j] != j:
            parent[j] = parent[parent[j]]
            j = parent[j]
        if i != j:
            parent[max(i, j)] = min(i, j)
    label = np.empty(n, np.int64)
    for i in range(n):
        r = i
        while parent[r] != r:
            r = parent[r]
        label[i] = r if movable[i] else -1
    return label


class Islands:
    """Sleep state of the bodies of one :class:`BodyModel`.  Attributes (n = body count):

    awake:      (n,) bool — movable bodies being stepped (fixed bodies: False).
    asleep:     (n,) bool — movable bodies that sleep.
    island:     (n,) int — island label (the smallest body index in it; −1 for fixed bodies), from the last
                sub-step's contacts of awake bodies; frozen while the island sleeps.
    rest_time:  (n,) — how long [s] each body has been resting (0 for sleeping and fixed bodies' purposes).
    """

    def __init__(self, model: BodyModel):
        self.model = model
        self.count = model.count
        self.movable = model.inv_mass > 0.0
        self.bounding_radius = model.bounding_radius()
        self.awake = self.movable.copy()
        self.island = np.where(self.movable, np.arange(self.count), -1)
        self.rest_time = np.zeros(self.count)

    def matches(self, model: BodyModel) -> bool:
        """Whether this sleep state belongs to ``model`` (the same object, with the same body count)."""
        return model is self.model and model.count == self.count

    @property
    def asleep(self) -> np.ndarray:
        return self.movable & ~self.awake

    @property
    def all_asleep(self) -> bool:
        return bool(self.movable.any()) and not self.awake.any()

    def wake(self, bodies=None) -> np.ndarray:
        """Wake the islands of ``bodies`` (indices; ``None`` = every body) and zero their rest timers.
        Returns the bodies woken (those that slept)."""
        if bodies is None:
            woken = np.flatnonzero(self.asleep)
            self.awake[:] = self.movable
            self.rest_time[:] = 0.0
            return woken
        bodies = np.asarray(bodies, dtype=np.intp).reshape(-1)
        labels = self.island[bodies]
        labels = labels[labels >= 0]
        members = np.isin(self.island, labels)
        woken = np.flatnonzero(members & ~self.awake & self.movable)
        self.awake |= members & self.movable
        self.rest_time[members] = 0.0
        return woken

    def update(self, state: BodyState, model: BodyModel, body_a: np.ndarray, body_b: np.ndarray,
               speed: np.ndarray, spin: np.ndarray, dt: float, joined=None) -> np.ndarray:
        """After a tick: islands from the last sub-step's contacts ``body_a, body_b`` (awake bodies only) and the
        ``joined`` pairs ``(a (k,), b (k,))`` of bodies held together by joints (always one island), rest timers
        from the speeds ``|v|``, ``|ω|`` (n,), and every island whose bodies have all rested :data:`SLEEP_TIME`
        put to sleep with zero momenta.  Returns the bodies that fell asleep."""
        awake = self.awake
        if not awake.any():
            return np.zeros(0, np.intp)
        if joined is not None and len(joined[0]):
            body_a = np.concatenate((np.asarray(body_a, np.int64), np.asarray(joined[0], np.int64)))
            body_b = np.concatenate((np.asarray(body_b, np.int64), np.asarray(joined[1], np.int64)))
        labels = island_labels(awake, np.ascontiguousarray(body_a, np.int64), np.ascontiguousarray(body_b, np.int64))
        self.island = np.where(awake, labels, self.island)
        resting = speed + spin * self.bounding_radius < SLEEP_SPEED
        self.rest_time = np.where(awake & resting, self.rest_time + dt, np.where(awake, 0.0, self.rest_time))
        # an island sleeps when its least rested body has rested long enough
        ids = self.island[awake]
        least = np.full(self.count, np.inf)
        np.minimum.at(least, ids, self.rest_time[awake])
        sleepy = awake & (least[np.maximum(self.island, 0)] >= SLEEP_TIME - 1e-12)
        if sleepy.any():
            self.awake &= ~sleepy
            state.linear_momentum[sleepy] = 0.0
            state.angular_momentum[sleepy] = 0.0
        return np.flatnonzero(sleepy)

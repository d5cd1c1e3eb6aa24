"""Predators: rigid bodies marked ``predator: true`` in the scene, which the boids of every flock flee.

A boid closer than its flock's ``fright_radius`` to a predator's surface (its bounding sphere) escapes with
an acceleration of up to ``max_acceleration`` (:func:`flee_acceleration`).  The flock treats it as avoidance
(``flock.py``): Reynolds flocks give it priority over cohesion, separation and alignment (they get only what
is left of ``max_acceleration``), Couzin flocks let it take over the desired direction (``couzin.py``).  A
predator is also an obstacle like any body: boids steer around it and can never enter it.

The escape direction is away from the predator *and off its line of motion*: ``unit(r̂ + l̂)`` with r̂ the
direction from the predator's centre to the boid and l̂ the unit component of that offset perpendicular to the
predator's velocity.  Fish flee at an angle to the attacker's path, not straight ahead of it (Hall, Wardle &
MacLennan 1986, the *fountain effect*): a boid straight ahead of a faster predator could never outrun it, while
one moving off the path at 45° or more clears it, so the school splits ahead of the predator and closes
behind it.  A predator at rest is fled radially (l̂ = 0).  The strength grows from 0 at the fright radius to
full in its inner half, so boids at the edge of the fright zone do not chatter in and out of panic.

Only a predator that is coming is fled: the fright fades out behind a moving predator (from full abeam,
r̂·û = 0, to none at r̂·û = −:data:`BEHIND_FADE`, û its direction of motion).  A boid the predator has passed
stops fleeing, so the sideways flight lasts only while the predator approaches and the two halves of a split
school stay within reach of each other's cohesion: the school closes behind the predator.  (Fleeing a
departing predator as hard as an approaching one drives the halves apart at full speed until they lose sight
of each other: measured, a 200-fish school then stays split for good.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..bodies import BodyModel, BodyState

#: the fright fades out behind a moving predator between r̂·û = 0 (abeam) and r̂·û = −BEHIND_FADE
BEHIND_FADE = 0.3


@dataclass
class Predators:
    """The predators at one instant (built once per tick).

    Attributes (shapes):
        position: (k, 3) — centres of mass, world [m].
        velocity: (k, 3) — linear velocities [m/s].
        radius:   (k,) — bounding-sphere radii about the centre of mass [m] (the surface the fright radius and
                  the test margins are measured from).
    """

    position: np.ndarray
    velocity: np.ndarray
    radius: np.ndarray

    @property
    def count(self) -> int:
        return len(self.radius)

    @staticmethod
    def from_bodies(model: BodyModel, state: BodyState, index: np.ndarray,
                    bounding_radius: np.ndarray | None = None) -> "Predators":
        """The bodies ``index`` (k,) of a world as predators (``bounding_radius`` (n,): precomputed radii)."""
        index = np.asarray(index, dtype=np.intp)
        radius = model.bounding_radius() if bounding_radius is None else bounding_radius
        return Predators(position=state.position[index].copy(),
                         velocity=state.linear_velocity(model)[index],
                         radius=np.asarray(radius, dtype=float)[index])


def flee_acceleration(positions: np.ndarray, predators: Predators, fright_radius: float,
                      full_strength: float) -> np.ndarray:
    """The escape acceleration of every boid, (3, N) [m/s²].

    Args:
        positions:     (3, N) boid positions [m].
        predators:     the predators this tick.
        fright_radius: boids closer than this to a predator's surface flee it [m].
        full_strength: the acceleration in the inner half of the fright zone [m/s²] (the flock's
                       ``max_acceleration``); it fades linearly to 0 at the fright radius.
    """
    flee = np.zeros_like(positions)
    if fright_radius <= 0.0 or full_strength <= 0.0:
        return flee
    for centre, velocity, radius in zip(predators.position, predators.velocity, predators.radius):
        offset = positions - centre[:, None]  # predator → boid
        distance = np.sqrt(np.einsum("ij,ij->j", offset, offset))
        clearance = distance - radius
        near = np.flatnonzero((clearance < fright_radius) & (distance > 1e-12))
        if len(near) == 0:
            continue
        away = offset[:, near] / distance[near]
        speed = float(np.linalg.norm(velocity))
        escape = away.copy()
        strength = full_strength * np.clip(2.0 * (fright_radius - clearance[near]) / fright_radius, 0.0, 1.0)
        if speed > 1e-9:
            path = velocity / speed
            along = path @ away
            lateral = away - np.outer(path, along)  # off the predator's line of motion
            length = np.sqrt(np.einsum("ij,ij->j", lateral, lateral))
            off_path = length > 1e-9
            escape[:, off_path] += lateral[:, off_path] / length[off_path]
            escape /= np.sqrt(np.einsum("ij,ij->j", escape, escape))
            strength *= np.clip(1.0 + along / BEHIND_FADE, 0.0, 1.0)  # a departing predator is no threat
        flee[:, near] += escape * strength
    return flee

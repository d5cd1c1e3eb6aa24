"""Predators: rigid bodies marked ``predator: true`` in the scene, which the boids of every flock flee.

A boid closer than its flock's ``fright_radius`` to a predator's surface (its bounding sphere) escapes with
an acceleration of up to ``max_acceleration`` (:func:`flee`).  The flock treats it as avoidance
(``flock.py``): Reynolds flocks give it priority over cohesion, separation and alignment (they get only what
is left of ``max_acceleration``), Couzin flocks let it take over the desired direction
(``couzin.blend_avoidance``).  A predator is also an obstacle like any body: boids steer around it and can
never enter it.

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

One compiled loop, one boid per iteration (parallel), each boid against every predator (a scene has a few).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..bodies import BodyModel, BodyState
from ..jit import njit, prange

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
    def from_bodies(model: BodyModel, state: BodyState) -> Predators | None:
        """The bodies of a world marked ``predator`` (``BodyModel.predator``), or None if there are none."""
        index = np.flatnonzero(model.predator)
        if len(index) == 0:
            return None
        return Predators(position=state.position[index].copy(),
                         velocity=state.linear_velocity(model)[index],
                         radius=model.bounding_radius()[index])


@njit(parallel=True)
def _flee(x, centre, velocity, radius, fright_radius, full_strength, out):
    """``out[i] +=`` boid i's escape from every predator (see the module docstring)."""
    for i in prange(x.shape[0]):
        for p in range(centre.shape[0]):
            ox = x[i, 0] - centre[p, 0]  # predator → boid
            oy = x[i, 1] - centre[p, 1]
            oz = x[i, 2] - centre[p, 2]
            distance = math.sqrt(ox * ox + oy * oy + oz * oz)
            clearance = distance - radius[p]
            if clearance >= fright_radius or distance <= 1e-12:
                continue
            rx, ry, rz = ox / distance, oy / distance, oz / distance  # r̂
            # 0 at the fright radius, full in its inner half
            strength = full_strength * min(max(2.0 * (fright_radius - clearance) / fright_radius, 0.0), 1.0)
            ex, ey, ez = rx, ry, rz
            vx, vy, vz = velocity[p, 0], velocity[p, 1], velocity[p, 2]
            speed = math.sqrt(vx * vx + vy * vy + vz * vz)
            if speed > 1e-9:
                ux, uy, uz = vx / speed, vy / speed, vz / speed  # û, the predator's path
                along = ux * rx + uy * ry + uz * rz
                lx, ly, lz = rx - along * ux, ry - along * uy, rz - along * uz  # off the path
                lateral = math.sqrt(lx * lx + ly * ly + lz * lz)
                if lateral > 1e-9:
                    ex, ey, ez = ex + lx / lateral, ey + ly / lateral, ez + lz / lateral
                length = math.sqrt(ex * ex + ey * ey + ez * ez)
                ex, ey, ez = ex / length, ey / length, ez / length
                strength *= min(max(1.0 + along / BEHIND_FADE, 0.0), 1.0)  # a departing predator is no threat
            out[i, 0] += ex * strength
            out[i, 1] += ey * strength
            out[i, 2] += ez * strength


def flee(positions: np.ndarray, predators: Predators, fright_radius: float, full_strength: float,
         out: np.ndarray) -> None:
    """Add every boid's escape acceleration [m/s²] to ``out`` (N, 3).

    Args:
        positions:     (N, 3) boid positions [m].
        predators:     the predators this tick.
        fright_radius: boids closer than this to a predator's surface flee it [m].
        full_strength: the acceleration in the inner half of the fright zone [m/s²] (the flock's
                       ``max_acceleration``); it fades linearly to 0 at the fright radius.
    """
    if fright_radius <= 0.0 or full_strength <= 0.0 or predators.count == 0:
        return
    _flee(positions, predators.position, predators.velocity, predators.radius, float(fright_radius),
          float(full_strength), out)

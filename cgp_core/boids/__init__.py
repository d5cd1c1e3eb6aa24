"""Boid flocks (Reynolds 1987; the lecture's "Flocking" slides and its fish-model exercise).

- ``params.py``    — :class:`FlockParams`: every knob, with units, defaults and validation.
- ``flock.py``     — :class:`Flock`: state (positions, velocities, frames) and the step pipeline.
- ``rules.py``     — cohesion, separation, alignment (one home each) and the loop over neighbours.
- ``neighbors.py`` — every boid's neighbours within d (grid, KD-tree, brute force) as lists rules loop over.
- ``frames.py``    — boid frames for the fish model: heading, banked dorsal axis, quaternions.
- ``obstacles.py`` — :class:`Obstacles`: the world's rigid bodies as seen by the boids.

Issue 14 (better flocking, against the literature):

- ``couzin.py``      — Couzin et al. 2002's zonal model, the second rule set (``rules: couzin``).
- ``topological.py`` — the k nearest neighbours (Ballerini et al. 2008) in the neighbour-list layout.
- ``predators.py``   — bodies marked ``predator`` and the boids' flight from them.
- ``order.py``       — order parameters (polarization, milling, ...) for ``~/flocks/<flock>/stats``.
"""

from .flock import Flock
from .neighbors import BruteForceSearch, GridSearch, KDTreeSearch, NeighborList, make_search
from .obstacles import ObstacleHits, Obstacles
from .order import FlockOrder
from .params import BOUNDS_MODES, MODELS, NEIGHBOR_MODES, NEIGHBOR_SEARCHES, RULES, CouzinParams, FlockParams
from .predators import Predators

__all__ = [
    "BOUNDS_MODES", "MODELS", "NEIGHBOR_MODES", "NEIGHBOR_SEARCHES", "RULES", "BruteForceSearch", "CouzinParams",
    "Flock", "FlockOrder", "FlockParams", "GridSearch", "KDTreeSearch", "NeighborList", "ObstacleHits", "Obstacles",
    "Predators", "make_search",
]

"""Boid flocks (Reynolds 1987; the lecture's "Flocking" slides and its fish-model exercise).

- ``params.py``    — :class:`FlockParams`: every knob, with units, defaults and validation.
- ``flock.py``     — :class:`Flock`: state (positions, velocities, frames) and the step pipeline.
- ``rules.py``     — cohesion, separation, alignment (one home each) and the loop over neighbours.
- ``neighbors.py`` — every boid's neighbours within d (grid, KD-tree, brute force) as lists rules loop over.
- ``frames.py``    — boid frames for the fish model: heading, banked dorsal axis, quaternions.
- ``obstacles.py`` — :class:`Obstacles`: the world's rigid bodies as seen by the boids.
"""

from .flock import Flock
from .neighbors import BruteForceSearch, GridSearch, KDTreeSearch, NeighborList, make_search
from .obstacles import ObstacleHits, Obstacles
from .params import BOUNDS_MODES, MODELS, NEIGHBOR_SEARCHES, FlockParams

__all__ = [
    "BOUNDS_MODES", "MODELS", "NEIGHBOR_SEARCHES", "BruteForceSearch", "Flock", "FlockParams", "GridSearch",
    "KDTreeSearch", "NeighborList", "ObstacleHits", "Obstacles", "make_search",
]

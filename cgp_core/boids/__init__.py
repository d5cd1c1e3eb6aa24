"""Boid flocks (Reynolds 1987; the lecture's "Flocking" slides and its fish-model exercise).

- ``params.py``    — :class:`FlockParams`: every knob, with units, defaults and validation.
- ``flock.py``     — :class:`Flock`: state (positions, velocities, frames) and the step pipeline.
- ``rules.py``     — cohesion, separation, alignment (one home each) and their neighbour sums.
- ``neighbors.py`` — fixed-radius neighbour search: cell-sorted grid, KD-tree, brute-force reference.
- ``frames.py``    — boid frames for the fish model: heading, banked dorsal axis, quaternions.
- ``obstacles.py`` — :class:`Obstacles`: the world's rigid bodies as seen by the boids.
"""

from .flock import Flock
from .neighbors import BruteForceSearch, GridSearch, KDTreeSearch, NeighborPairs, make_search
from .obstacles import ObstacleHits, Obstacles
from .params import BOUNDS_MODES, MODELS, NEIGHBOR_SEARCHES, FlockParams

__all__ = [
    "BOUNDS_MODES", "MODELS", "NEIGHBOR_SEARCHES", "BruteForceSearch", "Flock", "FlockParams", "GridSearch",
    "KDTreeSearch", "NeighborPairs", "ObstacleHits", "Obstacles", "make_search",
]

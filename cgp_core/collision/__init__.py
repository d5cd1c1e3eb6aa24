"""Collision detection (Ericson, *Real-Time Collision Detection*): primitives, broad phase, narrow phase and
the contact set the solver consumes.

- :mod:`.primitives` — bodies as convex primitives (a particle body is one sphere per particle).
- :mod:`.broadphase` — AABB overlap: uniform grid (default), sweep and prune, brute force (the reference).
- :mod:`.narrowphase`, :mod:`.box_box` — contact points per shape-pair type, one compiled kernel each.
- :mod:`.detector` — :class:`CollisionDetector`: the above, with speculative margins, into a :class:`ContactSet`.
- :mod:`.materials` — the ground plane and the friction / restitution combination rules.
"""

from .broadphase import BROAD_PHASES, DEFAULT_BROAD_PHASE, brute_force_pairs, grid_pairs, sweep_and_prune_pairs
from .contacts import GROUND, ContactSet
from .detector import DEFAULT_SPECULATIVE_DISTANCE, CollisionDetector
from .materials import Ground, combine_friction, combine_restitution
from .primitives import CollisionModel, build_collision_model

__all__ = [
    "BROAD_PHASES", "DEFAULT_BROAD_PHASE", "brute_force_pairs", "grid_pairs", "sweep_and_prune_pairs",
    "GROUND", "ContactSet", "DEFAULT_SPECULATIVE_DISTANCE", "CollisionDetector", "Ground",
    "combine_friction", "combine_restitution", "CollisionModel", "build_collision_model",
]

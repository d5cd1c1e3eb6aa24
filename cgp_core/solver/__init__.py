"""Contact response: one solver per file behind :class:`~cgp_core.solver.base.ContactSolver`, registry here.

=======================  ====================================================================================
name                     what it is
=======================  ====================================================================================
``sequential_impulse``   **default**: sequential impulses (projected Gauss–Seidel) with warm starting,
                         restitution, Coulomb friction cone and split-impulse penetration recovery, compiled,
                         one manifold at a time (:mod:`.sequential_impulse`)
=======================  ====================================================================================

Helpers: :mod:`.manifold` (exact block solve of a contact manifold's normal rows), :mod:`.base` (the interface
and :class:`SolverSettings`).

Materials (:mod:`cgp_core.collision.materials`, re-exported here): a contact's friction is
``√(μ_a μ_b)`` and its restitution ``max(e_a, e_b)`` (Box2D's rules); the ground defaults to μ = 0.6, e = 0
(``world.ground_friction``, ``world.ground_restitution`` in a scene).
"""

from __future__ import annotations

from ..collision.materials import (
    DEFAULT_GROUND_FRICTION,
    DEFAULT_GROUND_RESTITUTION,
    Ground,
    combine_friction,
    combine_restitution,
)
from .base import ContactSolver, SolverSettings
from .sequential_impulse import SequentialImpulseSolver

SOLVERS: dict[str, type] = {cls.name: cls for cls in (SequentialImpulseSolver,)}
DEFAULT_SOLVER = SequentialImpulseSolver.name


def make_solver(name: str = DEFAULT_SOLVER, **settings) -> ContactSolver:
    """The contact solver called ``name`` (keyword arguments: :class:`SolverSettings` fields, or
    ``detector=CollisionDetector(...)``); ``ValueError`` listing the valid names otherwise."""
    try:
        cls = SOLVERS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown contact solver {name!r}; valid: {', '.join(sorted(SOLVERS))}") from None
    return cls(**settings)


__all__ = ["ContactSolver", "SolverSettings", "SequentialImpulseSolver", "SOLVERS", "DEFAULT_SOLVER",
           "make_solver", "Ground", "combine_friction", "combine_restitution", "DEFAULT_GROUND_FRICTION",
           "DEFAULT_GROUND_RESTITUTION"]

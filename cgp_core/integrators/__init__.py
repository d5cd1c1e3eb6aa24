"""Integrators, one per file behind :class:`~cgp_core.integrators.base.Integrator`; selected per scene by
``world.integrator``.

=====================  =====  ==============================================================================
name                   order  what it is for
=====================  =====  ==============================================================================
``implicit_midpoint``  1 / 2  **default**: kick + implicit-midpoint free rotation; energy and world L of a
                              tumbling body conserved to round-off (second order without forces)
``rk4``                4      accurate smooth motion at small steps; invariants drift slowly
``symplectic_euler``   1      the game-engine classic: cheapest, bounded energy error for the linear part,
                              but a tumbling body gains energy (explicit gyroscopic term)
``explicit_euler``     1      the lecture's method on the rotation matrix; drifts (the teaching baseline)
=====================  =====  ==============================================================================

Why the default is ``implicit_midpoint``: see :mod:`cgp_core.integrators.implicit_midpoint`.
"""

from __future__ import annotations

from .base import Integrator
from .explicit_euler import ExplicitEuler
from .implicit_midpoint import ImplicitMidpoint
from .rk4 import RK4
from .symplectic_euler import SymplecticEuler

INTEGRATORS: dict[str, type] = {cls.name: cls for cls in (ImplicitMidpoint, RK4, SymplecticEuler, ExplicitEuler)}
DEFAULT_INTEGRATOR = ImplicitMidpoint.name


def make_integrator(name: str) -> Integrator:
    """The integrator called ``name``; ``ValueError`` listing the valid names otherwise."""
    try:
        return INTEGRATORS[name]()
    except (KeyError, TypeError):
        raise ValueError(f"unknown integrator {name!r}; valid: {', '.join(sorted(INTEGRATORS))}") from None


__all__ = ["Integrator", "INTEGRATORS", "DEFAULT_INTEGRATOR", "make_integrator", "ExplicitEuler",
           "ImplicitMidpoint", "RK4", "SymplecticEuler"]

"""Integrators, one per file behind :class:`~cgp_core.integrators.base.Integrator`; selected per scene by
``world.integrator``."""

from __future__ import annotations

from .base import Integrator
from .symplectic_euler import SymplecticEuler

INTEGRATORS: dict[str, type] = {cls.name: cls for cls in (SymplecticEuler,)}
DEFAULT_INTEGRATOR = "symplectic_euler"


def make_integrator(name: str) -> Integrator:
    """The integrator called ``name``; ``ValueError`` listing the valid names otherwise."""
    try:
        return INTEGRATORS[name]()
    except KeyError:
        raise ValueError(f"unknown integrator {name!r}; valid: {', '.join(sorted(INTEGRATORS))}") from None


__all__ = ["Integrator", "INTEGRATORS", "DEFAULT_INTEGRATOR", "make_integrator"]

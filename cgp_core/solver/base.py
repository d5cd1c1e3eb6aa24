"""The one interface every contact solver implements (one solver per file, Box2D v3 / solver2d style), and
the settings they share.

A solver is used in two stages of each rigid-body sub-step (see :func:`cgp_core.dynamics.step_bodies`):

- :meth:`ContactSolver.solve_velocities` (stage "solve contacts"), after the forces are accumulated and the
  contacts detected, before the integrator: it computes contact impulses such that the velocity the body
  will move with over the sub-step — momentum + h·force + impulse — satisfies non-penetration (with
  restitution) and Coulomb friction, and adds them to P and L as instantaneous momentum changes;
- :meth:`ContactSolver.recover_penetration` (stage "recover penetration"), after the integrator: it moves
  penetrating bodies apart without touching their momenta (so it adds no kinetic energy).

A solver may keep state from one sub-step to the next (warm starting); :meth:`reset` forgets it (call it
when the world is reset or bodies are teleported).  That memory belongs to one body model: a solver handed a
different model object (bodies spawned or deleted) starts cold instead of reusing per-body data.  Each solver owns the
:class:`~cgp_core.collision.CollisionDetector` it is fed from, so the pipeline is configured in one place.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import ClassVar, Protocol

from ..bodies import BodyModel, BodyState
from ..collision import CollisionDetector, ContactSet


@dataclass
class SolverSettings:
    """Contact solver parameters (SI units).

    Attributes:
        velocity_iterations:   sweeps over all contacts per sub-step for non-penetration and friction (at most:
                               see ``velocity_tolerance``).
        velocity_tolerance:    the sweeps stop early once a whole sweep changed no contact row's velocity by more
                               than this [m/s] (a warm-started resting stack is converged after one).  A resting pile
                               keeps creeping by up to h × this per sub-step: 1e-7 m/s is < 0.5 nm at h = 1/240 s
                               (with 1e-6 a settled pile's energy wandered by tens of nJ).
        position_iterations:   sweeps of the penetration recovery (0 disables it).
        restitution_threshold: a contact bounces only if it approaches faster than this [m/s] (Box2D's
                               ``restitutionThreshold`` idea: slower impacts are treated as resting, so a body
                               at rest does not jitter on the micro-bounces of gravity).  Box2D uses 1 m/s;
                               0.5 m/s keeps bounces of balls dropped from ≥ 1.3 cm.
        penetration_slop:      penetration [m] tolerated without correction: keeps resting contacts touching
                               (and warm-started) instead of being pushed apart and falling back each step.
        position_correction:   fraction β of the excess penetration removed per sub-step (Baumgarte's β).
        max_correction:        at most this much penetration [m] is removed per sub-step (no violent
                               pop-outs after a deep overlap).
        warm_start:            start each sub-step from the matched contacts' impulses of the previous one.
        rolling_resistance:    dimensionless coefficient c_rr of rolling resistance at every contact: a torque of
                               at most c_rr · N · r (N the normal force, r the rolling radius) opposing the
                               bodies' relative rolling (see ``resist_rolling`` in sequential_impulse.py).
                               0 (the default here) is the ideal rigid model, where a ball rolls for ever;
                               scenes default to ``world.rolling_resistance: 0.01``.
    """

    velocity_iterations: int = 8
    velocity_tolerance: float = 1e-7
    position_iterations: int = 3
    restitution_threshold: float = 0.5
    penetration_slop: float = 0.0005
    position_correction: float = 0.2
    max_correction: float = 0.05
    warm_start: bool = True
    rolling_resistance: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type in ("int", int):
                if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                    raise ValueError(f"solver setting {f.name} must be an integer >= 0, got {value!r}")
            elif f.type in ("float", float):
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                        or value < 0:
                    raise ValueError(f"solver setting {f.name} must be a finite number >= 0, got {value!r}")
        if not 0.0 < self.position_correction <= 1.0:
            raise ValueError(f"solver setting position_correction must be in (0, 1], got {self.position_correction!r}")
        if self.velocity_iterations < 1:
            raise ValueError("solver setting velocity_iterations must be >= 1")


class ContactSolver(Protocol):
    #: the name :func:`cgp_core.solver.make_solver` knows it by
    name: ClassVar[str]
    settings: SolverSettings
    detector: CollisionDetector

    def solve_velocities(self, model: BodyModel, state: BodyState, contacts: ContactSet, h: float, *,
                         inv_inertia=None, active=None, coupled=None) -> None:
        """Add contact impulses to ``state.linear_momentum`` / ``angular_momentum`` (see module docstring).
        ``inv_inertia`` (n, 3, 3): the world-frame I⁻¹ at ``state``'s poses if the caller has it already
        (default: computed from the state).  ``active`` (n,) bool: the bodies being stepped (default: all);
        the others (sleeping) act as static bodies.  ``coupled``: None, or the robots whose links touch free
        bodies this sub-step, whose rows are solved in the same loop as the contacts (``coupled.solve`` runs
        the velocity stage instead of the solver's own kernel: :mod:`cgp_core.robots.coupled`)."""
        ...

    def recover_penetration(self, model: BodyModel, state: BodyState, h: float) -> None:
        """Move penetrating bodies apart (positions / orientations only) for the contacts of the last
        :meth:`solve_velocities`, after the integrator has moved the bodies."""
        ...

    def reset(self) -> None:
        """Forget everything kept from previous sub-steps."""
        ...

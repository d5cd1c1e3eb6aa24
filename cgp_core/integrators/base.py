"""The one interface every integrator implements.

An integrator advances the free motion of all bodies over one (sub-)step ``h``: positions, orientations and
momenta, with ``state.force`` and ``state.torque`` (world frame, torque about the COM) held constant over the
step.  Contact impulses are not its business: the contact solver applies them to P and L before the
integrator runs (see ARCHITECTURE.md, "The step pipeline").  Fixed bodies (``inv_mass == 0``) never move.
"""

from __future__ import annotations

from typing import ClassVar, Protocol

from ..bodies import BodyModel, BodyState


class Integrator(Protocol):
    #: the scene key (``world.integrator``) that selects this integrator
    name: ClassVar[str]

    def step(self, model: BodyModel, state: BodyState, h: float) -> None:
        """Advance ``state`` in place by ``h`` seconds."""
        ...

"""Forces and torques on rigid bodies, accumulated into ``BodyState.force`` / ``BodyState.torque``.

This is the one home of the lecture's "force projection": a force F applied at a point p of a body acts
on the centre of mass with the *whole* force F (linear part) and produces the torque τ = (p − x̄) × F about
the COM (angular part): :func:`moment_about`, which :func:`apply_force_at_point` and the tick's wrench commands
(:class:`cgp_core.wrenches.WrenchSchedule`) both use.

Slide erratum ("Force projection", and "Whole Model" slides): the slides write
``F = F_ext (F_ext · (r_f − x̄))`` and ``τ = F_ext × (r_f − x̄)``.  Both are wrong: the linear part is F_ext
itself (a force's effect on the COM does not depend on where it acts — Newton's second law for the system
of particles), and the cross product is (r_f − x̄) × F_ext; the slide's order flips the sign of the torque
(r × F, as the slide "Torque" itself says).  Also on the "Torque" slide: the length of τ is in N·m (a
moment of force), not rad/s.
"""

from __future__ import annotations

import numpy as np

from .bodies import BodyModel, BodyState


def apply_gravity(model: BodyModel, state: BodyState, gravity: np.ndarray) -> None:
    """F += m g on every movable body (fixed bodies feel nothing: they are held)."""
    weight = model.mass[:, None] * np.asarray(gravity, dtype=float)[None, :]  # (n, 3)
    np.add(state.force, weight, out=state.force, where=(model.inv_mass > 0.0)[:, None])


def apply_damping(model: BodyModel, state: BodyState, linear: float, angular: float) -> None:
    """Viscous damping: F −= c_lin · m v, τ −= c_ang · L.

    Rates in 1/s, scaled by mass / inertia so the damping time constant is 1/c for every body whatever its size
    (what users mean by "damping 0.1"), rather than a force that makes light bodies stop faster.
    """
    if linear > 0.0:
        state.force -= linear * state.linear_momentum * (model.inv_mass > 0.0)[:, None]
    if angular > 0.0:
        state.torque -= angular * state.angular_momentum * (model.inv_mass > 0.0)[:, None]


def moment_about(point: np.ndarray, centre: np.ndarray, force: np.ndarray) -> np.ndarray:
    """τ = (p − x̄) × F: the moment about ``centre`` x̄ of ``force`` F acting at ``point`` p, (k, 3) each (rows
    broadcast) → (k, 3)."""
    return np.cross(point - centre, force)


def apply_force_at_point(state: BodyState, body: np.ndarray, force: np.ndarray, point: np.ndarray) -> None:
    """Accumulate forces ``force (k, 3)`` acting at world points ``point (k, 3)`` on bodies ``body (k,)``.

    Linear part: F on the COM.  Angular part: τ = (p − x̄) × F about the COM.  Several entries for the same
    body add up (``np.add.at``, not fancy-index assignment, which would keep only the last).
    """
    body = np.atleast_1d(np.asarray(body, dtype=np.intp))
    force = np.atleast_2d(np.asarray(force, dtype=float))
    point = np.atleast_2d(np.asarray(point, dtype=float))
    np.add.at(state.force, body, force)
    np.add.at(state.torque, body, moment_about(point, state.position[body], force))


def apply_torque(state: BodyState, body: np.ndarray, torque: np.ndarray) -> None:
    """Accumulate pure couples ``torque (k, 3)`` (world axes) on bodies ``body (k,)``: no linear effect."""
    body = np.atleast_1d(np.asarray(body, dtype=np.intp))
    np.add.at(state.torque, body, np.atleast_2d(np.asarray(torque, dtype=float)))

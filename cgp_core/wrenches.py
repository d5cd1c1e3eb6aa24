"""Wrench commands: forces applied at a point of a body (plus a pure couple), for one tick, for a while, or
until cleared.  What ``~/apply_wrench`` and ``~/bodies/<body>/wrench`` turn into; usable without ROS.

Semantics (one *tick* = one ``World.step``, i.e. ``dt = 1 / rate_hz``, which may run several physics
sub-steps):

- ``duration == 0``: the wrench acts during the next tick only (every sub-step of it): impulse F·dt.
- ``duration > 0``: it acts during the next ``ceil(duration / dt)`` ticks, i.e. for that much simulated time
  rounded up to whole ticks.
- ``duration < 0``: it acts every tick until :meth:`WrenchSchedule.clear`.
Several wrenches on one body add up.

Frames: ``frame == "world"``: ``force``, ``torque`` in world axes and ``point`` in world coordinates.
``frame == "body"``: all three in the body's own axes, ``point`` relative to its COM; they are re-expressed in
world axes at every sub-step, so a body-frame wrench turns with the body (a thruster).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .bodies import BodyState
from .forces import apply_force_at_point, apply_torque
from .rotation import quat_rotate

WORLD = "world"
BODY = "body"


@dataclass(frozen=True)
class WrenchCommand:
    """One validated command.  ``point is None`` means "at the COM"."""

    body: int
    force: tuple[float, float, float]
    torque: tuple[float, float, float] = (0.0, 0.0, 0.0)
    point: tuple[float, float, float] | None = None
    frame: str = WORLD
    duration: float = 0.0


class WrenchSchedule:
    """The active wrench commands, as arrays (k rows, one per active command):

    body (k,) int; force (k, 3); torque (k, 3); point (k, 3) (world coordinates, or body-frame offset from
    the COM for body-frame rows); at_com (k,) bool; body_frame (k,) bool; ticks_left (k,) int (−1 = until
    cleared).  ``max_active`` bounds k: a flood of long-lived commands cannot grow memory without limit.
    """

    def __init__(self, max_active: int = 10_000):
        self.max_active = max_active
        self._clear_arrays()

    def _clear_arrays(self) -> None:
        self.body = np.zeros(0, dtype=np.intp)
        self.force = np.zeros((0, 3))
        self.torque = np.zeros((0, 3))
        self.point = np.zeros((0, 3))
        self.at_com = np.zeros(0, dtype=bool)
        self.body_frame = np.zeros(0, dtype=bool)
        self.ticks_left = np.zeros(0, dtype=np.int64)

    @property
    def active(self) -> int:
        return len(self.body)

    def clear(self) -> None:
        self._clear_arrays()

    def add(self, commands: list[WrenchCommand], dt: float) -> int:
        """Schedule commands (already validated) from the next tick on; returns how many were accepted
        (the rest would exceed ``max_active``)."""
        room = max(0, self.max_active - self.active)
        commands = commands[:room]
        if not commands:
            return 0
        k = len(commands)
        ticks = np.array(
            [1 if c.duration == 0 else (-1 if c.duration < 0 else max(1, math.ceil(c.duration / dt - 1e-9)))
             for c in commands],
            dtype=np.int64,
        )
        self.body = np.concatenate((self.body, [c.body for c in commands]))
        self.force = np.concatenate((self.force, np.array([c.force for c in commands], dtype=float).reshape(k, 3)))
        self.torque = np.concatenate((self.torque, np.array([c.torque for c in commands], dtype=float).reshape(k, 3)))
        self.point = np.concatenate(
            (self.point, np.array([c.point or (0.0, 0.0, 0.0) for c in commands], dtype=float).reshape(k, 3)))
        self.at_com = np.concatenate((self.at_com, [c.point is None for c in commands]))
        self.body_frame = np.concatenate((self.body_frame, [c.frame == BODY for c in commands]))
        self.ticks_left = np.concatenate((self.ticks_left, ticks))
        return k

    def apply(self, state: BodyState) -> None:
        """Accumulate every active wrench into ``state.force`` / ``state.torque`` at the current poses
        (called once per sub-step)."""
        if self.active == 0:
            return
        q = state.orientation[self.body]
        com = state.position[self.body]
        bf = self.body_frame[:, None]
        force = np.where(bf, quat_rotate(q, self.force), self.force)
        torque = np.where(bf, quat_rotate(q, self.torque), self.torque)
        point = np.where(bf, com + quat_rotate(q, self.point), self.point)
        point = np.where(self.at_com[:, None], com, point)
        apply_force_at_point(state, self.body, force, point)
        apply_torque(state, self.body, torque)

    def end_tick(self) -> None:
        """Count one tick off every timed wrench and drop the expired ones."""
        if self.active == 0:
            return
        timed = self.ticks_left > 0
        self.ticks_left[timed] -= 1
        keep = self.ticks_left != 0
        if not keep.all():
            for name in ("body", "force", "torque", "point", "at_com", "body_frame", "ticks_left"):
                setattr(self, name, getattr(self, name)[keep])


class WrenchError(ValueError):
    """A wrench command that cannot be applied; ``field`` names the offending field."""

    def __init__(self, field: str, reason: str):
        self.field = field
        super().__init__(f"{field}: {reason}")


def _finite_vector(value, field: str, limit: float | None) -> tuple[float, float, float]:
    v = np.asarray(value, dtype=float).reshape(-1)
    if v.shape != (3,):
        raise WrenchError(field, f"must have 3 components, got {v.size}")
    if not np.all(np.isfinite(v)):
        raise WrenchError(field, f"must be finite, got {tuple(float(x) for x in v)}")
    if limit is not None and float(np.linalg.norm(v)) > limit:
        raise WrenchError(field, f"magnitude {np.linalg.norm(v):.3g} exceeds the limit {limit:.3g}")
    return (float(v[0]), float(v[1]), float(v[2]))


def make_command(body_names: list[str], body: str, *, force=(0.0, 0.0, 0.0), torque=(0.0, 0.0, 0.0), point=None,
                 frame: str = "", duration: float = 0.0, max_force: float = 1e6, max_torque: float = 1e6,
                 max_offset: float = 1e3, fixed: np.ndarray | None = None) -> WrenchCommand:
    """Validate a wrench request and turn it into a :class:`WrenchCommand`.

    ``frame`` is ``""`` or ``"world"`` (world axes) or the body's own name (body axes); any other frame is
    rejected, as are non-finite values, magnitudes above the limits, unknown bodies and NaN durations.
    Raises :class:`WrenchError` naming the field.
    """
    if body not in body_names:
        known = ", ".join(body_names[:20]) + (" ..." if len(body_names) > 20 else "")
        raise WrenchError("body", f"unknown body {body!r} (bodies: {known or 'none'})")
    index = body_names.index(body)
    if fixed is not None and bool(fixed[index]):
        raise WrenchError("body", f"{body!r} is fixed: wrenches cannot move it")
    if frame in ("", WORLD):
        kind = WORLD
    elif frame == body:
        kind = BODY
    else:
        raise WrenchError("header.frame_id", f"unknown frame {frame!r}: use '' or 'world' (world axes) or {body!r}"
                          " (the body's own axes)")
    duration = float(duration)
    if not math.isfinite(duration):
        raise WrenchError("duration", f"must be finite, got {duration}")
    return WrenchCommand(
        body=index,
        force=_finite_vector(force, "wrench.force", max_force),
        torque=_finite_vector(torque, "wrench.torque", max_torque),
        point=None if point is None else _finite_vector(point, "point", None),
        frame=kind,
        duration=duration,
    )

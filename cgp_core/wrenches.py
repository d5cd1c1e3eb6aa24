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

Validation (:func:`make_command`, what a simulator on a shared ROS graph needs): unknown or fixed bodies,
unknown frames, names longer than :data:`MAX_NAME_LENGTH`, non-finite numbers, force / torque magnitudes
above the caller's limits and lever arms above ``max_offset`` are rejected with a :class:`WrenchError` that
names the field; the schedule itself is bounded (:attr:`WrenchSchedule.max_active`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .bodies import BodyState
from .forces import moment_about
from .rotation import quat_rotate

WORLD = "world"
BODY = "body"

#: longest body name / frame id accepted: ROS names are short; a longer string is rejected before any lookup
MAX_NAME_LENGTH = 255
#: default bound on the lever arm |p − x̄| [m]: a force applied a kilometre away from a body is a mistake (and
#: would turn an accepted force into a torque far beyond ``max_torque``)
MAX_OFFSET = 1e3
#: timed wrenches are counted in ticks; longer than this is "until cleared" in practice
MAX_TICKS = 2**62


@dataclass(frozen=True)
class WrenchCommand:
    """One validated command.  ``point is None`` means "at the COM"."""

    body: int
    force: tuple[float, float, float]
    torque: tuple[float, float, float] = (0.0, 0.0, 0.0)
    point: tuple[float, float, float] | None = None
    frame: str = WORLD
    duration: float = 0.0


class WrenchSums(NamedTuple):
    """The active rows summed per body (m bodies), at the COMs ``com0`` they had when summed."""

    targets: np.ndarray   # (m,) the bodies
    com0: np.ndarray      # (m, 3) x̄₀
    force_w: np.ndarray   # (m, 3) ΣF_w of the world-frame rows
    force_p: np.ndarray   # (m, 3) ΣF_p of the world-frame rows with a point
    moment_w: np.ndarray  # (m, 3) Σ (p − x̄₀) × F_w + Στ_w
    force_b: np.ndarray   # (m, 3) ΣF_b of the body-frame rows (body axes)
    moment_b: np.ndarray  # (m, 3) Σ r_b × F_b + Στ_b (body axes)


class WrenchSchedule:
    """The active wrench commands, as arrays (k rows, one per active command):

    body (k,) int; force (k, 3); torque (k, 3); point (k, 3) (world coordinates, or body-frame offset from
    the COM for body-frame rows); at_com (k,) bool; body_frame (k,) bool; ticks_left (k,) int (−1 = until
    cleared).  ``max_active`` bounds k: a flood of long-lived commands cannot grow memory without limit.

    Applying them costs per *body*, not per row, so a flood of long-lived commands cannot slow the tick
    either: whenever the rows change (add, expiry, clear) they are summed once per body (lazily, at the next
    :meth:`apply`, at the COM ``x̄₀`` the body has then), and each sub-step applies the sums.  With ``R``,
    ``x̄`` the body's rotation and COM at the sub-step::

        F = ΣF_w + R ΣF_b
        τ = Σ (p − x̄₀) × F_w − (x̄ − x̄₀) × ΣF_p + Στ_w + R (Σ r_b × F_b + Στ_b)

    (w: world-frame rows, p: those of them with a point, b: body-frame rows).  The first line of τ is
    Σ (p − x̄) × F_w exactly; taking levers from x̄₀, the COM when summed, avoids the cancellation of
    Σ p × F − x̄ × ΣF for bodies far from the origin.
    """

    _ROWS = ("body", "force", "torque", "point", "at_com", "body_frame", "ticks_left")

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
        self._sums = None  # per-body sums of the rows; None = to be recomputed at the next apply

    @property
    def active(self) -> int:
        return len(self.body)

    def clear(self) -> None:
        self._clear_arrays()

    def remove_bodies(self, bodies) -> int:
        """Drop every row acting on one of ``bodies``; returns how many were dropped."""
        keep = ~np.isin(self.body, np.asarray(bodies, dtype=np.intp))
        dropped = int(keep.size - np.count_nonzero(keep))
        if dropped:
            self._keep_rows(keep)
        return dropped

    def renumber_bodies(self, new_index: np.ndarray) -> int:
        """After bodies were deleted: ``new_index (n_old,)`` maps each old body index to its new one, −1 for a
        deleted body.  Rows acting on deleted bodies are dropped (returns how many), the others follow their
        body."""
        new_index = np.asarray(new_index, dtype=np.intp)
        target = new_index[self.body] if self.active else self.body
        keep = target >= 0
        dropped = int(keep.size - np.count_nonzero(keep))
        self.body = target
        self._keep_rows(keep)
        return dropped

    def _keep_rows(self, keep: np.ndarray) -> None:
        for name in self._ROWS:
            setattr(self, name, getattr(self, name)[keep])
        self._sums = None

    def add(self, commands: list[WrenchCommand], dt: float) -> int:
        """Schedule commands (already validated) from the next tick on; returns how many were accepted
        (the rest would exceed ``max_active``)."""
        room = max(0, self.max_active - self.active)
        commands = commands[:room]
        if not commands:
            return 0
        k = len(commands)
        # A duration longer than MAX_TICKS ticks is "for ever" in practice; capping it keeps the count in int64.
        ticks = np.array(
            [1 if c.duration == 0 else (-1 if c.duration < 0 else
                                        max(1, min(MAX_TICKS, math.ceil(min(c.duration / dt, MAX_TICKS) - 1e-9))))
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
        self._sums = None
        return k

    def _sum_per_body(self, state: BodyState) -> WrenchSums:
        """The :class:`WrenchSums` over the m bodies that have rows (see the class docstring)."""
        targets, row_target = np.unique(self.body, return_inverse=True)
        m = len(targets)
        com0 = state.position[targets]
        world = ~self.body_frame[:, None]
        with_point = world & ~self.at_com[:, None]
        # each row's moment (p − centre) × F (forces.moment_about): world rows with a point about x̄₀; body rows
        # about their body's COM, their point being the body-frame offset; at-COM rows none (0 × F)
        point = np.where(self.at_com[:, None], 0.0, self.point)
        centre = np.where(with_point, com0[row_target], 0.0)
        moment = moment_about(point, centre, self.force) + self.torque

        def per_body(values: np.ndarray) -> np.ndarray:
            out = np.zeros((m, 3))
            np.add.at(out, row_target, values)
            return out

        return WrenchSums(targets, com0, per_body(np.where(world, self.force, 0.0)),
                          per_body(np.where(with_point, self.force, 0.0)), per_body(np.where(world, moment, 0.0)),
                          per_body(np.where(world, 0.0, self.force)), per_body(np.where(world, 0.0, moment)))

    def apply(self, state: BodyState) -> None:
        """Accumulate every active wrench into ``state.force`` / ``state.torque`` at the current poses
        (called once per sub-step)."""
        if self.active == 0:
            return
        if self._sums is None:
            self._sums = self._sum_per_body(state)
            # the common cases (only world-frame wrenches, or only at the COM) skip the terms they lack
            self._any_body_frame = bool(self.body_frame.any())
            self._any_with_point = bool((~self.body_frame & ~self.at_com).any())
        targets, com0, force_w, force_p, moment_w, force_b, moment_b = self._sums
        force, moment = force_w.copy(), moment_w.copy()
        if self._any_with_point:
            moment -= moment_about(state.position[targets], com0, force_p)
        if self._any_body_frame:
            q = state.orientation[targets]
            force += quat_rotate(q, force_b)
            moment += quat_rotate(q, moment_b)
        state.force[targets] += force
        state.torque[targets] += moment

    def end_tick(self) -> None:
        """Count one tick off every timed wrench and drop the expired ones."""
        if self.active == 0:
            return
        timed = self.ticks_left > 0
        self.ticks_left[timed] -= 1
        keep = self.ticks_left != 0
        if not keep.all():
            self._keep_rows(keep)


class WrenchError(ValueError):
    """A wrench command that cannot be applied.

    ``field`` names the offending message field (``body``, ``header.frame_id``, ``wrench.force``, ...);
    ``kind`` is a short, stable category of the problem (``unknown``, ``non-finite``, ``too large``, ...) so
    a caller can count and throttle reports per (field, kind) while the message carries the values."""

    def __init__(self, field: str, reason: str, kind: str = "invalid"):
        self.field = field
        self.kind = kind
        super().__init__(f"{field}: {reason}")


def _short(text: str, limit: int = 60) -> str:
    """``repr`` of a possibly huge string, cut to ``limit`` characters (error messages stay one line)."""
    return repr(text) if len(text) <= limit else repr(text[:limit]) + f"... ({len(text)} characters)"


def _magnitude(v: np.ndarray) -> float:
    return math.hypot(*v)  # scaled: no overflow warning for finite components near the float limit


def _finite_vector(value, field: str, limit: float | None, what: str = "magnitude") -> tuple[float, float, float]:
    try:
        v = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise WrenchError(field, f"must be 3 numbers, got {_short(repr(value))}", "malformed") from None
    if v.shape != (3,):
        raise WrenchError(field, f"must have 3 components, got {v.size}", "malformed")
    if not np.all(np.isfinite(v)):
        raise WrenchError(field, f"must be finite, got {tuple(float(x) for x in v)}", "non-finite")
    if limit is not None and _magnitude(v) > limit:
        raise WrenchError(field, f"{what} {_magnitude(v):.3g} exceeds the limit {limit:.3g}", "too large")
    return (float(v[0]), float(v[1]), float(v[2]))


def _name(value, field: str) -> str:
    if not isinstance(value, str):
        raise WrenchError(field, f"must be a string, got {type(value).__name__}", "malformed")
    if len(value) > MAX_NAME_LENGTH:
        raise WrenchError(field, f"{len(value)} characters; names are at most {MAX_NAME_LENGTH}", "too long")
    return value


@dataclass(frozen=True)
class CommandLimits:
    """What a wrench command may ask for (the node's ``max_force`` / ``max_torque`` parameters)."""

    max_force: float = 1e6            #: largest |F| [N]
    max_torque: float = 1e6           #: largest |τ| of the pure couple [N m]
    max_offset: float = MAX_OFFSET    #: largest lever arm |p − x̄| [m]


#: the limits of a command made without any
DEFAULT_LIMITS = CommandLimits()


def make_command(body_names: list[str], body: str, *, force=(0.0, 0.0, 0.0), torque=(0.0, 0.0, 0.0), point=None,
                 frame: str = "", duration: float = 0.0, limits: CommandLimits = DEFAULT_LIMITS,
                 fixed: np.ndarray | None = None, positions: np.ndarray | None = None) -> WrenchCommand:
    """Validate a wrench request and turn it into a :class:`WrenchCommand`.

    ``frame`` is ``""`` or ``"world"`` (world axes) or the body's own name (body axes); any other frame is
    rejected, as are non-finite values, force / torque magnitudes above ``limits.max_force`` /
    ``limits.max_torque``, a lever arm ``|p − x̄|`` above ``limits.max_offset`` (body frame: ``|point|``; world
    frame: checked against the body's current COM when ``positions`` (n, 3) is given), unknown or ``fixed``
    ((n,) bool) bodies, over-long names and NaN durations.  Raises :class:`WrenchError` naming the field.
    """
    body = _name(body, "body")
    frame = _name(frame, "header.frame_id")
    if body not in body_names:
        known = ", ".join(body_names[:20]) + (" ..." if len(body_names) > 20 else "")
        raise WrenchError("body", f"unknown body {_short(body)} (bodies: {known or 'none'})", "unknown")
    index = body_names.index(body)
    if fixed is not None and bool(fixed[index]):
        raise WrenchError("body", f"{body!r} is fixed: wrenches cannot move it", "fixed")
    if frame in ("", WORLD):
        kind = WORLD
    elif frame == body:
        kind = BODY
    else:
        raise WrenchError("header.frame_id", f"unknown frame {_short(frame)}: use '' or 'world' (world axes) or "
                          f"{body!r} (the body's own axes)", "unknown")
    try:
        duration = float(duration)
    except (TypeError, ValueError):
        raise WrenchError("duration", f"must be a number of seconds, got {_short(repr(duration))}",
                          "malformed") from None
    if not math.isfinite(duration):
        raise WrenchError("duration", f"must be finite, got {duration}", "non-finite")
    if point is not None:
        point = _finite_vector(point, "point", None)
        if kind == BODY:
            _finite_vector(point, "point", limits.max_offset, "distance from the centre of mass")
        elif positions is not None:
            _finite_vector(np.subtract(point, positions[index]), "point", limits.max_offset,
                           "distance from the centre of mass")
    return WrenchCommand(
        body=index,
        force=_finite_vector(force, "wrench.force", limits.max_force),
        torque=_finite_vector(torque, "wrench.torque", limits.max_torque),
        point=point,
        frame=kind,
        duration=duration,
    )

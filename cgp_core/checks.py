"""Argument checks shared by the core's public functions: one wording for "must be a positive number"."""

from __future__ import annotations

import math


def _number(value, what: str, requirement: str, ok) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number, got {value!r}") from None
    if not (math.isfinite(x) and ok(x)):
        raise ValueError(f"{what} must be {requirement}, got {value!r}")
    return x


def positive(value, what: str) -> float:
    """``value`` as a float; ``ValueError`` naming ``what`` unless it is a finite number > 0."""
    return _number(value, what, "a positive finite number", lambda x: x > 0.0)


def non_negative(value, what: str) -> float:
    """``value`` as a float; ``ValueError`` naming ``what`` unless it is a finite number >= 0."""
    return _number(value, what, "a finite number >= 0", lambda x: x >= 0.0)

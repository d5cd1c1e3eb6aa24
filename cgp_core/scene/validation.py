"""What every part of a scene's validation shares: :class:`SceneError` (every problem of a file, each as
``file: key: reason``) and :class:`Validator`, which checks one value at a time against its type and range
(:mod:`cgp_core.limits`) and records a problem instead of raising, so that one pass reports every problem in a
file.  A new kind of scene entry (a file of this package) parses its keys with a ``Validator`` it is handed::

    def parse_thing(v: Validator, raw: Any, key: str) -> ThingSpec | None:
        before = len(v.problems)
        d = v.mapping(raw, key)
        v.no_unknown_keys(d, {"name", "size"}, key)
        size = v.vector(d.get("size", [1, 1, 1]), f"{key}.size", 3, within=LENGTHS, unit="m")
        return ThingSpec(size) if len(v.problems) == before else None
"""

from __future__ import annotations

import math
import re
import reprlib
from typing import Any

import numpy as np

from ..limits import MAX_COORDINATE, MAX_LENGTH, MAX_MAGNITUDE, MAX_NAME_LENGTH, MIN_LENGTH
from ..user_input import YAML12_FLOAT

ROS_SAFE_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
#: the ground plane's entity name in contact reports (cgp_core.solver.report, the node's ~/contacts): no body or
#: flock may take it, or a contact with the ground could not be told from one with that entity
GROUND_NAME = "ground"
#: a SceneError message lists at most this many problems (all of them are in ``SceneError.problems``)
MAX_REPORTED_PROBLEMS = 50


class SceneError(ValueError):
    """A scene that cannot be loaded; the message lists every problem as ``file: key: reason``."""

    def __init__(self, source: str, problems: list[str]):
        self.source = source
        self.problems = problems
        shown = [f"{source}: {p}" for p in problems[:MAX_REPORTED_PROBLEMS]]
        if len(problems) > MAX_REPORTED_PROBLEMS:
            shown.append(f"{source}: ... and {len(problems) - MAX_REPORTED_PROBLEMS} more problems")
        super().__init__("\n".join(shown))


#: the ranges of lengths and coordinates (cgp_core.limits)
LENGTHS = (MIN_LENGTH, MAX_LENGTH)
COORDINATES = (-MAX_COORDINATE, MAX_COORDINATE)

_REPR = reprlib.Repr()
_REPR.maxstring = _REPR.maxother = 60
_REPR.maxlist = _REPR.maxdict = _REPR.maxtuple = 6
_REPR.maxlevel = 1


def short_repr(value: Any) -> str:
    """A short repr for error messages: a scene can hold huge (or alias-expanded) values."""
    return _REPR.repr(value)


def kind_of(value: Any) -> str:
    return {dict: "a mapping", list: "a list", str: "a string", bool: "a boolean", type(None): "nothing"}.get(
        type(value), type(value).__name__
    )


class Validator:
    """The validation of one scene file or request: ``source`` (its name, and the directory relative files are
    found from), ``problems`` (every problem found, as ``key: reason``) and ``files`` (the files it has read and
    what they gave, by identity: each is read once per request, :mod:`.mesh_files`)."""

    def __init__(self, source: str):
        self.source = source
        self.problems: list[str] = []
        self.files: dict[tuple, Any] = {}

    def fail(self, key: str, reason: str) -> None:
        self.problems.append(f"{key}: {reason}" if key else reason)

    def raise_if_any(self) -> None:
        if self.problems:
            raise SceneError(self.source, self.problems)

    def no_unknown_keys(self, mapping: dict, allowed: set[str], where: str) -> None:
        for key in mapping:
            if key not in allowed:
                path = f"{where}.{key}" if where else str(key)
                self.fail(path, f"unknown key (valid: {', '.join(sorted(allowed))})")

    def mapping(self, value: Any, key: str) -> dict:
        if value is None:
            return {}
        if not isinstance(value, dict):
            self.fail(key, f"must be a mapping, got {kind_of(value)}")
            return {}
        return value

    def number(self, value: Any, key: str, *, minimum: float | None = None, exclusive_min: bool = False,
               maximum: float | None = None, default: float = 0.0, within: tuple[float, float] | None = None,
               unit: str = "") -> float:
        """A finite number (bool is not one) >= / > ``minimum``, <= ``maximum``, then in the range ``within``
        (cgp_core.limits: what the simulation can hold; ``unit`` for the message); without ``maximum`` and
        ``within``, at most MAX_MAGNITUDE in magnitude."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            hint = ""
            if isinstance(value, str) and YAML12_FLOAT.match(value.strip()):
                hint = " (a number in quotes is text in YAML: write it without the quotes)"
            self.fail(key, f"must be a number, got {kind_of(value)} {short_repr(value)}{hint}")
            return default
        try:
            x = float(value)
        except OverflowError:  # an integer literal beyond the float range
            x = math.inf
        if not math.isfinite(x):
            self.fail(key, f"must be finite, got {short_repr(value)}")
            return default
        if minimum is not None and (x <= minimum if exclusive_min else x < minimum):
            self.fail(key, f"must be {'>' if exclusive_min else '>='} {minimum:g}, got {x:g}")
            return default
        if maximum is not None and x > maximum:
            self.fail(key, f"must be <= {maximum:g}, got {x:g}")
            return default
        if within is not None and not within[0] <= x <= within[1]:
            self.fail(key, f"must be in [{within[0]:g}, {within[1]:g}]{' ' + unit if unit else ''} (what cgp_sim "
                      f"simulates: cgp_core.limits), got {x:g}")
            return default
        if within is None and maximum is None and abs(x) > MAX_MAGNITUDE:
            self.fail(key, f"must be within ±{MAX_MAGNITUDE:g} (cgp_core.limits), got {x:g}")
            return default
        return x

    def integer(self, value: Any, key: str, *, minimum: int | None = None, maximum: int | None = None,
                default: int = 0) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, f"must be an integer, got {kind_of(value)} {short_repr(value)}")
            return default
        if minimum is not None and value < minimum:
            self.fail(key, f"must be >= {minimum}, got {value}")
            return default
        if maximum is not None and value > maximum:
            self.fail(key, f"must be <= {maximum}, got {value}")
            return default
        return value

    def boolean(self, value: Any, key: str, default: bool = False) -> bool:
        if not isinstance(value, bool):
            self.fail(key, f"must be true or false, got {kind_of(value)} {short_repr(value)}")
            return default
        return value

    def string(self, value: Any, key: str, default: str = "") -> str:
        if not isinstance(value, str):
            self.fail(key, f"must be a string, got {kind_of(value)}")
            return default
        return value

    def choice(self, value: Any, key: str, options: list[str], default: str) -> str:
        s = self.string(value, key, default)
        if s not in options:
            self.fail(key, f"must be one of {', '.join(options)}, got {short_repr(s)}")
            return default
        return s

    def vector(self, value: Any, key: str, length: int, *, minimum: float | None = None,
               exclusive_min: bool = False, default: np.ndarray | None = None,
               within: tuple[float, float] | None = None, unit: str = "", max_norm: float | None = None) -> np.ndarray:
        fallback = np.zeros(length) if default is None else np.asarray(default, dtype=float)
        if not isinstance(value, (list, tuple)) or len(value) != length:
            self.fail(key, f"must be a list of {length} numbers, got {kind_of(value)} {short_repr(value)}")
            return fallback
        before = len(self.problems)
        out = np.array([self.number(x, f"{key}[{i}]", minimum=minimum, exclusive_min=exclusive_min, within=within,
                                    unit=unit) for i, x in enumerate(value)])
        if len(self.problems) > before:
            return fallback
        if max_norm is not None and float(np.linalg.norm(out)) > max_norm:
            self.fail(key, f"its magnitude must be at most {max_norm:g}{' ' + unit if unit else ''} (what cgp_sim "
                      f"simulates: cgp_core.limits), got {float(np.linalg.norm(out)):g}")
            return fallback
        return out

    def name(self, value: Any, key: str, seen: set[str]) -> str:
        if not isinstance(value, str):
            self.fail(key, f"must be a string (a ROS-safe name), got {kind_of(value)} {short_repr(value)}")
            return ""
        s = value
        if not ROS_SAFE_NAME.match(s):
            self.fail(key, f"{short_repr(s)} is not a ROS-safe name (letters, digits, _; starting with a letter)")
        elif len(s) > MAX_NAME_LENGTH:
            self.fail(key, f"{short_repr(s)} is {len(s)} characters long; names are at most {MAX_NAME_LENGTH}")
        elif s == GROUND_NAME:
            self.fail(key, f"{s!r} is reserved: it names the ground plane in contact reports")
        elif s in seen:
            self.fail(key, f"duplicate name {s!r} (body and flock names must be unique)")
        seen.add(s)
        return s

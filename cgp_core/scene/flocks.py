"""A scene's ``flocks``: each entry mapped onto :class:`cgp_core.boids.FlockParams` (Reynolds' rules or Couzin's
zones, the neighbourhood, bounds, spawn box), and the density check that bounds a flock's step
(:func:`flock_crowding`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..limits import (
    MAX_ACCELERATION,
    MAX_BOIDS_BRUTE,
    MAX_BOIDS_PER_FLOCK,
    MAX_COORDINATE,
    MAX_EXPECTED_NEIGHBORS,
    MAX_LENGTH,
    MAX_MAGNITUDE,
    MAX_SPEED,
)
from .validation import COORDINATES, Validator, kind_of


def parse_flocks(v: Validator, raw: Any, reserved: set[str]) -> list[Any]:
    if raw is None:
        return []
    if not isinstance(raw, list):
        v.fail("flocks", f"must be a list of flocks, got {kind_of(raw)}")
        return []
    seen = set(reserved)
    out = []
    for i, item in enumerate(raw):
        params = parse_flock(v, item, f"flocks[{i}]", seen)
        if params is not None:
            out.append(params)
    return out


# YAML key -> FlockParams field, for the flat keys (numbers unless listed in the other tables).
_FLOCK_NUMBERS = {
    "radius": ("radius", True), "separation_radius": ("separation_radius", True),
    "min_speed": ("min_speed", True), "max_speed": ("max_speed", True),
    "max_acceleration": ("max_acceleration", True), "fov_deg": ("fov_deg", True),
    "goal_weight": ("goal_weight", False), "obstacle_margin": ("obstacle_margin", False),
    "boid_size": ("boid_size", True), "bank_gain": ("bank_gain", False),
    "orientation_time_constant": ("orientation_time_constant", False),
    "fright_radius": ("fright_radius", False),
}
_FLOCK_KEYS = {"name", "count", "seed", "spawn", "weights", "bounds", "goal", "avoid_bodies", "model",
               "neighbor_search", "rules", "couzin", "neighbors", *_FLOCK_NUMBERS}
#: the upper ends of the flat flock numbers (cgp_core.limits; the others: MAX_MAGNITUDE): YAML key -> (max, unit)
_FLOCK_RANGES = {
    "radius": (MAX_LENGTH, "m"), "separation_radius": (MAX_LENGTH, "m"), "boid_size": (MAX_LENGTH, "m"),
    "obstacle_margin": (MAX_LENGTH, "m"), "fright_radius": (MAX_LENGTH, "m"),
    "min_speed": (MAX_SPEED, "m/s"), "max_speed": (MAX_SPEED, "m/s"),
    "max_acceleration": (MAX_ACCELERATION, "m/s²"), "goal_weight": (MAX_ACCELERATION, "m/s²"),
    "fov_deg": (360.0, "degrees"),
}
#: issue 14: keys of Reynolds' rules, which a Couzin flock does not use (its zones, speed and field of
#: perception are in its `couzin` block)
_REYNOLDS_ONLY_KEYS = ("radius", "separation_radius", "weights", "min_speed", "max_speed", "fov_deg", "goal",
                       "goal_weight")
#: YAML key of the `couzin` block -> (minimum, strictly greater) ; all numbers
_COUZIN_NUMBERS = {
    "repulsion_radius": (0.0, False), "orientation_width": (0.0, False), "attraction_width": (0.0, False),
    "field_of_view_deg": (0.0, True), "turning_rate_deg": (0.0, True), "speed": (0.0, True),
    "noise": (0.0, False),
}


def parse_flock(v: Validator, raw: Any, key: str, seen: set[str]):
    """One flock: the scene keys of the flock issue (nested ``spawn``, ``weights``, ``bounds``) mapped onto
    :class:`cgp_core.boids.FlockParams` (whose docstring documents every field, unit and default)."""
    from ..boids import BOUNDS_MODES, MODELS, NEIGHBOR_SEARCHES, FlockParams

    if not isinstance(raw, dict):
        v.fail(key, f"must be a mapping, got {kind_of(raw)}")
        return None
    before = len(v.problems)
    v.no_unknown_keys(raw, _FLOCK_KEYS, key)
    if "name" not in raw:
        v.fail(f"{key}.name", "missing")
    else:
        name = v.name(raw["name"], f"{key}.name", seen)
        key = f"{key} ({name})"
    kwargs: dict[str, Any] = {"name": raw.get("name", "flock")}
    if "count" not in raw:
        v.fail(f"{key}.count", "missing (number of boids)")
    else:
        kwargs["count"] = v.integer(raw["count"], f"{key}.count", minimum=1, maximum=MAX_BOIDS_PER_FLOCK, default=1)
    if "seed" in raw:
        kwargs["seed"] = v.integer(raw["seed"], f"{key}.seed", minimum=0, maximum=2**63 - 1)
    for yaml_key, (field_name, strictly_positive) in _FLOCK_NUMBERS.items():
        if yaml_key in raw:
            top, unit = _FLOCK_RANGES.get(yaml_key, (MAX_MAGNITUDE, ""))
            kwargs[field_name] = v.number(raw[yaml_key], f"{key}.{yaml_key}", minimum=0.0,
                                          exclusive_min=strictly_positive, default=1.0, within=(0.0, top), unit=unit)
    spawn = v.mapping(raw.get("spawn"), f"{key}.spawn")
    v.no_unknown_keys(spawn, {"center", "extent"}, f"{key}.spawn")
    if "center" in spawn:
        kwargs["spawn_center"] = v.vector(spawn["center"], f"{key}.spawn.center", 3, within=COORDINATES, unit="m")
    if "extent" in spawn:
        kwargs["spawn_extent"] = v.vector(spawn["extent"], f"{key}.spawn.extent", 3, minimum=0.0,
                                          within=(0.0, MAX_COORDINATE), unit="m")
    weights = v.mapping(raw.get("weights"), f"{key}.weights")
    v.no_unknown_keys(weights, {"cohesion", "separation", "alignment"}, f"{key}.weights")
    for rule in ("cohesion", "separation", "alignment"):
        if rule in weights:
            kwargs[f"{rule}_weight"] = v.number(weights[rule], f"{key}.weights.{rule}", minimum=0.0)
    bounds = v.mapping(raw.get("bounds"), f"{key}.bounds")
    v.no_unknown_keys(bounds, {"min", "max", "mode", "margin", "strength"}, f"{key}.bounds")
    if "min" in bounds:
        kwargs["bounds_min"] = v.vector(bounds["min"], f"{key}.bounds.min", 3, within=COORDINATES, unit="m")
    if "max" in bounds:
        kwargs["bounds_max"] = v.vector(bounds["max"], f"{key}.bounds.max", 3, within=COORDINATES, unit="m")
    if "mode" in bounds:
        kwargs["bounds_mode"] = v.choice(bounds["mode"], f"{key}.bounds.mode", list(BOUNDS_MODES), "soft")
    for sub in ("margin", "strength"):
        if sub in bounds:
            kwargs[f"bounds_{sub}"] = v.number(bounds[sub], f"{key}.bounds.{sub}", minimum=0.0, within=(
                0.0, MAX_LENGTH if sub == "margin" else MAX_ACCELERATION), unit="m" if sub == "margin" else "m/s²")
    if raw.get("goal") is not None:
        kwargs["goal"] = v.vector(raw["goal"], f"{key}.goal", 3, within=COORDINATES, unit="m")
    if "avoid_bodies" in raw:
        kwargs["avoid_bodies"] = v.boolean(raw["avoid_bodies"], f"{key}.avoid_bodies", True)
    if "model" in raw:
        kwargs["model"] = v.choice(raw["model"], f"{key}.model", list(MODELS), "sphere")
    if "neighbor_search" in raw:
        kwargs["neighbor_search"] = v.choice(raw["neighbor_search"], f"{key}.neighbor_search",
                                             list(NEIGHBOR_SEARCHES), "grid")
    _parse_flock_rules(v, raw, key, kwargs)
    if len(v.problems) > before:
        return None
    try:  # relations between fields (separation < radius, spawn box inside bounds, ...)
        params = FlockParams(**kwargs)
    except ValueError as exc:
        v.fail(key, str(exc).split(": ", 1)[-1])
        return None
    if params.neighbor_search == "brute" and params.count > MAX_BOIDS_BRUTE:
        v.fail(f"{key}.neighbor_search", f"brute (the O(N²) reference search) is for flocks of at most "
               f"{MAX_BOIDS_BRUTE} boids (cgp_core.limits), this one has {params.count}: use grid or kdtree")
        return None
    crowding = flock_crowding(params)
    if crowding is not None:
        v.fail(f"{key}.count", crowding)
        return None
    return params


def flock_crowding(params) -> str | None:
    """Why a flock is too dense to step in bounded time (None if it is not): its expected neighbours per boid,
    N (4/3)π r³ / V, at its spawn density (V: the spawn box, each side taken as at least 2 r) and, with walls
    (soft / wrap bounds), at the density of its bounds box, must be at most MAX_EXPECTED_NEIGHBORS (a step
    costs N times that: :mod:`cgp_core.limits`)."""
    r = float(params.radius)
    ball = 4.0 / 3.0 * math.pi * r ** 3
    boxes = [("its spawn box", np.maximum(params.spawn_extent, 2.0 * r))]
    if params.bounds_mode != "none":
        boxes.append(("its bounds", np.maximum(params.bounds_max - params.bounds_min, 2.0 * r)))
    for where, size in boxes:
        expected = params.count * min(1.0, ball / float(np.prod(size)))
        if expected > MAX_EXPECTED_NEIGHBORS:
            return (f"{params.count} boids with a neighbourhood radius of {r:g} m would have ~{expected:.0f} "
                    f"neighbours each at the density of {where} ({' x '.join(f'{x:g}' for x in size)} m); at most "
                    f"{MAX_EXPECTED_NEIGHBORS} (a step costs N times that: cgp_core.limits): fewer boids, a larger "
                    "box or a smaller radius")
    return None


def _parse_flock_rules(v: Validator, raw: dict, key: str, kwargs: dict) -> None:
    """Issue 14's flock keys: ``rules`` and its ``couzin`` block, ``neighbors: {mode, k}`` (``fright_radius``
    is a plain number above)."""
    from ..boids.params import NEIGHBOR_MODES, RULES, CouzinParams

    rules = v.choice(raw["rules"], f"{key}.rules", list(RULES), "reynolds") if "rules" in raw else "reynolds"
    kwargs["rules"] = rules
    if rules == "couzin":
        for reynolds_key in _REYNOLDS_ONLY_KEYS:
            if reynolds_key in raw:
                v.fail(f"{key}.{reynolds_key}", "does not apply to rules: couzin (its zones, speed and field of "
                       "perception are set in the couzin block)")
        block = v.mapping(raw.get("couzin"), f"{key}.couzin")
        v.no_unknown_keys(block, set(_COUZIN_NUMBERS), f"{key}.couzin")
        values = {}
        for name, (minimum, strict) in _COUZIN_NUMBERS.items():
            if name in block:
                top, unit = {"speed": (MAX_SPEED, "m/s"), "field_of_view_deg": (360.0, "degrees")}.get(
                    name, (MAX_LENGTH, "m") if name.endswith(("_radius", "_width")) else (MAX_MAGNITUDE, ""))
                values[name] = v.number(block[name], f"{key}.couzin.{name}", minimum=minimum,
                                        exclusive_min=strict, default=1.0, within=(0.0, top), unit=unit)
        if "field_of_view_deg" in values and values["field_of_view_deg"] > 360.0:
            v.fail(f"{key}.couzin.field_of_view_deg", f"must be <= 360, got {values['field_of_view_deg']:g}")
            values.pop("field_of_view_deg")
        try:
            kwargs["couzin"] = CouzinParams(**values)
        except ValueError as exc:
            v.fail(f"{key}.couzin", str(exc).removeprefix("couzin: "))
    elif "couzin" in raw:
        v.fail(f"{key}.couzin", f"only applies to rules: couzin (this flock's rules: {rules})")
    neighbors = v.mapping(raw.get("neighbors"), f"{key}.neighbors")
    v.no_unknown_keys(neighbors, {"mode", "k"}, f"{key}.neighbors")
    if "mode" in neighbors:
        kwargs["neighbor_mode"] = v.choice(neighbors["mode"], f"{key}.neighbors.mode", list(NEIGHBOR_MODES),
                                           "metric")
    if "k" in neighbors:
        # kept with mode: metric too (unused there), so switching the mode is a one-word edit
        kwargs["neighbor_k"] = v.integer(neighbors["k"], f"{key}.neighbors.k", minimum=1, maximum=1000, default=7)

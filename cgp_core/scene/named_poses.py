"""``named_poses`` entries: poses a scene names for spawning, navigation goals and the like (what
``simulation_interfaces``' ``GetNamedPoses`` / ``GetNamedPoseBounds`` answer).

An entry::

    named_poses:
      - name: dock                      # ROS-safe, unique among the named poses
        position: [4.0, -2.0, 0.0]      # world frame [m]
        orientation: [0, 0, 0, 1]       # optional (x, y, z, w), normalized; default identity
        description: next to the pillar # optional
        tags: [spawn, robot]            # optional, strings
        bounds: {min: [-1, -1, 0], max: [1, 1, 2]}   # optional: a box about the position (world axes) ...
        # bounds: {radius: 1.5}                      # ... or a sphere centred on it

The names live apart from the entities' (a pose may be named like a body: they are looked up by different
services).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..limits import MAX_COORDINATE, MAX_LENGTH, MAX_NAME_LENGTH
from ..rotation import quat_normalize
from .validation import Validator, kind_of

#: the keys of a named pose, and of its bounds
NAMED_POSE_KEYS = {"name", "position", "orientation", "description", "tags", "bounds"}
BOUNDS_KEYS = {"min", "max", "radius"}
#: at most this many named poses per scene, tags per pose, characters per description or tag (they travel in
#: every GetNamedPoses reply)
MAX_NAMED_POSES = 1000
MAX_TAGS = 32
MAX_TEXT_LENGTH = 1000


@dataclass(frozen=True)
class NamedPoseBounds:
    """A box ``lower`` .. ``upper`` (each (3,), relative to the pose's position, world axes) or a sphere of
    ``radius`` about the position (``lower`` / ``upper`` None)."""

    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    radius: float | None = None


@dataclass(frozen=True)
class NamedPoseSpec:
    name: str
    position: np.ndarray  # (3,) world [m]
    orientation: np.ndarray  # (4,) x, y, z, w, normalized
    description: str = ""
    tags: tuple[str, ...] = ()
    bounds: NamedPoseBounds | None = None


def parse_named_poses(v: Validator, raw: Any) -> list[NamedPoseSpec]:
    if raw is None:
        return []
    if not isinstance(raw, list):
        v.fail("named_poses", f"must be a list of named poses, got {kind_of(raw)}")
        return []
    if len(raw) > MAX_NAMED_POSES:
        v.fail("named_poses", f"{len(raw)} entries; a scene names at most {MAX_NAMED_POSES} poses")
        return []
    seen: set[str] = set()
    poses = [parse_named_pose(v, entry, f"named_poses[{i}]", seen) for i, entry in enumerate(raw)]
    return [p for p in poses if p is not None]


def parse_named_pose(v: Validator, raw: Any, key: str, seen: set[str]) -> NamedPoseSpec | None:
    if not isinstance(raw, dict):
        v.fail(key, f"must be a mapping (name, position, ...), got {kind_of(raw)}")
        return None
    v.no_unknown_keys(raw, NAMED_POSE_KEYS, key)
    before = len(v.problems)
    if "name" not in raw:
        v.fail(key, "missing key 'name'")
    else:
        name = raw["name"]
        if isinstance(name, str) and name in seen:  # (Validator.name's own duplicate text speaks of bodies)
            v.fail(f"{key}.name", f"duplicate named pose {name!r}")
        else:
            v.name(name, f"{key}.name", seen)
        if isinstance(name, str):
            key = f"{key} ({name[:MAX_NAME_LENGTH]})"
    if "position" not in raw:
        v.fail(key, "missing key 'position' ([x, y, z] in the world frame)")
    position = v.vector(raw.get("position", [0, 0, 0]), f"{key}.position", 3,
                        within=(-MAX_COORDINATE, MAX_COORDINATE), unit="m")
    q = v.vector(raw.get("orientation", [0, 0, 0, 1]), f"{key}.orientation", 4, default=np.array([0, 0, 0, 1.0]))
    if not np.any(q):
        v.fail(f"{key}.orientation", "zero quaternion (x, y, z, w); identity is [0, 0, 0, 1]")
        q = np.array([0, 0, 0, 1.0])
    description = _text(v, raw.get("description", ""), f"{key}.description")
    tags = parse_tags(v, raw.get("tags", []), f"{key}.tags")
    bounds = _bounds(v, raw["bounds"], f"{key}.bounds") if "bounds" in raw else None
    if len(v.problems) > before:
        return None
    return NamedPoseSpec(raw["name"], position, quat_normalize(q), description, tags, bounds)


def parse_tags(v: Validator, raw: Any, key: str) -> tuple[str, ...]:
    """A list of at most MAX_TAGS strings (a named pose's, a scene's ``tags:``)."""
    if not isinstance(raw, list):
        v.fail(key, f"must be a list of strings, got {kind_of(raw)}")
        return ()
    if len(raw) > MAX_TAGS:
        v.fail(key, f"{len(raw)} tags; at most {MAX_TAGS}")
        return ()
    return tuple(_text(v, t, f"{key}[{i}]") for i, t in enumerate(raw))


def _text(v: Validator, value: Any, key: str) -> str:
    text = v.string(value, key)
    if len(text) > MAX_TEXT_LENGTH:
        v.fail(key, f"{len(text)} characters; at most {MAX_TEXT_LENGTH}")
        return ""
    return text


def _bounds(v: Validator, raw: Any, key: str) -> NamedPoseBounds | None:
    if not isinstance(raw, dict):
        v.fail(key, f"must be a mapping: {{min: [x, y, z], max: [x, y, z]}} (a box about the position) or "
                    f"{{radius: r}} (a sphere), got {kind_of(raw)}")
        return None
    v.no_unknown_keys(raw, BOUNDS_KEYS, key)
    box, sphere = "min" in raw or "max" in raw, "radius" in raw
    if box == sphere:
        v.fail(key, "give either min and max (a box about the position) or radius (a sphere), not "
                    + ("both" if box else "neither"))
        return None
    if sphere:
        radius = v.number(raw["radius"], f"{key}.radius", minimum=0.0, exclusive_min=True, within=(0.0, MAX_LENGTH),
                          unit="m")
        return NamedPoseBounds(radius=radius)
    if "min" not in raw or "max" not in raw:
        v.fail(key, f"a box needs both min and max, missing {'min' if 'min' not in raw else 'max'}")
        return None
    before = len(v.problems)
    lower = v.vector(raw["min"], f"{key}.min", 3, within=(-MAX_LENGTH, MAX_LENGTH), unit="m")
    upper = v.vector(raw["max"], f"{key}.max", 3, within=(-MAX_LENGTH, MAX_LENGTH), unit="m")
    if len(v.problems) > before:
        return None
    if not np.all(lower < upper):
        axes = ", ".join("xyz"[i] for i in range(3) if not lower[i] < upper[i])
        v.fail(key, f"min must be below max on every axis; not on {axes} (min {lower.tolist()}, max "
                    f"{upper.tolist()})")
        return None
    return NamedPoseBounds(lower=lower, upper=upper)

"""A scene's ``bodies``: each entry's common keys (name, shape, mass or density, pose, velocities, material,
colour) and the closed-form shapes (sphere, box, capsule); the particle sets (:mod:`.particles`) and issue 25's
shapes (:mod:`.shapes`) fill their own parts of the :class:`~.specs.BodySpec`."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..bodies import Shape
from ..inertia import particle_mass_properties, shape_mass_properties
from ..limits import (
    MAX_BODIES,
    MAX_DENSITY,
    MAX_FRICTION,
    MAX_MASS,
    MAX_SPEED,
    MAX_SPIN,
    MIN_DENSITY,
    MIN_INERTIA_RATIO,
    MIN_MASS,
)
from ..rotation import quat_normalize, quat_rotate
from .particles import parse_particles
from .shapes import parse_issue25_shape
from .specs import BODY_KEYS, SHAPE_KEYS, BodySpec
from .validation import COORDINATES, LENGTHS, Validator, kind_of


def parse_bodies(v: Validator, raw: Any) -> list[BodySpec]:
    if raw is None:
        return []
    if not isinstance(raw, list):
        v.fail("bodies", f"must be a list of bodies, got {kind_of(raw)}")
        return []
    if len(raw) > MAX_BODIES:
        v.fail("bodies", f"{len(raw)} bodies; at most {MAX_BODIES}")
        return []
    seen: set[str] = set()
    out = []
    for i, item in enumerate(raw):
        spec = parse_body(v, item, f"bodies[{i}]", seen)
        if spec is not None:
            out.append(spec)
    return out


def parse_body(v: Validator, raw: Any, key: str, seen: set[str]) -> BodySpec | None:
    if not isinstance(raw, dict):
        v.fail(key, f"must be a mapping, got {kind_of(raw)}")
        return None
    before = len(v.problems)
    v.no_unknown_keys(raw, BODY_KEYS, key)
    if "name" not in raw:
        v.fail(f"{key}.name", "missing")
    name = v.name(raw.get("name", ""), f"{key}.name", seen) if "name" in raw else f"body{key}"
    key = f"{key} ({name})" if "name" in raw else key
    if "shape" in raw:
        shape_name = v.choice(raw["shape"], f"{key}.shape", list(SHAPE_KEYS), "sphere")
    else:
        v.fail(f"{key}.shape", f"missing (one of {', '.join(SHAPE_KEYS)})")
        shape_name = "sphere"
    for other, keys in SHAPE_KEYS.items():
        for k in keys - SHAPE_KEYS[shape_name]:
            if k in raw:
                v.fail(f"{key}.{k}", f"does not apply to shape {shape_name} (it is for {other})")

    fixed = v.boolean(raw.get("fixed", False), f"{key}.fixed")
    has_mass, has_density = "mass" in raw, "density" in raw
    mass = density = None
    if shape_name == "particles":
        for k in ("mass", "density"):
            if k in raw:
                v.fail(f"{key}.{k}", "particle bodies take their mass from the particles' 4th column")
    elif shape_name == "mesh":
        if not fixed:
            v.fail(f"{key}.fixed", "a static mesh must be fixed (fixed: true): it is not a solid, only a surface "
                   "(for a movable body from a mesh file use shape: convex with mesh:, its convex hull)")
        for k in ("mass", "density"):
            if k in raw:
                v.fail(f"{key}.{k}", "a static mesh is fixed and has no mass: leave it out")
    elif has_mass and has_density:
        v.fail(key, "give mass or density, not both")
    elif has_mass:
        mass = v.number(raw["mass"], f"{key}.mass", minimum=0.0, exclusive_min=True, default=1.0,
                        within=(MIN_MASS, MAX_MASS), unit="kg")
    elif has_density:
        density = v.number(raw["density"], f"{key}.density", minimum=0.0, exclusive_min=True, default=1000.0,
                           within=(MIN_DENSITY, MAX_DENSITY), unit="kg/m³")
    else:
        density = 1000.0  # water: a sensible default for a body given only its size

    spec = BodySpec(name=name, shape=Shape[shape_name.upper()], mass=1.0, inertia_body=np.eye(3))
    radius = half_length = None
    size = None
    if shape_name in ("sphere", "capsule"):
        if "radius" not in raw:
            v.fail(f"{key}.radius", "missing")
        else:
            radius = v.number(raw["radius"], f"{key}.radius", minimum=0.0, exclusive_min=True, default=0.1,
                              within=LENGTHS, unit="m")
    if shape_name == "capsule":
        if "length" not in raw:
            v.fail(f"{key}.length", "missing (length of the axis segment, without the caps)")
        else:
            half_length = 0.5 * v.number(raw["length"], f"{key}.length", minimum=0.0, exclusive_min=True,
                                         default=1.0, within=LENGTHS, unit="m")
    if shape_name == "box":
        if "size" not in raw:
            v.fail(f"{key}.size", "missing (full extents [x, y, z])")
        else:
            size = v.vector(raw["size"], f"{key}.size", 3, minimum=0.0, exclusive_min=True, default=np.ones(3),
                            within=LENGTHS, unit="m")

    if shape_name == "particles":
        spec.radius = v.number(raw.get("radius", 0.05), f"{key}.radius", minimum=0.0, exclusive_min=True,
                               default=0.05, within=LENGTHS, unit="m")
        particles = parse_particles(v, raw.get("particles"), f"{key}.particles")
        if particles is not None:
            try:
                total, com, inertia = particle_mass_properties(particles[:, :3], particles[:, 3])
            except ValueError as exc:
                v.fail(f"{key}.particles", str(exc))
            else:
                moments = np.linalg.eigvalsh(inertia)
                if not moments.min() >= MIN_INERTIA_RATIO * moments.max():
                    v.fail(f"{key}.particles", f"principal moments of inertia {moments.min():.3g} .. "
                           f"{moments.max():.3g} kg m²: a body this thin cannot be simulated (their ratio must be "
                           f"at least {MIN_INERTIA_RATIO:g}: cgp_core.limits)")
                spec.mass, spec.inertia_body = total, inertia
                spec.particles = particles.copy()
                spec.particles[:, :3] -= com
                spec.half_extents = np.abs(spec.particles[:, :3]).max(axis=0) + spec.radius
                spec.position = com  # body-frame COM offset; turned into a world position below
    elif shape_name in ("convex", "compound", "mesh"):
        if len(v.problems) == before:
            parse_issue25_shape(v, raw, key, shape_name, spec, mass, density)
        if len(v.problems) == before and shape_name != "mesh":  # the ranges every solid body is held to
            moments = np.linalg.eigvalsh(spec.inertia_body)
            if not moments.min() >= MIN_INERTIA_RATIO * moments.max():
                v.fail(key, f"principal moments of inertia {moments.min():.3g} .. {moments.max():.3g} kg m²: a body "
                       f"this thin cannot be simulated (their ratio must be at least {MIN_INERTIA_RATIO:g}: "
                       "cgp_core.limits)")
            if not MIN_MASS <= spec.mass <= MAX_MASS:
                v.fail(f"{key}.density", f"gives a mass of {spec.mass:g} kg; masses must be in [{MIN_MASS:g}, "
                       f"{MAX_MASS:g}] kg (what cgp_sim simulates: cgp_core.limits)")
    elif len(v.problems) == before:
        try:
            spec.mass, spec.inertia_body = shape_mass_properties(
                shape_name, radius=radius, size=size, half_length=half_length, mass=mass, density=density)
        except ValueError as exc:
            v.fail(key, str(exc))
        else:
            moments = np.linalg.eigvalsh(spec.inertia_body)
            if not moments.min() >= MIN_INERTIA_RATIO * moments.max():
                v.fail(key, f"principal moments of inertia {moments.min():.3g} .. {moments.max():.3g} kg m²: a body "
                       f"this thin cannot be simulated (their ratio must be at least {MIN_INERTIA_RATIO:g}: "
                       "cgp_core.limits; a 1 cm x 10 m pole has 2e-6)")
            if not MIN_MASS <= spec.mass <= MAX_MASS:
                v.fail(f"{key}.density", f"gives a mass of {spec.mass:g} kg; masses must be in [{MIN_MASS:g}, "
                       f"{MAX_MASS:g}] kg (what cgp_sim simulates: cgp_core.limits)")
        spec.radius = radius or 0.0
        if shape_name == "box":
            spec.half_extents = 0.5 * size
        elif shape_name == "capsule":
            spec.half_extents = np.array([0.0, 0.0, half_length])

    origin = v.vector(raw.get("position", [0, 0, 0]), f"{key}.position", 3, within=COORDINATES, unit="m")
    q = v.vector(raw.get("orientation", [0, 0, 0, 1]), f"{key}.orientation", 4, default=np.array([0, 0, 0, 1.0]))
    if np.linalg.norm(q) < 1e-9:
        v.fail(f"{key}.orientation", "zero quaternion (x, y, z, w); identity is [0, 0, 0, 1]")
        q = np.array([0.0, 0.0, 0.0, 1.0])
    spec.orientation = quat_normalize(q)
    spec.position = origin + quat_rotate(spec.orientation, spec.position)  # COM in world
    spec.linear_velocity = v.vector(raw.get("linear_velocity", [0, 0, 0]), f"{key}.linear_velocity", 3,
                                    max_norm=MAX_SPEED, unit="m/s")
    spec.angular_velocity = v.vector(raw.get("angular_velocity", [0, 0, 0]), f"{key}.angular_velocity", 3,
                                     max_norm=MAX_SPIN, unit="rad/s")
    rim_speed = float(np.linalg.norm(spec.linear_velocity) + np.linalg.norm(spec.angular_velocity) * body_reach(
        spec.shape, spec.radius, spec.half_extents))
    if rim_speed > MAX_SPEED:
        v.fail(f"{key}.angular_velocity", f"its surface would move at up to {rim_speed:.4g} m/s (|v| + |ω| times "
               f"its reach); at most {MAX_SPEED:g} m/s (what cgp_sim simulates: cgp_core.limits)")
    spec.restitution = v.number(raw.get("restitution", 0.3), f"{key}.restitution", minimum=0.0, maximum=1.0)
    spec.friction = v.number(raw.get("friction", 0.5), f"{key}.friction", minimum=0.0, default=0.5,
                             within=(0.0, MAX_FRICTION))
    spec.fixed = fixed
    spec.predator = v.boolean(raw.get("predator", False), f"{key}.predator")
    if "color" in raw:
        spec.color = v.vector(raw["color"], f"{key}.color", 4, minimum=0.0, default=spec.color)
        if np.any(spec.color > 1.0):
            v.fail(f"{key}.color", "RGBA components must be in [0, 1]")
    return spec if len(v.problems) == before else None


def body_reach(shape, radius: float, half_extents) -> float:
    """The farthest a body's surface is from its COM [m] (a particle body: a bound, from its half extents)."""
    half = np.asarray(half_extents, dtype=float)
    if shape == Shape.SPHERE:
        return float(radius)
    if shape == Shape.CAPSULE:
        return float(half[2] + radius)
    return float(np.linalg.norm(half))

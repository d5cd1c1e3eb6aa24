"""Build a BodyModel / BodyState directly (no scene file) for the collision and contact tests.

Closed-form inertia of homogeneous solids, one line each (about the COM, shape axes).
"""

from __future__ import annotations

import numpy as np

from cgp_core.bodies import BodyModel, BodyState, Shape
from cgp_core.rotation import quat_to_matrix


def sphere(radius, mass=1.0, **kw):
    return dict(shape=Shape.SPHERE, radius=radius, half_extents=(0.0, 0.0, 0.0), mass=mass,
                inertia=np.eye(3) * 0.4 * mass * radius ** 2, **kw)


def box(half_extents, mass=1.0, **kw):
    hx, hy, hz = half_extents
    inertia = np.diag([hy ** 2 + hz ** 2, hx ** 2 + hz ** 2, hx ** 2 + hy ** 2]) * mass / 3.0
    return dict(shape=Shape.BOX, radius=0.0, half_extents=tuple(half_extents), mass=mass, inertia=inertia, **kw)


def capsule(radius, half_length, mass=1.0, **kw):
    # a solid cylinder of the same length is close enough for the tests that use capsules
    across = mass * (3 * radius ** 2 + (2 * half_length) ** 2) / 12.0
    return dict(shape=Shape.CAPSULE, radius=radius, half_extents=(0.0, 0.0, half_length), mass=mass,
                inertia=np.diag([across, across, 0.5 * mass * radius ** 2]), **kw)


def particles(points, radius, **kw):
    """A particle body: ``points`` (k, 4) [x, y, z, m] in any frame; moved to the COM here."""
    pts = np.asarray(points, dtype=float)
    mass = pts[:, 3].sum()
    com = (pts[:, :3] * pts[:, 3:]).sum(0) / mass
    rel = pts[:, :3] - com
    inertia = sum(m * (r @ r * np.eye(3) - np.outer(r, r)) for r, m in zip(rel, pts[:, 3]))
    inertia = inertia + np.eye(3) * 0.4 * pts[:, 3].min() * radius ** 2  # the particles' own spheres
    extent = np.abs(rel).max(0) + radius
    return dict(shape=Shape.PARTICLES, radius=radius, half_extents=tuple(extent), mass=mass, inertia=inertia,
                particles=np.column_stack((rel, pts[:, 3])), position_offset=com, **kw)


def make_bodies(specs: list[dict]) -> tuple[BodyModel, BodyState]:
    """Model and state from a list of dicts made by :func:`sphere` / :func:`box` / ... with optional keys
    ``position``, ``orientation`` (x, y, z, w), ``velocity``, ``angular_velocity``, ``restitution``,
    ``friction``, ``fixed``."""
    n = len(specs)
    fixed = np.array([bool(s.get("fixed", False)) for s in specs])
    mass = np.array([float(s["mass"]) for s in specs])
    inertia = np.stack([np.asarray(s["inertia"], float) for s in specs])
    inv_mass = np.where(fixed, 0.0, 1.0 / mass)
    inv_inertia = np.linalg.inv(inertia)
    inv_inertia[fixed] = 0.0
    model = BodyModel(
        names=[s.get("name", f"body{i}") for i, s in enumerate(specs)],
        shape=np.array([int(s["shape"]) for s in specs], dtype=np.int8),
        radius=np.array([float(s["radius"]) for s in specs]),
        half_extents=np.array([s["half_extents"] for s in specs], dtype=float),
        mass=mass, inv_mass=inv_mass, inertia_body=inertia, inv_inertia_body=inv_inertia,
        restitution=np.array([float(s.get("restitution", 0.0)) for s in specs]),
        friction=np.array([float(s.get("friction", 0.5)) for s in specs]),
        fixed=fixed,
        particles=[s.get("particles") for s in specs],
        color=np.ones((n, 4)),
    )
    position = np.array([np.add(s.get("position", (0, 0, 0)), s.get("position_offset", 0.0)) for s in specs],
                        dtype=float)
    orientation = np.array([s.get("orientation", (0, 0, 0, 1)) for s in specs], dtype=float)
    orientation /= np.linalg.norm(orientation, axis=1, keepdims=True)
    velocity = np.array([s.get("velocity", (0, 0, 0)) for s in specs], dtype=float)
    omega = np.array([s.get("angular_velocity", (0, 0, 0)) for s in specs], dtype=float)
    R = quat_to_matrix(orientation)
    inertia_world = R @ inertia @ np.swapaxes(R, 1, 2)
    movable = (~fixed)[:, None]
    state = BodyState(position=position, orientation=orientation,
                      linear_momentum=velocity * mass[:, None] * movable,
                      angular_momentum=np.einsum("nij,nj->ni", inertia_world, omega) * movable)
    return model, state


def mechanical_energy(model: BodyModel, state: BodyState, g: float = 9.81) -> float:
    """Kinetic + gravitational potential energy (z up) of the movable bodies."""
    movable = model.inv_mass > 0
    kinetic = state.kinetic_energy(model)[movable].sum()
    return float(kinetic + g * (model.mass[movable] * state.position[movable, 2]).sum())

"""A robot's links as bodies of the world's :class:`~cgp_core.bodies.BodyModel`: what collides, is drawn and
reported like any body, while its motion comes from the robot's joint space (:mod:`cgp_core.robots.world`).

Each body of a :class:`~cgp_core.robots.model.RobotModel` that has collision geometry becomes one compound body
named ``<robot>/<link>``: body frame = the link's axes with the origin moved to the link's centre of mass (the
convention of every body in :mod:`cgp_core.bodies`), mass and inertia from the URDF's ``<inertial>`` (not from
the geometry's volume: a URDF's collision shapes are often coarse or hollow), parts from ``<collision>``:

- ``box`` and ``sphere``: the compound part of that shape;
- ``cylinder``: the convex hull of a prism with :data:`CYLINDER_SIDES` sides around it (cgp_sim has no cylinder
  kernel; a capsule would add round caps a cylinder does not have);
- ``mesh``: the convex hull of the file's vertices (STL / OBJ read by :mod:`cgp_core.collision.meshfile`), as
  PyBullet and MuJoCo do with a link's collision mesh by default.

A body without collision geometry is no body of the world (nothing can touch it); its frame is still published.
A fixed root is a fixed body (it never moves: the world's contacts with it are the body solver's).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..bodies import CompoundParts, Shape
from ..collision.convex import centred_hull, convex_hull
from ..collision.meshfile import MeshFileError, load_mesh
from ..scene.shapes import compound_half_extents
from ..scene.specs import BodySpec
from .model import JOINT_FIXED_ROOT

#: sides of the prism that stands for a URDF cylinder
CYLINDER_SIDES = 16
#: the grey of a link without a URDF colour
LINK_COLOR = np.array([0.75, 0.75, 0.78, 1.0])


class Part(NamedTuple):
    """One compound part of a link body, in the link's frame."""

    shape: int             # Shape.BOX, SPHERE or CONVEX
    centre: np.ndarray     # (3,) [m] (a hull's: its COM)
    rotation: np.ndarray   # (3, 3) the part's axes in the link's
    radius: float          # sphere radius [m]; 0 otherwise
    half_extents: np.ndarray  # (3,) box half sizes [m]; zeros otherwise
    hull: object           # a CONVEX part's ConvexPolyhedron about its COM, None otherwise


class LinkGeometryError(ValueError):
    """A link's collision geometry that cannot be built (names the link and why)."""


def link_name(robot: str, link: str) -> str:
    """The world body name of ``link`` of ``robot``."""
    return f"{robot}/{link}"


def cylinder_points(radius: float, length: float) -> np.ndarray:
    """(2 × CYLINDER_SIDES, 3) corners of the prism circumscribing nothing less than the cylinder's ends: the
    polygon's vertices on the circle (its edges cut inside by at most r (1 − cos(π / sides)), 1.9 % at 16)."""
    angle = np.linspace(0.0, 2.0 * np.pi, CYLINDER_SIDES, endpoint=False)
    ring = np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)
    top = np.column_stack([ring, np.full(CYLINDER_SIDES, 0.5 * length)])
    bottom = np.column_stack([ring, np.full(CYLINDER_SIDES, -0.5 * length)])
    return np.vstack([top, bottom])


def _part(geometry, robot: str, cache: dict) -> Part:
    """The :class:`Part` of one collision geometry."""
    kind = geometry.kind
    R = np.asarray(geometry.rotation, dtype=float)
    p = np.asarray(geometry.position, dtype=float)
    size = np.asarray(geometry.size, dtype=float).ravel()
    if kind == "box":
        return Part(Shape.BOX, p, R, 0.0, 0.5 * size[:3], None)
    if kind == "sphere":
        return Part(Shape.SPHERE, p, R, float(size[0]), np.zeros(3), None)
    if kind == "cylinder":
        points = cylinder_points(float(size[0]), float(size[1]))
    elif kind == "mesh":
        path = geometry.mesh_path
        if path is None:
            raise LinkGeometryError(f"robot {robot}: link {geometry.link}: a mesh without a file")
        key = str(path)
        if key not in cache:
            try:
                cache[key] = load_mesh(path)[0]
            except MeshFileError as exc:
                raise LinkGeometryError(f"robot {robot}: link {geometry.link}: {exc}") from None
        points = cache[key] * np.asarray(geometry.mesh_scale, dtype=float)
    else:
        raise LinkGeometryError(f"robot {robot}: link {geometry.link}: unknown collision geometry {kind!r}")
    hull, _, com, _ = centred_hull(convex_hull(points, what=f"robot {robot}: link {geometry.link}: {kind}"),
                                   density=1.0)
    return Part(Shape.CONVEX, p + R @ com, R, 0.0, np.zeros(3), hull)


def link_body_specs(model, robot: str, rotation: np.ndarray, position: np.ndarray, *, friction: float,
                    restitution: float) -> tuple[list[BodySpec], np.ndarray]:
    """The world bodies of a robot's links at the body poses ``rotation (n, 3, 3)``, ``position (n, 3)`` (link
    frames in the world, :func:`cgp_core.robots.algorithms.forward_kinematics`).

    Returns ``(specs, body_of_spec)``: one :class:`~cgp_core.scene.specs.BodySpec` per robot body with collision
    geometry, and for each the index of the robot body it is."""
    specs, owners, cache = [], [], {}
    for i, geometries in enumerate(model.collisions):
        if not geometries:
            continue
        parts = [_part(g, robot, cache) for g in geometries]
        com = np.asarray(model.com[i], dtype=float)
        fixed = int(model.joint_type[i]) == JOINT_FIXED_ROOT
        mass = float(model.mass[i])
        inertia = np.asarray(model.inertia[i], dtype=float)
        if fixed and mass <= 0.0:  # a massless fixed root: drawn and collided with, never moved
            mass, inertia = 1.0, np.eye(3)
        rgba = next((g.rgba for g in model.visuals[i] if g.rgba is not None), None)
        compound = CompoundParts(
            shape=np.array([int(p.shape) for p in parts], np.int8),
            position=np.array([p.centre - com for p in parts]),
            rotation=np.array([p.rotation for p in parts]),
            radius=np.array([p.radius for p in parts]),
            half_extents=np.array([p.half_extents for p in parts]),
            hulls=[p.hull for p in parts],
            mass=np.full(len(parts), mass / len(parts)),
        )
        R = rotation[i]
        specs.append(BodySpec(
            name=link_name(robot, model.body_names[i]), shape=Shape.COMPOUND, mass=mass, inertia_body=inertia,
            half_extents=compound_half_extents(compound), position=position[i] + R @ com,
            orientation=_quat(R), restitution=restitution, friction=friction, fixed=fixed,
            color=np.asarray(rgba, dtype=float) if rgba is not None else LINK_COLOR.copy(), parts=compound))
        owners.append(i)
    return specs, np.array(owners, dtype=np.int64)


def _quat(R: np.ndarray) -> np.ndarray:
    from ..rotation import matrix_to_quat

    return matrix_to_quat(np.asarray(R, dtype=float)[None])[0]

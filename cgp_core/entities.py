"""What a world says about its entities beyond their state (``simulation_interfaces``' ``GetEntityInfo`` /
``SetEntityInfo`` / ``GetEntityBounds``, without ROS): an entity's category, description and tags
(:class:`EntityInfo`), and the box that holds a body's shape in its own frame (:func:`body_frame_bounds`, from
the shapes' closed forms and vertices).  :class:`~cgp_core.world.World` keeps the info per entity and answers the
queries (``entity_info``, ``set_entity_info``, ``entity_bounds``).

Categories are the standard's (``simulation_interfaces/msg/EntityCategory``), by name here: ``object`` (0),
``robot`` (1), ``human`` (2), ``dynamic_object`` (4), ``static_object`` (5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bodies import BodyModel, Shape
from .editing import EditError

#: category name -> the standard's number (simulation_interfaces/msg/EntityCategory)
CATEGORIES = {"object": 0, "robot": 1, "human": 2, "dynamic_object": 4, "static_object": 5}
#: bounds on what set_entity_info stores (it travels in every GetEntityInfo reply)
MAX_INFO_TAGS = 32
MAX_INFO_TEXT = 1000


@dataclass(frozen=True)
class EntityInfo:
    """An entity's category (a key of :data:`CATEGORIES`), a human-readable description and tags."""

    category: str
    description: str = ""
    tags: tuple[str, ...] = ()


def check_info(category: str, description: str, tags) -> EntityInfo:
    """An :class:`EntityInfo`, or :class:`EditError` ``invalid_info`` naming what was wrong."""
    if category not in CATEGORIES:
        raise EditError("invalid_info", f"category {category!r}: not one of {', '.join(CATEGORIES)}")
    if not isinstance(description, str) or len(description) > MAX_INFO_TEXT:
        raise EditError("invalid_info", f"description: at most {MAX_INFO_TEXT} characters, got "
                        f"{len(description) if isinstance(description, str) else type(description).__name__}")
    tags = tuple(tags)
    if len(tags) > MAX_INFO_TAGS:
        raise EditError("invalid_info", f"tags: at most {MAX_INFO_TAGS}, got {len(tags)}")
    for i, tag in enumerate(tags):
        if not isinstance(tag, str) or not tag or len(tag) > MAX_INFO_TEXT:
            raise EditError("invalid_info", f"tags[{i}]: a tag is a non-empty string of at most {MAX_INFO_TEXT} "
                            "characters")
    return EntityInfo(category, description, tags)


def tags_match(tags, wanted, match_all: bool) -> bool:
    """``simulation_interfaces/msg/TagsFilter``: no ``wanted`` tags match everything; else any of them
    (``match_all`` False: FILTER_MODE_ANY) or all of them (FILTER_MODE_ALL) must be among ``tags``."""
    if not wanted:
        return True
    have = set(tags)
    return all(t in have for t in wanted) if match_all else any(t in have for t in wanted)


_SHAPE_NAMES = {Shape.SPHERE: "sphere", Shape.BOX: "box", Shape.CAPSULE: "capsule", Shape.PARTICLES: "particle",
                Shape.CONVEX: "convex", Shape.COMPOUND: "compound", Shape.MESH: "static mesh"}


def default_body_info(model: BodyModel, i: int, robot: str | None) -> EntityInfo:
    """What an entity is before anyone says otherwise: a robot's link is ``robot``, a fixed body
    ``static_object``, any other body ``object``."""
    name = model.names[i]
    if robot is not None:
        return EntityInfo("robot", f"link {name.split('/', 1)[1]} of robot {robot}")
    shape = _SHAPE_NAMES.get(Shape(int(model.shape[i])), "body")
    if model.fixed[i]:
        return EntityInfo("static_object", f"fixed {shape} body")
    return EntityInfo("object", f"{shape} body, {float(model.mass[i]):g} kg")


def body_frame_bounds(model: BodyModel, i: int) -> tuple[np.ndarray, np.ndarray]:
    """``(lower, upper)`` (3,) each: the smallest axis-aligned box, in body ``i``'s own frame (origin at its COM,
    its axes; a static mesh: its file's frame), that holds its shape.  Closed forms for spheres, boxes and
    capsules; a hull's and a mesh's vertices; a particle body's spheres; a compound body's parts, each turned
    into the body's axes (a box part's box turned, which holds it exactly: its corners are on it)."""
    shape = Shape(int(model.shape[i]))
    if shape == Shape.SPHERE:
        r = float(model.radius[i])
        return np.full(3, -r), np.full(3, r)
    if shape == Shape.BOX:
        half = np.asarray(model.half_extents[i], dtype=float)
        return -half, half.copy()
    if shape == Shape.CAPSULE:
        r = float(model.radius[i])
        half = np.array([r, r, float(model.half_extents[i][2]) + r])
        return -half, half
    if shape == Shape.PARTICLES:
        points = np.asarray(model.particles[i])[:, :3]
        r = float(model.radius[i])
        return points.min(axis=0) - r, points.max(axis=0) + r
    if shape == Shape.CONVEX:
        vertices = model.hulls[i].vertices
        return vertices.min(axis=0), vertices.max(axis=0)
    if shape == Shape.MESH:
        vertices = model.meshes[i].vertices
        return vertices.min(axis=0), vertices.max(axis=0)
    parts = model.parts[i]
    lower, upper = np.full(3, np.inf), np.full(3, -np.inf)
    for k in range(parts.count):
        R, p = parts.rotation[k], parts.position[k]
        if parts.hulls[k] is not None:
            corners = parts.hulls[k].vertices @ R.T + p
            lo, hi = corners.min(axis=0), corners.max(axis=0)
        else:  # sphere: radius; box: |R| half; capsule: |R| (0, 0, half_length) + radius
            half = np.abs(R) @ parts.half_extents[k] + parts.radius[k]
            lo, hi = p - half, p + half
        lower, upper = np.minimum(lower, lo), np.maximum(upper, hi)
    return lower, upper


def box_corners(lower, upper) -> np.ndarray:
    """(8, 3): the corners of the box ``lower`` .. ``upper``."""
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    pick = np.array([[(k >> a) & 1 for a in range(3)] for k in range(8)], dtype=bool)
    return np.where(pick, upper, lower)
